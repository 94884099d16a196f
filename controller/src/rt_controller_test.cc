// The RT controller's cycle on a fake robot: modes, re-reference and hot swap, trims, faults,
// the safety chain, allocation-free stages (rt_rig.hpp: the fixture).
#include <gtest/gtest.h>

#include "rt_rig.hpp"

namespace cdpr::controller {
namespace {

using rig::make_geometry;
using rig::RtRig;
using testing::FakeRobotIO;
using namespace std::chrono_literals;

TEST_F(RtRig, DisabledTargetsFollowThisCyclesActualPositions) {
  io_.position[0] += 1234.0;
  cycle();
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.mode, RtMode::kDisabled);
  EXPECT_FALSE(io_.last().send_targets) << "a disabled loop sends no targets";
  // Read before update: the target is the position read in the same cycle.
  EXPECT_EQ(s.target_counts[0], std::lround(io_.position[0]));
  EXPECT_EQ(s.actual_counts[0], s.target_counts[0]);
}

TEST_F(RtRig, ModesGoFromDisabledToHoldingToMovingToHolding) {
  cycle();
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kDisabled);
  hold_home();
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kHolding);
  Pose to = geometry_.model.home;
  to.position.z() += 0.02;
  const std::uint64_t move = post_move(to);
  cycle();
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kMoving);
  EXPECT_EQ(rt_->snapshot().command_taken, move);
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == move; }, 5000));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.mode, RtMode::kHolding);
  EXPECT_NEAR(s.pose().position.z(), to.position.z(), 1e-12);
  // The targets written are the pose's inverse kinematics.
  const std::array<double, kMaxAxes> ik = ik_counts(geometry_, to);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    EXPECT_NEAR(io_.last().target_counts[k], ik[k], 0.5) << "cable " << i;
  }
  EXPECT_GT(s.largest_move_step, 0.0);
  EXPECT_TRUE(run_until([](const RtSnapshot& r) { return r.settled; }, 2000));
}

TEST_F(RtRig, ReReferenceSlewsFromWhereTheDrivesAreWithoutAJump) {
  // The drives stand 5 mm of cable off their home targets.
  const double off = 0.005 * counts_per_metre();
  for (int i = 0; i < m_; ++i) io_.position[static_cast<std::size_t>(i)] += i % 2 ? off : -off;
  const std::array<double, kMaxAxes> start = io_.position;
  const std::uint64_t seq = post_reference(geometry_.model.home, true);
  cycle();
  ASSERT_EQ(rt_->snapshot().mode, RtMode::kSlewing);
  const double step_bound = options_.slew_velocity * counts_per_metre() * options_.cycle_s;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    EXPECT_LE(std::abs(io_.last().target_counts[k] - start[k]), step_bound + 1.0) << i;
  }
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 2000));
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kHolding);
  EXPECT_LE(rt_->snapshot().largest_reference_step, step_bound * (1 + 1e-9));
  const std::array<double, kMaxAxes> ik = ik_counts(geometry_, geometry_.model.home);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    EXPECT_NEAR(rt_->snapshot().target_counts[k], ik[k], 1e-6) << "cable " << i;
  }
}

TEST_F(RtRig, AHoldPostedFirstIsTakenBeforeAMovePostedAfterItWithItsNewOffsets) {
  hold_home();
  // The drives' counters were set anew while the loop paused (the drives' own homing): every
  // count shifted, the platform did not move.
  const double shift = 12345.0;
  for (int i = 0; i < m_; ++i) io_.position[static_cast<std::size_t>(i)] += shift;
  MotionCommand& hold = make_command(MotionCommand::Type::kReference);
  hold.hold_actual = hold.from_actual = true;
  hold.pose = geometry_.model.home;
  std::array<double, kMaxAxes> offsets{};
  offsets.fill(shift);
  hold.offsets = offsets;
  hold.seq = ++seq_;
  rt_->post_first(&hold);
  const std::uint64_t move = post_move(Pose{Eigen::Vector3d(0.01, 0, 0), Eigen::Vector3d::Zero()});
  cycle();
  // The first cycle holds the new counts: no target jumps by the shift.
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    EXPECT_NEAR(io_.last().target_counts[k], io_.position[k], 1.0) << i;
  }
  EXPECT_EQ(rt_->encoder_offsets()[0], shift);
  ASSERT_TRUE(
      run_until([&](const RtSnapshot& s) { return s.command_done == move && s.settled; }, 2000));
  const std::array<double, kMaxAxes> ik =
      ik_counts(geometry_, Pose{Eigen::Vector3d(0.01, 0, 0), Eigen::Vector3d::Zero()});
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    EXPECT_NEAR(rt_->snapshot().target_counts[k], ik[k] + shift, 1.0) << "cable " << i;
  }
}

