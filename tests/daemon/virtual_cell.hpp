// A robot cell in one process: cdprd's Daemon and the virtual robot (CANopen drives and force
// node on the in-process virtual bus with a manual clock, the laser's Modbus slave on loopback
// TCP, or Modbus RTU over a pty, read by our laser driver). For the native daemon tests and the
// daemon benchmark; the composition lives here, not in the daemon: the two only meet on the bus and
// the Modbus link.
//
// Truth: config/mini-measured.yaml with config/scenarios/mini-calibration.yaml's hidden effects;
// the drives power on with the true platform at home (the reference platform).
#pragma once

#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/controller/state_store.hpp"
#include "cdpr/controller/tension_control.hpp"
#include "cdpr/modbus/laser_sensor.hpp"
#include "cdpr/modbus/register_map.hpp"
#include "cdpr/sim/can_robot.hpp"
#include "cdpr/sim/laser_slave.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::controller::testing {

using namespace std::chrono_literals;

// The daemon configuration groups a cell starts with (YAML flow mappings).
struct CellSettings {
  std::string measuring =
      "{poses: 25, laser_samples: 5, laser_interval_s: 0.002, average_cycles: 25, "
      "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4, tension_band: 3}";
  std::string motion =
      "{max_linear_velocity: 0.15, max_linear_acceleration: 0.5, max_linear_jerk: 5, "
      "max_angular_velocity: 0.5, max_angular_acceleration: 2, max_angular_jerk: 20}";
  std::string identification = "{bootstrap: 30}";
  std::string acceptance = "{mode: manual}";
  // The virtual robot powers up on its reference platform and is enabled at start.
  std::string start = "{enable: at-start, home_without_record: reference}";
  std::string canopen;  // the daemon's network file; "": config/canopen-mini.yaml (as the sim's)
  std::string extra;
};

class VirtualCell {
 public:
  // Per try of the laser driver (of 3): the slave answers from a thread of this process.
  static constexpr double kLaserAnswerTimeoutS = 1.0;
  // `source` is the project's root (config/), `dir` a scratch folder for the state directory.
  // How the laser reaches the daemon: Modbus TCP on loopback (the driver configured in code), or
  // Modbus RTU over a pseudo-terminal the virtual robot serves, read by the driver that cdprd's
  // `laser:` file configures (as cdprd's main does).
  enum class LaserLink { kTcp, kRtuThroughConfig };
  // The tensions the platform is homed with (it powers up standing on its reference platform at
  // home): the planner's own at home, or the ones cdprd's tension control holds there (its plan
  // keeps the band's margin and the guard: TensionControlOptions). A platform held at other
  // tensions than it was homed with moves off home where the geometry is still wrong (its
  // internal force is the nominal model's, not the truth's: 20 N more turned the uncalibrated
  // MINI 1.3 mrad), and the identification's home-pose gauge turns every anchor with it.
  enum class HomeTensions { kPlanner, kHeld };
  static Result<std::unique_ptr<VirtualCell>> create(const std::string& source,
                                                     std::filesystem::path dir,
                                                     std::uint64_t seed = 7,
                                                     LaserLink link = LaserLink::kTcp,
                                                     HomeTensions home = HomeTensions::kPlanner) {
    std::unique_ptr<VirtualCell> c(new VirtualCell(source, std::move(dir)));
    c->link_ = link;
    c->home_tensions_ = home;
    if (Status s = c->make_robot(seed); !s.ok()) return s;
    return c;
  }
  ~VirtualCell() {
    if (daemon) daemon->shutdown();
    daemon.reset();
    if (laser) laser->stop();
    if (slave) slave->stop();
    robot.reset();  // before its bus endpoint
  }
  VirtualCell(const VirtualCell&) = delete;
  VirtualCell& operator=(const VirtualCell&) = delete;

