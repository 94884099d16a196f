// cdpr-sim: the virtual robot (docs/sim-scenarios.md).
//
//   cdpr-sim --config nominal.yaml --scenario scenario.yaml --modbus rtu[:/link]|tcp:PORT
//            [--can vcan0 --canopen network.yaml] [--seed N] [--lockstep poses.csv --out rec.csv]
//
// Lock-step mode (--lockstep): commands the poses as the daemon would, steps the physics to the
// equilibrium at each and writes a recording (drivers/recording format); no bus, no wall clock.
// Real-time mode: the laser is served over Modbus (--modbus) and/or the winch drives and force
// sensors of the CANopen network (--canopen) over SocketCAN (--can, sim/can_robot.hpp). With
// --can the physics steps at every SYNC of the master, starting at the nominal model's home
// counts; without it the physics runs at --rate Hz and the winches hold their home counts.
// GCC 12 reports a false "potential null pointer dereference" in std::string code that CLI11's
// CLI::detail::split inlines at -O2; the warning is not about this file's code.
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <exception>
#include <limits>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/can/socketcan_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/output_paths.hpp"
#include "cdpr/modbus/register_map.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/can_robot.hpp"
#include "cdpr/sim/laser_slave.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"
#include "cdpr/version.hpp"

namespace {

// Exit statuses (docs/sim-scenarios.md): 0 done (or stopped by a signal), 1 an input was refused
// or the work failed, 2 command-line usage error (also an output path naming an input), 70
// internal error (an unexpected exception: a bug).
constexpr int kExitFailed = 1;
constexpr int kExitUsage = 2;
constexpr int kExitInternal = 70;

std::atomic<bool> g_stop{false};
std::atomic<bool> g_report_pose{false};
std::atomic<int> g_estop_toggles{0};

void on_signal(int) {
  g_stop = true;
}
void on_report(int) {
  g_report_pose = true;
}
void on_estop(int) {
  g_estop_toggles.fetch_add(1);
}

int fail(const std::string& what) {
  std::fprintf(stderr, "cdpr-sim: %s\n", what.c_str());
  return kExitFailed;
}

int run(int argc, char** argv) {
  CLI::App app{"cdpr-sim: the virtual cable robot (physics with hidden effects, Modbus laser)"};
  app.set_version_flag("--version", std::string("cdpr-sim ") + cdpr::kVersion);
  std::string config_path, scenario_path, modbus_spec, can_if, canopen_path, lockstep_path,
      out_path, laser_map_path;
  std::uint64_t seed = 1;
  double rate_hz = 100.0, duration_s = 0.0, dwell_s = 2.0;
  int laser_samples = 1, substeps = 10;
  std::string home_mode = "nominal";
  double home_margin = 0.0;
  std::vector<std::string> evaluate;
  app.add_option("--config", config_path, "nominal robot description (what the daemon uses)")
      ->required();
  app.add_option("--scenario", scenario_path, "scenario: true robot, hidden effects, faults")
      ->required();
  app.add_option("--modbus", modbus_spec,
                 "serve the laser: rtu (a new pty), rtu:/path (pty + symlink at path), tcp:PORT");
  app.add_option("--can", can_if, "CAN interface (SocketCAN) for the CANopen slaves");
  app.add_option("--canopen", canopen_path,
                 "CANopen network (drivers/canopen YAML, e.g. config/canopen-mini.yaml) for --can");
  app.add_option("--seed", seed, "noise seed (std::mt19937_64)");
  app.add_option("--lockstep", lockstep_path, "pose list CSV: run offline, faster than real time");
  app.add_option("--out", out_path, "recording CSV written by --lockstep");
  app.add_option("--laser-map", laser_map_path,
                 "register map served (default: the scenario's laser.register_map)");
  app.add_option("--home", home_mode,
                 "real time: drive counts at power-on: 'nominal' (the nominal model's home "
                 "counts) or 'reference' (the true platform stands at home, as on a reference "
                 "platform)")
      ->check(CLI::IsMember({"nominal", "reference"}));
  app.add_option("--home-margin", home_margin,
                 "with --home reference: the platform is homed at the tensions of the nominal "
                 "planner's plan at home keeping this far inside [f_min, f_max], N (cdprd with "
                 "tension control holds its margin plus guard there: 30 N with the defaults); "
                 "default: the planner's own tensions")
      ->check(CLI::Range(0.0, 1e5));
  app.add_option("--evaluate", evaluate,
                 "judge robot descriptions against the scenario's truth: frame-anchor error and "
                 "the ISO 9283 box position error they realise on the true robot; then exit");
  app.add_option("--rate", rate_hz, "real-time physics rate, Hz")->check(CLI::Range(0.1, 10000.0));
  app.add_option("--duration", duration_s, "real-time: stop after this many seconds (0: never)");
  app.add_option("--dwell", dwell_s, "lock-step: scenario time per pose, s")
      ->check(CLI::PositiveNumber);
  app.add_option("--laser-samples", laser_samples, "lock-step: laser readings averaged per pose")
      ->check(CLI::Range(1, 10000));
  std::vector<std::string> channels;
  app.add_option("--channels", channels,
                 "lock-step: extra channels read at the true pose: swivel, inclinometer, imu-yaw "
                 "(noise 1 mrad, 0.5 mrad, 10 mrad from a stream seeded by --seed)")
      ->delimiter(',')
      ->check(CLI::IsMember({"swivel", "inclinometer", "imu-yaw"}));
  app.add_option("--substeps", substeps, "lock-step: SYNC steps per pose")
      ->check(CLI::Range(1, 100000));
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : kExitUsage;
  }
  std::vector<cdpr::io::NamedPath> inputs = {{"--config", config_path},
                                             {"--scenario", scenario_path},
                                             {"--lockstep", lockstep_path},
                                             {"--laser-map", laser_map_path},
                                             {"--canopen", canopen_path}};
  for (const std::string& e : evaluate) inputs.push_back({"--evaluate", e});
  auto usage = [](const cdpr::Status& s) {
    std::fprintf(stderr, "cdpr-sim: %s\n", s.to_string().c_str());
    return kExitUsage;
  };
  if (cdpr::Status s = cdpr::io::check_output_paths(inputs, {{"--out", out_path}}); !s.ok()) {
    return usage(s);
  }