TEST_F(RtRig, HotSwapTakesTheNewGeometryWithoutAJump) {
  hold_home();
  RobotModel moved = geometry_.model;
  moved.frame_anchors(0, 0) += 0.003;
  const Geometry next = make_geometry(2, moved);
  const std::array<double, kMaxAxes> before = rt_->snapshot().target_counts;
  const std::uint64_t seq = post_reference(geometry_.model.home, false, &next);
  cycle();
  EXPECT_EQ(rt_->geometry_in_use(), 2);
  const double step_bound = options_.slew_velocity * counts_per_metre() * options_.cycle_s;
  EXPECT_LE(std::abs(rt_->snapshot().target_counts[0] - before[0]), step_bound + 1e-9);
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 2000));
  const std::array<double, kMaxAxes> ik = ik_counts(next, next.model.home);
  EXPECT_NEAR(rt_->snapshot().target_counts[0], ik[0], 1e-6);
  EXPECT_GT(std::abs(ik[0] - before[0]), 100.0) << "the new geometry moves cable 1";
  EXPECT_EQ(rt_->snapshot().geometry_version, 2);
}

TEST_F(RtRig, TrimsMoveAtTheirRateThenFadeOutOverTheNextMove) {
  hold_home();
  const double rate = options_.trim_velocity * counts_per_metre() * options_.cycle_s;
  MotionCommand& trim = make_command(MotionCommand::Type::kTrim);
  trim.trim[1] = 20.5 * rate;
  const std::array<double, kMaxAxes> before = rt_->snapshot().target_counts;
  const std::uint64_t seq = post(trim);
  cycle();
  EXPECT_NEAR(rt_->snapshot().trim_counts[1], rate, 1e-9) << "one cycle's worth";
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 100));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.trim_counts[1], trim.trim[1]);
  EXPECT_NEAR(s.target_counts[1] - before[1], trim.trim[1], 1e-6);
  EXPECT_EQ(s.target_counts[0], before[0]) << "only cable 2 is trimmed";
  Pose to = geometry_.model.home;
  to.position.x() += 0.01;
  const std::uint64_t move = post_move(to);
  ASSERT_TRUE(run_until([&](const RtSnapshot& r) { return r.command_done == move; }, 5000));
  EXPECT_EQ(rt_->snapshot().trim_counts[1], 0.0);
}

TEST_F(RtRig, DriveFaultQuickStopsInTheSameCycleAndLatchesUntilReset) {
  hold_home();
  io_.fault(2, 0x7500);
  const int stops = io_.quick_stops();
  cycle();
  RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.mode, RtMode::kDisabled);
  EXPECT_EQ(s.fault.kind, FaultKind::kDriveFault);
  EXPECT_EQ(s.fault.node, 3);
  EXPECT_EQ(s.fault.code, 0x7500);
  EXPECT_EQ(io_.quick_stops(), stops + 1) << "written in the cycle that read the fault";
  RtEvent e;
  ASSERT_TRUE(rt_->pop_event(e));
  EXPECT_EQ(e.event.type, canopen::EventType::kDriveFault);
  // Latched: no command is taken, the fault stays.
  const std::uint64_t ref = post_reference(geometry_.model.home, true);
  cycle(20);
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kDriveFault);
  EXPECT_NE(rt_->snapshot().command_taken, ref);
  rt_->request_fault_reset();
  cycle();
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kNone);
  EXPECT_TRUE(io_.last().fault_reset && io_.last().enable);
  EXPECT_FALSE(io_.last().quick_stop);
  ASSERT_TRUE(
      run_until([&](const RtSnapshot& r) { return r.command_done == ref && r.settled; }, 2000));
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kHolding);
}

