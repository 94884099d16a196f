#include "cdpr/calibration/slew.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "alloc_counter.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/winch.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

// Distance covered by a cycle at velocity v followed by the hardest braking (v - dv, v - 2 dv,
// ...).
double braking_distance_after(double v, double dv, double dt) {
  double d = v * dt;
  for (double u = v - dv; u > 0.0; u -= dv) d += u * dt;
  return d;
}

// Runs the limiter to the end and checks every cycle: velocity and acceleration within limits,
// never past the target (from rest), lands exactly on it. Returns the number of cycles.
int run_and_check(SlewLimiter& slew, const std::vector<double>& start,
                  const std::vector<double>& target, const std::vector<double>& v_max,
                  const std::vector<double>& a_max, int max_cycles = 100000) {
  const double dt = slew.cycle_time();
  const std::size_t n = start.size();
  std::vector<double> prev_cmd(start), prev_vel(n, 0.0);
  int cycles = 0;
  while (!slew.done() && cycles < max_cycles) {
    slew.step();
    ++cycles;
    for (std::size_t i = 0; i < n; ++i) {
      const double cmd = slew.command()[i];
      const double vel = (cmd - prev_cmd[i]) / dt;  // the velocity the drive sees
      const double scale = std::max({std::abs(start[i]), std::abs(target[i]), 1.0});
      EXPECT_LE(std::abs(vel), v_max[i] * (1 + 1e-9) + 1e-9 * scale / dt) << "axis " << i;
      EXPECT_LE(std::abs(vel - prev_vel[i]), a_max[i] * dt * (1 + 1e-9) + 1e-9 * scale / dt)
          << "axis " << i << " cycle " << cycles;
      // No overshoot: the command stays between start and target.
      EXPECT_LE((cmd - start[i]) * (cmd - target[i]), 1e-12 * scale * scale)
          << "axis " << i << " passed its target at cycle " << cycles;
      prev_vel[i] = vel;
      prev_cmd[i] = cmd;
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    EXPECT_EQ(slew.command()[i], target[i]) << "axis " << i;
    // Arrives at rest: the last step is a legal deceleration to 0.
    EXPECT_LE(std::abs(prev_vel[i]), a_max[i] * dt * (1 + 1e-9) + 1e-9);
  }
  return cycles;
}

TEST(SlewLimiter, StoppingVelocityStopsExactlyInTheRemainingDistance) {
  const double dv = 0.3, dt = 0.004;
  for (double d : {1e-9, 1e-4, 0.0012, 0.0036, 0.01, 0.5, 3.0, 1234.5}) {
    const double v = SlewLimiter::stopping_velocity(d, dv, dt);
    EXPECT_NEAR(braking_distance_after(v, dv, dt), d, 1e-9 * d) << "d = " << d;
    // Any faster and the hardest braking would pass the target.
    EXPECT_GT(braking_distance_after(v * (1 + 1e-6) + 1e-12, dv, dt), d);
  }
  EXPECT_EQ(SlewLimiter::stopping_velocity(0.0, dv, dt), 0.0);
}

TEST(SlewLimiter, ReachesTargetsExactlyWithoutOvershootWithinLimits) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    const int n = 1 + trial % 8;
    std::vector<double> start(n), target(n), v(n), a(n);
    for (int i = 0; i < n; ++i) {
      // Encoder-count-sized values on some axes, metre-sized on others.
      const double scale = trial % 2 == 0 ? 1.0 : 2e5;
      start[i] = scale * u(rng);
      target[i] = i == 0 ? start[i] : scale * u(rng);  // one axis already there
      v[i] = scale * (0.2 + std::abs(u(rng)));
      a[i] = scale * (0.5 + 3.0 * std::abs(u(rng)));
    }
    SlewLimiter slew;
    ASSERT_TRUE(slew.configure(0.004, v, a).ok());
    ASSERT_TRUE(slew.reset(start).ok());
    ASSERT_TRUE(slew.set_target(target).ok());
    SCOPED_TRACE("trial " + std::to_string(trial));
    const int cycles = run_and_check(slew, start, target, v, a);
    EXPECT_TRUE(slew.done());
    // Close to the continuous time-optimal bang-bang move of the slowest axis (within a few
    // cycles: the discrete law loses at most about two).
    double t_opt = 0.0;
    for (int i = 0; i < n; ++i) {
      const double d = std::abs(target[i] - start[i]);
      const double t = d >= v[i] * v[i] / a[i] ? d / v[i] + v[i] / a[i] : 2 * std::sqrt(d / a[i]);
      t_opt = std::max(t_opt, t);
    }
    EXPECT_LE(cycles * 0.004, t_opt + 3 * 0.004);
    EXPECT_GE(cycles * 0.004, t_opt - 0.004);
  }
}

