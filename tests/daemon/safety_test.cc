// The safety chain in cdprd composed with the virtual robot (in-process, manual clock): the e-stop
// input's latched quick stop and who clears it, the holding brakes' sequence through the drives'
// digital outputs, the software limits and the workspace box that refuse a move before it starts
// (docs/daemon.md "Safety chain").
#include <gtest/gtest.h>

#include <string>

#include "cdpr/calibration/kinematics.hpp"
#include "cell_fixture.hpp"
#include "virtual_cell.hpp"

namespace cdpr::controller {
namespace {

using json = nlohmann::json;

class DaemonSafety : public testing::CellTest {
 protected:
  DaemonSafety() : CellTest("cdprd-safety-") {}

  // The cell's daemon on the network with the safety objects mapped, with `safety` as its
  // `safety:` group.
  void start_with(const std::string& safety) {
    auto network = cell_->write_safety_network();
    ASSERT_TRUE(network.ok()) << network.status().to_string();
    testing::VirtualCell::Settings s;
    s.canopen = *network;
    s.extra = "safety: " + safety + "\n";
    start_daemon(s);
    ASSERT_TRUE(holds_settled(5.0)) << daemon().status().dump(2);
  }
  bool faulted(double max_s) {
    return run_until([&] { return daemon().state() == DaemonState::kFault; }, max_s);
  }
  bool holding(double max_s) {
    return run_until([&] { return daemon().state() == DaemonState::kHolding; }, max_s);
  }
  int brakes_applied() {
    int n = 0;
    for (int i = 0; i < cell_->robot->num_cables(); ++i)
      n += cell_->robot->drive(i).brake_applied();
    return n;
  }
};

TEST_F(DaemonSafety, AnOpenEStopLatchesAQuickStopThatOnlyAResetWithTheInputClosedClears) {
  start_with("{estop: [{kind: drive_input, node: 3, bit: 16}]}");
  cell_->robot->set_estop(true);
  ASSERT_TRUE(faulted(0.5));
  EXPECT_EQ(daemon().status()["fault"]["fault"], "estop");
  EXPECT_EQ(daemon().rt().snapshot().mode, RtMode::kDisabled) << "quick stop";
  const Reply refused = request("fault_reset");
  EXPECT_FALSE(refused.ok);
  EXPECT_NE(refused.message.find("e-stop input open, silent or stale: source 1"), std::string::npos)
      << refused.message;
  EXPECT_NE(refused.message.find("safety.estop[0]"), std::string::npos) << refused.message;
  cell_->robot->set_estop(false);
  EXPECT_FALSE(holding(1.0)) << "closing the input clears nothing by itself";
  ASSERT_TRUE(request("fault_reset").ok);
  ASSERT_TRUE(holding(10.0)) << daemon().status().dump(2);
}

TEST_F(DaemonSafety, AStartWithTheEStopOpenIsRefusedNamingTheSource) {
  auto network = cell_->write_safety_network();
  ASSERT_TRUE(network.ok()) << network.status().to_string();
  testing::VirtualCell::Settings s;
  s.canopen = *network;
  s.extra = "safety: {estop: [{kind: drive_input, node: 3, bit: 16}]}\n";
  cell_->robot->set_estop(true);
  const Status refused = cell_->start_daemon(s);
  EXPECT_EQ(refused.code(), ErrorCode::kFailedPrecondition) << refused.to_string();
  EXPECT_NE(refused.to_string().find("e-stop input open, silent or stale: source 1"),
            std::string::npos)
      << refused.to_string();
  EXPECT_EQ(daemon().state(), DaemonState::kFault);
  cell_->robot->set_estop(false);
  const Status again = cell_->start_daemon(s);
  EXPECT_TRUE(again.ok()) << again.to_string();
}

TEST_F(DaemonSafety, TheEStopSourcesNodeSilentIsAnOpenInput) {
  start_with("{estop: [{kind: drive_input, node: 3, bit: 16, stale_s: 0.05}]}");
  cell_->robot->drive(2).faults().silent = true;
  ASSERT_TRUE(faulted(0.5));
  EXPECT_EQ(daemon().status()["fault"]["fault"], "estop") << "stale before the heartbeat is lost";
}

TEST_F(DaemonSafety, BrakesReleaseOnlyWhileHoldingAndAFaultAppliesEveryOne) {
  start_with("{brakes: {control: output, release_delay_s: 0.1, apply_delay_s: 0.1}}");
  EXPECT_EQ(brakes_applied(), 0) << "holding: released";
  cell_->robot->drive(2).inject_fault(0x2310);
  ASSERT_TRUE(faulted(0.5));
  ASSERT_TRUE(run_until([&] { return brakes_applied() == cell_->robot->num_cables(); }, 0.1));
  ASSERT_TRUE(request("fault_reset").ok);
  ASSERT_TRUE(holds_settled(10.0)) << daemon().status().dump(2);
  EXPECT_EQ(brakes_applied(), 0);
  for (int i = 0; i < cell_->robot->num_cables(); ++i) {
    EXPECT_EQ(cell_->robot->drive(i).braked_syncs(), 0u)
        << "cable " << i + 1 << ": no target against an applied brake";
  }
}

TEST_F(DaemonSafety, AMoveBeyondTheWorkspaceBoxIsRefusedBeforeItStarts) {
  start_with("{workspace: {min: [-0.1, -0.1, -0.1], max: [0.1, 0.1, 0.1]}}");
  const Reply box = request("move", {{"pose", {0.15, 0, 0, 0, 0, 0}}});
  EXPECT_FALSE(box.ok);
  EXPECT_NE(box.message.find("workspace box"), std::string::npos) << box.message;
  EXPECT_TRUE(request("move", {{"pose", {0.05, 0, 0, 0, 0, 0}}}).ok);
  ASSERT_TRUE(holds_settled(10.0));
  EXPECT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kNone);
}

TEST_F(DaemonSafety, AMoveBeyondAWinchsCableLengthLimitIsRefusedNamingTheCable) {
  // Each cable may grow 5 mm beyond its length at home: a 5 cm move lengthens some by more.
  const RobotModel& model = cell_->nominal;
  KinematicsData home(model.num_cables()), there(model.num_cables());
  ASSERT_TRUE(inverse_kinematics(model, model.home, home));
  Pose to = model.home;
  to.position.x() += 0.05;
  ASSERT_TRUE(inverse_kinematics(model, to, there));
  std::string max;
  for (int i = 0; i < model.num_cables(); ++i) {
    max += (i == 0 ? "" : ", ") + std::to_string(home.lengths(i) + 0.005);
  }
  int longer = 0;
  (there.lengths - home.lengths).maxCoeff(&longer);
  ASSERT_GT(there.lengths(longer) - home.lengths(longer), 0.005);
  start_with("{cable_length: {min: 0.05, max: [" + max + "]}}");
  const std::uint64_t taken = daemon().rt().snapshot().command_taken;
  const Reply r =
      request("move", {{"pose", {to.position.x(), to.position.y(), to.position.z(), 0, 0, 0}}});
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.message.find("m long >"), std::string::npos) << r.message;
  cell_->run_until([] { return false; }, 0.1);
  EXPECT_EQ(daemon().rt().snapshot().command_taken, taken) << "nothing moved";
}

}  // namespace
}  // namespace cdpr::controller
