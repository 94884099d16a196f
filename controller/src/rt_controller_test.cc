#include "cdpr/controller/rt_controller.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <memory>
#include <set>
#include <vector>

#include "alloc_counter.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"
#include "fake_robot_io.hpp"
#include "testing/test_robots.hpp"

namespace cdpr::controller {
namespace {

using testing::FakeRobotIO;
using namespace std::chrono_literals;

Geometry make_geometry(int version, RobotModel model) {
  Geometry g;
  g.version = version;
  g.reference_tension = default_reference_tension(model);
  g.model = std::move(model);
  return g;
}

// The controller on the fake robot, time driven by the test (one SYNC period per cycle).
class RtRig : public ::testing::Test {
 protected:
  void SetUp() override { make(RtControllerOptions{}); }

  void make(const RtControllerOptions& options) {
    options_ = options;
    auto rt = RtController::create(io_, geometry_, options_);
    ASSERT_TRUE(rt.ok()) << rt.status().to_string();
    rt_ = std::move(*rt);
    // The drives stand at the home pose's targets, the tensions at its plan.
    const std::array<double, kMaxAxes> targets = ik_counts(geometry_, geometry_.model.home);
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      io_.position[k] = targets[k];
      io_.tension[k] = planned_[k];
    }
  }

  // Encoder targets of `pose` under `g` (offsets 0), and its planned tensions in planned_.
  std::array<double, kMaxAxes> ik_counts(const Geometry& g, const Pose& pose) {
    CommandData data(g.model);
    EXPECT_TRUE(command_counts(g.model, pose, g.reference_tension, data).ok());
    std::array<double, kMaxAxes> counts{};
    for (int i = 0; i < m_; ++i) {
      counts[static_cast<std::size_t>(i)] = data.cable.counts(i);
      planned_[static_cast<std::size_t>(i)] = data.plan.tensions(i);
    }
    return counts;
  }

  void cycle(int n = 1) {
    for (int c = 0; c < n; ++c) {
      rt_->cycle(now_);
      now_ += kPeriod;
    }
  }
  bool run_until(const std::function<bool(const RtSnapshot&)>& done, int max_cycles) {
    for (int c = 0; c < max_cycles; ++c) {
      if (done(rt_->snapshot())) return true;
      cycle();
    }
    return done(rt_->snapshot());
  }

  // Commands live in the rig (the loop keeps a pointer to the active one).
  MotionCommand& make_command(MotionCommand::Type type) {
    MotionCommand& c = commands_.emplace_back();
    c.type = type;
    return c;
  }
  std::uint64_t post(MotionCommand& c) {
    c.seq = ++seq_;
    rt_->post(&c);
    return seq_;
  }
  std::uint64_t post_reference(const Pose& pose, bool from_actual,
                               const Geometry* geometry = nullptr) {
    MotionCommand& c = make_command(MotionCommand::Type::kReference);
    c.pose = pose;
    c.from_actual = from_actual;
    c.geometry = geometry;
    return post(c);
  }
  std::uint64_t post_move(const Pose& to) {
    auto traj = PoseTrajectory::plan(rt_->snapshot().pose(), to, MotionLimits{});
    EXPECT_TRUE(traj.ok());
    MotionCommand& c = make_command(MotionCommand::Type::kMove);
    c.trajectory = std::move(*traj);
    return post(c);
  }
  // From disabled to holding still at home.
  void hold_home() {
    const std::uint64_t seq = post_reference(geometry_.model.home, true);
    ASSERT_TRUE(
        run_until([&](const RtSnapshot& s) { return s.command_done == seq && s.settled; }, 2000));
  }
  // Kinematic cable lengths at `pose` (m).
  Eigen::VectorXd lengths_at(const Pose& pose) {
    CommandData data(geometry_.model);
    EXPECT_TRUE(command_counts(geometry_.model, pose, geometry_.reference_tension, data).ok());
    return data.kinematics.lengths;
  }
  double counts_per_metre() const {
    return 1.0 / winch_metres_per_count(geometry_.model.winches[0]);
  }

