#include "cdpr/calibration/trajectory.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>
#include <string>

#include "alloc_counter.hpp"
#include "cdpr/calibration/kinematics.hpp"

namespace cdpr {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

DoubleSProfile plan_profile(double d, double v, double a, double j) {
  auto p = DoubleSProfile::plan(d, v, a, j);
  EXPECT_TRUE(p.ok()) << p.status().to_string();
  return p.ok() ? *p : DoubleSProfile{};
}

// Samples densely and checks every limit, monotonic progress and consistency of the derivatives.
void expect_profile_within_limits(const DoubleSProfile& p, double v, double a, double j) {
  const double T = p.duration();
  const int n = 20000;
  const double rel = 1e-9;
  DoubleSProfile::Sample prev = p.sample(0.0);
  double max_v = 0.0, max_a = 0.0;
  for (int k = 1; k <= n; ++k) {
    const double t = T * k / n;
    const DoubleSProfile::Sample x = p.sample(t);
    ASSERT_LE(std::abs(x.ds), v * (1.0 + rel)) << "t = " << t;
    ASSERT_LE(std::abs(x.dds), a * (1.0 + rel)) << "t = " << t;
    ASSERT_LE(std::abs(x.jerk), j * (1.0 + rel)) << "t = " << t;
    ASSERT_GE(x.ds, -1e-12 * v) << "t = " << t;
    ASSERT_GE(x.s, prev.s - 1e-12 * p.distance()) << "t = " << t;
    ASSERT_LE(x.s, p.distance() * (1.0 + 1e-12)) << "t = " << t;
    // Continuity: no step larger than the limits allow over one sampling interval.
    const double dt = T / n;
    ASSERT_LE(std::abs(x.s - prev.s), v * dt * (1.0 + 1e-6) + 1e-12 * p.distance());
    ASSERT_LE(std::abs(x.ds - prev.ds), a * dt * (1.0 + 1e-6) + 1e-12 * v);
    ASSERT_LE(std::abs(x.dds - prev.dds), j * dt * (1.0 + 1e-6) + 1e-12 * a);
    max_v = std::max(max_v, x.ds);
    max_a = std::max(max_a, x.dds);
    prev = x;
  }
  // The derivatives are those of s (central differences inside the profile).
  for (int k = 1; k < 50; ++k) {
    const double t = T * k / 50.0, h = 1e-6 * T;
    const auto lo = p.sample(t - h), hi = p.sample(t + h), mid = p.sample(t);
    EXPECT_NEAR((hi.s - lo.s) / (2 * h), mid.ds, 1e-5 * v + 1e-6 * a * T);
    EXPECT_NEAR((hi.ds - lo.ds) / (2 * h), mid.dds, 1e-3 * a + j * h);
  }
  EXPECT_NEAR(max_v, p.peak_velocity(), 1e-6 * v + a * T / n);
  EXPECT_NEAR(max_a, p.peak_acceleration(), 1e-6 * a + j * T / n);
}

TEST(MotionLimits, ValidateNamesTheOffendingField) {
  EXPECT_TRUE(MotionLimits{}.validate().ok());
  MotionLimits l;
  l.max_angular_jerk = 0.0;
  Status s = l.validate();
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(s.message().find("max_angular_jerk"), std::string_view::npos) << s.to_string();
  l = MotionLimits{};
  l.max_linear_acceleration = std::nan("");
  s = l.validate();
  EXPECT_NE(s.message().find("max_linear_acceleration"), std::string_view::npos);
  l = MotionLimits{};
  l.max_linear_velocity = -1.0;
  EXPECT_NE(l.validate().message().find("max_linear_velocity"), std::string_view::npos);
}

TEST(DoubleSProfile, LongMoveReachesVelocityAndAccelerationLimits) {
  const double D = 10.0, v = 1.0, a = 2.0, j = 4.0;
  const DoubleSProfile p = plan_profile(D, v, a, j);
  // Both limits reached: T = D / v + v / a + a / j.
  EXPECT_NEAR(p.duration(), D / v + v / a + a / j, 1e-12);
  EXPECT_DOUBLE_EQ(p.peak_velocity(), v);
  EXPECT_DOUBLE_EQ(p.peak_acceleration(), a);
  EXPECT_NEAR(p.jerk_time(), a / j, 1e-15);
  EXPECT_GT(p.cruise_time(), 0.0);
  expect_profile_within_limits(p, v, a, j);
}

TEST(DoubleSProfile, VelocityLimitReachedBeforeAccelerationLimit) {
  // v j < a^2: the acceleration peaks at sqrt(v j) < a, T = D / v + 2 sqrt(v / j).
  const double D = 5.0, v = 0.5, a = 2.0, j = 4.0;
  const DoubleSProfile p = plan_profile(D, v, a, j);
  EXPECT_NEAR(p.duration(), D / v + 2.0 * std::sqrt(v / j), 1e-12);
  EXPECT_DOUBLE_EQ(p.peak_velocity(), v);
  EXPECT_NEAR(p.peak_acceleration(), std::sqrt(v * j), 1e-12);
  EXPECT_LT(p.peak_acceleration(), a);
  expect_profile_within_limits(p, v, a, j);
}

TEST(DoubleSProfile, ShortMoveReachesAccelerationButNotVelocity) {
  // D >= 2 a^3 / j^2 but v never reached: vp^2 + (a^2 / j) vp - a D = 0, T = 2 (a / j + vp / a).
  const double D = 1.0, v = 10.0, a = 1.0, j = 10.0;
  const DoubleSProfile p = plan_profile(D, v, a, j);
  const double b = a * a / j;
  const double vp = (-b + std::sqrt(b * b + 4.0 * a * D)) / 2.0;
  EXPECT_NEAR(p.peak_velocity(), vp, 1e-12);
  EXPECT_LT(p.peak_velocity(), v);
  EXPECT_DOUBLE_EQ(p.peak_acceleration(), a);
  EXPECT_EQ(p.cruise_time(), 0.0);
  EXPECT_NEAR(p.duration(), 2.0 * (a / j + vp / a), 1e-12);
  expect_profile_within_limits(p, v, a, j);
}

TEST(DoubleSProfile, VeryShortMoveReachesNeitherLimit) {
  // D < 2 a^3 / j^2: four jerk phases of Tj = cbrt(D / (2 j)), T = 4 Tj.
  const double D = 1e-3, v = 1.0, a = 1.0, j = 1.0;
  const DoubleSProfile p = plan_profile(D, v, a, j);
  EXPECT_NEAR(p.duration(), 4.0 * std::cbrt(D / (2.0 * j)), 1e-12);
  EXPECT_LT(p.peak_velocity(), v);
  EXPECT_LT(p.peak_acceleration(), a);
  expect_profile_within_limits(p, v, a, j);
}

TEST(DoubleSProfile, HandComputedUnitCase) {
  // D = v = a = j = 1: a reached at v (v j = a^2) but then v Ta = 2 > D, and D < 2 a^3 / j^2 = 2:
  // neither limit is reached, T = 4 cbrt(1 / 2).
  const DoubleSProfile p = plan_profile(1.0, 1.0, 1.0, 1.0);
  EXPECT_NEAR(p.duration(), 4.0 * std::cbrt(0.5), 1e-12);
  // At the boundary D = 2 a^3 / j^2 = 2 the acceleration just reaches a: T = 4 a / j = 4.
  EXPECT_NEAR(plan_profile(2.0, 1.0, 1.0, 1.0).duration(), 4.0, 1e-12);
  // And at D = v Ta = 2 with v = 1, a = 1, j = 1 both meet too (no cruise).
  EXPECT_NEAR(plan_profile(2.0, 1.0, 1.0, 1.0).peak_velocity(), 1.0, 1e-12);
}

TEST(DoubleSProfile, DurationIsContinuousAcrossTheCaseBoundaries) {
  // Around each boundary between the cases the duration changes continuously.
  const double v = 1.0, a = 2.0, j = 4.0;
  const double d_acc = 2.0 * a * a * a / (j * j);  // a just reached
  const double d_vel = v * (a / j + v / a);        // v just reached
  for (double d : {d_acc, d_vel}) {
    const double lo = plan_profile(d * (1 - 1e-9), v, a, j).duration();
    const double hi = plan_profile(d * (1 + 1e-9), v, a, j).duration();
    EXPECT_NEAR(lo, hi, 1e-7) << "D = " << d;
  }
}

TEST(DoubleSProfile, RandomCasesStayWithinLimitsAndEndExactly) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> decade(-3.0, 3.0);
  for (int c = 0; c < 40; ++c) {
    const double D = std::pow(10.0, decade(rng)), v = std::pow(10.0, decade(rng));
    const double a = std::pow(10.0, decade(rng)), j = std::pow(10.0, decade(rng));
    SCOPED_TRACE("D " + std::to_string(D) + " v " + std::to_string(v) + " a " + std::to_string(a) +
                 " j " + std::to_string(j));
    const DoubleSProfile p = plan_profile(D, v, a, j);
    // At least one limit is active in the peak, as time-optimality demands.
    EXPECT_TRUE(std::abs(p.peak_velocity() - v) < 1e-9 * v ||
                std::abs(p.peak_acceleration() - a) < 1e-9 * a || p.cruise_time() == 0.0);
    expect_profile_within_limits(p, v, a, j);
    EXPECT_EQ(p.sample(p.duration()).s, D);
    EXPECT_EQ(p.sample(p.duration() * 2).s, D);
    EXPECT_EQ(p.sample(p.duration()).ds, 0.0);
  }
}

