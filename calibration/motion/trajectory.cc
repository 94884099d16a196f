#include "cdpr/calibration/trajectory.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "cdpr/calibration/kinematics.hpp"

namespace cdpr {
namespace {

bool positive_finite(double x) {
  return std::isfinite(x) && x > 0.0;
}

Status invalid_limit(const char* field, double value) {
  return Status::error(ErrorCode::kInvalidArgument,
                       "motion limits: %s must be finite and > 0 (got %g)", field, value);
}

// The tightest of two limits over their distances; a class that does not move (distance 0)
// imposes nothing. At least one distance is > 0.
double path_limit(double linear_limit, double linear_distance, double angular_limit, double angle) {
  double limit = std::numeric_limits<double>::infinity();
  if (linear_distance > 0.0) limit = std::min(limit, linear_limit / linear_distance);
  if (angle > 0.0) limit = std::min(limit, angular_limit / angle);
  return limit;
}

// x shifted by a multiple of 2 pi to lie within pi of `reference`.
double unwrap_near(double x, double reference) {
  constexpr double kTwoPi = 2.0 * std::numbers::pi;
  return x + kTwoPi * std::round((reference - x) / kTwoPi);
}

}  // namespace

Status MotionLimits::validate() const {
  const struct {
    const char* name;
    double value;
  } fields[] = {
      {"max_linear_velocity", max_linear_velocity},
      {"max_linear_acceleration", max_linear_acceleration},
      {"max_linear_jerk", max_linear_jerk},
      {"max_angular_velocity", max_angular_velocity},
      {"max_angular_acceleration", max_angular_acceleration},
      {"max_angular_jerk", max_angular_jerk},
  };
  for (const auto& f : fields) {
    if (!positive_finite(f.value)) return invalid_limit(f.name, f.value);
  }
  return Status::success();
}

Result<DoubleSProfile> DoubleSProfile::plan(double distance, double max_velocity,
                                            double max_acceleration, double max_jerk) {
  if (!std::isfinite(distance) || distance < 0.0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "double-S profile: distance must be finite and >= 0 (got %g)", distance);
  }
  if (!positive_finite(max_velocity) || !positive_finite(max_acceleration) ||
      !positive_finite(max_jerk)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "double-S profile: limits must be finite and > 0 (velocity %g, "
                         "acceleration %g, jerk %g)",
                         max_velocity, max_acceleration, max_jerk);
  }
  DoubleSProfile p;
  p.distance_ = distance;
  p.jerk_ = max_jerk;
  if (distance == 0.0) return p;
  const double v = max_velocity, a = max_acceleration, j = max_jerk;
  // Acceleration phase (rest to peak velocity vp): jerk time and total time.
  auto accel_phase = [&](double vp, double& tj, double& ta) {
    if (vp * j >= a * a) {
      tj = a / j;
      ta = tj + vp / a;
    } else {
      tj = std::sqrt(vp / j);
      ta = 2.0 * tj;
    }
  };
  double tj = 0.0, ta = 0.0;
  accel_phase(v, tj, ta);
  if (v * ta <= distance) {  // the velocity limit is reached: cruise
    p.peak_velocity_ = v;
    p.jerk_time_ = tj;
    p.accel_time_ = ta;
    p.cruise_time_ = std::max(0.0, distance / v - ta);
    return p;
  }
  if (distance >= 2.0 * a * a * a / (j * j)) {  // acceleration limit reached, velocity not
    // Root of vp^2 + b vp - a D = 0 (b = a^2 / j), written without cancellation.
    const double b = a * a / j;
    const double vp = 2.0 * a * distance / (std::sqrt(b * b + 4.0 * a * distance) + b);
    p.peak_velocity_ = vp;
    p.jerk_time_ = a / j;
    p.accel_time_ = p.jerk_time_ + vp / a;
  } else {  // neither limit reached
    p.jerk_time_ = std::cbrt(distance / (2.0 * j));
    p.peak_velocity_ = j * p.jerk_time_ * p.jerk_time_;
    p.accel_time_ = 2.0 * p.jerk_time_;
  }
  p.cruise_time_ = 0.0;
  return p;
}