TEST(SlewLimiter, BrakesByExactlyOneAccelerationStepPerCycle) {
  SlewLimiter slew;
  const double dt = 0.004, v_max = 1.0, a_max = 5.0;
  ASSERT_TRUE(slew.configure(1, dt, v_max, a_max).ok());
  const std::vector<double> start{0.0}, target{0.5};
  ASSERT_TRUE(slew.reset(start).ok());
  ASSERT_TRUE(slew.set_target(target).ok());
  std::vector<double> velocities;
  while (!slew.done()) {
    slew.step();
    velocities.push_back(slew.velocity()[0]);
  }
  // Cruise at v_max, then a braking curve: a first partial step onto the curve, steps of exactly
  // a_max dt, the landing step (below a_max dt) and 0.
  ASSERT_GT(velocities.size(), 4u);
  const std::size_t last = velocities.size() - 1;
  EXPECT_EQ(velocities[last], 0.0);
  std::size_t first = last;  // first cycle slower than the one before
  while (first > 0 && velocities[first - 1] > velocities[first]) --first;
  ++first;
  ASSERT_LT(first + 2, last);
  EXPECT_EQ(velocities[first - 1], v_max);  // cruising before the braking
  EXPECT_LE(velocities[first - 1] - velocities[first], a_max * dt * (1 + 1e-12));
  for (std::size_t k = first + 1; k < last; ++k) {
    EXPECT_NEAR(velocities[k - 1] - velocities[k], a_max * dt, 1e-9) << k;
  }
  EXPECT_LT(velocities[last - 1], a_max * dt);
  EXPECT_GE(static_cast<double>(last - first), v_max / (a_max * dt) - 1);
  EXPECT_EQ(slew.command()[0], 0.5);
}

TEST(SlewLimiter, TargetMovedBehindAFastCommandIsReachedAfterTurningBack) {
  SlewLimiter slew;
  const double dt = 0.004;
  ASSERT_TRUE(slew.configure(1, dt, 2.0, 4.0).ok());
  ASSERT_TRUE(slew.reset(std::vector<double>{0.0}).ok());
  ASSERT_TRUE(slew.set_target(std::vector<double>{1.0}).ok());
  for (int k = 0; k < 200; ++k) slew.step();
  ASSERT_GT(slew.velocity()[0], 0.5);
  const double here = slew.command()[0];
  ASSERT_TRUE(slew.set_target(std::vector<double>{here}).ok());  // cannot stop in zero distance
  double prev = slew.command()[0], prev_v = slew.velocity()[0];
  int cycles = 0;
  while (!slew.done() && cycles < 10000) {
    slew.step();
    ++cycles;
    const double v = (slew.command()[0] - prev) / dt;
    EXPECT_LE(std::abs(v - prev_v), 4.0 * dt * (1 + 1e-9));
    EXPECT_LE(std::abs(v), 2.0 * (1 + 1e-9));
    prev = slew.command()[0];
    prev_v = v;
  }
  EXPECT_TRUE(slew.done());
  EXPECT_EQ(slew.command()[0], here);
}

TEST(SlewLimiter, AlreadyOnTargetIsDone) {
  SlewLimiter slew;
  ASSERT_TRUE(slew.configure(3, 0.004, 1.0, 1.0).ok());
  const std::vector<double> p{1.0, -2.0, 3.0};
  ASSERT_TRUE(slew.reset(p).ok());
  EXPECT_TRUE(slew.done());
  slew.step();
  EXPECT_TRUE(slew.done());
  EXPECT_EQ(slew.command()[1], -2.0);
}

