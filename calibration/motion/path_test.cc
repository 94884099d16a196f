#include "cdpr/calibration/path.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include "alloc_counter.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

Pose pose_at(double x, double y, double z, double roll = 0, double pitch = 0, double yaw = 0) {
  Pose p;
  p.position << x, y, z;
  p.rpy << roll, pitch, yaw;
  return p;
}

PathSegment line_to(const Pose& p, int line = 0) {
  PathSegment s;
  s.kind = PathSegment::Kind::kLine;
  s.target = p;
  s.line = line;
  return s;
}

PathSegment arc_to(const Pose& p, const Eigen::Vector3d& center, const Eigen::Vector3d& axis,
                   int line = 0) {
  PathSegment s = line_to(p, line);
  s.kind = PathSegment::Kind::kArc;
  s.center = center;
  s.axis = axis;
  return s;
}

PathSegment spline_to(const Pose& p) {
  PathSegment s = line_to(p);
  s.kind = PathSegment::Kind::kSpline;
  return s;
}

Path plan(const Pose& start, const std::vector<PathSegment>& segs, const PathLimits& limits = {},
          const RobotModel* model = nullptr) {
  auto p = Path::plan(start, segs, limits, model);
  EXPECT_TRUE(p.ok()) << p.status().to_string();
  return p.ok() ? *p : Path{};
}

// Largest velocity, acceleration and jerk of the position and of the rotation over the path, by
// finite differences of the samples (the angular ones from the relative rotation of successive
// samples).
struct Peaks {
  double v = 0, a = 0, j = 0, w = 0, dw = 0;
};
Peaks peaks(const Path& path, double dt) {
  Peaks pk;
  const int n = static_cast<int>(path.duration() / dt) + 4;
  std::vector<Eigen::Vector3d> p(static_cast<std::size_t>(n));
  std::vector<Eigen::Vector3d> w(static_cast<std::size_t>(n));
  Eigen::Matrix3d prev = Eigen::Matrix3d::Identity();
  for (int k = 0; k < n; ++k) {
    Pose s;
    path.sample((k - 2) * dt, s);
    p[static_cast<std::size_t>(k)] = s.position;
    const Eigen::Matrix3d R = rotation_from_rpy<double>(s.rpy);
    if (k > 0) w[static_cast<std::size_t>(k)] = rotation_log(prev.transpose() * R) / dt;
    prev = R;
  }
  for (std::size_t k = 3; k < p.size(); ++k) {
    pk.v = std::max(pk.v, (p[k] - p[k - 1]).norm() / dt);
    pk.a = std::max(pk.a, (p[k] - 2 * p[k - 1] + p[k - 2]).norm() / (dt * dt));
    pk.j = std::max(pk.j, (p[k] - 3 * p[k - 1] + 3 * p[k - 2] - p[k - 3]).norm() / (dt * dt * dt));
    pk.w = std::max(pk.w, w[k].norm());
    pk.dw = std::max(pk.dw, (w[k] - w[k - 1]).norm() / dt);
  }
  return pk;
}

void expect_within_limits(const Path& path, const MotionLimits& l) {
  const Peaks pk = peaks(path, 1e-3);
  EXPECT_LE(pk.v, l.max_linear_velocity * 1.01);
  EXPECT_LE(pk.a, l.max_linear_acceleration * 1.02);
  EXPECT_LE(pk.w, l.max_angular_velocity * 1.01);
  EXPECT_LE(pk.dw, l.max_angular_acceleration * 1.02);
  const Peaks fine = peaks(path, 2e-4);
  EXPECT_LE(fine.j, l.max_linear_jerk * 1.03);
}

TEST(Path, AStraightLineIsExactlyTheTimeOptimalPoseTrajectory) {
  const Pose a = pose_at(-0.05, 0.02, -0.03), b = pose_at(0.12, -0.1, 0.08, 0.1, -0.05, 0.2);
  const Path path = plan(a, {line_to(b)});
  auto move = PoseTrajectory::plan(a, b, MotionLimits{});
  ASSERT_TRUE(move.ok());
  EXPECT_NEAR(path.duration(), move->duration(), 1e-9);
  for (double t = 0; t <= path.duration(); t += path.duration() / 37) {
    Pose p, q;
    path.sample(t, p);
    move->sample(t, q);
    EXPECT_LT((p.position - q.position).norm(), 1e-9) << t;
    EXPECT_LT((p.rpy - q.rpy).norm(), 1e-9) << t;
  }
}

