// cdprd's supervisor and RT cycle composed with the virtual robot in ONE process, over the
// in-process virtual CAN bus with a manual clock and the laser over Modbus TCP on loopback: the
// daemon's logic tested in seconds (the same scenarios run across processes on vcan in
// tests/daemon/daemon_vcan_test.cc). The composition lives here, not in the daemon: the
// controller and the virtual robot only meet on the bus and the Modbus link, as on the robot.
//
// Truth: config/mini-measured.yaml with config/scenarios/mini-calibration.yaml's hidden effects
// (softer cables, encoder zero offsets, noise); the daemon starts from config/mini.yaml. The drives
// power on with the true platform at home (the reference platform).
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <thread>

#include "alloc_counter.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/modbus/laser_sensor.hpp"
#include "cdpr/modbus/register_map.hpp"
#include "cdpr/sim/can_robot.hpp"
#include "cdpr/sim/laser_slave.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::controller {
namespace {

using namespace std::chrono_literals;
using json = nlohmann::json;
namespace fs = std::filesystem;

const std::string kSource = CDPR_SOURCE_DIR;

// RMS over cables of the frame-anchor distance between two models, m.
double anchor_rms(const RobotModel& a, const RobotModel& b) {
  double s = 0.0;
  for (std::size_t i = 0; i < a.cables.size(); ++i) {
    s += (a.frame_anchors.col(static_cast<Eigen::Index>(i)) -
          b.frame_anchors.col(static_cast<Eigen::Index>(i)))
             .squaredNorm();
  }
  return std::sqrt(s / static_cast<double>(a.cables.size()));
}

class DaemonNative : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("cdprd-native-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    make_robot();
  }
  void TearDown() override {
    if (daemon_) daemon_->shutdown();
    daemon_.reset();
    if (laser_) laser_->stop();
    if (slave_) slave_->stop();
    fs::remove_all(dir_);
  }

  void make_robot() {
    auto nominal = config::load_robot_config(kSource + "/config/mini.yaml");
    ASSERT_TRUE(nominal.ok()) << nominal.status().to_string();
    nominal_ = *nominal;
    auto scenario = sim::load_scenario(kSource + "/config/scenarios/mini-calibration.yaml");
    ASSERT_TRUE(scenario.ok()) << scenario.status().to_string();
    scenario_ = *scenario;
    auto truth = sim::resolve_truth(scenario_, nominal_);
    ASSERT_TRUE(truth.ok()) << truth.status().to_string();
    auto p = sim::Physics::create(*truth, scenario_, 7);
    ASSERT_TRUE(p.ok()) << p.status().to_string();
    physics_ = std::make_unique<sim::Physics>(std::move(*p));
    auto home = sim::true_pose_counts(*physics_, physics_->truth().home);
    ASSERT_TRUE(home.ok()) << home.status().to_string();
    ASSERT_TRUE(physics_->step(home->array().round().matrix(), 0.0).ok());
    auto network = canopen::load_config(kSource + "/config/canopen-mini.yaml");
    ASSERT_TRUE(network.ok()) << network.status().to_string();
    network_ = *network;
    sim::CanRobotOptions ro;
    for (int i = 0; i < home->size(); ++i) {
      ro.initial_counts.push_back(static_cast<std::int32_t>(std::lround((*home)(i))));
    }
    auto r = sim::CanRobot::create(*robot_ep_, network_, *physics_, ro);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    robot_ = std::move(*r);
    robot_->power_on(clock_.now());

    // The laser: the sim's Modbus slave on loopback TCP, our driver reading it.
    auto map = modbus::load_register_map(kSource + "/config/lasers/baumer-om20-om30.yaml");
    ASSERT_TRUE(map.ok()) << map.status().to_string();
    sim::LaserSlaveConfig lc;
    lc.transport = sim::LaserSlaveConfig::Transport::kTcp;
    lc.map = *map;
    lc.noise_sigma_m = scenario_.noise.laser;
    auto slave = sim::LaserSlave::start(lc);
    ASSERT_TRUE(slave.ok()) << slave.status().to_string();
    slave_ = std::move(*slave);
    update_laser();
    modbus::LaserConfig cfg;
    cfg.map = *map;
    modbus::TcpSettings tcp;
    tcp.port = slave_->port();
    cfg.link.transport = tcp;
    cfg.poll_rate_hz = 200.0;
    laser_ = std::make_unique<modbus::LaserSensor>(cfg);
    ASSERT_TRUE(laser_->start().ok());
  }

