// cdprd: the calibration and control daemon on the robot PC (docs/daemon.md).
//
//   cdprd --config /etc/cdpr/cdprd.yaml [--log-level info] [--check-config]
//
// Every file is checked (config_check.hpp) before the bus is opened; --check-config only checks
// them and exits (0 valid; 2 with every error on stderr, one per line).
// Threads: the RT loop (SCHED_FIFO where allowed: one SYNC per period, Daemon::cycle), the
// control socket's server, the calibration worker (inside the daemon) and this main thread, which
// supervises (Daemon::service every 10 ms), publishes the loop's figures, feeds the systemd
// watchdog only while the RT loop advances, and stops cleanly on SIGTERM/SIGINT.
// Exit status: 0 stopped by a signal (or, with --check-config, every file valid); 1 start-up failed
// (bus, nodes, homing); 2 bad configuration.
// GCC 12 reports a false "potential null pointer dereference" in std::string code that CLI11's
// CLI::detail::split inlines at -O2; the warning is not about this file's code.
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/can/socketcan_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/controller/config_check.hpp"
#include "cdpr/controller/control_server.hpp"
#include "cdpr/controller/cycle_stats.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/controller/rt_thread.hpp"
#include "cdpr/controller/sd_notify.hpp"
#include "cdpr/modbus/laser_sensor.hpp"

namespace {

using namespace cdpr;
using namespace cdpr::controller;
using json = nlohmann::json;

std::atomic<bool> g_stop{false};
void on_signal(int) {
  g_stop = true;
}

// The RT cycle: the daemon's cycle at the wake-up time of CLOCK_MONOTONIC.
class Cycle final : public CycleHandler {
 public:
  explicit Cycle(Daemon& d) : d_(d) {}
  void cycle(const Wake&) noexcept override {
    const auto now = std::chrono::duration_cast<can::Timestamp>(
        std::chrono::steady_clock::now().time_since_epoch());
    d_.cycle(now);
  }

