// daemon_bench: cdprd's RT cycle and a full calibration, in one process with the virtual robot
// (tests/daemon/virtual_cell.hpp: in-process CAN bus, manual clock, laser over loopback TCP).
//
//   daemon_bench [--cycles N] [--calibration-only] [--measuring "{poses: 25, ...}"]
//   daemon_bench --compare-tension-control "{gain: 20}" [--cycles N] [--rounds R]
//
// The second form prints only the cycle's compute time, holding and moving, without and with the
// tension control in the null space (the daemon's tension_control group as given), two daemons
// measured in alternating rounds of the same run (default 3) so both see the same machine load.
//
// Prints (figures, not assertions):
// - the compute time of Daemon::cycle (tension QP + compensated IK with pulleys for 8 cables,
//   8 drives and the force node through the CANopen master, tension watch, stillness test),
//   holding and moving, against the master's cycle alone (the I/O baseline, measured the same
//   way in the same run) and against the 10 us target;
// - a full 25-pose calibration: robot time of the measuring sequence (moves, settling, tension
//   regulation, averaging, laser), of the identification and diagnosis (the robot holds), wall
//   time; the sum of the planned move durations as the lower bound of the sequence;
// - the memory the process holds (VmRSS, VmHWM) before and after.
// The wake-up latency of the RT loop at 250 Hz is bench/rt_loop_bench's figure.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "virtual_cell.hpp"

namespace {

using namespace cdpr;
using namespace cdpr::controller;
using WallClock = std::chrono::steady_clock;

long status_kib(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key, 0) == 0) return std::stol(line.substr(std::strlen(key) + 1));
  }
  return -1;
}

struct Percentiles {
  double p50, p99, max;
};
Percentiles percentiles(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  auto at = [&](double q) {
    return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
  };
  return {at(0.5), at(0.99), v.back()};
}

// Times `n` calls of `f` (us), the robot stepped between them (not timed).
template <typename F>
std::vector<double> time_cycles(testing::VirtualCell& cell, int n, F&& f) {
  std::vector<double> us;
  us.reserve(static_cast<std::size_t>(n));
  for (int c = 0; c < n; ++c) {
    const auto t0 = WallClock::now();
    f();
    us.push_back(std::chrono::duration<double, std::micro>(WallClock::now() - t0).count());
    const can::Timestamp next = cell.clock.now() + cell.network.sync_period;
    while (cell.clock.now() < next) cell.idle();
  }
  return us;
}

void print(const char* what, const Percentiles& p, double baseline_p50) {
  std::printf("  %-44s p50 %6.2f us  p99 %6.2f us  max %7.2f us  (p50 x%.1f the master alone)\n",
              what, p.p50, p.p99, p.max, p.p50 / baseline_p50);
}

// Daemon::cycle's compute time along moves there and back along x; false: a move was refused.
bool time_moves(testing::VirtualCell& cell, std::vector<double>& moving) {
  Daemon& d = *cell.daemon;
  for (double x : {0.08, -0.08, 0.0}) {
    const Reply r = cell.request("move", {{"pose", {x, 0.02, 0.0, 0.0, 0.0, 0.0}}});
    if (!r.ok) {
      std::fprintf(stderr, "daemon_bench: move: %s\n", r.message.c_str());
      return false;
    }
    for (int c = 0; c < 5; ++c) cell.cycle();  // taken at the next cycle boundary
    while (d.rt().snapshot().mode == RtMode::kMoving) {
      moving.push_back(time_cycles(cell, 1, [&] { d.cycle(cell.clock.now()); })[0]);
      d.service();
    }
  }
  return true;
}

struct ComputeTimes {
  std::vector<double> holding, moving;
};

