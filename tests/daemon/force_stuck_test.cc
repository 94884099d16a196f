// The stuck force reading watch of cdprd's RT loop (docs/daemon.md, "The RT cycle"): a force
// channel whose raw value does not change while its cable's expected tension is made to change
// (a move, a tension-regulation trim) by more than tension_watch.stuck_raw_units raw units is the
// named fault `force_stuck`; found on a still robot it holds (no command is taken until
// fault_reset), found while moving it quick-stops. A still, healthy robot never raises it.
//
// cdprd's Daemon and the virtual robot in one process (tests/daemon/virtual_cell.hpp: the virtual
// CAN bus with a manual clock); the virtual robot's sensor noise is the scenario's
// (config/scenarios/mini-calibration.yaml: 0.2 raw units, gain 2 raw/N).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <tuple>

#include "alloc_counter.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cell_fixture.hpp"
#include "virtual_cell.hpp"

namespace cdpr::controller {
namespace {

using json = nlohmann::json;

class ForceStuck : public testing::CellTest {
 protected:
  ForceStuck() : CellTest("cdprd-stuck-") {}

  void SetUp() override {
    CellTest::SetUp();
    if (HasFatalFailure()) return;
    start_daemon();
    if (HasFatalFailure()) return;
    ASSERT_TRUE(holds_settled(10.0));
  }
  // Raw units per N of the force channels (config/canopen-mini.yaml).
  double gain() { return daemon().master().force_sensors()[0].gain(0); }
  // Planned tensions at a pose under the active geometry (what the RT loop plans there).
  Eigen::VectorXd planned(const Pose& pose) {
    CommandData data(cell_->nominal);
    const Status s =
        command_counts(cell_->nominal, pose, daemon().rt().snapshot().reference_tension, data);
    EXPECT_TRUE(s.ok()) << s.to_string();
    return data.plan.tensions;
  }
  // Counts of cable `k` that shorten it by the stretch of `newtons` more tension at `pose`.
  double counts_for(int k, double newtons, const Pose& pose) {
    CommandData data(cell_->nominal);
    EXPECT_TRUE(
        command_counts(cell_->nominal, pose, daemon().rt().snapshot().reference_tension, data)
            .ok());
    const auto kk = static_cast<std::size_t>(k);
    const double stiffness = cell_->nominal.cables[kk].ea / data.cable.loaded_lengths(k);
    const WinchModel& w = cell_->nominal.winches[kk];
    return -newtons / stiffness / (w.direction * winch_metres_per_count(w));
  }
  // A trim command owned by the test (it outlives its use in the RT loop).
  void post_trim(int k, double counts) {
    trim_ = std::make_unique<MotionCommand>();
    trim_->type = MotionCommand::Type::kTrim;
    trim_->seq = 1u << 30;
    trim_->trim[static_cast<std::size_t>(k)] = counts;
    daemon().rt().post(trim_.get());
  }
  double stuck_raw_units() { return daemon().config().tension_watch.stuck_raw_units; }
  // The move from `from` along one axis (up to 0.15 m, feasible) whose planned tensions change
  // most for one cable: its target, that cable and the change (N).
  std::tuple<Pose, Eigen::Index, double> largest_plan_change(const Pose& from) {
    Pose target = from;
    Eigen::Index k = 0;
    double largest = 0.0;
    for (int axis = 0; axis < 3; ++axis) {
      for (double d : {-0.15, -0.12, -0.1, 0.1, 0.12, 0.15}) {
        Pose p = from;
        p.position(axis) += d;
        if (!check_pose(cell_->nominal, p, PathCheckOptions{}).ok()) continue;
        Eigen::Index i = 0;
        const double c = (planned(p) - planned(from)).cwiseAbs().maxCoeff(&i);
        if (c > largest) {
          largest = c;
          target = p;
          k = i;
        }
      }
    }
    return {target, k, largest};
  }