DoubleSProfile::Sample DoubleSProfile::accelerating(double t) const noexcept {
  const double j = jerk_, tj = jerk_time_, ta = accel_time_, vp = peak_velocity_;
  const double a_lim = j * tj;
  Sample out;
  if (t <= tj) {  // phase 1: jerk +j from rest
    out.jerk = j;
    out.dds = j * t;
    out.ds = 0.5 * j * t * t;
    out.s = j * t * t * t / 6.0;
  } else if (t <= ta - tj) {  // phase 2: constant acceleration
    const double u = t - tj;
    const double v1 = 0.5 * j * tj * tj;
    out.jerk = 0.0;
    out.dds = a_lim;
    out.ds = v1 + a_lim * u;
    out.s = j * tj * tj * tj / 6.0 + v1 * u + 0.5 * a_lim * u * u;
  } else if (t <= ta) {  // phase 3: jerk -j up to vp, written from its end (mirror of phase 1)
    const double u = ta - t;
    out.jerk = -j;
    out.dds = j * u;
    out.ds = vp - 0.5 * j * u * u;
    out.s = 0.5 * vp * ta - vp * u + j * u * u * u / 6.0;
  } else {  // phase 4: cruise
    out.jerk = 0.0;
    out.dds = 0.0;
    out.ds = vp;
    out.s = 0.5 * vp * ta + vp * (t - ta);
  }
  return out;
}

DoubleSProfile::Sample DoubleSProfile::sample(double t) const noexcept {
  const double T = duration();
  if (!(t > 0.0)) return {};  // also NaN
  if (t >= T) return {distance_, 0.0, 0.0, 0.0};
  if (t <= 0.5 * T) return accelerating(t);
  // Deceleration half: s(t) = D - s_acc(T - t).
  const Sample m = accelerating(T - t);
  return {distance_ - m.s, m.ds, -m.dds, m.jerk};
}

Eigen::Vector3d rotation_log(const Eigen::Matrix3d& R) {
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  const double n = q.vec().norm();
  if (n < 1e-12) return 2.0 * q.vec() / q.w();  // sin(theta/2) ~ theta/2
  const double angle = 2.0 * std::atan2(n, q.w());
  return q.vec() * (angle / n);
}

Result<PoseTrajectory> PoseTrajectory::plan(const Pose& from, const Pose& to,
                                            const MotionLimits& limits) {
  if (!from.vector().allFinite() || !to.vector().allFinite()) {
    return Status(ErrorCode::kInvalidArgument, "trajectory: a pose is not finite");
  }
  if (Status s = limits.validate(); !s.ok()) return s;
  PoseTrajectory traj;
  traj.from_ = from;
  traj.to_ = to;
  traj.rotation_from_ = rotation_from_rpy<double>(from.rpy);
  const Eigen::Matrix3d rotation_to = rotation_from_rpy<double>(to.rpy);
  traj.displacement_ = to.position - from.position;
  traj.linear_distance_ = traj.displacement_.norm();
  traj.rotation_vector_ = rotation_log(traj.rotation_from_.transpose() * rotation_to);
  traj.angle_ = traj.rotation_vector_.norm();
  traj.angular_axis_world_ = traj.rotation_from_ * traj.rotation_vector_;
  traj.rpy_end_ = to.rpy;
  traj.rpy_end_(0) = unwrap_near(to.rpy(0), from.rpy(0));
  traj.rpy_end_(2) = unwrap_near(to.rpy(2), from.rpy(2));
  if (traj.linear_distance_ == 0.0 && traj.angle_ == 0.0) return traj;  // duration 0
  const double L = traj.linear_distance_, th = traj.angle_;
  Result<DoubleSProfile> profile = DoubleSProfile::plan(
      1.0, path_limit(limits.max_linear_velocity, L, limits.max_angular_velocity, th),
      path_limit(limits.max_linear_acceleration, L, limits.max_angular_acceleration, th),
      path_limit(limits.max_linear_jerk, L, limits.max_angular_jerk, th));
  if (!profile.ok()) return profile.status();
  traj.profile_ = *profile;
  return traj;
}

void PoseTrajectory::path_point(double s, Eigen::Vector3d& position,
                                Eigen::Matrix3d& rotation) const noexcept {
  s = std::clamp(s, 0.0, 1.0);
  position = from_.position + s * displacement_;
  rotation = rotation_from_ * rotation_exp(s * rotation_vector_);
}

void PoseTrajectory::sample(double t, Pose& pose, TaskVelocity* velocity,
                            TaskAcceleration* acceleration) const noexcept {
  const DoubleSProfile::Sample p = profile_.sample(t);
  if (!(t > 0.0)) {
    pose = from_;
  } else if (t >= duration()) {
    pose = to_;
  } else {
    Eigen::Matrix3d rotation;
    path_point(p.s, pose.position, rotation);
    const Eigen::Vector3d rpy = rpy_from_rotation(rotation);
    const Eigen::Vector3d reference = from_.rpy + p.s * (rpy_end_ - from_.rpy);
    pose.rpy << unwrap_near(rpy(0), reference(0)), rpy(1), unwrap_near(rpy(2), reference(2));
  }
  if (velocity != nullptr) {
    velocity->linear = p.ds * displacement_;
    velocity->angular = p.ds * angular_axis_world_;
  }
  if (acceleration != nullptr) {
    acceleration->linear = p.dds * displacement_;
    acceleration->angular = p.dds * angular_axis_world_;
  }
}

}  // namespace cdpr
