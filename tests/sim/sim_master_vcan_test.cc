// cdpr-sim against our own CANopen master on a kernel CAN bus (run through tests/vcan/vcan-run:
// native vcan or user-mode-linux).
//
// The real cdpr-sim binary runs as a separate process on vcan0 with the MINI network
// (config/sim/canopen.yaml: 8 CiA 402 drives, force node 9, SYNC 20 ms) and a scenario
// with a drive fault at a known time (tests/sim/sim-master-fault.yaml). Our Master on
// SocketCanBus("vcan0") boots every node (reset communication, PDO mapping over SDO, start),
// enables the drives in CSP without a jump, streams a small ramp of counts to every winch and
// checks the position actuals follow and the force values arrive. Then it waits for the injected
// fault: the EMCY of the right node with the right code, the drive's FAULT and the master's
// quick stop of the other drives. Every wait is bounded; cdpr-sim is killed on every exit path.
// Same scheme as sim/src/can_robot_test.cc (the in-process virtual bus), here across processes.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/can/socketcan_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/master.hpp"
#include "subprocess.hpp"

extern char** environ;

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
// SIGTERM, then SIGKILL after 5 s.
struct Process : cdpr::test::Subprocess {
  Process(const std::vector<std::string>& argv, const std::string& out)
      : Subprocess(argv, out, std::chrono::seconds(5)) {}
};

// Kept in step with tests/sim/sim-master-fault.yaml.
constexpr double kFaultAt = 15.0;  // s after the slaves powered on
constexpr NodeId kFaultNode = 3;   // cable 3 = the third cia402 node
constexpr std::uint16_t kFaultEmcy = 0x7500;
constexpr NodeId kDrives[] = {1, 2, 3, 4, 5, 6, 7, 8};
constexpr NodeId kForceNode = 9;
constexpr std::size_t kChannels = 8;
constexpr int kRampCycles = 50;         // 1 s at 20 ms
constexpr std::int32_t kRampStep = -4;  // counts per cycle (1 um per count): 0.2 mm shorter
constexpr int kMaxSettleCycles = 500;   // until the drives report the last target

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

Timestamp mono_now() {
  return std::chrono::duration_cast<Timestamp>(Clock::now().time_since_epoch());
}

bool wait_until(const std::function<bool()>& done, std::chrono::nanoseconds timeout) {
  const auto end = Clock::now() + timeout;
  while (Clock::now() < end) {
    if (done()) return true;
    std::this_thread::sleep_for(20ms);
  }
  return done();
}