TEST_F(RtRig, BusEventsAndAnOperatorQuickStopAreNamedFaults) {
  struct Case {
    canopen::EventType event;
    FaultKind fault;
    int node;
  };
  for (const Case& c : {Case{canopen::EventType::kHeartbeatLost, FaultKind::kNodeLost, 4},
                        Case{canopen::EventType::kBusOff, FaultKind::kBusOff, 0}}) {
    hold_home();
    canopen::Event e;
    e.type = c.event;
    e.node = static_cast<canopen::NodeId>(c.node);
    io_.push_event(e);
    cycle();
    EXPECT_EQ(rt_->snapshot().fault.kind, c.fault) << to_string(c.fault);
    EXPECT_EQ(rt_->snapshot().fault.node, c.node);
    EXPECT_TRUE(io_.last().quick_stop);
    rt_->request_fault_reset();
    cycle();
  }
  hold_home();
  rt_->request_quick_stop();
  cycle();
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kQuickStop);
  EXPECT_TRUE(io_.last().quick_stop);
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kDisabled);
}

TEST_F(RtRig, OverloadQuickStopsAfterTheWatchCyclesSlackIsOnlyCounted) {
  hold_home();
  io_.tension[3] = 0.5;  // slack
  cycle(options_.watch_cycles + 3);
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kNone);
  EXPECT_EQ(rt_->snapshot().slack_cycles[3], options_.watch_cycles + 3);
  io_.tension[3] = planned_[3];
  io_.tension[5] = 1.2 * geometry_.model.cables[5].f_max;
  cycle(options_.watch_cycles - 1);
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kNone) << "not yet: watch_cycles";
  cycle();
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kOverload);
  EXPECT_EQ(s.fault.cable, 5);
  EXPECT_NEAR(s.fault.value, io_.tension[5], 0.2);
  EXPECT_EQ(s.mode, RtMode::kDisabled);
}

TEST_F(RtRig, StuckReadingIsAFaultWhileItsPlanChangesNotOnAStillRobot) {
  hold_home();
  io_.frozen[0] = true;
  cycle(3 * options_.stuck_confirm_cycles);
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kNone) << "still: the plan does not change";
  Pose to = geometry_.model.home;
  to.position.z() += 0.1;
  const std::uint64_t move = post_move(to);
  ASSERT_TRUE(run_until(
      [&](const RtSnapshot& s) {
        return s.fault.kind != FaultKind::kNone || s.command_done == move;
      },
      5000));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kForceStuck);
  EXPECT_EQ(s.fault.cable, 0);
  EXPECT_EQ(s.mode, RtMode::kDisabled) << "moving: quick stop";
}

TEST_F(RtRig, StuckReadingWhileTrimmingHoldsThePose) {
  hold_home();
  io_.frozen[2] = true;
  MotionCommand& trim = make_command(MotionCommand::Type::kTrim);
  trim.trim[2] = 0.002 * counts_per_metre();  // 2 mm of cable: far more than the threshold
  post(trim);
  ASSERT_TRUE(
      run_until([](const RtSnapshot& s) { return s.fault.kind != FaultKind::kNone; }, 2000));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kForceStuck);
  EXPECT_EQ(s.fault.cable, 2);
  EXPECT_EQ(s.mode, RtMode::kHolding) << "holding: the pose is held";
  EXPECT_LT(s.trim_counts[2], trim.trim[2]) << "the trim stopped where it was";
}

TEST_F(RtRig, CycleAllocatesNothingWhileHoldingMovingOrFaulted) {
  hold_home();
  Pose to = geometry_.model.home;
  to.position.y() += 0.02;
  post_move(to);
  std::uint64_t allocations = 0;
  {
    test::AllocationCounter count;
    cycle(300);  // moving, then holding
    io_.fault(1, 0x2310);
    cycle(5);
    rt_->request_fault_reset();
    cycle(5);
    allocations = count.allocations();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_GT(rt_->snapshot().largest_move_step, 0.0) << "the platform moved";
}

// ---- The safety chain (rt_controller_safety.cc) -------------------------------------------------

TEST_F(RtRig, OpenEStopLatchesAQuickStopThatResetsOnlyOnceTheInputCloses) {
  io_.safety_inputs = 2;
  hold_home();
  io_.safety_open = 0b10;  // the second source opens
  cycle();
  RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kEStop);
  EXPECT_EQ(s.fault.code, 2) << "the source, from 1";
  EXPECT_EQ(s.mode, RtMode::kDisabled);
  EXPECT_EQ(io_.quick_stops(), 1) << "quick stop in the cycle that read it";
  EXPECT_EQ(s.safety_open, 0b10u);
  rt_->request_fault_reset();
  cycle();
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kEStop) << "refused while the input is open";
  EXPECT_EQ(io_.fault_resets(), 0);
  io_.safety_open = 0;
  cycle(10);
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kEStop) << "closing it alone clears nothing";
  rt_->request_fault_reset();
  cycle();
  s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kNone);
  EXPECT_EQ(io_.fault_resets(), 1);
  EXPECT_EQ(s.safety_open, 0u);
}

