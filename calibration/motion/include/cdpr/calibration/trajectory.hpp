// Task-space point-to-point motion for the daemon: motion limits, the 1-D time-optimal
// jerk-limited rest-to-rest profile ("double S") and the straight-line pose trajectory built on it.
//
// Planning (plan()) runs outside the RT loop and validates its input; sampling (sample()) is
// allocation-free and noexcept, so the RT cycle calls it every period.
//
// Double-S profile (rest to rest, 0 -> D, limits v, a, j > 0). Jerk is +-j or 0, in up to seven
// phases: jerk +j for Tj, 0 for Ta - 2 Tj (acceleration held at a_lim = j Tj), -j for Tj, cruise at
// v_lim for Tv, then the mirror image. With v_lim the peak velocity reached:
//   a reached    (v_lim j >= a^2): Tj = a / j,            Ta = Tj + v_lim / a
//   a not reached (v_lim j < a^2): Tj = sqrt(v_lim / j),  Ta = 2 Tj
// The distance covered while accelerating and braking is v_lim Ta. When v Ta(v) <= D the velocity
// limit is reached, v_lim = v and Tv = D / v - Ta. Otherwise v_lim < v solves v_lim Ta(v_lim) = D
// (monotonic in v_lim), Tv = 0:
//   D >= 2 a^3 / j^2:  v_lim = (sqrt(a^4 / j^2 + 4 a D) - a^2 / j) / 2   (a still reached)
//   D <  2 a^3 / j^2:  Tj = cbrt(D / (2 j)), v_lim = j Tj^2                (neither reached)
// Duration T = 2 Ta + Tv; e.g. T = D / v + v / a + a / j when both limits are reached. These are
// exact phase durations (no numeric search). The profile is bang-bang in jerk with every
// constraint active where it can be, which makes it the time-optimal rest-to-rest motion under
// |ds| <= v, |dds| <= a, |d3s| <= j.
//
// Pose trajectory (straight line, synchronised): from pose A (p_A, R_A) to B,
//   p(s) = p_A + s dp,                  dp = p_B - p_A,  L = |dp|
//   R(s) = R_A exp(s [w]x),             w = log(R_A^T R_B),  theta = |w| in [0, pi]
// with one path parameter s(t) in [0, 1] following a double-S profile of D = 1 whose limits are,
// order by order, the tightest of the linear limit over L and the angular limit over theta:
//   v_s = min(v_lin / L, v_ang / theta), a_s = min(a_lin / L, a_ang / theta), likewise j_s
// (a class with no motion, L = 0 or theta = 0, imposes nothing). Linear velocity is ds dp and the
// world angular velocity ds R_A w (constant axis), so every derivative of the translation has norm
// L |s^(k)| and every derivative of the angular velocity norm theta |s^(k)|: the per-class limits
// (Euclidean norms of linear velocity, acceleration, jerk and of angular velocity, angular
// acceleration, its derivative) are exactly the limits above on s. Hence the trajectory is
// time-optimal among rest-to-rest motions along this geometric path (straight line with the
// orientation on the geodesic, both tied to the same s). It is not time-optimal over other paths,
// over unsynchronised moves (translation and rotation finishing at different times trace another
// path in SE(3)), or under per-axis (box) limits, which this class does not model; and linear and
// angular motion always start and end together.
#pragma once

#include <Eigen/Core>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Velocity, acceleration and jerk limits of the platform, SI (m/s, m/s^2, m/s^3, rad/s, rad/s^2,
// rad/s^3), on the Euclidean norms of the linear and the angular quantities.
struct MotionLimits {
  double max_linear_velocity = 0.1;
  double max_linear_acceleration = 0.5;
  double max_linear_jerk = 5.0;
  double max_angular_velocity = 0.5;
  double max_angular_acceleration = 2.0;
  double max_angular_jerk = 20.0;

  // kInvalidArgument naming the first field that is not finite and > 0.
  Status validate() const;
};

// The 1-D rest-to-rest double-S profile from 0 to `distance` (see the file comment).
class DoubleSProfile {
 public:
  struct Sample {
    double s = 0.0;     // position
    double ds = 0.0;    // velocity
    double dds = 0.0;   // acceleration
    double jerk = 0.0;  // third derivative
  };

  // A zero-length profile (duration 0).
  DoubleSProfile() = default;

