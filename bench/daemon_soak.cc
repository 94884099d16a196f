// daemon_soak: cdprd and the virtual robot for a long stretch of simulated robot time, in one
// process (tests/daemon/virtual_cell.hpp: in-process CAN bus, manual clock, laser over loopback
// TCP), with repeated calibrations, accepts, rejects and rollbacks and moves between them.
//
//   daemon_soak [--minutes 30] [--poses 12]
//
// Robot time is simulated (the manual clock), so 30 minutes of robot time take what the
// computation takes. Prints, and exits non-zero when a limit is broken:
// - RSS (VmRSS) and the number of open file descriptors at start (after the first calibration,
//   when every lazy allocation has happened), in the middle and at the end;
// - the compute time of Daemon::cycle per cycle (p50, p99, p99.9, max) against the SYNC period,
//   as wall time (which includes the time other processes preempt it) and as the thread's CPU
//   time (a cycle whose CPU time exceeds the period would be an overrun the program causes);
// - the calibrations, activations and the geometry snapshots the daemon keeps (one per
//   activation) with the heap a RobotModel copy takes.
#include <malloc.h>
#include <spdlog/spdlog.h>
#include <time.h>
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
namespace fs = std::filesystem;

// RSS after handing free heap back to the system (malloc_trim), so that what is counted is
// memory in use, not memory the allocator keeps for reuse.
long rss_kib() {
  ::malloc_trim(0);
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  }
  return -1;
}

int open_fds() {
  int n = 0;
  for (const auto& e : fs::directory_iterator("/proc/self/fd")) {
    (void)e;
    ++n;
  }
  return n - 1;  // the iterator's own
}

// Heap in use (malloc's arenas and mmapped blocks), bytes.
std::size_t heap_in_use() {
  const struct mallinfo2 mi = mallinfo2();
  return mi.uordblks + mi.hblkhd;
}