TEST(DoubleSProfile, EndsExactlyAndStartsAtRest) {
  const DoubleSProfile p = plan_profile(0.3, 0.1, 0.5, 5.0);
  const auto end = p.sample(p.duration());
  EXPECT_EQ(end.s, 0.3);
  EXPECT_EQ(end.ds, 0.0);
  EXPECT_EQ(end.dds, 0.0);
  EXPECT_EQ(end.jerk, 0.0);
  const auto start = p.sample(0.0);
  EXPECT_EQ(start.s, 0.0);
  EXPECT_EQ(start.ds, 0.0);
  EXPECT_EQ(p.sample(-1.0).s, 0.0);
  // Just before the end the state is within rounding of the end (no jump at T).
  const auto before = p.sample(p.duration() * (1 - 1e-12));
  EXPECT_NEAR(before.s, 0.3, 1e-12);
  EXPECT_NEAR(before.ds, 0.0, 1e-9);
}

TEST(DoubleSProfile, ZeroDistanceHasZeroDuration) {
  const DoubleSProfile p = plan_profile(0.0, 1.0, 1.0, 1.0);
  EXPECT_EQ(p.duration(), 0.0);
  EXPECT_EQ(p.sample(0.0).s, 0.0);
  EXPECT_EQ(p.sample(1.0).s, 0.0);
}