TEST(Path, AFullCircleStaysOnItsCircleWithinEveryLimit) {
  const Pose start = pose_at(0.1, 0.0, 0.02);
  MotionLimits l;
  l.max_linear_velocity = 0.2;
  const Path path = plan(
      start, {arc_to(start, Eigen::Vector3d(0, 0, 0.02), Eigen::Vector3d::UnitZ())}, PathLimits{l});
  ASSERT_EQ(path.motions().size(), 1u);
  EXPECT_NEAR(path.length(), 2 * std::numbers::pi * 0.1, 1e-12);
  double max_radius_error = 0;
  bool passed_quarter = false;
  for (double t = 0; t <= path.duration(); t += 1e-3) {
    Pose p;
    path.sample(t, p);
    max_radius_error = std::max(max_radius_error, std::abs(p.position.head<2>().norm() - 0.1));
    EXPECT_NEAR(p.position.z(), 0.02, 1e-12);
    // Counter-clockwise about +z: y grows first.
    if (p.position.x() < 1e-3 && p.position.y() > 0.099) passed_quarter = true;
  }
  EXPECT_LT(max_radius_error, 1e-12);
  EXPECT_TRUE(passed_quarter);
  Pose end;
  path.sample(path.duration(), end);
  EXPECT_LT((end.position - start.position).norm(), 1e-12);
  expect_within_limits(path, l);
  // The curvature (a = v^2 / r) caps the speed: v = sqrt(a / (2 r)) here.
  EXPECT_LT(peaks(path, 1e-3).v, std::sqrt(l.max_linear_acceleration * 0.1 / 2) * 1.001);
}

TEST(Path, ClockwiseArcsAndHelixesFollowTheirAxis) {
  const Pose start = pose_at(0.1, 0.0, 0.0);
  // Clockwise about +z (axis -z) a quarter turn to (0, -0.1), rising 0.05 m.
  const Path path =
      plan(start,
           {arc_to(pose_at(0.0, -0.1, 0.05), Eigen::Vector3d::Zero(), -Eigen::Vector3d::UnitZ())});
  Eigen::Vector3d p;
  Eigen::Matrix3d R;
  path.path_point(path.length() / 2, p, R);
  EXPECT_NEAR(p.x(), 0.1 * std::cos(std::numbers::pi / 4), 1e-12);
  EXPECT_NEAR(p.y(), -0.1 * std::sin(std::numbers::pi / 4), 1e-12);
  EXPECT_NEAR(p.z(), 0.025, 1e-12);
}

TEST(Path, StopsAtCornersAndJoinsCollinearLines) {
  const Pose o = pose_at(0, 0, 0);
  const Path corner = plan(o, {line_to(pose_at(0.1, 0, 0)), line_to(pose_at(0.1, 0.1, 0))});
  ASSERT_EQ(corner.motions().size(), 2u);
  TaskVelocity v;
  Pose p;
  corner.sample(corner.motions()[1].t_begin, p, &v);
  EXPECT_LT(v.linear.norm(), 1e-12);
  EXPECT_NEAR(p.position.x(), 0.1, 1e-12);
  const Path straight = plan(o, {line_to(pose_at(0.05, 0, 0)), line_to(pose_at(0.1, 0, 0))});
  ASSERT_EQ(straight.motions().size(), 1u);
  const Path whole = plan(o, {line_to(pose_at(0.1, 0, 0))});
  EXPECT_NEAR(straight.duration(), whole.duration(), 1e-9);
  // A line into a tangent arc: the curvature jumps, so the platform stops there.
  const Path rounded = plan(
      o, {line_to(pose_at(0.1, 0, 0)),
          arc_to(pose_at(0.2, 0.1, 0), Eigen::Vector3d(0.1, 0.1, 0), Eigen::Vector3d::UnitZ())});
  EXPECT_EQ(rounded.motions().size(), 2u);
}

TEST(Path, ASplinePassesThroughItsWaypointsSmoothlyWithinTheLimits) {
  const Pose start = pose_at(0, 0, 0);
  const std::vector<Pose> w = {pose_at(0.05, 0.04, 0.0, 0, 0, 0.1),
                               pose_at(0.1, 0.0, 0.03, 0.05, 0, 0.2),
                               pose_at(0.15, -0.05, 0.0, 0, 0.05, 0.0)};
  std::vector<PathSegment> segs;
  for (const Pose& p : w) segs.push_back(spline_to(p));
  const Path path = plan(start, segs);
  ASSERT_EQ(path.motions().size(), 1u);  // C2 through the interior waypoints
  ASSERT_EQ(path.pieces(), 3);
  // Each waypoint is the end of a piece: found as the sample where the distance is smallest.
  for (const Pose& target : w) {
    double best = 1e9;
    Eigen::Vector3d rpy_best = Eigen::Vector3d::Zero();
    for (double s = 0; s <= path.length(); s += path.length() / 4000) {
      Eigen::Vector3d p;
      Eigen::Matrix3d R;
      path.path_point(s, p, R);
      const double d = (p - target.position).norm();
      if (d < best) {
        best = d;
        rpy_best = rpy_from_rotation(R);
      }
    }
    EXPECT_LT(best, 1e-4);
    EXPECT_LT((rpy_best - target.rpy).norm(), 5e-3);
  }
  Pose end;
  path.sample(path.duration(), end);
  EXPECT_LT((end.position - w.back().position).norm(), 1e-12);
  EXPECT_LT((end.rpy - w.back().rpy).norm(), 1e-9);
  expect_within_limits(path, MotionLimits{});
}