TEST_F(RtRig, BrakesReleaseOnlyAfterTheDriveHoldsTorqueAndApplyBeforeItIsDisabled) {
  RtControllerOptions o;
  o.brakes = true;
  o.brake_release_cycles = 10;
  o.brake_apply_cycles = 7;
  make(o);
  io_.brakes = true;
  io_.state.fill(FakeRobotIO::DriveState::kDisabled);
  const std::uint64_t seq = post_reference(geometry_.model.home, true);
  cycle(3);
  EXPECT_FALSE(io_.brake_released(0)) << "not enabled: applied";
  rt_->request_disable();
  cycle();
  rt_->request_enable();
  int enabled_cycles = 0, released_at = -1;
  for (int c = 0; c < 40 && released_at < 0; ++c) {
    cycle();
    enabled_cycles = io_.state[0] == FakeRobotIO::DriveState::kEnabled ? enabled_cycles + 1 : 0;
    if (io_.brake_released(0)) released_at = enabled_cycles;
    EXPECT_EQ(rt_->snapshot().command_taken, 0u) << "no motion against an applied brake";
  }
  EXPECT_GT(released_at, o.brake_release_cycles) << "released after the delay, drive enabled";
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 2000));
  EXPECT_TRUE(rt_->snapshot().brakes_released);
  // Disable: the brakes at once, the drives only after the apply delay.
  rt_->request_disable();
  int applied_for = 0;
  while (io_.state[0] == FakeRobotIO::DriveState::kEnabled && applied_for < 40) {
    cycle();
    EXPECT_FALSE(io_.brake_released(0));
    if (!io_.last().disable) ++applied_for;
  }
  EXPECT_EQ(applied_for, o.brake_apply_cycles) << "the disable follows the apply delay";
  EXPECT_EQ(io_.state[0], FakeRobotIO::DriveState::kDisabled);
  EXPECT_TRUE(rt_->snapshot().disabled);
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kDisabled);
}

TEST_F(RtRig, AFaultAppliesTheBrakesAtOnceAndTheResetReleasesThemOnlyAfterTheDelay) {
  RtControllerOptions o;
  o.brakes = true;
  o.brake_release_cycles = 5;
  make(o);
  io_.brakes = true;
  hold_home();
  ASSERT_TRUE(io_.brake_released(3));
  io_.fault(1, 0x2310);
  cycle();
  for (int i = 0; i < m_; ++i) EXPECT_FALSE(io_.brake_released(i)) << "cable " << i + 1;
  EXPECT_FALSE(rt_->snapshot().brakes_released);
  rt_->request_fault_reset();
  cycle(o.brake_release_cycles);
  EXPECT_FALSE(io_.brake_released(0)) << "the drives are enabled again, not yet holding";
  cycle(3);
  EXPECT_TRUE(io_.brake_released(0));
}

TEST_F(RtRig, ACommandedCableLengthBeyondItsWinchLimitLatchesWithoutSendingIt) {
  // The cable that a 3 cm move down lengthens most gets a limit 1 cm above its home length.
  Pose to = geometry_.model.home;
  to.position.z() -= 0.03;
  const Eigen::VectorXd home = lengths_at(geometry_.model.home), there = lengths_at(to);
  int c = 0;
  (there - home).maxCoeff(&c);
  ASSERT_GT(there(c) - home(c), 0.015);
  RtControllerOptions o;
  o.max_cable_length[static_cast<std::size_t>(c)] = home(c) + 0.01;
  make(o);
  hold_home();
  post_move(to);
  ASSERT_TRUE(
      run_until([](const RtSnapshot& s) { return s.fault.kind != FaultKind::kNone; }, 3000));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kCableLimit);
  EXPECT_EQ(s.fault.cable, c);
  EXPECT_EQ(s.fault.node, c + 1);
  EXPECT_GT(s.fault.value, o.max_cable_length[static_cast<std::size_t>(c)]);
  EXPECT_EQ(s.mode, RtMode::kDisabled);
  EXPECT_FALSE(io_.last().send_targets) << "the target beyond the limit is not sent";
  EXPECT_EQ(io_.quick_stops(), 1);
}