  void update_laser() {
    const sim::LaserChannel l = physics_->state().lasers.front();
    slave_->set_distance(l.true_distance, l.status);
  }

  std::string config_text(const std::string& extra = "") const {
    return "robot: " + kSource + "/config/mini.yaml\n" + "canopen: " + kSource +
           "/config/canopen-mini.yaml\n" + "state_directory: " + (dir_ / "state").string() +
           "\n"
           "identity: {vendor_id: 0x00CD9001, drive_product_code: 0x402, force_product_code: "
           "0x404}\n"
           "motion: {max_linear_velocity: 0.15, max_linear_acceleration: 0.5, "
           "max_linear_jerk: 5, max_angular_velocity: 0.5, max_angular_acceleration: 2, "
           "max_angular_jerk: 20}\n"
           "measuring: {poses: 25, laser_samples: 5, laser_interval_s: 0.002, average_cycles: "
           "25, noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4, tension_band: 1}\n"
           "identification: {bootstrap: 30}\n" +
           extra;
  }

  // Creates and starts the daemon (state directory kept between calls: a restart).
  void start_daemon(const std::string& extra = "") {
    auto cfg = parse_daemon_config(config_text(extra), (dir_ / "cdprd.yaml").string());
    ASSERT_TRUE(cfg.ok()) << cfg.status().to_string();
    config_ = *cfg;
    DaemonIo io;
    io.bus = master_ep_.get();
    io.laser = laser_.get();
    io.clock = &clock_;
    io.idle = [this] { idle(); };
    io.poll = 200us;
    auto d = Daemon::create(config_, io);
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    daemon_ = std::move(*d);
    daemon_->set_event_sink([this](const json& e) {
      std::lock_guard lock(events_mu_);
      events_.push_back(e);
    });
    const Status s = daemon_->start();
    ASSERT_TRUE(s.ok()) << s.to_string();
    run_until([&] { return daemon_->rt().snapshot().mode == RtMode::kHolding; }, 5.0);
  }

  void idle() {
    clock_.advance(250us);
    robot_->step(clock_.now());
    update_laser();
  }