  std::unique_ptr<MotionCommand> trim_;
};

TEST_F(ForceStuck, AStuckReadingFoundWhileTrimmingHoldsTheRobotAndIsNamed) {
  const int k = 2;  // cable 3
  const Pose here = daemon().rt().snapshot().pose();
  // A trim worth twice the threshold of tension (trims count against a multiple of it).
  const double newtons = 2.0 * RtController::kStuckTrimFactor * stuck_raw_units() / gain();
  cell_->robot->set_force_fault(k, sim::ForceChannelFault::kStuck);
  post_trim(k, counts_for(k, newtons, here));
  std::uint64_t allocations = 0;
  for (int c = 0; c < 2000 && daemon().rt().snapshot().fault.kind == FaultKind::kNone; ++c) {
    {
      test::AllocationCounter count;
      daemon().cycle(cell_->clock.now());
      allocations += count.allocations();
    }
    const can::Timestamp next = cell_->clock.now() + cell_->network.sync_period;
    while (cell_->clock.now() < next) cell_->idle();
  }
  EXPECT_EQ(allocations, 0u) << "the RT cycle allocated while it found the stuck reading";
  const RtSnapshot s = daemon().rt().snapshot();
  ASSERT_EQ(s.fault.kind, FaultKind::kForceStuck);
  EXPECT_EQ(s.fault.cable, k);
  EXPECT_EQ(s.mode, RtMode::kHolding) << "found on a still robot: hold, not a quick stop";
  EXPECT_TRUE(s.all_enabled);
  cell_->run_until([&] { return daemon().state() == DaemonState::kFault; }, 1.0);
  const json st = daemon().status();
  EXPECT_EQ(st["state"], "fault");
  EXPECT_EQ(st["fault"]["fault"], "force_stuck");
  EXPECT_EQ(st["fault"]["cable"], k + 1);
  EXPECT_NE(st["fault"]["message"].get<std::string>().find("force_stuck on cable 3"),
            std::string::npos)
      << st.dump();
  // Nothing that moves the robot is taken while the fault is latched.
  const Reply cal = cell_->request("calibrate");
  EXPECT_FALSE(cal.ok);
  EXPECT_EQ(cal.code, "fault");
  const Pose before = daemon().rt().snapshot().pose();
  cell_->run_until([] { return false; }, 1.0);
  EXPECT_EQ((daemon().rt().snapshot().pose().position - before.position).norm(), 0.0);
  EXPECT_EQ(daemon().rt().snapshot().mode, RtMode::kHolding);

  // The way back: the sensor repaired, fault_reset, holding again.
  cell_->robot->set_force_fault(k, sim::ForceChannelFault::kNone);
  const Reply r = cell_->request("fault_reset");
  ASSERT_TRUE(r.ok) << r.message;
  ASSERT_TRUE(holds_settled(10.0)) << daemon().status().dump();
  EXPECT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kNone);
}

TEST_F(ForceStuck, TheSameTrimWithAHealthyReadingRaisesNothing) {
  const int k = 2;
  const Pose here = daemon().rt().snapshot().pose();
  const double newtons = 2.0 * RtController::kStuckTrimFactor * stuck_raw_units() / gain();
  const std::int64_t raw_before = daemon().master().force_sensors()[0].raw(k);
  post_trim(k, counts_for(k, newtons, here));
  ASSERT_TRUE(
      cell_->run_until([&] { return daemon().rt().snapshot().command_done >= trim_->seq; }, 10.0));
  cell_->run_until([] { return false; }, 2.0);
  EXPECT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kNone);
  EXPECT_EQ(daemon().state(), DaemonState::kHolding);
  // The reading followed the trim (by about the tension it was worth).
  // (By less than the cable's own stiffness predicts: the platform yields to the shortened cable
  // and the others share the change. The watch's threshold leaves room for that: a reading
  // changes by several raw units before the expectation passes it.)
  const std::int64_t raw_after = daemon().master().force_sensors()[0].raw(k);
  EXPECT_GE(static_cast<double>(raw_after - raw_before), stuck_raw_units())
      << "trimmed by " << newtons * gain() << " raw units' worth";
}

