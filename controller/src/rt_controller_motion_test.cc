// The RT controller's paths, smooth stop and setpoint stream on a fake robot (rt_rig.hpp).
#include <gtest/gtest.h>

#include "rt_rig.hpp"

namespace cdpr::controller {
namespace {

using rig::make_geometry;
using rig::RtRig;
using testing::FakeRobotIO;
using namespace std::chrono_literals;
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