  // The daemon's configuration: MINI, the state directory in `dir`. Each group can be replaced
  // (a flow mapping); `extra` adds other top-level groups.
  using Settings = CellSettings;
  std::string config_text(const Settings& s) const {
    return "robot: " + source_ + "/config/mini.yaml\n" +
           "canopen: " + (s.canopen.empty() ? source_ + "/config/canopen-mini.yaml" : s.canopen) +
           "\n" + "state_directory: " + (dir_ / "state").string() +
           "\n"
           "identity: {vendor_id: 0x00CD9001, drive_product_code: 0x402, force_product_code: "
           "0x404}\n"
           "motion: " +
           s.motion + "\nmeasuring: " + s.measuring + "\nidentification: " + s.identification +
           "\nacceptance: " + s.acceptance + "\nstart: " + s.start + "\n" + laser_line() + s.extra;
  }

  // The shipped MINI network (which maps each winch's digital inputs 0x60FD in an event-driven
  // TPDO2; the virtual drives report the e-stop chain in bit 16) with the holding brakes switched
  // by the master: digital outputs 0x60FE:01 (bit 0: the brake applied) in a synchronous RPDO2,
  // written into the cell's folder. Returns its path.
  Result<std::string> write_safety_network() const {
    auto shipped = read_text_file(source_ + "/config/canopen-mini.yaml");
    if (!shipped.ok()) return shipped.status();
    std::string text = *shipped;
    const std::pair<std::string, std::string> edits[] = {
        {"eds: eds/", "eds: " + source_ + "/config/eds/"},
        {"eds: eds/", "eds: " + source_ + "/config/eds/"},
        {"map: [\"0x6040:00 u16\", \"0x607A:00 i32\"]\n",
         "map: [\"0x6040:00 u16\", \"0x607A:00 i32\"]\n"
         "      - {number: 2, transmission: 1, map: [\"0x60FE:01 u32\"]}\n"},
    };
    for (const auto& [from, to] : edits) {
      const std::size_t at = text.find(from);
      if (at == std::string::npos) {
        return Status(ErrorCode::kNotFound, "config/canopen-mini.yaml has no '" + from + "'");
      }
      text.replace(at, from.size(), to);
    }
    const std::string path = (dir_ / "canopen-safety.yaml").string();
    std::ofstream(path) << text;
    return path;
  }

  // The same from YAML lines: a `measuring:`, `identification:`, `acceptance:` or `canopen:` line
  // replaces that group, other lines are added.
  Status start_daemon(const std::string& lines) {
    Settings s;
    std::string rest;
    std::size_t pos = 0;
    while (pos < lines.size()) {
      std::size_t end = lines.find('\n', pos);
      if (end == std::string::npos) end = lines.size();
      const std::string line = lines.substr(pos, end - pos);
      pos = end + 1;
      auto group = [&](const char* key, std::string& out) {
        const std::string k = std::string(key) + ":";
        if (line.rfind(k, 0) != 0) return false;
        out = line.substr(k.size());
        return true;
      };
      if (!group("measuring", s.measuring) && !group("identification", s.identification) &&
          !group("acceptance", s.acceptance) && !group("start", s.start) &&
          !group("canopen", s.canopen) && !line.empty()) {
        rest += line + "\n";
      }
    }
    s.extra = rest;
    return start_daemon(s);
  }

  // Creates and starts the daemon (the state directory is kept between calls: a restart, as
  // abrupt as a kill -9: nothing orderly is done; kill_daemon() alone does the same), then
  // cycles until it holds (its drives enabled at start) or it started with disabled drives.
  Status start_daemon(const Settings& settings = {}) {
    kill_daemon();
    auto cfg = parse_daemon_config(config_text(settings), (dir_ / "cdprd.yaml").string());
    if (!cfg.ok()) return cfg.status();
    config = *cfg;
    DaemonIo io;
    io.bus = master_ep_.get();
    io.laser = laser.get();
    io.clock = &clock;
    io.idle = [this] { idle(); };
    io.poll = 200us;
    auto d = Daemon::create(config, io);
    if (!d.ok()) return d.status();
    daemon = std::move(*d);
    daemon->set_event_sink([this](const nlohmann::json& e) {
      std::lock_guard lock(events_mu_);
      events_.push_back(e);
    });
    if (Status s = daemon->start(); !s.ok()) return s;
    if (config.start.enable == StartSettings::Enable::kOperator) return Status::success();
    if (!run_until(
            [&] {
              const RtMode m = daemon->rt().snapshot().mode;
              return m == RtMode::kHolding || m == RtMode::kHoldingCounts;
            },
            30.0)) {
      const nlohmann::json st = daemon->status();
      return Status(ErrorCode::kTimeout,
                    "the daemon did not hold within 30 s after start-up (state " +
                        st["state"].dump() + ", reason " + st["reason"].dump() + ", fault " +
                        st["fault"].dump() + ", rt mode " +
                        std::string(to_string(daemon->rt().snapshot().mode)) + ")");
    }
    return Status::success();
  }