TEST(DoubleSProfile, RejectsBadInput) {
  EXPECT_EQ(DoubleSProfile::plan(-1.0, 1, 1, 1).status().code(), ErrorCode::kInvalidArgument);
  EXPECT_FALSE(DoubleSProfile::plan(std::nan(""), 1, 1, 1).ok());
  EXPECT_FALSE(DoubleSProfile::plan(1.0, 0.0, 1, 1).ok());
  EXPECT_FALSE(DoubleSProfile::plan(1.0, 1, INFINITY, 1).ok());
  EXPECT_FALSE(DoubleSProfile::plan(1.0, 1, 1, -2).ok());
}

double angle_between(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return rotation_log(a.transpose() * b).norm();
}

MotionLimits test_limits() {
  MotionLimits l;
  l.max_linear_velocity = 0.2;
  l.max_linear_acceleration = 0.8;
  l.max_linear_jerk = 8.0;
  l.max_angular_velocity = 0.4;
  l.max_angular_acceleration = 1.5;
  l.max_angular_jerk = 15.0;
  return l;
}

TEST(RotationLog, InvertsRotationExpUpToPi) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  for (double angle : {0.0, 1e-9, 1e-5, 0.3, 2.0, 3.1, std::numbers::pi - 1e-7}) {
    Eigen::Vector3d axis(n(rng), n(rng), n(rng));
    axis.normalize();
    const Eigen::Vector3d w = angle * axis;
    EXPECT_LT((rotation_log(rotation_exp(w)) - w).norm(), 1e-9) << "angle " << angle;
  }
  // At pi either sign of the axis is the same rotation.
  const Eigen::Vector3d w = std::numbers::pi * Eigen::Vector3d::UnitY();
  EXPECT_LT((rotation_exp(rotation_log(rotation_exp(w))) - rotation_exp(w)).norm(), 1e-12);
}