 private:
  Daemon& d_;
};

double us(std::chrono::nanoseconds d) {
  return static_cast<double>(d.count()) * 1e-3;
}

json figures(const RtLoop& loop) {
  const CycleStatsSnapshot s = loop.stats();
  return {{"cycles", s.cycles},
          {"overruns", s.overruns},
          {"period_ms", std::chrono::duration<double, std::milli>(loop.options().period).count()},
          {"setup", loop.setup().describe()},
          {"wake_latency_us",
           {{"p50", us(s.wake_latency.p50)},
            {"p99", us(s.wake_latency.p99)},
            {"p99_9", us(s.wake_latency.p999)},
            {"max", us(s.wake_latency.max)}}},
          {"compute_us",
           {{"p50", us(s.compute.p50)},
            {"p99", us(s.compute.p99)},
            {"p99_9", us(s.compute.p999)},
            {"max", us(s.compute.max)}}}};
}

// The configured laser, started (nullptr: none configured).
Result<std::unique_ptr<modbus::LaserSensor>> start_laser(const DaemonConfig& cfg) {
  if (cfg.laser.empty()) {
    spdlog::warn("no laser configured: the daemon can drive the robot but not calibrate it");
    return std::unique_ptr<modbus::LaserSensor>();
  }
  auto lc = modbus::load_laser_config(cfg.laser);
  if (!lc.ok()) return lc.status();
  auto laser = std::make_unique<modbus::LaserSensor>(std::move(*lc));
  if (Status s = laser->start(); !s.ok()) return s.prepend("laser: ");
  return laser;
}

// The main thread until a signal or the RT loop stops: the supervisor's tick every 10 ms, the
// loop's figures and the state for systemd every second, the watchdog while the loop advances.
void supervise(Daemon& d, const RtLoop& loop, SystemdNotifier& notify) {
  const auto watchdog = SystemdNotifier::watchdog_interval();
  auto next_figures = std::chrono::steady_clock::now();
  auto next_watchdog = next_figures;
  std::uint64_t last_cycles = 0;
  std::string last_state;
  while (!g_stop.load()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    d.service();
    const auto now = std::chrono::steady_clock::now();
    if (now >= next_figures) {
      d.set_loop_figures(figures(loop));
      d.rt().set_overruns(loop.stats().overruns);
      next_figures = now + std::chrono::seconds(1);
      const std::string state = to_string(d.state());
      if (state != last_state) {
        (void)notify.status(state);
        last_state = state;
      }
    }
    // The watchdog is fed only while the RT loop advances.
    if (watchdog && now >= next_watchdog) {
      const std::uint64_t cycles = loop.cycles();
      if (cycles != last_cycles) (void)notify.watchdog();
      last_cycles = cycles;
      next_watchdog = now + *watchdog / 3;
    }
    if (!loop.running()) {
      spdlog::error("the RT loop stopped");
      break;
    }
  }
}

// The RT thread's settings from the daemon's configuration.
RtOptions rt_thread_options(const DaemonConfig& cfg, std::chrono::nanoseconds period) {
  RtOptions ro;
  ro.priority = cfg.realtime.priority;
  ro.cpu = cfg.realtime.cpu;
  ro.period = period;
  ro.lock_memory = cfg.realtime.lock_memory;
  return ro;
}

// The control socket, its requests handed to the daemon and the daemon's events published on it.
Result<std::unique_ptr<control::ControlServer>> start_control(const DaemonConfig& cfg, Daemon& d) {
  control::ControlServerOptions so;
  so.path = cfg.control.socket;
  // Its directory (under systemd RuntimeDirectory= made it; by hand it may not exist yet).
  std::error_code ec;
  const std::filesystem::path dir = std::filesystem::path(so.path).parent_path();
  if (!dir.empty()) std::filesystem::create_directories(dir, ec);
  if (ec) return Status(ErrorCode::kIoError, "control socket directory: " + ec.message());
  so.group = cfg.control.group;
  auto server = control::ControlServer::start(so, [&d](const control::ControlRequest& r) {
    const PeerInfo peer{static_cast<int>(r.peer.pid), static_cast<int>(r.peer.uid),
                        static_cast<int>(r.peer.gid)};
    return d.handle(r.cmd, r.args, peer).to_control();
  });
  if (!server.ok()) return server.status();
  control::ControlServer& srv = **server;
  d.set_event_sink([&srv](const json& e) { srv.publish(e); });
  spdlog::info("control socket {}", so.path);
  return server;
}

// The orderly end: hold, quick stop and disable, then the socket, the RT loop, the bus, the laser.
void stop_all(Daemon& d, control::ControlServer& srv, RtLoop& loop, modbus::LaserSensor* laser) {
  spdlog::info("stopping: holding, then quick stop and disable");
  d.persist_stop();
  d.shutdown();
  srv.stop();
  if (Status s = d.apply_brakes_and_disable(2.0 + d.config().safety.brakes.apply_delay_s);
      !s.ok()) {
    spdlog::warn("shutdown: {}", s.to_string());
  }
  loop.stop();
  if (Status s = d.master().shutdown(std::chrono::seconds(2)); !s.ok()) {
    spdlog::warn("shutdown: {}", s.to_string());
  }
  if (laser != nullptr) laser->stop();
}

// Every file checked before the bus: each error on its own line. True when all are valid.
bool files_valid(const std::string& config_path, bool check_only) {
  const std::vector<Status> errors = check_daemon_files(config_path);
  for (const Status& e : errors) {
    if (check_only) {
      std::fprintf(stderr, "cdprd: %s\n", e.to_string().c_str());
    } else {
      spdlog::error("{}", e.to_string());
    }
  }
  if (check_only && errors.empty())
    std::printf("cdprd: %s and every file it names: valid\n", config_path.c_str());
  if (check_only && !errors.empty()) {
    std::fprintf(stderr, "cdprd: %zu error(s) in the configuration\n", errors.size());
  }
  return errors.empty();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cdprd: calibration and control daemon for cable-driven parallel robots"};
  std::string config_path, log_level = "info";
  bool check_only = false;
  app.add_option("--config", config_path, "daemon configuration (YAML, docs/daemon.md)")
      ->required();
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  app.add_flag("--check-config", check_only,
               "check every file (robot, network, EDS, laser, socket, state directory) and exit "
               "without touching the bus");
  app.set_version_flag("--version", kDaemonVersion);
  CLI11_PARSE(app, argc, argv);

  spdlog::set_level(spdlog::level::from_str(log_level));
  // Under systemd the journal stamps the time itself.
  if (std::getenv("JOURNAL_STREAM") != nullptr) spdlog::set_pattern("<%l> %v");
  SystemdNotifier notify;

  // Every file before the bus: on a host without CAN a robot-file error is named, not the bus's.
  if (!files_valid(config_path, check_only)) return 2;
  if (check_only) return 0;
  auto cfg = load_daemon_config(config_path);
  if (!cfg.ok()) {
    spdlog::error("{}", cfg.status().to_string());
    return 2;
  }
  auto network = canopen::load_config(cfg->canopen);
  if (!network.ok()) {
    spdlog::error("{}", network.status().to_string());
    return 2;
  }
  const std::string ifname = cfg->can_interface.empty() ? network->interface : cfg->can_interface;
  const auto period =
      cfg->realtime.sync_period.count() > 0 ? cfg->realtime.sync_period : network->sync_period;

  auto bus = can::SocketCanBus::open(ifname);
  if (!bus.ok()) {
    spdlog::error("CAN interface: {}", bus.status().to_string());
    return 1;
  }
  auto started_laser = start_laser(*cfg);
  if (!started_laser.ok()) {
    spdlog::error("{}", started_laser.status().to_string());
    return 2;
  }
  std::unique_ptr<modbus::LaserSensor> laser = std::move(*started_laser);

  static const cdpr::SteadyClock clock;
  DaemonIo io;
  io.bus = bus->get();
  io.laser = laser.get();
  io.clock = &clock;
  auto daemon = Daemon::create(*cfg, io);
  if (!daemon.ok()) {
    spdlog::error("{}", daemon.status().to_string());
    return 2;
  }
  Daemon& d = **daemon;
  (void)notify.status("starting: booting the CANopen network on " + ifname);
  if (Status s = d.start(); !s.ok()) {
    spdlog::error("start-up failed: {}", s.to_string());
    (void)notify.stopping("start-up failed: " + s.to_string());
    return 1;
  }

  // The RT loop: from here on only it talks to the master.
  Cycle cycle(d);
  RtLoop loop(rt_thread_options(*cfg, period), cycle);
  if (Status s = loop.start(); !s.ok()) {
    spdlog::error("RT loop: {}", s.to_string());
    return 1;
  }
  for (const std::string& w : loop.setup().warnings) spdlog::warn("RT loop: {}", w);
  spdlog::info("RT loop: {} every {:.1f} ms", loop.setup().describe(),
               std::chrono::duration<double, std::milli>(period).count());

  auto server = start_control(*cfg, d);
  if (!server.ok()) {
    spdlog::error("control socket: {}", server.status().to_string());
    loop.stop();
    return 1;
  }

  std::signal(SIGTERM, on_signal);
  std::signal(SIGINT, on_signal);
  (void)notify.ready("holding; geometry version " +
                     std::to_string(d.status()["geometry_version"].get<int>()));

  supervise(d, loop, notify);
  (void)notify.stopping("stopping");
  stop_all(d, **server, loop, laser.get());
  std::printf("cdprd: stopped\n");
  return 0;
}