  cdpr::Result<cdpr::RobotModel> nominal = cdpr::config::load_robot_config(config_path);
  if (!nominal.ok()) return fail(nominal.status().to_string());
  cdpr::Result<cdpr::sim::Scenario> scenario = cdpr::sim::load_scenario(scenario_path);
  if (!scenario.ok()) return fail(scenario.status().to_string());
  // The scenario's files are inputs too (its true robot's config, its laser register map).
  inputs.push_back({"the scenario's truth.config", scenario->truth.config_path});
  inputs.push_back({"the scenario's laser.register_map", scenario->laser.register_map_path});
  if (cdpr::Status s = cdpr::io::check_output_paths(inputs, {{"--out", out_path}}); !s.ok()) {
    return usage(s);
  }
  cdpr::Result<cdpr::RobotModel> truth = cdpr::sim::resolve_truth(*scenario, *nominal);
  if (!truth.ok()) return fail(truth.status().to_string());
  cdpr::Result<cdpr::sim::Physics> physics =
      cdpr::sim::Physics::create(std::move(*truth), *scenario, seed);
  if (!physics.ok()) return fail(physics.status().to_string());

  // ---- evaluate ----------------------------------------------------------------------------
  if (!evaluate.empty()) {
    const cdpr::RobotModel& true_robot = physics->truth();
    std::printf("%-40s %12s %12s %14s %14s\n", "model", "anchor RMS", "anchor max", "box pos. RMS",
                "box pos. max");
    for (const std::string& path : evaluate) {
      auto model = cdpr::config::load_robot_config(path);
      if (!model.ok()) return fail(model.status().to_string());
      if (model->num_cables() != true_robot.num_cables())
        return fail(path + ": cable count differs");
      double sum = 0.0, worst = 0.0;
      for (int i = 0; i < true_robot.num_cables(); ++i) {
        const double d = (model->frame_anchors.col(i) - true_robot.frame_anchors.col(i)).norm();
        sum += d * d;
        worst = std::max(worst, d);
      }
      const cdpr::CalibratedModel controller = cdpr::CalibratedModel::from_robot(*model);
      auto homed = cdpr::homed_truth(true_robot, *model);
      if (!homed.ok()) return fail(path + ": " + homed.status().to_string());
      cdpr::AccuracyBox box;
      box.center = true_robot.home.position;
      auto acc = cdpr::measure_position_accuracy(*homed, controller, box);
      if (!acc.ok()) return fail(path + ": " + acc.status().to_string());
      std::printf("%-40s %9.3f mm %9.3f mm %11.3f mm %11.3f mm\n", path.c_str(),
                  1e3 * std::sqrt(sum / true_robot.num_cables()), 1e3 * worst,
                  1e3 * acc->position_rms_m, 1e3 * acc->position_max_m);
    }
    return 0;
  }