  static constexpr canopen::Timestamp kPeriod = 4ms;
  Geometry geometry_ = make_geometry(1, cdpr::testing::mini_robot());
  int m_ = geometry_.model.num_cables();
  FakeRobotIO io_{geometry_.model.num_cables()};
  RtControllerOptions options_;
  std::unique_ptr<RtController> rt_;
  std::array<double, kMaxAxes> planned_{};
  std::deque<MotionCommand> commands_;
  std::uint64_t seq_ = 0;
  canopen::Timestamp now_{1s};
};

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

// ---- Paths, the smooth stop and the setpoint stream (rt_controller_motion.cc) ------------------

namespace motion {

// Commanded positions cycle by cycle while `n` cycles run.
std::vector<Eigen::Vector3d> positions(RtController& rt, const std::function<void()>& step, int n) {
  std::vector<Eigen::Vector3d> p;
  for (int c = 0; c < n; ++c) {
    step();
    p.push_back(rt.snapshot().pose().position);
  }
  return p;
}

// Largest second difference of the positions over dt^2: the commanded acceleration, m/s^2.
double largest_acceleration(const std::vector<Eigen::Vector3d>& p, double dt) {
  double a = 0.0;
  for (std::size_t k = 2; k < p.size(); ++k) {
    a = std::max(a, (p[k] - 2.0 * p[k - 1] + p[k - 2]).norm() / (dt * dt));
  }
  return a;
}

}  // namespace motion

class RtMotion : public RtRig {
 protected:
  // A straight path along +x (line 3), then +y (line 5), from the pose held.
  std::uint64_t post_path(double dx, double dy) {
    const Pose start = rt_->snapshot().pose();
    std::vector<PathSegment> segs(2);
    segs[0].target = start;
    segs[0].target.position.x() += dx;
    segs[0].line = 3;
    segs[1].target = segs[0].target;
    segs[1].target.position.y() += dy;
    segs[1].line = 5;
    auto path = Path::plan(start, segs, PathLimits{options_.stop_limits});
    EXPECT_TRUE(path.ok()) << path.status().to_string();
    MotionCommand& c = make_command(MotionCommand::Type::kMove);
    c.path = std::move(*path);
    return post(c);
  }
  std::uint64_t post_stream() { return post(make_command(MotionCommand::Type::kStream)); }
  void send(std::uint64_t seq, const Pose& p) {
    StreamSetpoint sp;
    sp.seq = seq;
    sp.sent_ns = (now_ - 1ms).count();
    sp.received_ns = now_.count();
    for (int j = 0; j < 3; ++j) {
      sp.pose[static_cast<std::size_t>(j)] = p.position(j);
      sp.pose[static_cast<std::size_t>(j + 3)] = p.rpy(j);
    }
    ASSERT_TRUE(rt_->push_setpoint(sp));
  }
  double dt() const { return std::chrono::duration<double>(kPeriod).count(); }
};

TEST_F(RtMotion, APathIsSampledEveryCycleNamingItsLineAndEndsHoldingAtItsEnd) {
  hold_home();
  const Pose home = rt_->snapshot().pose();
  const std::uint64_t seq = post_path(0.03, 0.02);
  std::set<int> lines;
  ASSERT_TRUE(run_until(
      [&](const RtSnapshot& s) {
        if (s.mode == RtMode::kMoving) lines.insert(s.move.line);
        return s.command_done == seq;
      },
      5000));
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(lines, (std::set<int>{3, 5}));
  EXPECT_EQ(s.mode, RtMode::kHolding);
  EXPECT_FALSE(s.move.stopped);
  EXPECT_NEAR(s.move.elapsed_s, s.move.duration_s, 1e-9);
  EXPECT_NEAR((s.pose().position - home.position - Eigen::Vector3d(0.03, 0.02, 0.0)).norm(), 0.0,
              1e-9);
}

TEST_F(RtMotion, AStopRequestSlowsThePathToRestWithinTheLimitsThenHolds) {
  hold_home();
  const std::uint64_t seq = post_path(0.15, 0.0);
  cycle(150);  // at speed (0.1 m/s after 0.3 s)
  ASSERT_EQ(rt_->snapshot().mode, RtMode::kMoving);
  rt_->request_motion_stop(seq);
  const auto p = motion::positions(
      *rt_, [&] { cycle(); }, 200);
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.mode, RtMode::kHolding);
  EXPECT_EQ(s.command_done, seq);
  EXPECT_TRUE(s.move.stopped);
  EXPECT_LT(s.move.elapsed_s, s.move.duration_s) << "it stopped before the path's end";
  // The stop adds at most the acceleration limit to the path's own (docs/motion.md).
  const MotionLimits& l = options_.stop_limits;
  EXPECT_LE(motion::largest_acceleration(p, dt()), 2.0 * l.max_linear_acceleration * 1.02);
  EXPECT_LT((p.back() - p[p.size() - 2]).norm(), 1e-12) << "at rest";
  EXPECT_GT((p.back() - p.front()).norm(), 1e-3) << "it slowed down rather than halted";
}