  // The daemon gone without an orderly stop (the robot and the bus stay).
  void kill_daemon() {
    if (!daemon) return;
    daemon->shutdown();
    daemon.reset();
  }

  // The robot between two SYNCs (and the laser's distance follows the physics). While
  // `robot_dead` the robot takes nothing in and sends nothing (as if cdpr-sim were killed);
  // `laser_status` overrides the laser's status (e.g. kNoTarget) while set.
  void idle() {
    clock.advance(250us);
    if (robot_dead) {  // what the master sends is lost
      can::Frame f;
      while (robot_ep_->receive(f, std::chrono::nanoseconds(0)).ok()) {
      }
      return;
    }
    robot->step(clock.now());
    const sim::LaserChannel l = physics->state().lasers.front();
    slave->set_distance(l.true_distance + laser_offset_m, laser_status.value_or(l.status));
  }
  bool robot_dead = false;
  std::optional<sim::LaserStatus> laser_status;
  double laser_offset_m = 0.0;  // added to the laser's distance (a beam on the wrong target)

  // One SYNC period: the daemon's RT cycle, then the robot until the next one; the supervisor
  // every 5 cycles. While the worker identifies (in real time), robot time runs with the wall
  // clock, as on a robot: a bound in robot time on the identification is then one in real
  // seconds, whatever the machine's load (stepped as fast as it could go, 900 s of robot time went
  // by while a loaded machine's worker was still diagnosing), and the CPU is left to the worker.
  void cycle() {
    daemon->cycle(clock.now());
    const can::Timestamp next = clock.now() + network.sync_period;
    while (clock.now() < next) idle();
    if (++cycles_ % 5 == 0) daemon->service();
    const bool pace_now = paced_ || daemon->state() == DaemonState::kIdentifying;
    if (pace_now && !pacing_) anchor_pace();
    pacing_ = pace_now;
    if (pacing_) std::this_thread::sleep_until(wall_origin_ + (clock.now() - robot_origin_));
  }
  // Paced: robot time runs with the wall clock (from now on), so what the daemon's threads do in
  // real time (laser readings, the identification) costs the robot time it would cost on a robot.
  void pace(bool on) {
    paced_ = on;
    pacing_ = on;
    anchor_pace();
  }

  // Cycles until `done` or `max_s` of robot time; returns whether done.
  bool run_until(const std::function<bool()>& done, double max_s) {
    const double end = seconds() + max_s;
    while (seconds() < end) {
      if (done()) return true;
      cycle();
    }
    return done();
  }
  double seconds() const { return std::chrono::duration<double>(clock.now()).count(); }

  Reply request(const std::string& cmd, const nlohmann::json& args = nlohmann::json::object()) {
    PeerInfo peer{static_cast<int>(::getpid()), static_cast<int>(::getuid()),
                  static_cast<int>(::getgid())};
    return daemon->handle(cmd, args, peer);
  }

  // Events of `type` whose data[key] is a string containing `part`.
  int count_events(const std::string& type, const std::string& key, const std::string& part) {
    std::lock_guard lock(events_mu_);
    int n = 0;
    for (const nlohmann::json& e : events_) {
      if (e["event"] == type && e["data"].contains(key) && e["data"][key].is_string() &&
          e["data"][key].get<std::string>().find(part) != std::string::npos) {
        ++n;
      }
    }
    return n;
  }
  // The daemon's end of the bus (e.g. to make its transmissions fail).
  can::VirtualCanEndpoint& master_endpoint() { return *master_ep_; }

