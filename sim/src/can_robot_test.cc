// The virtual robot's CANopen side against our own master (drivers/canopen) on the in-process
// virtual bus with a manual clock: boot, CSP motion through the physics, force readings, faults.
#include "cdpr/sim/can_robot.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/master.hpp"
#include "cdpr/config/robot_config.hpp"

namespace cdpr::sim {
namespace {

using namespace std::chrono_literals;
namespace co = cdpr::canopen;

class CanRobotTest : public ::testing::Test {
 protected:
  // Builds the physics for a scenario with these `faults:` lines, the CAN robot (drives at the
  // true model's home counts) and the master, and boots the master.
  void make(const std::string& faults_yaml = "") {
    auto nominal = config::load_robot_config(CDPR_SOURCE_DIR "/config/mini.yaml");
    ASSERT_TRUE(nominal.ok()) << nominal.status().to_string();
    const std::string text = "name: can-test\n" + faults_yaml;
    auto scenario = parse_scenario(text, "can-test.yaml", CDPR_SOURCE_DIR "/config/scenarios");
    ASSERT_TRUE(scenario.ok()) << scenario.status().to_string();
    auto truth = resolve_truth(*scenario, *nominal);
    ASSERT_TRUE(truth.ok()) << truth.status().to_string();
    auto p = Physics::create(*truth, *scenario, 1);
    ASSERT_TRUE(p.ok()) << p.status().to_string();
    physics = std::make_unique<Physics>(std::move(*p));
    auto home = nominal_counts(physics->truth(), physics->truth().home);
    ASSERT_TRUE(home.ok()) << home.status().to_string();
    CanRobotOptions opts;
    for (int i = 0; i < home->size(); ++i) {
      home_counts.push_back(static_cast<std::int32_t>(std::lround((*home)(i))));
    }
    opts.initial_counts = home_counts;
    opts.report = [this](double t, const std::string& s) {
      reports.push_back(s);
      std::printf("[t = %.3f s] %s\n", t, s.c_str());
    };
    auto c = co::load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    config = *c;
    auto r = CanRobot::create(*robot_ep, config, *physics, opts);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    robot = std::move(*r);
    robot->power_on(clock.now());

    co::MasterHooks hooks;
    hooks.now = [this] { return clock.now(); };
    hooks.idle = [this] { idle(); };
    hooks.receive_timeout = 0ns;
    auto m = co::Master::create(*master_ep, config, hooks);
    ASSERT_TRUE(m.ok()) << m.status().to_string();
    master = std::move(*m);
    const Status s = master->boot();
    ASSERT_TRUE(s.ok()) << s.to_string();
    // The fault scenarios below start at 1 s: the boot must be over by then.
    ASSERT_LT(robot->scenario_time(clock.now()), 0.9);
  }

  void idle() {
    clock.advance(250us);
    robot->step(clock.now());
  }

  // The RT loop for `d`: cycle at the SYNC period, the robot in between.
  void run(std::chrono::nanoseconds d) {
    const Timestamp end = clock.now() + d;
    while (clock.now() < end) {
      master->cycle(clock.now());
      const Timestamp next = clock.now() + config.sync_period;
      while (clock.now() < next) idle();
    }
  }
  void run_until(double scenario_t) {
    while (robot->scenario_time(clock.now()) < scenario_t) run(config.sync_period);
  }

  std::vector<co::Event> drain() {
    std::vector<co::Event> out;
    co::Event e;
    while (master->events().pop(e)) out.push_back(e);
    return out;
  }