TEST_F(ForceStuck, AStuckReadingFoundWhileMovingQuickStops) {
  // The move whose planned tensions change most for one cable, and that cable.
  const Pose home = daemon().rt().snapshot().pose();
  const auto [target, k, largest] = largest_plan_change(home);
  // Found early enough in the move to stop it: the span passes the threshold before the end.
  ASSERT_GT(largest * gain(), 1.5 * stuck_raw_units())
      << "no move changes a cable's planned tension by 1.5 times the threshold";
  cell_->robot->set_force_fault(static_cast<int>(k), sim::ForceChannelFault::kStuck);
  const Reply mv = cell_->request(
      "move",
      {{"pose", {target.position.x(), target.position.y(), target.position.z(), 0.0, 0.0, 0.0}}});
  ASSERT_TRUE(mv.ok) << mv.message;
  ASSERT_TRUE(cell_->run_until([&] { return daemon().state() == DaemonState::kFault; }, 10.0))
      << daemon().status().dump();
  const RtSnapshot s = daemon().rt().snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kForceStuck);
  EXPECT_EQ(s.fault.cable, k);
  EXPECT_EQ(s.mode, RtMode::kDisabled) << "found while moving: quick stop";
  // It stopped before the end of the move.
  EXPECT_GT((s.pose().position - target.position).norm(), 1e-3)
      << "move to " << target.position.transpose();
}

// A move after tension-regulation trims: the platform yields to the other cables' trims as they
// fade, and a healthy cable's real tension can stay on one raw value while its plan moves (the
// virtual MINI before calibration: cable 8 at 12.0 N at pose 16, a false force_stuck). The plan is
// evidence only beyond the fading trims' worth; the next move without trims finds the stuck
// reading.
TEST_F(ForceStuck, AReadingHeldWhileOtherCablesTrimsFadeIsNotStuckTheNextMoveFindsIt) {
  const Pose home = daemon().rt().snapshot().pose();
  const auto [target, k, largest] = largest_plan_change(home);
  ASSERT_GT(largest * gain(), 1.5 * stuck_raw_units());
  // Another cable trimmed by more than the plan's change of cable k plus the threshold.
  const int j = static_cast<int>((k + 1) % cell_->nominal.num_cables());
  const double worth = largest + 2.0 * stuck_raw_units() / gain();
  post_trim(j, counts_for(j, worth, home));
  ASSERT_TRUE(
      cell_->run_until([&] { return daemon().rt().snapshot().command_done >= trim_->seq; }, 10.0));
  ASSERT_TRUE(holds_settled(10.0));
  ASSERT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kNone);
  // Cable k's reading now keeps its raw value (as a real one held by the others' trims would).
  cell_->robot->set_force_fault(static_cast<int>(k), sim::ForceChannelFault::kStuck);
  auto move_to = [&](const Pose& p) {
    return cell_->request(
        "move", {{"pose", {p.position.x(), p.position.y(), p.position.z(), 0.0, 0.0, 0.0}}});
  };
  const Reply there = move_to(target);
  ASSERT_TRUE(there.ok) << there.message;
  ASSERT_TRUE(holds_settled(30.0)) << daemon().status().dump();
  EXPECT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kNone)
      << "the plan of cable " << k + 1 << " moved " << largest << " N, the trims faded " << worth
      << " N";
  // Back without trims: the plan's change alone is evidence, and the reading is found stuck.
  const Reply back = move_to(home);
  ASSERT_TRUE(back.ok) << back.message;
  ASSERT_TRUE(cell_->run_until([&] { return daemon().state() == DaemonState::kFault; }, 30.0))
      << daemon().status().dump();
  EXPECT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kForceStuck);
  EXPECT_EQ(daemon().rt().snapshot().fault.cable, k);
}