  // ---- lock-step -------------------------------------------------------------------------
  if (!lockstep_path.empty()) {
    if (out_path.empty()) return fail("--lockstep needs --out (the recording to write)");
    if (!modbus_spec.empty() || !can_if.empty()) {
      return fail("--lockstep runs offline: drop --modbus and --can");
    }
    cdpr::Result<cdpr::recording::PoseList> poses = cdpr::recording::read_pose_list(lockstep_path);
    if (!poses.ok()) return fail(poses.status().to_string());
    if (cdpr::Status s = cdpr::recording::check_plausible(*poses, *nominal, lockstep_path);
        !s.ok()) {
      return fail(s.to_string());
    }
    cdpr::sim::LockstepOptions lo;
    lo.dwell_s = dwell_s;
    lo.laser_samples = laser_samples;
    lo.substeps = substeps;
    for (const std::string& c : channels) {
      lo.swivel = lo.swivel || c == "swivel";
      lo.inclinometer = lo.inclinometer || c == "inclinometer";
      lo.imu_yaw = lo.imu_yaw || c == "imu-yaw";
    }
    lo.channel_seed = seed ^ 0x9e3779b97f4a7c15ULL;
    const auto t0 = std::chrono::steady_clock::now();
    auto samples = cdpr::sim::run_lockstep(*physics, *nominal, poses->poses, lo);
    if (!samples.ok()) return fail(samples.status().to_string());
    const double cpu = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    cdpr::sim::RecordingProvenance prov{config_path, scenario_path, seed, dwell_s};
    prov.sigma_swivel = lo.sigma_swivel;
    prov.sigma_inclination = lo.sigma_inclination;
    prov.sigma_imu_yaw = lo.sigma_imu_yaw;
    auto rec = cdpr::sim::make_recording(*samples, *nominal, *scenario, prov);
    if (!rec.ok()) return fail(rec.status().to_string());
    const cdpr::Status st = cdpr::recording::write_recording(*rec, out_path);
    if (!st.ok()) return fail(st.to_string());
    std::printf("cdpr-sim: lock-step: %zu poses, %.1f s of scenario time in %.3f s, recording %s\n",
                samples->size(), dwell_s * static_cast<double>(samples->size()), cpu,
                out_path.c_str());
    return 0;
  }

  // ---- real time -------------------------------------------------------------------------
  if (modbus_spec.empty() && can_if.empty()) {
    return fail("nothing to serve: give --modbus and/or --can, or --lockstep");
  }
  if (!can_if.empty() && canopen_path.empty()) {
    return fail("--can needs --canopen (the CANopen network: node ids and PDOs)");
  }
  double home_reference = std::numeric_limits<double>::quiet_NaN();
  if (home_margin > 0.0) {
    home_reference = cdpr::sim::home_reference_tension(*nominal, home_margin);
    if (std::isnan(home_reference)) {
      return fail("--home-margin: no plan at the home pose keeps " + std::to_string(home_margin) +
                  " N inside the cable limits");
    }
  }
  auto home = home_mode == "reference"
                  ? cdpr::sim::true_pose_counts(*physics, physics->truth().home, home_reference)
                  : cdpr::sim::nominal_counts(*nominal, nominal->home);
  if (!home.ok()) return fail("home counts: " + home.status().to_string());
  const Eigen::VectorXd counts = home->array().round().matrix();
  cdpr::Status st = physics->step(counts, 0.0);
  if (!st.ok()) return fail(st.to_string());