TEST(PoseTrajectory, LinearAndAngularMotionStayInSyncAndEndTogether) {
  Pose a, b;
  a.position << 0.05, -0.02, 0.01;
  a.rpy << 5 * kDeg, -3 * kDeg, 10 * kDeg;
  b.position << -0.10, 0.08, 0.06;
  b.rpy << -8 * kDeg, 6 * kDeg, -12 * kDeg;
  const MotionLimits limits = test_limits();
  auto traj = PoseTrajectory::plan(a, b, limits);
  ASSERT_TRUE(traj.ok()) << traj.status().to_string();
  const double L = (b.position - a.position).norm();
  const Eigen::Matrix3d Ra = rotation_from_rpy<double>(a.rpy);
  const Eigen::Matrix3d Rb = rotation_from_rpy<double>(b.rpy);
  const double theta = angle_between(Ra, Rb);
  EXPECT_NEAR(traj->linear_distance(), L, 1e-15);
  EXPECT_NEAR(traj->angular_distance(), theta, 1e-12);
  const double T = traj->duration();
  ASSERT_GT(T, 0.0);
  const int n = 4000;
  Pose prev = a;
  double max_v = 0, max_w = 0, max_a = 0, max_alpha = 0;
  for (int k = 1; k <= n; ++k) {
    const double t = T * k / n;
    Pose p;
    TaskVelocity vel;
    TaskAcceleration acc;
    traj->sample(t, p, &vel, &acc);
    const Eigen::Matrix3d R = rotation_from_rpy<double>(p.rpy);
    // Same fraction of the translation and of the rotation at every instant.
    const double lin_fraction = (p.position - a.position).norm() / L;
    const double ang_fraction = angle_between(Ra, R) / theta;
    ASSERT_NEAR(lin_fraction, ang_fraction, 1e-9) << "t = " << t;
    // On the straight line and on the geodesic.
    const Eigen::Vector3d off_line =
        (p.position - a.position) - lin_fraction * (b.position - a.position);
    ASSERT_LT(off_line.norm(), 1e-12);
    ASSERT_LT((R - Ra * rotation_exp(ang_fraction * rotation_log(Ra.transpose() * Rb))).norm(),
              1e-9);
    // Continuity: one sampling interval moves no further than the velocity limits allow.
    const double dt = T / n;
    ASSERT_LE((p.position - prev.position).norm(),
              limits.max_linear_velocity * dt * (1 + 1e-6) + 1e-15);
    ASSERT_LE(angle_between(rotation_from_rpy<double>(prev.rpy), R),
              limits.max_angular_velocity * dt * (1 + 1e-6) + 1e-12);
    ASSERT_LT((p.rpy - prev.rpy).cwiseAbs().maxCoeff(), 0.01);
    max_v = std::max(max_v, vel.linear.norm());
    max_w = std::max(max_w, vel.angular.norm());
    max_a = std::max(max_a, acc.linear.norm());
    max_alpha = std::max(max_alpha, acc.angular.norm());
    prev = p;
  }
  EXPECT_LE(max_v, limits.max_linear_velocity * (1 + 1e-9));
  EXPECT_LE(max_w, limits.max_angular_velocity * (1 + 1e-9));
  EXPECT_LE(max_a, limits.max_linear_acceleration * (1 + 1e-9));
  EXPECT_LE(max_alpha, limits.max_angular_acceleration * (1 + 1e-9));
  // Time-optimal under the tightest class: one of the classes reaches its velocity limit or its
  // acceleration limit (the move is long enough for the velocity here).
  const double v_ratio =
      std::max(max_v / limits.max_linear_velocity, max_w / limits.max_angular_velocity);
  EXPECT_NEAR(v_ratio, 1.0, 1e-9);
  // Both classes end together, exactly on `to`.
  Pose end;
  TaskVelocity vend;
  traj->sample(T, end, &vend);
  EXPECT_EQ(end.position, b.position);
  EXPECT_EQ(end.rpy, b.rpy);
  EXPECT_EQ(vend.linear.norm(), 0.0);
  EXPECT_EQ(vend.angular.norm(), 0.0);
  traj->sample(T + 5.0, end);
  EXPECT_EQ(end.position, b.position);
  traj->sample(0.0, end);
  EXPECT_EQ(end.position, a.position);
  EXPECT_EQ(end.rpy, a.rpy);
}