TEST_F(RtMotion, AMoveStoppedBeforeTheLoopTookItNeverMoves) {
  hold_home();
  const Pose home = rt_->snapshot().pose();
  Pose to = home;
  to.position.x() += 0.05;
  const std::uint64_t seq = post_move(to);
  rt_->request_motion_stop(seq);
  cycle(50);
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.command_done, seq);
  EXPECT_EQ(s.mode, RtMode::kHolding);
  EXPECT_EQ((s.pose().position - home.position).norm(), 0.0);
}

TEST_F(RtMotion, TheStreamFollowsSetpointsHoldsSmoothlyWhenLateAndEndsOnAJump) {
  hold_home();
  const Pose home = rt_->snapshot().pose();
  const std::uint64_t seq = post_stream();
  cycle();
  const double v = 0.05;  // m/s along +x, one setpoint per cycle, from rest at home
  Pose p = home;
  std::uint64_t n = 0;
  send(++n, p);
  cycle();
  for (int c = 0; c < 100; ++c) {
    p.position.x() += v * dt();
    send(++n, p);
    cycle();
    ASSERT_NEAR((rt_->snapshot().pose().position - p.position).norm(), 0.0, 1e-12) << c;
  }
  EXPECT_EQ(rt_->snapshot().stream.state, StreamState::kFollowing);
  EXPECT_EQ(rt_->snapshot().stream.applied, 101u);
  // Missing setpoints: the pose coasts, brakes after the deadline, never jumps.
  std::vector<Eigen::Vector3d> held = {rt_->snapshot().pose().position};
  const auto more = motion::positions(
      *rt_, [&] { cycle(); }, 100);
  held.insert(held.end(), more.begin(), more.end());
  const RtSnapshot h = rt_->snapshot();
  EXPECT_EQ(h.stream.state, StreamState::kHolding);
  EXPECT_EQ(h.stream.holds, 1u);
  EXPECT_EQ(h.mode, RtMode::kMoving) << "the stream stays armed";
  const MotionLimits& l = options_.stop_limits;
  EXPECT_LE(motion::largest_acceleration(held, dt()), l.max_linear_acceleration * 1.02);
  const double coast = (held.back() - held.front()).norm();
  EXPECT_GT(coast, 0.0);
  // It coasts until the deadline, then brakes (jerk-limited): v^2 / (2 a) + v a / (2 j) at most.
  EXPECT_LT(coast, v * (options_.stream_deadline_cycles + 1) * dt() +
                       v * v / l.max_linear_acceleration +
                       v * l.max_linear_acceleration / l.max_linear_jerk);
  EXPECT_LT((held.back() - held[held.size() - 2]).norm(), 1e-12) << "at rest";
  // A setpoint within one cycle of acceleration from rest of the held pose resumes; a jump
  // ends the stream.
  Pose q = h.pose();
  q.position.x() += 0.25 * l.max_linear_acceleration * dt() * dt();
  send(++n, q);
  cycle();
  EXPECT_EQ(rt_->snapshot().stream.state, StreamState::kFollowing);
  q.position.x() += 2.0 * options_.stream_max_step;
  send(++n, q);
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 500));
  const RtSnapshot e = rt_->snapshot();
  EXPECT_EQ(e.mode, RtMode::kHolding);
  EXPECT_EQ(e.stream.end, StreamEnd::kStepRefused);
  EXPECT_EQ(e.stream.end_seq, n);
  EXPECT_NEAR(e.stream.end_value, 2.0 * options_.stream_max_step, 1e-9);
  EXPECT_LT((e.pose().position - q.position).norm(), 2.5 * options_.stream_max_step)
      << "the refused setpoint was not applied";
  EXPECT_EQ(e.stream.latency_ns, std::chrono::nanoseconds(1ms).count());
}