  std::unique_ptr<cdpr::sim::LaserSlave> laser;
  if (!modbus_spec.empty()) {
    cdpr::sim::LaserSlaveConfig lc;
    if (modbus_spec == "rtu" || modbus_spec.rfind("rtu:", 0) == 0) {
      lc.transport = cdpr::sim::LaserSlaveConfig::Transport::kRtuPty;
      if (modbus_spec.size() > 4) lc.pty_link = modbus_spec.substr(4);
    } else if (modbus_spec.rfind("tcp:", 0) == 0) {
      lc.transport = cdpr::sim::LaserSlaveConfig::Transport::kTcp;
      try {
        lc.port = std::stoi(modbus_spec.substr(4));
      } catch (...) {
        lc.port = -1;
      }
      if (lc.port < 0 || lc.port > 65535) return fail("--modbus tcp:PORT: bad port");
    } else {
      return fail("--modbus: expected rtu, rtu:/path or tcp:PORT, got '" + modbus_spec + "'");
    }
    if (laser_map_path.empty()) laser_map_path = scenario->laser.register_map_path;
    if (laser_map_path.empty()) {
      return fail("no laser register map: set laser.register_map in the scenario or --laser-map");
    }
    auto map = cdpr::modbus::load_register_map(laser_map_path);
    if (!map.ok()) return fail(map.status().to_string());
    lc.map = *map;
    lc.slave_id = scenario->laser.slave_id;
    lc.baud = scenario->laser.baud;
    lc.parity = scenario->laser.parity;
    lc.noise_sigma_m = scenario->noise.laser;
    lc.seed = seed ^ 0x9E3779B97F4A7C15ULL;
    if (physics->true_lasers().empty()) return fail("the true robot has no laser to serve");
    auto slave = cdpr::sim::LaserSlave::start(lc);
    if (!slave.ok()) return fail(slave.status().to_string());
    laser = std::move(*slave);
    const cdpr::sim::LaserChannel l0 = physics->state().lasers.front();
    laser->set_distance(l0.true_distance, l0.status);
    std::printf("cdpr-sim: laser slave %s\n", laser->describe().c_str());
    if (lc.transport == cdpr::sim::LaserSlaveConfig::Transport::kRtuPty) {
      std::printf("cdpr-sim: laser pty %s\n", laser->pty_path().c_str());
    } else {
      std::printf("cdpr-sim: laser tcp port %d\n", laser->port());
    }
    std::printf("cdpr-sim: true laser distance %.9f m (%s)\n", l0.true_distance,
                std::string(cdpr::sim::to_string(l0.status)).c_str());
  }

  // The CANopen slaves: the drives and force sensors of the network description on --can.
  std::unique_ptr<cdpr::can::SocketCanBus> can_bus;
  std::unique_ptr<cdpr::sim::CanRobot> robot;
  if (!can_if.empty()) {
    auto network = cdpr::canopen::load_config(canopen_path);
    if (!network.ok()) return fail(network.status().to_string());
    auto bus = cdpr::can::SocketCanBus::open(can_if);
    if (!bus.ok()) return fail(bus.status().to_string());
    can_bus = std::move(*bus);
    cdpr::sim::CanRobotOptions ro;
    for (int i = 0; i < counts.size(); ++i) {
      ro.initial_counts.push_back(static_cast<std::int32_t>(counts(i)));
    }
    ro.report = [](double t, const std::string& what) {
      std::printf("cdpr-sim: t = %.3f s: %s\n", t, what.c_str());
      std::fflush(stdout);
    };
    auto r = cdpr::sim::CanRobot::create(*can_bus, *network, *physics, std::move(ro));
    if (!r.ok()) return fail(r.status().to_string());
    robot = std::move(*r);
    std::string ids;
    for (const auto& n : network->nodes) {
      ids += (ids.empty() ? "" : ", ") + std::to_string(n.id) + " " + n.name;
    }
    std::printf("cdpr-sim: CANopen on %s: nodes %s\n", can_if.c_str(), ids.c_str());
  } else {
    std::printf("cdpr-sim: no --can: the winches hold their home counts\n");
  }
  std::fflush(stdout);
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  // SIGUSR1: print where the true platform is (tests compare it with a commanded target).
  std::signal(SIGUSR1, on_report);
  // SIGUSR2: the e-stop chain opens (and closes at the next SIGUSR2): every drive's 0x60FD bit 16.
  std::signal(SIGUSR2, on_estop);