TEST(PoseTrajectory, ReportedTwistIsTheDerivativeOfThePose) {
  Pose a, b;
  b.position << 0.1, 0.05, -0.03;
  b.rpy << 10 * kDeg, 20 * kDeg, -30 * kDeg;
  auto traj = PoseTrajectory::plan(a, b, test_limits());
  ASSERT_TRUE(traj.ok());
  const double T = traj->duration(), h = 1e-6;
  for (int k = 1; k < 20; ++k) {
    const double t = T * k / 20.0;
    Pose lo, hi, mid;
    TaskVelocity v;
    TaskAcceleration acc;
    TaskVelocity vlo, vhi;
    traj->sample(t - h, lo, &vlo);
    traj->sample(t + h, hi, &vhi);
    traj->sample(t, mid, &v, &acc);
    EXPECT_LT(((hi.position - lo.position) / (2 * h) - v.linear).norm(), 1e-6);
    const Eigen::Matrix3d Rlo = rotation_from_rpy<double>(lo.rpy);
    const Eigen::Matrix3d Rhi = rotation_from_rpy<double>(hi.rpy);
    const Eigen::Vector3d w_world = rotation_log(Rhi * Rlo.transpose()) / (2 * h);
    EXPECT_LT((w_world - v.angular).norm(), 1e-6);
    EXPECT_LT(((vhi.linear - vlo.linear) / (2 * h) - acc.linear).norm(), 1e-4);
    EXPECT_LT(((vhi.angular - vlo.angular) / (2 * h) - acc.angular).norm(), 1e-4);
  }
}