TEST_F(ForceStuck, AForceNodeThatFallsSilentWhileMovingIsNodeLostNotStuck) {
  // Its readings stop changing because none arrive: the heartbeat watch names that.
  const Pose home = daemon().rt().snapshot().pose();
  Pose target = home;
  target.position += Eigen::Vector3d(0.05, -0.04, 0.03);
  ASSERT_TRUE(cell_
                  ->request("move", {{"pose",
                                      {target.position.x(), target.position.y(),
                                       target.position.z(), 0.0, 0.0, 0.0}}})
                  .ok);
  ASSERT_TRUE(
      cell_->run_until([&] { return daemon().rt().snapshot().mode == RtMode::kMoving; }, 2.0));
  const int force_node = daemon().master().force_sensors()[0].node();
  cell_->robot->node(force_node).faults().silent = true;
  ASSERT_TRUE(cell_->run_until(
      [&] { return daemon().rt().snapshot().fault.kind != FaultKind::kNone; }, 10.0));
  const RtSnapshot s = daemon().rt().snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kNodeLost) << to_string(s.fault.kind);
  EXPECT_EQ(s.fault.node, force_node);
}

TEST_F(ForceStuck, AStillHealthyRobotWithSensorNoiseRaisesNoFalseAlarmOverALongHold) {
  // Ten minutes of holding still: the readings carry the scenario's noise and sit on one raw
  // value for long stretches, which alone must not look stuck.
  constexpr double kHoldS = 600.0;
  const int m = daemon().rt().snapshot().num_cables;
  std::vector<std::int64_t> last(static_cast<std::size_t>(m));
  std::vector<double> since(static_cast<std::size_t>(m), 0.0), longest(since);
  std::vector<int> changes(static_cast<std::size_t>(m), 0);
  const auto& force = daemon().master().force_sensors()[0];
  for (int i = 0; i < m; ++i) last[static_cast<std::size_t>(i)] = force.raw(i);
  const double t0 = cell_->seconds();
  bool alarm = false;
  while (cell_->seconds() - t0 < kHoldS && !alarm) {
    cell_->cycle();
    for (int i = 0; i < m; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (force.raw(k) != last[k]) {
        last[k] = force.raw(k);
        since[k] = cell_->seconds();
        ++changes[k];
      }
      longest[k] = std::max(longest[k], cell_->seconds() - std::max(since[k], t0));
    }
    alarm = daemon().rt().snapshot().fault.kind != FaultKind::kNone;
  }
  EXPECT_FALSE(alarm) << daemon().status().dump();
  EXPECT_EQ(daemon().state(), DaemonState::kHolding);
  EXPECT_GE(cell_->seconds() - t0, kHoldS);
  // The hold is a real test of the watch: the noise moves the readings now and then, and some
  // channel stays on one raw value longer than the watch's confirmation time (an "unchanged for
  // a while" rule alone would have raised a false alarm).
  const double confirm = daemon().config().tension_watch.stuck_confirm_s;
  EXPECT_GT(*std::max_element(changes.begin(), changes.end()), 0);
  EXPECT_GT(*std::max_element(longest.begin(), longest.end()), confirm);
  // Then a healthy robot that moves and comes back raises nothing either.
  const Pose home = daemon().rt().snapshot().pose();
  for (const Eigen::Vector3d& d :
       {Eigen::Vector3d(0.05, -0.04, 0.03), Eigen::Vector3d(0.0, 0.0, 0.0)}) {
    const Eigen::Vector3d p = home.position + d;
    ASSERT_TRUE(cell_->request("move", {{"pose", {p.x(), p.y(), p.z(), 0.0, 0.0, 0.0}}}).ok);
    ASSERT_TRUE(holds_settled(20.0)) << daemon().status().dump();
  }
  EXPECT_EQ(daemon().rt().snapshot().fault.kind, FaultKind::kNone);
}

}  // namespace
}  // namespace cdpr::controller