  // One SYNC period: the daemon's RT cycle, then the robot until the next one.
  void cycle() {
    daemon_->cycle(clock_.now());
    const can::Timestamp next = clock_.now() + network_.sync_period;
    while (clock_.now() < next) idle();
    if (++cycles_ % 5 == 0) daemon_->service();
    // Leave the CPU to the worker while it identifies (the robot holds meanwhile).
    if (daemon_->state() == DaemonState::kIdentifying) std::this_thread::sleep_for(2ms);
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
  double seconds() const { return std::chrono::duration<double>(clock_.now()).count(); }

  Reply request(const std::string& cmd, const json& args = json::object()) {
    PeerInfo peer{static_cast<int>(::getpid()), static_cast<int>(::getuid()),
                  static_cast<int>(::getgid())};
    return daemon_->handle(cmd, args, peer);
  }

  bool saw_event(const std::string& type, const std::string& key, const std::string& value) {
    std::lock_guard lock(events_mu_);
    for (const json& e : events_) {
      if (e["event"] == type && e["data"].contains(key) && e["data"][key] == value) return true;
    }
    return false;
  }

  // One cycle's normal motion: the largest target change per cycle at the configured cable speed.
  double one_cycle_counts() const {
    const double dt = std::chrono::duration<double>(network_.sync_period).count();
    return config_.motion.max_cable_speed * dt / winch_metres_per_count(nominal_.winches[0]);
  }

  // Runs a full calibration through the control requests; returns the calibration id.
  int calibrate() {
    const Reply r = request("calibrate");
    EXPECT_TRUE(r.ok) << r.code << ": " << r.message;
    if (!r.ok) return 0;
    const bool done = run_until(
        [&] {
          const DaemonState s = daemon_->state();
          return s == DaemonState::kAwaitingAcceptance || s == DaemonState::kFault ||
                 (s == DaemonState::kHolding && !daemon_->status()["calibration"].is_null() &&
                  daemon_->status()["calibration"]["outcome"] != "measuring" &&
                  daemon_->status()["calibration"]["outcome"] != "identifying");
        },
        900.0);
    EXPECT_TRUE(done) << daemon_->status().dump(2);
    EXPECT_EQ(daemon_->state(), DaemonState::kAwaitingAcceptance) << daemon_->status().dump(2);
    return r.result["calibration"].get<int>();
  }

  fs::path dir_;
  can::ManualClock clock_;
  can::VirtualCanBus bus_{clock_};
  std::unique_ptr<can::VirtualCanEndpoint> master_ep_ = bus_.endpoint("cdprd");
  std::unique_ptr<can::VirtualCanEndpoint> robot_ep_ = bus_.endpoint("cdpr-sim");
  RobotModel nominal_;
  sim::Scenario scenario_;
  std::unique_ptr<sim::Physics> physics_;
  canopen::MasterConfig network_;
  std::unique_ptr<sim::CanRobot> robot_;
  std::unique_ptr<sim::LaserSlave> slave_;
  std::unique_ptr<modbus::LaserSensor> laser_;
  DaemonConfig config_;
  std::unique_ptr<Daemon> daemon_;
  std::mutex events_mu_;
  std::vector<json> events_;
  std::uint64_t cycles_ = 0;
};

TEST_F(DaemonNative, CalibratesMiniAcceptsBumplesslyAndTheNextMoveLandsOnTarget) {
  start_daemon();
  const double t0 = seconds();
  const auto wall0 = std::chrono::steady_clock::now();
  const int id = calibrate();
  ASSERT_GT(id, 0);
  std::printf("[daemon-native] calibration %d: %.1f s of robot time, %.1f s wall\n", id,
              seconds() - t0,
              std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count());
  const json st = daemon_->status();
  ASSERT_EQ(st["calibration"]["outcome"], "awaiting_acceptance") << st.dump(2);
  // The report names the hidden elasticity and proposes anchors close to the truth.
  auto report = request("report");
  ASSERT_TRUE(report.ok) << report.message;
  const json& rep = report.result["report"];
  std::printf("[daemon-native] verdict: %s; gates passed: %d\n",
              rep["verdict"].get<std::string>().c_str(), rep["gates_passed"].get<bool>());
  std::printf("[daemon-native] fit: %s\n", rep["fit"].dump().c_str());
  EXPECT_TRUE(rep["gates_passed"].get<bool>()) << rep["gates"].dump(2);
  auto after =
      config::load_robot_config(daemon_->store().calibration_dir(id) + "/model_after.yaml");
  ASSERT_TRUE(after.ok()) << after.status().to_string();
  const double before_rms = anchor_rms(nominal_, physics_->truth());
  const double after_rms = anchor_rms(*after, physics_->truth());
  std::printf("[daemon-native] anchors RMS vs truth: %.3f mm before, %.3f mm after\n",
              before_rms * 1e3, after_rms * 1e3);
  EXPECT_LT(after_rms, 1e-3);
  EXPECT_LT(after_rms, before_rms);

  // Accept: the hot swap does not jump.
  const Reply acc = request("accept");
  ASSERT_TRUE(acc.ok) << acc.message;
  const int version = acc.result["version"].get<int>();
  ASSERT_TRUE(run_until([&] { return daemon_->state() == DaemonState::kHolding; }, 30.0))
      << daemon_->status().dump(2);
  EXPECT_EQ(daemon_->status()["geometry_version"], version);
  const RtSnapshot snap = daemon_->rt().snapshot();
  std::printf(
      "[daemon-native] hot swap: largest target step %.1f counts (one cycle of normal "
      "motion: %.1f counts)\n",
      snap.largest_reference_step, one_cycle_counts());
  EXPECT_LE(snap.largest_reference_step, one_cycle_counts());
  EXPECT_TRUE(saw_event("calibration", "outcome", "applied"));

  // A test move with the new geometry lands within 0.5 mm of its target in the sim.
  Pose target = nominal_.home;
  target.position += Eigen::Vector3d(0.05, -0.04, 0.03);
  const Reply mv = request(
      "move",
      {{"pose", {target.position.x(), target.position.y(), target.position.z(), 0.0, 0.0, 0.0}}});
  ASSERT_TRUE(mv.ok) << mv.message;
  ASSERT_TRUE(run_until(
      [&] {
        const RtSnapshot s = daemon_->rt().snapshot();
        return daemon_->state() == DaemonState::kHolding && s.settled &&
               (s.pose().position - target.position).norm() < 1e-9;
      },
      30.0));
  const double error = (physics_->state().pose.position - target.position).norm();
  std::printf("[daemon-native] test move: true position error %.3f mm\n", error * 1e3);
  EXPECT_LT(error, 0.5e-3);
}

TEST_F(DaemonNative, RtCycleDoesNotAllocateWhileHoldingOrMoving) {
  start_daemon();
  Pose target = nominal_.home;
  target.position.z() += 0.02;
  ASSERT_TRUE(request("move", {{"pose", {0.0, 0.0, target.position.z(), 0.0, 0.0, 0.0}}}).ok);
  // The robot's steps allocate (it stands in for devices); count only the daemon's cycle.
  std::uint64_t allocations = 0;
  for (int c = 0; c < 300; ++c) {
    {
      test::AllocationCounter count;
      daemon_->cycle(clock_.now());
      allocations += count.allocations();
    }
    const can::Timestamp next = clock_.now() + network_.sync_period;
    while (clock_.now() < next) idle();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_GT(daemon_->rt().snapshot().largest_move_step, 0.0) << "the platform did not move";
}

TEST_F(DaemonNative, AbortHoldsTheRobotAndKeepsTheGeometry) {
  start_daemon();
  const int before = daemon_->status()["geometry_version"].get<int>();
  ASSERT_TRUE(request("calibrate").ok);
  ASSERT_TRUE(
      run_until([&] { return daemon_->status()["calibration"]["pose"].get<int>() >= 3; }, 120.0));
  const Reply ab = request("abort");
  ASSERT_TRUE(ab.ok) << ab.message;
  ASSERT_TRUE(run_until(
      [&] { return daemon_->state() == DaemonState::kHolding && daemon_->rt().snapshot().settled; },
      30.0))
      << daemon_->status().dump(2);
  const json st = daemon_->status();
  EXPECT_EQ(st["calibration"]["outcome"], "aborted");
  EXPECT_EQ(st["geometry_version"], before);
  EXPECT_TRUE(st["fault"].is_null());
  // The partial recording is kept and readable.
  const std::string rec =
      daemon_->store().calibration_dir(st["calibration"]["id"].get<int>()) + "/recording.csv";
  auto r = recording::read_recording(rec);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_GE(r->poses.size(), 3u);
}

TEST_F(DaemonNative, RejectKeepsTheGeometryRestartKeepsTheAcceptedOneAndRollbackIsBumpless) {
  start_daemon(
      "measuring: {poses: 12, laser_samples: 3, laser_interval_s: 0.002}\n"
      "identification: {diagnose: false}\n");
  const int v1 = daemon_->status()["geometry_version"].get<int>();
  ASSERT_GT(calibrate(), 0);
  ASSERT_TRUE(request("reject").ok);
  run_until([&] { return daemon_->state() == DaemonState::kHolding; }, 5.0);
  EXPECT_EQ(daemon_->status()["geometry_version"], v1);
  EXPECT_TRUE(saw_event("calibration", "outcome", "rejected"));

  ASSERT_GT(calibrate(), 0);
  const Reply acc = request("accept");
  ASSERT_TRUE(acc.ok) << acc.message;
  const int v2 = acc.result["version"].get<int>();
  ASSERT_TRUE(run_until([&] { return daemon_->state() == DaemonState::kHolding; }, 30.0));
  ASSERT_EQ(daemon_->status()["geometry_version"], v2);

  // Restart: a new daemon on the same state directory comes back with version v2, where the
  // platform is, without a jump.
  const RtSnapshot old = daemon_->rt().snapshot();
  daemon_->shutdown();
  daemon_.reset();
  start_daemon(
      "measuring: {poses: 12, laser_samples: 3, laser_interval_s: 0.002}\n"
      "identification: {diagnose: false}\n");
  EXPECT_EQ(daemon_->status()["geometry_version"], v2);
  const RtSnapshot now = daemon_->rt().snapshot();
  EXPECT_LT((now.pose().position - old.pose().position).norm(), 0.2e-3);
  EXPECT_LE(now.largest_reference_step, one_cycle_counts());

  // Rollback to v1: bumpless too, and recorded in the history.
  const Reply rb = request("geometry_rollback", {{"version", v1}});
  ASSERT_TRUE(rb.ok) << rb.message;
  ASSERT_TRUE(run_until([&] { return daemon_->state() == DaemonState::kHolding; }, 30.0));
  EXPECT_EQ(daemon_->status()["geometry_version"], v1);
  EXPECT_LE(daemon_->rt().snapshot().largest_reference_step, one_cycle_counts());
  const Reply h = request("geometry_history");
  ASSERT_TRUE(h.ok);
  EXPECT_EQ(h.result["activations"].back()["version"], v1);
  const Reply diff = request("geometry_diff", {{"from", v1}, {"to", v2}});
  ASSERT_TRUE(diff.ok) << diff.message;
  EXPECT_GT(diff.result["largest_change_m"].get<double>(), 0.0);
}

TEST_F(DaemonNative, AnOperatorQuickStopFaultsAndFaultResetHoldsWhereThePlatformStopped) {
  start_daemon();
  ASSERT_TRUE(request("stop").ok);
  ASSERT_TRUE(run_until([&] { return daemon_->state() == DaemonState::kFault; }, 2.0));
  const json st = daemon_->status();
  EXPECT_EQ(st["fault"]["fault"], "quick_stop");
  EXPECT_EQ(request("calibrate").code, "fault");
  ASSERT_TRUE(request("fault_reset").ok);
  ASSERT_TRUE(run_until([&] { return daemon_->state() == DaemonState::kHolding; }, 10.0))
      << daemon_->status().dump(2);
  EXPECT_LE(daemon_->rt().snapshot().largest_reference_step, one_cycle_counts());
}

TEST_F(DaemonNative, RequestsWithBadArgumentsAreNamedErrors) {
  start_daemon();
  EXPECT_EQ(request("nonsense").code, "unknown_command");
  EXPECT_EQ(request("accept").code, "invalid_state");
  EXPECT_EQ(request("geometry_rollback", {{"version", "x"}}).code, "bad_request");
  EXPECT_EQ(request("geometry_rollback", {{"version", 99}}).code, "not_found");
  EXPECT_EQ(request("calibrate",
                    {{"poses_csv", "# units: SI\npose,x,y,z,roll,pitch,yaw\n0,5,0,0,0,0,0\n"}})
                .code,
            "bad_request");
  const Reply dry = request("calibrate", {{"dry_run", true}});
  ASSERT_TRUE(dry.ok) << dry.message;
  EXPECT_EQ(dry.result["poses"].size(), 25u);
  EXPECT_EQ(daemon_->state(), DaemonState::kHolding);
}

}  // namespace
}  // namespace cdpr::controller