TEST(SlewLimiter, RejectsBadConfigurationNamingAxisAndField) {
  SlewLimiter slew;
  const std::vector<double> v{1.0, 1.0, 0.0}, a{1.0, 1.0, 1.0};
  Status s = slew.configure(0.004, v, a);
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(s.message().find("axis 3: max_velocity"), std::string_view::npos) << s.to_string();
  const std::vector<double> a_bad{1.0, std::nan(""), 1.0}, v_ok{1.0, 1.0, 1.0};
  s = slew.configure(0.004, v_ok, a_bad);
  EXPECT_NE(s.message().find("axis 2: max_acceleration"), std::string_view::npos);
  EXPECT_FALSE(slew.configure(0.0, v_ok, v_ok).ok());
  EXPECT_FALSE(slew.configure(17, 0.004, 1.0, 1.0).ok());
  EXPECT_FALSE(slew.configure(0.004, v_ok, std::vector<double>{1.0}).ok());
  ASSERT_TRUE(slew.configure(0.004, v_ok, v_ok).ok());
  EXPECT_FALSE(slew.reset(std::vector<double>{1.0, 2.0}).ok());
  EXPECT_FALSE(slew.set_target(std::vector<double>{1.0, 2.0, INFINITY}).ok());
  EXPECT_EQ(slew.target()[2], 0.0);  // unchanged
}

TEST(SlewLimiter, StepAllocatesNothing) {
  SlewLimiter slew;
  ASSERT_TRUE(slew.configure(16, 0.004, 1000.0, 5000.0).ok());
  std::vector<double> start(16, 0.0), target(16);
  for (int i = 0; i < 16; ++i) target[static_cast<std::size_t>(i)] = 100.0 * (i - 8);
  ASSERT_TRUE(slew.reset(start).ok());
  test::AllocationCounter count;
  Status s = slew.set_target(target);
  int cycles = 0;
  while (!slew.done() && cycles < 10000) {
    slew.step();
    ++cycles;
  }
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_TRUE(s.ok());
  EXPECT_TRUE(slew.done());
}

TEST(CableCountLimits, BoundTheCableRateOfTheTaskSpaceLimits) {
  const RobotModel mini = testing::mini_robot();
  const MotionLimits limits;
  std::vector<double> v(8), a(8);
  ASSERT_TRUE(cable_count_limits(mini, limits, v, a).ok());
  // Sampled check: along a move within the limits, no cable's count changes faster than its
  // limit (the cable rate is bounded by the anchor's speed).
  Pose to;
  to.position << 0.1, -0.05, 0.04;
  to.rpy << 0.05, -0.04, 0.08;
  auto move = PoseTrajectory::plan(Pose{}, to, limits);
  ASSERT_TRUE(move.ok());
  const double dt = 0.004;
  KinematicsData prev(mini), now(mini);
  Pose p;
  move->sample(0.0, p);
  ASSERT_TRUE(inverse_kinematics(mini, p, prev));
  double largest_ratio = 0.0;
  for (double t = dt; t <= move->duration() + dt; t += dt) {
    move->sample(t, p);
    ASSERT_TRUE(inverse_kinematics(mini, p, now));
    for (int i = 0; i < 8; ++i) {
      const double counts_rate =
          std::abs(winch_counts_change(mini.winches[0], now.lengths(i) - prev.lengths(i))) / dt;
      largest_ratio = std::max(largest_ratio, counts_rate / v[static_cast<std::size_t>(i)]);
    }
    std::swap(prev, now);
  }
  EXPECT_LE(largest_ratio, 1.0);
  EXPECT_GT(largest_ratio, 0.3);  // and not absurdly loose
  for (double x : a) EXPECT_GT(x, 0.0);
  // Wrong output sizes and invalid limits are refused.
  std::vector<double> short_out(4);
  EXPECT_FALSE(cable_count_limits(mini, limits, short_out, a).ok());
  MotionLimits bad;
  bad.max_angular_velocity = 0.0;
  EXPECT_NE(cable_count_limits(mini, bad, v, a).message().find("max_angular_velocity"),
            std::string_view::npos);
}

}  // namespace
}  // namespace cdpr