// The compute time of Daemon::cycle holding (n cycles) and along the moves there and back along x
// of a cell started with `settings`; false: the cell or a move failed (printed).
bool compute_times(const testing::VirtualCell::Settings& settings, int n, ComputeTimes& out) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("cdpr-daemon-bench-tc-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  auto cell_r = testing::VirtualCell::create(CDPR_SOURCE_DIR, dir);
  if (!cell_r.ok() || !(*cell_r)->start_daemon(settings).ok()) {
    std::fprintf(stderr, "daemon_bench: the cell did not start\n");
    return false;
  }
  testing::VirtualCell& cell = **cell_r;
  Daemon& d = *cell.daemon;
  cell.run_until([&] { return d.state() == DaemonState::kHolding; }, 5.0);
  auto hold = time_cycles(cell, n, [&] { d.cycle(cell.clock.now()); });
  out.holding.insert(out.holding.end(), hold.begin(), hold.end());
  if (!time_moves(cell, out.moving)) return false;
  cell.daemon->shutdown();
  cell_r->reset();
  std::filesystem::remove_all(dir);
  return true;
}

int compare_tension_control(const std::string& group, int cycles, int rounds) {
  testing::VirtualCell::Settings off, on;
  off.extra = "tension_control: {gain: 0}\n";
  on.extra = "tension_control: " + group + "\n";
  ComputeTimes a, b;
  for (int r = 0; r < rounds; ++r) {
    if (!compute_times(off, cycles, a) || !compute_times(on, cycles, b)) return 1;
  }
  std::printf("Daemon::cycle compute time, %d rounds, without and with tension_control %s:\n",
              rounds, group.c_str());
  const auto line = [](const char* what, const std::vector<double>& v) {
    const Percentiles p = percentiles(v);
    std::printf("  %-34s %6zu cycles  p50 %6.2f us  p99 %6.2f us  max %7.2f us\n", what, v.size(),
                p.p50, p.p99, p.max);
  };
  line("holding, tension control off", a.holding);
  line("holding, tension control on", b.holding);
  line("moving, tension control off", a.moving);
  line("moving, tension control on", b.moving);
  std::printf("  target <= 10 us p99 with tension control: holding %s, moving %s\n",
              percentiles(b.holding).p99 <= 10.0 ? "met" : "NOT met",
              percentiles(b.moving).p99 <= 10.0 ? "met" : "NOT met");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  int cycles = 20000;
  testing::VirtualCell::Settings settings;
  bool calibrate_only = false;
  std::string compare;
  int rounds = 3;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--cycles" && i + 1 < argc) cycles = std::max(100, std::atoi(argv[++i]));
    // The daemon's measuring group (a YAML flow mapping), e.g. "{poses: 25, tension_band: 0}".
    if (a == "--measuring" && i + 1 < argc) settings.measuring = argv[++i];
    if (a == "--calibration-only") calibrate_only = true;
    if (a == "--compare-tension-control" && i + 1 < argc) compare = argv[++i];
    if (a == "--rounds" && i + 1 < argc) rounds = std::max(1, std::atoi(argv[++i]));
  }
  if (!compare.empty()) return compare_tension_control(compare, cycles, rounds);
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("cdpr-daemon-bench-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  auto cell_r = testing::VirtualCell::create(CDPR_SOURCE_DIR, dir);
  if (!cell_r.ok()) {
    std::fprintf(stderr, "daemon_bench: %s\n", cell_r.status().to_string().c_str());
    return 1;
  }
  testing::VirtualCell& cell = **cell_r;
  const long rss0 = status_kib("VmRSS:");
  if (Status s = cell.start_daemon(settings); !s.ok()) {
    std::fprintf(stderr, "daemon_bench: %s\n", s.to_string().c_str());
    return 1;
  }
  Daemon& d = *cell.daemon;
  const long rss_started = status_kib("VmRSS:");

  std::printf(
      "daemon_bench: MINI (8 cables, swivel pulleys, Hooke elongation compensation), 8 CiA "
      "402 drives + 1 force node, SYNC %.0f ms\n",
      std::chrono::duration<double, std::milli>(cell.network.sync_period).count());
  if (calibrate_only) cycles = 100;
  std::printf("RT cycle compute time, %d cycles each:\n", cycles);
  const Percentiles master =
      percentiles(time_cycles(cell, cycles, [&] { d.master().cycle(cell.clock.now()); }));
  print("master cycle alone (I/O baseline)", master, master.p50);
  const Percentiles hold =
      percentiles(time_cycles(cell, cycles, [&] { d.cycle(cell.clock.now()); }));
  print("Daemon::cycle, holding", hold, master.p50);
  // A long move: there and back along x, timed while the trajectory runs.
  std::vector<double> moving;
  if (!time_moves(cell, moving)) return 1;
  print("Daemon::cycle, moving", percentiles(moving), master.p50);
  std::printf(
      "  target <= 10 us per cycle: p50 %s, p99 %s (this machine's other load shows in p99)\n",
      percentiles(moving).p50 <= 10.0 ? "met" : "NOT met",
      percentiles(moving).p99 <= 10.0 ? "met" : "NOT met");

  // A full calibration, robot time running with the wall clock.
  cell.run_until([&] { return d.state() == DaemonState::kHolding; }, 5.0);
  cell.pace(true);
  const double t0 = cell.seconds();
  const auto w0 = WallClock::now();
  const Reply r = cell.request("calibrate");
  if (!r.ok) {
    std::fprintf(stderr, "daemon_bench: calibrate: %s\n", r.message.c_str());
    return 1;
  }
  double t_identify = -1.0, t_done = -1.0;
  double w_identify = 0.0;
  cell.run_until(
      [&] {
        const DaemonState s = d.state();
        if (s == DaemonState::kIdentifying && t_identify < 0) {
          t_identify = cell.seconds();
          w_identify = std::chrono::duration<double>(WallClock::now() - w0).count();
        }
        if (s == DaemonState::kAwaitingAcceptance || s == DaemonState::kFault ||
            (s == DaemonState::kHolding && t_identify >= 0)) {
          t_done = cell.seconds();
          return true;
        }
        return false;
      },
      1200.0);
  const double wall = std::chrono::duration<double>(WallClock::now() - w0).count();
  const nlohmann::json st = d.status();
  if (d.state() != DaemonState::kAwaitingAcceptance) {
    std::fprintf(stderr, "daemon_bench: the calibration did not finish: %s\n", st.dump().c_str());
    return 1;
  }
  auto report = cell.request("report");
  const nlohmann::json& rep = report.result["report"];
  std::printf("Full calibration (%d poses measured, verdict: %s):\n", rep["poses"].get<int>(),
              rep["verdict"].get<std::string>().c_str());
  std::printf("  measuring sequence: %.1f s of robot time (target <= 60 s: %s)\n", t_identify - t0,
              t_identify - t0 <= 60.0 ? "met" : "NOT met");
  std::printf("  identification + diagnosis: %.1f s of wall time (the robot holds meanwhile)\n",
              wall - w_identify);
  std::printf("  whole calibration: %.1f s of wall time = robot time (paced; %.1f s)\n", wall,
              t_done - t0);
  auto after = config::load_robot_config(
      d.store().calibration_dir(r.result["calibration"].get<int>()) + "/model_after.yaml");
  if (after.ok()) {
    std::printf("  frame anchors vs truth: %.3f mm RMS before, %.3f mm after\n",
                1e3 * testing::VirtualCell::anchor_rms(cell.nominal, cell.physics->truth()),
                1e3 * testing::VirtualCell::anchor_rms(*after, cell.physics->truth()));
  }
  const long rss_end = status_kib("VmRSS:");
  std::printf(
      "Memory (this process: daemon + virtual robot): VmRSS %.1f MiB before the daemon, "
      "%.1f MiB started (daemon +%.1f MiB), %.1f MiB after the calibration; VmHWM %.1f MiB\n",
      rss0 / 1024.0, rss_started / 1024.0, (rss_started - rss0) / 1024.0, rss_end / 1024.0,
      status_kib("VmHWM:") / 1024.0);
  cell.daemon->shutdown();
  cell_r->reset();
  std::filesystem::remove_all(dir);
  return 0;
}