TEST(Path, InterpolatesOrientationOnTheGeodesic) {
  const Pose a = pose_at(0, 0, 0), b = pose_at(0, 0, 0, 0.2, -0.1, 0.3);
  const Path path = plan(a, {line_to(b)});
  Eigen::Vector3d p;
  Eigen::Matrix3d R;
  path.path_point(path.length() / 2, p, R);
  const Eigen::Matrix3d Ra = rotation_from_rpy<double>(a.rpy),
                        Rb = rotation_from_rpy<double>(b.rpy);
  const Eigen::Vector3d w = rotation_log(Ra.transpose() * Rb);
  EXPECT_LT((R - Ra * rotation_exp(w / 2)).norm(), 1e-12);
  expect_within_limits(path, MotionLimits{});
}

TEST(Path, DwellsHoldThePose) {
  const Pose o = pose_at(0, 0, 0);
  PathSegment dwell;
  dwell.kind = PathSegment::Kind::kDwell;
  dwell.dwell = 0.75;
  const Path path = plan(o, {line_to(pose_at(0.05, 0, 0)), dwell, line_to(pose_at(0.1, 0, 0))});
  ASSERT_EQ(path.motions().size(), 2u);
  const double t1 = path.motions()[0].t_begin + path.motions()[0].profile.duration();
  EXPECT_NEAR(path.motions()[1].t_begin, t1 + 0.75, 1e-12);
  for (double t = t1; t < t1 + 0.75; t += 0.05) {
    Pose p;
    path.sample(t, p);
    EXPECT_NEAR(p.position.x(), 0.05, 1e-12);
  }
}

TEST(Path, RespectsTheCableSpeedLimit) {
  const RobotModel mini = testing::mini_robot();
  PathLimits limits;
  limits.max_cable_velocity = 0.02;
  const Pose start = pose_at(0.1, 0.0, 0.0);
  const Path path = plan(start, {arc_to(start, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ())},
                         limits, &mini);
  KinematicsData k0(mini), k1(mini);
  double fastest = 0;
  const double dt = 1e-3;
  Pose p;
  path.sample(0, p);
  inverse_kinematics(mini, p, k0);
  for (double t = dt; t <= path.duration(); t += dt) {
    path.sample(t, p);
    inverse_kinematics(mini, p, k1);
    fastest = std::max(fastest, ((k1.lengths - k0.lengths) / dt).cwiseAbs().maxCoeff());
    std::swap(k0, k1);
  }
  EXPECT_LE(fastest, 0.02 * 1.001);
  EXPECT_GT(fastest, 0.02 * 0.8);  // the limit is what slows it down
}

TEST(Path, SamplingAllocatesNothing) {
  const Pose start = pose_at(0.1, 0.0, 0.0);
  std::vector<PathSegment> segs = {arc_to(start, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ()),
                                   spline_to(pose_at(0.05, 0.05, 0.02, 0.1, 0, 0)),
                                   spline_to(pose_at(0.0, 0.0, 0.0)),
                                   line_to(pose_at(0.1, 0.0, 0.0))};
  const Path path = plan(start, segs);
  Pose p;
  TaskVelocity v;
  double sum = 0;
  const test::AllocationCounter count;
  for (int k = 0; k <= 5000; ++k) {
    path.sample(path.duration() * k / 5000.0, p, &v);
    sum += p.position.x() + v.linear.x() + path.sigma_at(k * 1e-3);
  }
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_TRUE(std::isfinite(sum));
}

Result<Path> try_plan(const Pose& start, const std::vector<PathSegment>& segs,
                      const PathLimits& limits = {}, std::string_view source = "path") {
  return Path::plan(start, segs, limits, nullptr, source);
}

TEST(Path, RefusesBadSegmentsNamingTheLine) {
  const Pose o = pose_at(0.1, 0, 0);
  auto off = try_plan(
      o, {arc_to(pose_at(0.0, 0.12, 0), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), 7)},
      PathLimits{}, "demo.path");
  ASSERT_FALSE(off.ok());
  EXPECT_NE(off.status().message().find("demo.path:7: arc: the end is 0.1200 m from the axis"),
            std::string_view::npos)
      << off.status().to_string();
  auto twice = try_plan(o, {spline_to(pose_at(0.2, 0, 0)), spline_to(pose_at(0.2, 0, 0))});
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().message().find("segment 2: spline: the waypoint equals"),
            std::string_view::npos);
  PathLimits cable;
  cable.max_cable_velocity = 0.1;
  EXPECT_FALSE(try_plan(o, {line_to(pose_at(0, 0, 0))}, cable).ok());
  EXPECT_FALSE(try_plan(o, {line_to(pose_at(0, std::nan(""), 0))}).ok());
}

}  // namespace
}  // namespace cdpr