TEST(PoseTrajectory, PureRotationKeepsThePositionAndUsesTheAngularLimits) {
  Pose a, b;
  a.position << 0.02, 0.03, -0.01;
  b.position = a.position;
  const double theta = 30 * kDeg;
  const Eigen::Vector3d axis = Eigen::Vector3d(1.0, -2.0, 0.5).normalized();
  b.rpy = rpy_from_rotation(rotation_exp(theta * axis));
  MotionLimits l = test_limits();
  l.max_angular_velocity = 0.5;
  l.max_angular_acceleration = 2.0;
  l.max_angular_jerk = 20.0;
  auto traj = PoseTrajectory::plan(a, b, l);
  ASSERT_TRUE(traj.ok());
  EXPECT_EQ(traj->linear_distance(), 0.0);
  EXPECT_NEAR(traj->angular_distance(), theta, 1e-12);
  // v j >= a^2 and theta > v (v / a + a / j): both angular limits reached, T = theta / v + v / a
  // + a / j.
  const double v = l.max_angular_velocity, acc = l.max_angular_acceleration, j = l.max_angular_jerk;
  EXPECT_NEAR(traj->duration(), theta / v + v / acc + acc / j, 1e-12);
  for (int k = 0; k <= 100; ++k) {
    Pose p;
    TaskVelocity vel;
    traj->sample(traj->duration() * k / 100.0, p, &vel);
    EXPECT_EQ(p.position, a.position);
    EXPECT_EQ(vel.linear.norm(), 0.0);
    // The rotation axis stays fixed (world frame: R_A w, here R_A = I).
    if (vel.angular.norm() > 1e-9) {
      EXPECT_NEAR(vel.angular.normalized().dot(axis), 1.0, 1e-9);
    }
  }
}

TEST(PoseTrajectory, YawAcrossPiDoesNotWrapMidMove) {
  Pose a, b;
  a.rpy << 0.0, 0.0, 170 * kDeg;
  b.rpy << 0.0, 0.0, -170 * kDeg;
  auto traj = PoseTrajectory::plan(a, b, test_limits());
  ASSERT_TRUE(traj.ok());
  EXPECT_NEAR(traj->angular_distance(), 20 * kDeg, 1e-12);  // the short way round
  Pose prev = a;
  const int n = 500;
  for (int k = 1; k < n; ++k) {
    Pose p;
    traj->sample(traj->duration() * k / n, p);
    EXPECT_LT(std::abs(p.rpy.z() - prev.rpy.z()), 1 * kDeg) << k;
    prev = p;
  }
  EXPECT_NEAR(prev.rpy.z(), 190 * kDeg, 1e-3);  // continuous up to the end, then exactly `to`
}

TEST(PoseTrajectory, ZeroLengthMoveHasZeroDuration) {
  Pose a;
  a.position << 0.1, 0.2, 0.3;
  a.rpy << 0.1, 0.2, 0.3;
  auto traj = PoseTrajectory::plan(a, a, MotionLimits{});
  ASSERT_TRUE(traj.ok());
  EXPECT_EQ(traj->duration(), 0.0);
  Pose p;
  TaskVelocity v;
  traj->sample(0.0, p, &v);
  EXPECT_EQ(p.position, a.position);
  EXPECT_EQ(p.rpy, a.rpy);
  EXPECT_EQ(v.linear.norm(), 0.0);
}

TEST(PoseTrajectory, RejectsInvalidLimitsAndPoses) {
  MotionLimits l;
  l.max_linear_jerk = -5.0;
  auto t = PoseTrajectory::plan(Pose{}, Pose{}, l);
  ASSERT_FALSE(t.ok());
  EXPECT_NE(t.status().message().find("max_linear_jerk"), std::string_view::npos);
  Pose bad;
  bad.position.x() = std::nan("");
  EXPECT_EQ(PoseTrajectory::plan(bad, Pose{}, MotionLimits{}).status().code(),
            ErrorCode::kInvalidArgument);
}

TEST(PoseTrajectory, SamplingAllocatesNothing) {
  Pose a, b;
  b.position << 0.1, -0.1, 0.05;
  b.rpy << 0.1, -0.05, 0.2;
  auto traj = PoseTrajectory::plan(a, b, MotionLimits{});
  ASSERT_TRUE(traj.ok());
  Pose p;
  TaskVelocity v;
  TaskAcceleration acc;
  double sum = 0.0;
  test::AllocationCounter count;
  for (int k = 0; k <= 1000; ++k) {
    traj->sample(traj->duration() * k / 1000.0, p, &v, &acc);
    sum += p.position.x() + v.linear.x() + acc.angular.z() + traj->profile().sample(0.1).s;
  }
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_TRUE(std::isfinite(sum));
}

}  // namespace
}  // namespace cdpr