  bool saw_event(const std::string& type, const std::string& key, const std::string& value) {
    std::lock_guard lock(events_mu_);
    for (const nlohmann::json& e : events_) {
      if (e["event"] == type && e["data"].contains(key) && e["data"][key] == value) return true;
    }
    return false;
  }

  // Runs a calibration through the control requests until it awaits acceptance (or ends
  // otherwise); returns the calibration id or the reason it did not get there.
  Result<int> calibrate(const nlohmann::json& args = nlohmann::json::object()) {
    const Reply r = request("calibrate", args);
    if (!r.ok) return Status(ErrorCode::kAborted, "calibrate: " + r.code + ": " + r.message);
    const bool done = run_until(
        [&] {
          const DaemonState s = daemon->state();
          if (s == DaemonState::kAwaitingAcceptance || s == DaemonState::kFault) return true;
          const nlohmann::json c = daemon->status()["calibration"];
          return s == DaemonState::kHolding && !c.is_null() && c["outcome"] != "measuring" &&
                 c["outcome"] != "identifying";
        },
        900.0);
    if (!done || daemon->state() != DaemonState::kAwaitingAcceptance) {
      return Status(ErrorCode::kAborted,
                    "the calibration did not reach acceptance: " + daemon->status().dump());
    }
    return r.result["calibration"].get<int>();
  }

  // RMS over cables of the frame-anchor distance between two models, m.
  static double anchor_rms(const RobotModel& a, const RobotModel& b) {
    return std::sqrt((a.frame_anchors - b.frame_anchors).colwise().squaredNorm().mean());
  }

  cdpr::ManualClock clock;
  RobotModel nominal;
  sim::Scenario scenario;
  std::unique_ptr<sim::Physics> physics;
  canopen::MasterConfig network;
  std::unique_ptr<sim::CanRobot> robot;
  std::unique_ptr<sim::LaserSlave> slave;
  std::unique_ptr<modbus::LaserSensor> laser;
  DaemonConfig config;
  std::unique_ptr<Daemon> daemon;

 private:
  VirtualCell(std::string source, std::filesystem::path dir)
      : source_(std::move(source)), dir_(std::move(dir)) {}

  // The pretension of the planner's plan at home the platform is homed with (NaN: its default).
  double home_reference_tension() const {
    if (home_tensions_ == HomeTensions::kPlanner) return std::numeric_limits<double>::quiet_NaN();
    return sim::home_reference_tension(
        nominal, MotionSettings{}.tension_margin + TensionControlOptions{}.guard);
  }

  Status make_robot(std::uint64_t seed) {
    auto nom = config::load_robot_config(source_ + "/config/mini.yaml");
    if (!nom.ok()) return nom.status();
    nominal = *nom;
    auto sc = sim::load_scenario(source_ + "/config/scenarios/mini-calibration.yaml");
    if (!sc.ok()) return sc.status();
    scenario = *sc;
    auto truth = sim::resolve_truth(scenario, nominal);
    if (!truth.ok()) return truth.status();
    auto p = sim::Physics::create(*truth, scenario, seed);
    if (!p.ok()) return p.status();
    physics = std::make_unique<sim::Physics>(std::move(*p));
    auto home = sim::true_pose_counts(*physics, physics->truth().home, home_reference_tension());
    if (!home.ok()) return home.status();
    if (Status s = physics->step(home->array().round().matrix(), 0.0); !s.ok()) return s;
    auto net = canopen::load_config(source_ + "/config/canopen-mini.yaml");
    if (!net.ok()) return net.status();
    network = *net;
    sim::CanRobotOptions ro;
    for (int i = 0; i < home->size(); ++i) {
      ro.initial_counts.push_back(static_cast<std::int32_t>(std::lround((*home)(i))));
    }
    auto r = sim::CanRobot::create(*robot_ep_, network, *physics, ro);
    if (!r.ok()) return r.status();
    robot = std::move(*r);
    robot->power_on(clock.now());

    const std::string map_path = source_ + "/config/lasers/baumer-om20-om30.yaml";
    auto map = modbus::load_register_map(map_path);
    if (!map.ok()) return map.status();
    sim::LaserSlaveConfig lc;
    lc.transport = sim::LaserSlaveConfig::Transport::kTcp;
    lc.map = *map;
    lc.noise_sigma_m = scenario.noise.laser;
    if (link_ == LaserLink::kRtuThroughConfig) return start_rtu_laser(lc, map_path);
    auto sl = sim::LaserSlave::start(lc);
    if (!sl.ok()) return sl.status();
    slave = std::move(*sl);
    const sim::LaserChannel l = physics->state().lasers.front();
    slave->set_distance(l.true_distance, l.status);
    modbus::LaserConfig cfg;
    cfg.map = *map;
    modbus::TcpSettings tcp;
    tcp.port = slave->port();
    cfg.link.transport = tcp;
    // Generous (the product's 0.1 s per try is missed when a loaded machine leaves the slave's
    // thread unscheduled): a timeout seen here is the slave's injected one.
    cfg.link.response_timeout_s = kLaserAnswerTimeoutS;
    cfg.poll_rate_hz = 200.0;
    laser = std::make_unique<modbus::LaserSensor>(cfg);
    return laser->start();
  }