  cdpr::ManualClock clock;
  can::VirtualCanBus bus{clock};
  std::unique_ptr<can::VirtualCanEndpoint> master_ep = bus.endpoint("master");
  std::unique_ptr<can::VirtualCanEndpoint> robot_ep = bus.endpoint("cdpr-sim");
  std::unique_ptr<Physics> physics;
  std::vector<std::int32_t> home_counts;
  std::vector<std::string> reports;
  co::MasterConfig config;
  std::unique_ptr<CanRobot> robot;
  std::unique_ptr<co::Master> master;
};

double position_error(const Pose& a, const Pose& b) {
  return (a.position - b.position).norm();
}

TEST_F(CanRobotTest, BootsEnablesMovesThePlatformAndReportsForces) {
  make();
  // Identity and what the master configured.
  for (co::NodeId id = 1; id <= 9; ++id) {
    auto serial = master->sdo(id)->read<std::uint32_t>({0x1018, 4}, master->pump());
    ASSERT_TRUE(serial.ok()) << serial.status().to_string();
    EXPECT_EQ(*serial, 0x5100'0000u + id);
    auto vendor = master->sdo(id)->read<std::uint32_t>({0x1018, 1}, master->pump());
    ASSERT_TRUE(vendor.ok());
    EXPECT_EQ(*vendor, 0x00CD9001u);
    EXPECT_EQ(robot->node(id).nmt_state(), co::NmtState::kOperational);
  }
  auto product = master->sdo(9)->read<std::uint32_t>({0x1018, 2}, master->pump());
  ASSERT_TRUE(product.ok());
  EXPECT_EQ(*product, 0x404u);
  EXPECT_EQ(robot->node(9).od().get({0x1A01, 4}), 0x64010810);
  for (int i = 0; i < 8; ++i) EXPECT_EQ(robot->drive(i).od().get({0x6061, 0}), 8);

  ASSERT_TRUE(master->enable_all(2s).ok());
  run(40ms);
  for (co::NodeId id = 1; id <= 8; ++id) {
    co::Drive* d = master->drive(id);
    ASSERT_NE(d, nullptr);
    EXPECT_TRUE(d->enabled());
    EXPECT_EQ(d->actual_counts(), home_counts[id - 1u]);
    EXPECT_EQ(robot->drive(id - 1).max_jump_on_enable(), 0);
  }
  const Pose home = physics->truth().home;
  EXPECT_LT(position_error(physics->state().pose, home), 1e-3);

  // Command the true geometry's IK counts of a pose away from home, ramped over 0.4 s.
  Pose target = home;
  target.position += Eigen::Vector3d(0.04, -0.03, 0.05);
  target.rpy = Eigen::Vector3d(0.02, -0.01, 0.03);
  auto c = nominal_counts(physics->truth(), target);
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  const int steps = 100;
  for (int k = 1; k <= steps; ++k) {
    for (co::NodeId id = 1; id <= 8; ++id) {
      const double h = home_counts[id - 1u];
      const double x = h + ((*c)(id - 1) - h) * k / steps;
      ASSERT_TRUE(master->drive(id)->set_target_counts(static_cast<std::int32_t>(std::lround(x))));
    }
    run(config.sync_period);
  }
  run(5 * config.sync_period);
  for (co::NodeId id = 1; id <= 8; ++id) {
    const auto want = static_cast<std::int32_t>(std::lround((*c)(id - 1)));
    EXPECT_EQ(robot->drive(id - 1).position(), want) << int{id};
    EXPECT_EQ(master->drive(id)->actual_counts(), want) << int{id};
  }
  const PhysicsState& s = physics->state();
  EXPECT_TRUE(s.converged);
  EXPECT_GT(position_error(target, home), 0.07);
  // Compensated IK of the true model: only the count rounding (1 um per count) is left.
  EXPECT_LT(position_error(s.pose, target), 1e-4);
  EXPECT_LT((s.pose.rpy - target.rpy).cwiseAbs().maxCoeff(), 1e-3);
  EXPECT_EQ(robot->stats().physics_failures, 0u);
  EXPECT_GT(robot->stats().syncs, 100u);

  // Forces through the master: raw = 2 * tension (i16), read back with the configured gain.
  co::ForceSensor* f = master->force_sensor(9);
  ASSERT_NE(f, nullptr);
  ASSERT_EQ(f->channels(), 8u);
  for (std::size_t k = 0; k < 8; ++k) {
    const double truth_n = s.tensions(static_cast<int>(k));
    EXPECT_GT(truth_n, 1.0);
    EXPECT_NEAR(f->tension(k), truth_n, 0.26) << "channel " << k;
    EXPECT_EQ(f->raw(k), std::lround(2.0 * truth_n));
  }
}

TEST_F(CanRobotTest, ScenarioDriveFaultIsTheMastersEmcy) {
  make("faults:\n  - {type: drive_fault, at: 1.0, cable: 4, emcy: 0x7500}\n");
  ASSERT_TRUE(master->enable_all(2s).ok());
  run_until(0.95);
  for (const co::Event& e : drain()) EXPECT_NE(e.type, co::EventType::kEmcy);
  EXPECT_TRUE(master->drive(4)->enabled());
  run_until(1.1);
  bool emcy = false, fault = false;
  for (const co::Event& e : drain()) {
    if (e.type == co::EventType::kEmcy) {
      EXPECT_EQ(e.node, 4);
      EXPECT_EQ(e.emcy.code, 0x7500);
      emcy = true;
    }
    if (e.type == co::EventType::kDriveFault && e.node == 4) fault = true;
  }
  EXPECT_TRUE(emcy);
  EXPECT_TRUE(fault);
  EXPECT_EQ(master->drive(4)->state(), co::cia402::State::kFault);
  EXPECT_TRUE(master->faulted());
}

TEST_F(CanRobotTest, ScenarioSilentDriveIsHeartbeatLoss) {
  make("faults:\n  - {type: drive_silent, at: 1.0, duration: 0.5, cable: 6}\n");
  ASSERT_TRUE(master->enable_all(2s).ok());
  run_until(0.95);
  for (const co::Event& e : drain()) EXPECT_NE(e.type, co::EventType::kHeartbeatLost);
  run_until(1.3);
  bool lost = false;
  for (const co::Event& e : drain()) {
    if (e.type == co::EventType::kHeartbeatLost) {
      EXPECT_EQ(e.node, 6);
      lost = true;
    }
  }
  EXPECT_TRUE(lost);
  EXPECT_TRUE(master->faulted());
  run_until(1.7);
  bool regained = false;
  for (const co::Event& e : drain()) {
    if (e.type == co::EventType::kHeartbeatRegained && e.node == 6) regained = true;
  }
  EXPECT_TRUE(regained);
}

TEST_F(CanRobotTest, ScenarioOverloadSdoAbortAndBusOff) {
  make(
      "faults:\n"
      "  - {type: cable_overload, at: 1.0, cable: 2, limit: 1, emcy: 0x2311}\n"
      "  - {type: sdo_abort, at: 1.0, cable: 1, object: 0x6064, subindex: 0, code: 0x06010000}\n"
      "  - {type: bus_off, at: 1.5, duration: 0.2}\n");
  ASSERT_TRUE(master->enable_all(2s).ok());
  auto before = master->sdo(1)->read<std::int32_t>({0x6064, 0}, master->pump());
  ASSERT_TRUE(before.ok()) << before.status().to_string();
  EXPECT_EQ(*before, home_counts[0]);
  run_until(1.1);
  bool overload = false;
  for (const co::Event& e : drain()) {
    if (e.type == co::EventType::kEmcy) {
      EXPECT_EQ(e.node, 2);
      EXPECT_EQ(e.emcy.code, 0x2311);
      overload = true;
    }
  }
  EXPECT_TRUE(overload);
  EXPECT_EQ(master->drive(2)->state(), co::cia402::State::kFault);
  auto after = master->sdo(1)->read<std::int32_t>({0x6064, 0}, master->pump());
  ASSERT_FALSE(after.ok());
  EXPECT_NE(after.status().to_string().find("0x06010000"), std::string::npos)
      << after.status().to_string();
  run_until(1.6);
  EXPECT_TRUE(robot->bus_off());
  run_until(2.5);
  bool off = false, recovered = false;
  for (const co::Event& e : drain()) {
    if (e.type == co::EventType::kBusOff) off = true;
    if (e.type == co::EventType::kBusRecovered) recovered = off;
  }
  EXPECT_TRUE(off);
  EXPECT_TRUE(recovered);
  EXPECT_GT(robot->stats().frames_dropped_bus_off, 0u);
}

// The nodes are built from the shipped EDS files that canopen-mini.yaml names: the drives come
// with their default PDO mappings enabled, as real drives do, and the master disables what it
// does not use, so no frame of those PDOs reaches the bus.
TEST_F(CanRobotTest, NodesComeFromTheEdsWithDefaultPdosThatTheMasterDisables) {
  make();
  ASSERT_NE(config.nodes[0].eds_data, nullptr);
  for (int cable = 0; cable < robot->num_cables(); ++cable) {
    auto& od = robot->drive(cable).od();
    const co::NodeId id = robot->drive(cable).id();
    // RPDO1, TPDO1 and TPDO2 (the digital inputs) are the configuration's.
    for (std::uint16_t comm : {0x1401, 0x1402, 0x1403, 0x1802, 0x1803}) {
      const auto* e = od.find({comm, 1});
      ASSERT_NE(e, nullptr);
      EXPECT_EQ(e->default_data[3] & 0x80, 0)
          << "the EDS default of 0x" << std::hex << comm << " should be enabled";
      EXPECT_NE(od.get({comm, 1}) & co::cob::kInvalidBit, 0u)
          << "node " << int{id} << " 0x" << std::hex << comm << " left enabled";
    }
    EXPECT_EQ(master->disabled_pdos(id).size(), 5u);
    EXPECT_EQ(od.get({0x6502, 0}), 0xA1);
    EXPECT_FALSE(od.find({0x607C, 0})->mappable);  // PDOMapping=0 in the EDS
  }
  auto type = master->sdo(9)->read<std::uint32_t>({0x1000, 0}, master->pump());
  ASSERT_TRUE(type.ok());
  EXPECT_EQ(*type, 0x194u);
  ASSERT_TRUE(master->enable_all(2s).ok());
  const auto unknown = master->stats().unknown_frames;
  run(200ms);
  EXPECT_EQ(master->stats().unknown_frames, unknown) << "frames of PDOs nobody configured";
  EXPECT_LT(master->bus_load().load, 0.7);
}

// Issue 39 (7): the vcan tests' network builds the virtual robot from the shipped EDS files, the
// same ones config/canopen-mini.yaml names, so those tests see the dictionaries that ship.
TEST(CanRobotNetworks, TheVcanTestNetworkUsesTheShippedEdsFiles) {
  auto shipped = co::load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
  ASSERT_TRUE(shipped.ok()) << shipped.status().to_string();
  auto test = co::load_config(CDPR_SOURCE_DIR "/config/sim/canopen.yaml");
  ASSERT_TRUE(test.ok()) << test.status().to_string();
  ASSERT_EQ(test->nodes.size(), shipped->nodes.size());
  for (std::size_t i = 0; i < test->nodes.size(); ++i) {
    const co::NodeConfig& t = test->nodes[i];
    ASSERT_NE(t.eds_data, nullptr) << t.name << " has no EDS";
    EXPECT_EQ(std::filesystem::weakly_canonical(t.eds),
              std::filesystem::weakly_canonical(shipped->nodes[i].eds))
        << t.name;
  }
}

}  // namespace
}  // namespace cdpr::sim