struct Soak {
  // The cycle-time samples are stored in buffers sized (and touched) once, before the baseline:
  // growing vectors of samples would be the soak's own RSS growth (16 bytes per cycle).
  Soak(testing::VirtualCell& c, std::size_t capacity)
      : cell(c), cycle_us(capacity, 0.0), cycle_cpu_us(capacity, 0.0) {}
  testing::VirtualCell& cell;
  std::vector<double> cycle_us;      // wall time (includes being preempted by other processes)
  std::vector<double> cycle_cpu_us;  // the thread's CPU time: what the program itself costs
  std::size_t samples = 0;           // cycles recorded (at most the capacity)
  static double thread_cpu_us() {
    timespec ts{};
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) * 1e6 + static_cast<double>(ts.tv_nsec) * 1e-3;
  }
  int calibrations = 0, accepted = 0, rejected = 0, rollbacks = 0, moves = 0, failures = 0;

  // One SYNC period, the daemon's cycle timed (the robot and the supervisor are not).
  void cycle() {
    const auto t0 = WallClock::now();
    const double c0 = thread_cpu_us();
    cell.daemon->cycle(cell.clock.now());
    const double cpu = thread_cpu_us() - c0;
    const double wall = std::chrono::duration<double, std::micro>(WallClock::now() - t0).count();
    if (samples < cycle_us.size()) {
      cycle_cpu_us[samples] = cpu;
      cycle_us[samples] = wall;
      ++samples;
    }
    const can::Timestamp next = cell.clock.now() + cell.network.sync_period;
    while (cell.clock.now() < next) cell.idle();
    if (++n_ % 5 == 0) cell.daemon->service();
    if (cell.daemon->state() == DaemonState::kIdentifying) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }
  bool run_until(const std::function<bool()>& done, double max_s) {
    const double end = cell.seconds() + max_s;
    while (cell.seconds() < end) {
      if (done()) return true;
      cycle();
    }
    return done();
  }
  bool holding() {
    return cell.daemon->state() == DaemonState::kHolding &&
           cell.daemon->rt().snapshot().mode == RtMode::kHolding &&
           cell.daemon->rt().snapshot().settled;
  }
  // A calibration to acceptance; true when it got there.
  bool calibrate() {
    const Reply r = cell.request("calibrate");
    if (!r.ok) return false;
    ++calibrations;
    return run_until(
               [&] {
                 const DaemonState s = cell.daemon->state();
                 return s == DaemonState::kAwaitingAcceptance || s == DaemonState::kFault ||
                        (s == DaemonState::kHolding &&
                         cell.daemon->status()["calibration"]["outcome"] != "measuring");
               },
               900.0) &&
           cell.daemon->state() == DaemonState::kAwaitingAcceptance;
  }
  void move(double dx, double dy, double dz) {
    const Pose home = cell.nominal.home;
    if (cell.request("move", {{"pose",
                               {home.position.x() + dx, home.position.y() + dy,
                                home.position.z() + dz, 0.0, 0.0, 0.0}}})
            .ok) {
      ++moves;
    }
    run_until([&] { return holding(); }, 30.0);
  }

 private:
  std::uint64_t n_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  double minutes = 30.0;
  int poses = 12;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (std::strcmp(argv[i], "--minutes") == 0) minutes = std::atof(argv[i + 1]);
    if (std::strcmp(argv[i], "--poses") == 0) poses = std::atoi(argv[i + 1]);
  }
  spdlog::set_level(spdlog::level::warn);
  const fs::path dir = fs::temp_directory_path() / ("cdpr-soak-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  int exit_code = 0;
  {
    auto c = testing::VirtualCell::create(CDPR_SOURCE_DIR, dir);
    if (!c.ok()) {
      std::fprintf(stderr, "daemon_soak: %s\n", c.status().to_string().c_str());
      return 2;
    }
    testing::VirtualCell& cell = **c;
    const std::string extra = "measuring: {poses: " + std::to_string(poses) +
                              ", laser_samples: 3, laser_interval_s: 0.002, average_cycles: 25, "
                              "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4, "
                              "tension_band: 1}\nidentification: {diagnose: false}\n";
    if (Status s = cell.start_daemon(extra); !s.ok()) {
      std::fprintf(stderr, "daemon_soak: %s\n", s.to_string().c_str());
      return 2;
    }
    // The cell keeps every event the daemon publishes (for the tests' saw_event): in the soak
    // they are only counted, or that list would be the soak's own growth.
    std::size_t events = 0;
    cell.daemon->set_event_sink([&events](const nlohmann::json&) { ++events; });
    const double period_us =
        std::chrono::duration<double, std::micro>(cell.network.sync_period).count();
    Soak soak(cell, static_cast<std::size_t>(minutes * 60.0e6 / period_us * 1.1) + 100000);
    const auto wall0 = WallClock::now();
    const double t0 = cell.seconds();
    long rss_start = -1, rss_mid = -1;
    std::size_t heap_start = 0, heap_mid = 0;
    int fds_start = -1, fds_mid = -1;
    // Round r: calibrate; accept (even r) or reject (odd r); moves; every 4th round a rollback.
    for (int round = 0; cell.seconds() - t0 < minutes * 60.0; ++round) {
      if (!soak.calibrate()) {
        ++soak.failures;
        std::fprintf(stderr, "daemon_soak: round %d: the calibration did not reach acceptance\n",
                     round);
        if (cell.daemon->state() == DaemonState::kFault) (void)cell.request("fault_reset");
        soak.run_until([&] { return soak.holding(); }, 30.0);
      } else if (round % 2 == 0) {
        if (cell.request("accept").ok) ++soak.accepted;
        soak.run_until([&] { return soak.holding(); }, 30.0);
      } else {
        if (cell.request("reject").ok) ++soak.rejected;
        soak.run_until([&] { return soak.holding(); }, 30.0);
      }
      soak.move(0.05, -0.04, 0.03);
      soak.move(-0.04, 0.05, -0.02);
      soak.move(0.0, 0.0, 0.0);
      if (round % 4 == 3) {
        const int v = cell.daemon->status()["geometry_version"].get<int>();
        if (v > 1 && cell.request("geometry_rollback", {{"version", v - 1}}).ok) ++soak.rollbacks;
        soak.run_until([&] { return soak.holding(); }, 30.0);
      }
      if (round == 0) {  // the baseline: after the first of everything
        rss_start = rss_kib();
        heap_start = heap_in_use();
        fds_start = open_fds();
      }
      if (rss_mid < 0 && cell.seconds() - t0 >= minutes * 30.0) {
        rss_mid = rss_kib();
        heap_mid = heap_in_use();
        fds_mid = open_fds();
      }
      std::printf(
          "[soak] round %d: robot time %.1f min, state %s, geometry v%d, RSS %ld KiB, heap in use "
          "%.1f KiB, %d fds\n",
          round, (cell.seconds() - t0) / 60.0,
          cell.daemon->status()["state"].get<std::string>().c_str(),
          cell.daemon->status()["geometry_version"].get<int>(), rss_kib(),
          static_cast<double>(heap_in_use()) / 1024.0, open_fds());
      std::fflush(stdout);
    }
    const long rss_end = rss_kib();
    const std::size_t heap_end = heap_in_use();
    const int fds_end = open_fds();
    const auto n = static_cast<std::ptrdiff_t>(soak.samples);
    std::vector<double> v(soak.cycle_us.begin(), soak.cycle_us.begin() + n);
    std::vector<double> cpu(soak.cycle_cpu_us.begin(), soak.cycle_cpu_us.begin() + n);
    std::sort(v.begin(), v.end());
    std::sort(cpu.begin(), cpu.end());
    auto at = [&](double q) {
      return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
    };
    auto cpu_at = [&](double q) {
      return cpu[static_cast<std::size_t>(q * static_cast<double>(cpu.size() - 1))];
    };
    const auto late = static_cast<long>(
        std::count_if(v.begin(), v.end(), [&](double us) { return us > period_us; }));
    const auto cpu_late = static_cast<long>(
        std::count_if(cpu.begin(), cpu.end(), [&](double us) { return us > period_us; }));
    // The heap one geometry snapshot holds (a RobotModel copy).
    const std::size_t heap0 = mallinfo2().uordblks;
    std::vector<RobotModel> copies(100, cell.nominal);
    const double per_model =
        static_cast<double>(mallinfo2().uordblks - heap0) / 100.0 + sizeof(RobotModel);
    copies.clear();
    const int activations = soak.accepted + soak.rollbacks + 1;
    std::printf(
        "[soak] robot time %.1f min in %.0f s wall; %d calibrations (%d accepted, %d "
        "rejected, %d failed), %d rollbacks, %d moves\n",
        (cell.seconds() - t0) / 60.0,
        std::chrono::duration<double>(WallClock::now() - wall0).count(), soak.calibrations,
        soak.accepted, soak.rejected, soak.failures, soak.rollbacks, soak.moves);
    std::printf(
        "[soak] RSS %ld KiB after round 0, %ld KiB half-way, %ld KiB at the end (%+ld KiB)\n",
        rss_start, rss_mid, rss_end, rss_end - rss_start);
    auto kib = [](std::size_t b) { return static_cast<double>(b) / 1024.0; };
    std::printf(
        "[soak] heap in use %.1f KiB after round 0, %.1f KiB half-way, %.1f KiB at the end "
        "(first half %+.1f KiB, second half %+.1f KiB); %zu events published\n",
        kib(heap_start), kib(heap_mid), kib(heap_end), kib(heap_mid) - kib(heap_start),
        kib(heap_end) - kib(heap_mid), events);
    std::printf("[soak] open fds %d after round 0, %d half-way, %d at the end\n", fds_start,
                fds_mid, fds_end);
    std::printf(
        "[soak] Daemon::cycle over %zu cycles: p50 %.1f us, p99 %.1f us, p99.9 %.1f us, "
        "max %.1f us; %ld longer than the %.0f us period\n",
        v.size(), at(0.5), at(0.99), at(0.999), v.back(), late, period_us);
    std::printf(
        "[soak] Daemon::cycle CPU time: p50 %.1f us, p99 %.1f us, p99.9 %.1f us, max %.1f "
        "us; %ld longer than the period (overruns the program itself causes)\n",
        cpu_at(0.5), cpu_at(0.99), cpu_at(0.999), cpu.back(), cpu_late);
    std::printf("[soak] geometry snapshots kept: %d (one per activation), %.1f KiB each\n",
                activations, per_model / 1024.0);
    if (fds_end > fds_start) exit_code = 1;
    if (cpu_late > 0) exit_code = 1;
    if (soak.failures > 0) exit_code = 1;
  }
  fs::remove_all(dir);
  return exit_code;
}