  // The laser file of cdprd's configuration (RTU through config), or nothing.
  std::string laser_line() const {
    return link_ == LaserLink::kRtuThroughConfig ? "laser: " + (dir_ / "laser.yaml").string() + "\n"
                                                 : std::string();
  }
  // The virtual robot serves Modbus RTU on a pty (symlinked in `dir`); a laser file names it
  // (transport rtu, the baud and parity the slave announces) and the driver comes from that file.
  Status start_rtu_laser(sim::LaserSlaveConfig lc, const std::string& map_path) {
    lc.transport = sim::LaserSlaveConfig::Transport::kRtuPty;
    lc.pty_link = (dir_ / "laser-tty").string();
    lc.slave_id = 1;
    lc.baud = 57600;
    lc.parity = 'E';
    auto sl = sim::LaserSlave::start(lc);
    if (!sl.ok()) return sl.status();
    slave = std::move(*sl);
    const sim::LaserChannel l = physics->state().lasers.front();
    slave->set_distance(l.true_distance, l.status);
    const std::string file = (dir_ / "laser.yaml").string();
    std::ofstream(file) << "name: platform-laser\ntransport: rtu\ndevice: " << lc.pty_link
                        << "\nbaud: 57600\nparity: even\nslave_id: 1\nresponse_timeout: "
                        << kLaserAnswerTimeoutS
                        << "\n"
                           "retries: 2\npoll_rate: 200\nregister_map: "
                        << map_path << "\n";
    auto cfg = modbus::load_laser_config(file);
    if (!cfg.ok()) return cfg.status();
    laser = std::make_unique<modbus::LaserSensor>(std::move(*cfg));
    return laser->start();
  }

  HomeTensions home_tensions_ = HomeTensions::kPlanner;
  LaserLink link_ = LaserLink::kTcp;
  std::string source_;
  std::filesystem::path dir_;
  can::VirtualCanBus bus_{clock};
  std::unique_ptr<can::VirtualCanEndpoint> master_ep_ = bus_.endpoint("cdprd");
  std::unique_ptr<can::VirtualCanEndpoint> robot_ep_ = bus_.endpoint("cdpr-sim");
  std::mutex events_mu_;
  std::vector<nlohmann::json> events_;
  std::uint64_t cycles_ = 0;
  // Pacing: asked for (pace), or while the daemon identifies; robot time then runs with the wall
  // clock from the origins taken when it began.
  void anchor_pace() {
    wall_origin_ = std::chrono::steady_clock::now();
    robot_origin_ = clock.now();
  }
  bool paced_ = false;
  bool pacing_ = false;
  std::chrono::steady_clock::time_point wall_origin_;
  can::Timestamp robot_origin_{0};
};

}  // namespace cdpr::controller::testing