  // distance >= 0, limits finite and > 0; kInvalidArgument otherwise.
  static Result<DoubleSProfile> plan(double distance, double max_velocity, double max_acceleration,
                                     double max_jerk);

  double distance() const { return distance_; }
  double duration() const { return 2.0 * accel_time_ + cruise_time_; }
  double jerk_time() const { return jerk_time_; }      // Tj: each of phases 1, 3, 5, 7, s
  double accel_time() const { return accel_time_; }    // Ta: phases 1 to 3 together, s
  double cruise_time() const { return cruise_time_; }  // Tv: phase 4, s
  double peak_velocity() const { return peak_velocity_; }
  double peak_acceleration() const { return jerk_ * jerk_time_; }
  double jerk() const { return jerk_; }

  // State at time t; t <= 0 gives the start at rest, t >= duration() exactly (distance, 0, 0, 0).
  // The deceleration half is evaluated as the mirror image of the acceleration half.
  Sample sample(double t) const noexcept;

 private:
  Sample accelerating(double t) const noexcept;  // 0 <= t <= duration() / 2

  double distance_ = 0.0;
  double jerk_ = 0.0;
  double jerk_time_ = 0.0;
  double accel_time_ = 0.0;
  double cruise_time_ = 0.0;
  double peak_velocity_ = 0.0;
};

// Platform twist, world frame: linear velocity of the platform origin (m/s) and angular velocity
// (rad/s).
struct TaskVelocity {
  Eigen::Vector3d linear = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular = Eigen::Vector3d::Zero();
};

// Time derivative of TaskVelocity (m/s^2, rad/s^2), world frame.
struct TaskAcceleration {
  Eigen::Vector3d linear = Eigen::Vector3d::Zero();
  Eigen::Vector3d angular = Eigen::Vector3d::Zero();
};

// log of a rotation matrix: the rotation vector w (|w| in [0, pi]) with rotation_exp(w) = R.
Eigen::Vector3d rotation_log(const Eigen::Matrix3d& R);

class PoseTrajectory {
 public:
  // Straight-line synchronised move (file comment). kInvalidArgument for non-finite poses or
  // invalid limits (MotionLimits::validate). A zero-length move has duration 0.
  static Result<PoseTrajectory> plan(const Pose& from, const Pose& to, const MotionLimits& limits);

  double duration() const { return profile_.duration(); }
  const Pose& from() const { return from_; }
  const Pose& to() const { return to_; }
  double linear_distance() const { return linear_distance_; }  // L, m
  double angular_distance() const { return angle_; }           // theta, rad
  const DoubleSProfile& profile() const { return profile_; }   // the path parameter s(t)

  // Pose (and optionally twist and its derivative) at time t; t <= 0 gives exactly `from`,
  // t >= duration() exactly `to`. The rpy comes from the interpolated rotation, with roll and yaw
  // unwrapped (shifted by multiples of 2 pi) near the straight interpolation from `from`'s rpy to
  // `to`'s rpy taken within pi of `from`'s, so they do not wrap at +-pi mid-move. The rpy is then
  // continuous over [0, duration()] when `to`'s roll and yaw are within pi of `from`'s and both
  // pitches are in [-pi/2, pi/2], and the path stays away from pitch = +-pi/2 (the rpy
  // singularity); otherwise the final sample may differ from the one before by a multiple of
  // 2 pi in roll or yaw (the same rotation). Allocation-free, noexcept.
  void sample(double t, Pose& pose, TaskVelocity* velocity = nullptr,
              TaskAcceleration* acceleration = nullptr) const noexcept;

  // The geometric path at parameter s in [0, 1] (clamped): position and rotation matrix, without
  // the rpy conversion. Used by the feasibility check. Allocation-free.
  void path_point(double s, Eigen::Vector3d& position, Eigen::Matrix3d& rotation) const noexcept;

 private:
  Pose from_, to_;
  Eigen::Matrix3d rotation_from_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d displacement_ = Eigen::Vector3d::Zero();        // dp, m
  Eigen::Vector3d rotation_vector_ = Eigen::Vector3d::Zero();     // w, in the frame of `from`
  Eigen::Vector3d angular_axis_world_ = Eigen::Vector3d::Zero();  // R_A w
  double linear_distance_ = 0.0;
  double angle_ = 0.0;
  Eigen::Vector3d rpy_end_ = Eigen::Vector3d::Zero();  // to's rpy unwrapped near from's
  DoubleSProfile profile_;
};

}  // namespace cdpr