  const auto start = std::chrono::steady_clock::now();
  auto mono = [] {
    return std::chrono::duration_cast<cdpr::can::Timestamp>(
        std::chrono::steady_clock::now().time_since_epoch());
  };
  if (robot) robot->power_on(mono());
  const auto period = std::chrono::duration<double>(1.0 / rate_hz);
  auto next = start;
  cdpr::sim::LaserFaultMode last_fault = cdpr::sim::LaserFaultMode::kNone;
  std::vector<bool> reported(static_cast<std::size_t>(counts.size()), false);
  int estop_toggles = 0;
  while (!g_stop.load()) {
    if (robot) {
      // The physics steps at every SYNC of the master (inside the robot).
      robot->wait(std::chrono::milliseconds(1));
      robot->step(mono());
    } else {
      next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
      std::this_thread::sleep_until(next);
    }
    const double t =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (duration_s > 0.0 && t >= duration_s) break;
    if (!robot) {
      st = physics->step(counts, t);
      if (!st.ok()) {
        std::fprintf(stderr, "cdpr-sim: %s\n", st.to_string().c_str());
        continue;
      }
    }
    if (robot && g_estop_toggles.load() != estop_toggles) {
      estop_toggles = g_estop_toggles.load();
      robot->set_estop(estop_toggles % 2 == 1);
      std::printf("cdpr-sim: t = %.3f s: e-stop chain %s\n", t,
                  estop_toggles % 2 == 1 ? "open" : "closed");
      std::fflush(stdout);
    }
    if (g_report_pose.exchange(false)) {
      const cdpr::Pose& p = physics->state().pose;
      std::printf("cdpr-sim: t = %.3f s: true platform pose %.9f %.9f %.9f %.9f %.9f %.9f\n", t,
                  p.position.x(), p.position.y(), p.position.z(), p.rpy.x(), p.rpy.y(), p.rpy.z());
      std::fflush(stdout);
    }
    if (laser) {
      const cdpr::sim::LaserChannel l = physics->state().lasers.front();
      laser->set_distance(l.true_distance, l.status);
      const cdpr::sim::LaserFaultMode f = cdpr::sim::laser_fault_mode(scenario->laser_fault_at(t));
      if (f != last_fault) {
        std::printf("cdpr-sim: t = %.3f s: laser fault mode %s\n", t,
                    std::string(cdpr::sim::to_string(f)).c_str());
        std::fflush(stdout);
        last_fault = f;
      }
      laser->set_fault(f);
    }
    if (robot) continue;  // the robot reports overloads (and faults the drive)
    for (std::size_t i = 0; i < reported.size(); ++i) {
      if (physics->state().overloaded[i] && !reported[i]) {
        std::printf(
            "cdpr-sim: t = %.3f s: cable %zu overloaded (%.1f N): no --can, no drive to "
            "fault\n",
            t, i + 1, physics->state().tensions(static_cast<int>(i)));
        std::fflush(stdout);
        reported[i] = true;
      }
    }
  }
  if (laser) laser->stop();
  std::printf("cdpr-sim: stopped (%llu laser requests answered, %llu SYNCs)\n",
              static_cast<unsigned long long>(laser ? laser->answered() : 0),
              static_cast<unsigned long long>(robot ? robot->stats().syncs : 0));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // Nothing escapes: an unexpected exception is a bug, reported as one.
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cdpr-sim: internal error: %s (please report it)\n", e.what());
  } catch (...) {
    std::fprintf(stderr, "cdpr-sim: internal error: unknown exception (please report it)\n");
  }
  return kExitInternal;
}