// A unique temporary directory, removed on every exit path.
class TempDir {
 public:
  TempDir() {
    const char* base = std::getenv("TMPDIR");
    std::string tmpl = std::string(base != nullptr && *base != '\0' ? base : "/tmp") +
                       "/cdpr-sim-master-vcan.XXXXXX";
    std::vector<char> buf(tmpl.begin(), tmpl.end());
    buf.push_back('\0');
    if (::mkdtemp(buf.data()) != nullptr) path_ = buf.data();
  }
  ~TempDir() {
    if (path_.empty()) return;
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// A child started with posix_spawn (no shell), stdout+stderr to `out_path`. The destructor ends
// it on every exit path: SIGTERM, SIGKILL after 5 s.

class SimMasterVcan : public ::testing::Test {
 protected:
  // One master cycle per SYNC period on absolute wake-up times; `before` runs ahead of each.
  void cycle_once(const std::function<void()>& before = {}) {
    next_ += master->config().sync_period;
    const auto ns = next_.count();
    timespec ts{};
    ts.tv_sec = static_cast<time_t>(ns / 1000000000LL);
    ts.tv_nsec = static_cast<long>(ns % 1000000000LL);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    // A late wake-up (user-mode-linux) must not make the following cycles burst.
    if (mono_now() - next_ > master->config().sync_period) next_ = mono_now();
    if (before) before();
    master->cycle(mono_now());
    Event e;
    while (master->events().pop(e)) events.push_back(e);
  }
  double sim_time() const { return std::chrono::duration<double>(Clock::now() - sim_up).count(); }
  std::string sim_log() const { return read_file(dir.path() + "/cdpr-sim.out"); }

  TempDir dir;
  Clock::time_point sim_up;
  std::unique_ptr<can::SocketCanBus> bus;
  std::unique_ptr<Master> master;
  std::vector<Event> events;
  Timestamp next_{0};
};

TEST_F(SimMasterVcan, BootsEnablesMovesReadsForcesAndSeesTheInjectedDriveFault) {
  ASSERT_FALSE(dir.path().empty()) << "mkdtemp: " << std::strerror(errno);
  const std::string tests = CDPR_SOURCE_DIR "/tests/sim";
  const std::string network = CDPR_SOURCE_DIR "/config/sim/canopen.yaml";

  // 1. cdpr-sim on vcan0; it prints its node list (flushed) just before the slaves power on.
  Process sim({CDPR_SIM_EXE, "--config", CDPR_SOURCE_DIR "/config/mini.yaml", "--scenario",
               tests + "/sim-master-fault.yaml", "--can", "vcan0", "--canopen", network, "--seed",
               "1", "--duration", "200"},
              dir.path() + "/cdpr-sim.out");
  ASSERT_TRUE(sim.started()) << CDPR_SIM_EXE << ": " << sim.error();
  ASSERT_TRUE(wait_until(
      [&] { return sim_log().find("CANopen on vcan0") != std::string::npos || !sim.running(); },
      60s))
      << "cdpr-sim did not come up within 60 s:\n"
      << sim_log();
  sim_up = Clock::now();  // the slaves' power-on, to within the start-up of its loop
  ASSERT_TRUE(sim.running()) << "cdpr-sim exited:\n" << sim_log();

  // 2. Our master boots all nine nodes: reset communication, SDO configuration, start, SYNC.
  auto bus_r = can::SocketCanBus::open("vcan0");
  ASSERT_TRUE(bus_r.ok()) << bus_r.status().to_string();
  bus = std::move(*bus_r);
  auto cfg = load_config(network);
  ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
  ASSERT_EQ(cfg->sync_period, 20ms);
  MasterHooks hooks;
  hooks.now = mono_now;
  auto m = Master::create(*bus, *cfg, hooks);
  ASSERT_TRUE(m.ok()) << m.status().to_string();
  master = std::move(*m);
  const Status boot = master->boot();
  ASSERT_TRUE(boot.ok()) << boot.to_string() << "\ncdpr-sim:\n" << sim_log();
  std::printf("[sim-master] booted at t = %.2f s (scenario time)\n", sim_time());
  for (NodeId id = 1; id <= 9; ++id) {
    auto serial = master->sdo(id)->read<std::uint32_t>({0x1018, 4}, master->pump());
    ASSERT_TRUE(serial.ok()) << serial.status().to_string();
    EXPECT_EQ(*serial, 0x5100'0000u + id);
  }
  // The force node's PDO mapping as the master wrote it over SDO.
  auto map = master->sdo(kForceNode)->read<std::uint32_t>({0x1A01, 4}, master->pump());
  ASSERT_TRUE(map.ok()) << map.status().to_string();
  EXPECT_EQ(*map, 0x64010810u);
  for (NodeId id : kDrives) {
    auto mode = master->sdo(id)->read<std::int8_t>({0x6061, 0}, master->pump());
    ASSERT_TRUE(mode.ok()) << mode.status().to_string();
    EXPECT_EQ(*mode, 8) << "node " << int{id};
  }

  // 3. Enable in CSP: no jump (the target followed the actual position).
  const Status en = master->enable_all(20s);
  ASSERT_TRUE(en.ok()) << en.to_string() << "\ncdpr-sim:\n" << sim_log();
  next_ = mono_now();
  for (int c = 0; c < 5; ++c) cycle_once();
  std::vector<std::int32_t> home;
  for (NodeId id : kDrives) {
    const Drive& d = *master->drive(id);
    EXPECT_TRUE(d.enabled()) << "node " << int{id};
    EXPECT_EQ(d.mode(), Mode::kCyclicSyncPosition) << "node " << int{id};
    EXPECT_EQ(d.max_enable_error(), 0) << "node " << int{id} << ": jump at enable";
    EXPECT_EQ(d.target_counts(), d.actual_counts()) << "node " << int{id};
    home.push_back(d.actual_counts());
  }
  std::printf("[sim-master] enabled at t = %.2f s\n", sim_time());

  // 4. A small ramp on every winch; the actuals follow to the last target.
  const std::uint64_t tpdos_before = master->stats().tpdos_received;
  auto at_final = [&] {
    for (std::size_t k = 0; k < std::size(kDrives); ++k) {
      if (master->drive(kDrives[k])->actual_counts() != home[k] + kRampStep * kRampCycles) {
        return false;
      }
    }
    return true;
  };
  int followed = 0;  // cycles in which a drive reported a target the master had sent
  for (int c = 0; c < kRampCycles + kMaxSettleCycles; ++c) {
    if (c >= kRampCycles && at_final()) break;
    const int ramp = std::min(c + 1, kRampCycles);
    cycle_once([&] {
      for (std::size_t k = 0; k < std::size(kDrives); ++k) {
        ASSERT_TRUE(master->drive(kDrives[k])->set_target_counts(home[k] + kRampStep * ramp))
            << "node " << int{kDrives[k]} << " refused a target in cycle " << c;
      }
    });
    const std::int32_t a = master->drive(kDrives[0])->actual_counts();
    if (a != home[0] && a != home[0] + kRampStep * kRampCycles) ++followed;
    ASSERT_FALSE(master->faulted()) << "master latched a fault in cycle " << c << "\n" << sim_log();
  }
  ASSERT_TRUE(at_final()) << "the drives did not report the last target\n" << sim_log();
  EXPECT_GT(followed, kRampCycles / 2) << "the actuals did not follow the ramp step by step";
  for (NodeId id : kDrives) EXPECT_TRUE(master->drive(id)->enabled()) << "node " << int{id};

  // 5. Force values arrived (raw = 2 * tension, i16): the platform hangs in its cables.
  ForceSensor& force = *master->force_sensor(kForceNode);
  ASSERT_EQ(force.channels(), kChannels);
  EXPECT_GT(master->stats().tpdos_received - tpdos_before, 10u * std::size(kDrives));
  for (std::size_t ch = 0; ch < kChannels; ++ch) {
    EXPECT_GT(force.raw(ch), 2) << "channel " << ch;
    EXPECT_GT(force.tension(ch), 1.0) << "channel " << ch;
    EXPECT_LT(force.tension(ch), 10000.0) << "channel " << ch;
    EXPECT_DOUBLE_EQ(force.tension(ch), static_cast<double>(force.raw(ch)) / 2.0)
        << "channel " << ch;
  }
  const double ready_t = sim_time();
  std::printf("[sim-master] ramp done at t = %.2f s; waiting for the fault at %.1f s\n", ready_t,
              kFaultAt);
  ASSERT_LT(ready_t, kFaultAt - 1.0)
      << "too slow: boot, enable and ramp ran into the injected fault time";
  for (const Event& e : events) {
    EXPECT_NE(e.type, EventType::kEmcy) << "EMCY from node " << int{e.node} << " before the fault";
  }
  events.clear();

  // 6. Hold the position until the injected fault: EMCY (node, code), FAULT, quick stop.
  bool emcy = false, fault = false;
  double emcy_t = 0.0;
  const auto deadline = sim_up + std::chrono::duration_cast<Clock::duration>(
                                     std::chrono::duration<double>(kFaultAt + 30.0));
  while (Clock::now() < deadline && !(emcy && fault)) {
    cycle_once();
    for (const Event& e : events) {
      if (e.type == EventType::kEmcy) {
        EXPECT_EQ(e.node, kFaultNode);
        EXPECT_EQ(e.emcy.code, kFaultEmcy) << "EMCY code";
        if (!emcy) emcy_t = sim_time();
        emcy = true;
      }
      if (e.type == EventType::kDriveFault) {
        EXPECT_EQ(e.node, kFaultNode);
        fault = fault || e.node == kFaultNode;
      }
      EXPECT_NE(e.type, EventType::kHeartbeatLost) << "node " << int{e.node};
    }
    events.clear();
  }
  ASSERT_TRUE(emcy) << "no EMCY within 30 s after the fault time\n" << sim_log();
  ASSERT_TRUE(fault) << "node " << int{kFaultNode} << " never reported FAULT\n" << sim_log();
  std::printf("[sim-master] EMCY 0x%04X from node %d at t = %.2f s\n", kFaultEmcy, int{kFaultNode},
              emcy_t);
  EXPECT_GE(emcy_t, kFaultAt - 0.5);
  EXPECT_TRUE(master->faulted());
  EXPECT_EQ(master->drive(kFaultNode)->state(), cia402::State::kFault);

  // The master quick-stops the other drives: they leave OPERATION_ENABLED on the quick-stop path.
  auto all_stopped = [&] {
    for (NodeId id : kDrives) {
      if (id == kFaultNode) continue;
      const cia402::State s = master->drive(id)->state();
      if (s != cia402::State::kQuickStopActive && s != cia402::State::kSwitchOnDisabled) {
        return false;
      }
    }
    return true;
  };
  for (int c = 0; c < 250 && !all_stopped(); ++c) cycle_once();
  for (NodeId id : kDrives) {
    if (id == kFaultNode) continue;
    const Drive& d = *master->drive(id);
    EXPECT_FALSE(d.enabled()) << "node " << int{id};
    EXPECT_TRUE(d.state() == cia402::State::kQuickStopActive ||
                d.state() == cia402::State::kSwitchOnDisabled)
        << "node " << int{id} << " in " << cia402::to_string(d.state());
    // Controlword bit 2 ("quick stop", active low) is low: quick stop or disable voltage.
    EXPECT_EQ(d.controlword() & 0x0004u, 0u) << "node " << int{id};
  }
  ASSERT_TRUE(sim.running()) << "cdpr-sim exited:\n" << sim_log();
  const std::string log = sim_log();
  std::printf("[sim-master] cdpr-sim said:\n%s", log.c_str());
  master.reset();
  sim.stop(SIGTERM, 5s);
}

}  // namespace
}  // namespace cdpr::canopen