// A stream never starts with a jump: its first setpoint (and the first after a hold) may be at
// most what the acceleration limit covers in one cycle from rest from the held pose; further,
// the stream ends and the robot never moves.
TEST_F(RtMotion, AStreamStartingAwayFromTheHeldPoseEndsWithoutMoving) {
  hold_home();
  const Pose home = rt_->snapshot().pose();
  const std::uint64_t seq = post_stream();
  cycle();
  const double limit = 0.5 * options_.stop_limits.max_linear_acceleration * dt() * dt();
  Pose q = home;
  q.position.y() += 2.0 * limit;  // far within the step limit of a running stream
  ASSERT_LT(2.0 * limit, options_.stream_max_step);
  send(1, q);
  std::vector<Eigen::Vector3d> at = {rt_->snapshot().pose().position};
  ASSERT_TRUE(run_until(
      [&](const RtSnapshot& s) {
        at.push_back(s.pose().position);
        return s.command_done == seq;
      },
      50));
  const RtSnapshot e = rt_->snapshot();
  EXPECT_EQ(e.mode, RtMode::kHolding);
  EXPECT_EQ(e.stream.end, StreamEnd::kResumeRefused);
  EXPECT_STREQ(to_string(e.stream.end), "resume_refused");
  EXPECT_NEAR(e.stream.end_value, 2.0 * limit, 1e-12);
  EXPECT_EQ(e.stream.applied, 0u);
  for (const Eigen::Vector3d& x : at) EXPECT_EQ((x - home.position).norm(), 0.0);
}

TEST_F(RtMotion, AReceiverRefusalOrAStopEndsTheStreamAndTheRobotHolds) {
  hold_home();
  std::uint64_t seq = post_stream();
  cycle();
  StreamSetpoint bad;
  bad.seq = 1;
  bad.pose = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  bad.verdict = StreamSetpoint::Verdict::kRefused;
  ASSERT_TRUE(rt_->push_setpoint(bad));
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 50));
  EXPECT_EQ(rt_->snapshot().stream.end, StreamEnd::kRefused);
  seq = post_stream();
  cycle(2);
  ASSERT_EQ(rt_->snapshot().mode, RtMode::kMoving);
  rt_->request_motion_stop(seq);
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == seq; }, 50));
  EXPECT_EQ(rt_->snapshot().stream.end, StreamEnd::kStopped);
  EXPECT_EQ(rt_->snapshot().mode, RtMode::kHolding);
}

TEST_F(RtMotion, PathSamplingTheStopAndTheStreamReaderAllocateNothing) {
  hold_home();
  const std::uint64_t run = post_path(0.1, 0.02);
  std::uint64_t allocations = 0;
  {
    test::AllocationCounter count;
    cycle(200);
    rt_->request_motion_stop(run);
    cycle(300);
    allocations += count.allocations();
  }
  ASSERT_EQ(rt_->snapshot().command_done, run);
  const std::uint64_t stream = post_stream();
  Pose p = rt_->snapshot().pose();
  {
    test::AllocationCounter count;
    cycle();
    for (std::uint64_t n = 1; n <= 200; ++n) {
      if (n > 1) p.position.y() += 0.0002;  // from rest at the held pose
      if (n % 50 != 0) send(n, p);          // with gaps: holds too
      cycle();
    }
    rt_->request_motion_stop(stream);
    cycle(100);
    allocations += count.allocations();
  }
  EXPECT_EQ(rt_->snapshot().command_done, stream);
  EXPECT_GT(rt_->snapshot().stream.applied, 100u);
  EXPECT_EQ(allocations, 0u);
}

}  // namespace
}  // namespace cdpr::controller