TEST_F(RtRig, AnActualCableLengthBeyondItsLimitLatchesNamingTheWinch) {
  RtControllerOptions o;
  o.cable_length_tolerance = 0.001;
  o.min_cable_length[6] = lengths_at(geometry_.model.home)(6) - 0.0005;
  make(o);
  hold_home();
  EXPECT_EQ(rt_->snapshot().fault.kind, FaultKind::kNone) << "within the tolerance";
  // The drive of cable 7 no longer follows its target and stands 2 mm of cable shorter.
  io_.state[6] = FakeRobotIO::DriveState::kQuickStop;
  io_.position[6] -= 0.002 * counts_per_metre() * geometry_.model.winches[6].direction;
  cycle();
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kCableLimit);
  EXPECT_EQ(s.fault.cable, 6);
  EXPECT_EQ(s.fault.node, 7);
  EXPECT_NEAR(s.fault.value, o.min_cable_length[6] - 0.0015, 2e-4);
}

TEST_F(RtRig, HoldingCountsWithoutATrustedPoseChecksNoLengthOrBox) {
  // A start whose pose cannot be trusted holds the drives' counts: no pose was solved, so there
  // is no length or position to judge (once they were judged from an unsolved pose: a cable at
  // -1.1 mm latched cable_limit at every restart of the fault matrix's e-stop row).
  RtControllerOptions o;
  o.cable_length_tolerance = 0.001;
  for (int i = 0; i < m_; ++i) o.min_cable_length[static_cast<std::size_t>(i)] = 0.05;
  o.workspace_box = true;
  o.box_min = {-0.4, -0.4, -0.3};
  o.box_max = {0.4, 0.4, 0.5};
  make(o);
  MotionCommand& hold = make_command(MotionCommand::Type::kReference);
  hold.hold_actual = hold.from_actual = hold.counts_only = true;
  hold.pose.position = Eigen::Vector3d(5.0, 5.0, 5.0);  // not known: far outside everything
  post(hold);
  cycle(50);
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.mode, RtMode::kHoldingCounts);
  EXPECT_EQ(s.fault.kind, FaultKind::kNone);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    EXPECT_NEAR(io_.last().target_counts[k], io_.position[k], 1.0) << i;
  }
}

TEST_F(RtRig, ACommandedPositionOutsideTheWorkspaceBoxLatches) {
  RtControllerOptions o;
  o.workspace_box = true;
  for (int j = 0; j < 3; ++j) {
    o.box_min[static_cast<std::size_t>(j)] = geometry_.model.home.position(j) - 0.02;
    o.box_max[static_cast<std::size_t>(j)] = geometry_.model.home.position(j) + 0.02;
  }
  make(o);
  hold_home();
  Pose to = geometry_.model.home;
  to.position.z() += 0.05;
  post_move(to);
  ASSERT_TRUE(
      run_until([](const RtSnapshot& s) { return s.fault.kind != FaultKind::kNone; }, 3000));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.fault.kind, FaultKind::kWorkspace);
  EXPECT_EQ(s.fault.code, 2) << "axis z";
  EXPECT_LE(s.pose_vector[2], o.box_max[2] + 0.001);
}

TEST_F(RtRig, SafetyStagesAllocateNothing) {
  RtControllerOptions o;
  o.brakes = true;
  o.brake_release_cycles = 3;
  o.workspace_box = true;
  o.box_min = {-10, -10, -10};
  o.box_max = {10, 10, 10};
  make(o);
  io_.safety_inputs = 1;
  hold_home();
  std::uint64_t allocations = 0;
  {
    test::AllocationCounter count;
    io_.safety_open = 1;
    cycle(5);
    io_.safety_open = 0;
    rt_->request_fault_reset();
    rt_->request_disable();
    cycle(40);
    rt_->request_enable();
    cycle(10);
    allocations = count.allocations();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_EQ(io_.fault_resets(), 1);
}

TEST(RtController, CreateRefusesAnIoThatDoesNotFitTheRobot) {
  const Geometry g = make_geometry(1, cdpr::testing::mini_robot());
  FakeRobotIO io(g.model.num_cables() - 1);
  auto rt = RtController::create(io, g, RtControllerOptions{});
  ASSERT_FALSE(rt.ok());
  EXPECT_NE(rt.status().to_string().find("axes"), std::string::npos) << rt.status().to_string();
}

}  // namespace
}  // namespace cdpr::controller
