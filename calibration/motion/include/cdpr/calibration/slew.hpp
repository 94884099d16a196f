// Joint-space slew limiter for the RT cycle: steps a command vector (encoder counts, metres, ...)
// toward a target, each axis within its own velocity and acceleration limits, and stops exactly
// on the target. The bumpless hot swap uses it to absorb the remainder between the old and the
// new drive targets. Fixed capacity (kMaxSlewAxes), allocation-free, noexcept.
//
// Discrete-time law (cycle time dt, per axis, along the direction of the remaining distance d,
// with Dv = a_max dt the largest velocity change per cycle): the command moves by v dt each cycle,
// v constant over the cycle. After a cycle at velocity v, braking as hard as allowed (v - Dv,
// v - 2 Dv, ... down to 0) still covers dt * sum_{i>=1} max(v - i Dv, 0). So v may be at most the
// largest velocity with
//   g(v) = dt (v + sum_{i>=1} max(v - i Dv, 0)) <= d,
// and with v = (n + f) Dv (n integer, 0 <= f < 1), g(v) = dt Dv (n + 1) (n / 2 + f): exactly
//   n = largest integer with n (n + 1) / 2 <= q,  f = q / (n + 1) - n / 2,  q = d / (dt Dv).
// Each cycle takes v = min(v_max, v_prev + Dv, v_stop(d)). Started at rest (or anywhere it can
// still stop in time), the command never passes the target; on the braking curve the velocity
// drops by exactly Dv per cycle, and the last step (velocity below Dv) lands exactly on the
// target, after which the velocity is 0. When it cannot stop in time (the target was moved
// behind a fast-moving command), it brakes at a_max, passes the target and comes back.
#pragma once

#include <array>
#include <span>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/calibration/trajectory.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

inline constexpr int kMaxSlewAxes = 16;

class SlewLimiter {
 public:
  SlewLimiter() = default;

  // Sets the number of axes (1 to kMaxSlewAxes), the cycle time (s) and per-axis limits (units of
  // the command per s and per s^2, finite and > 0); the command is at rest at 0 with target 0.
  // kInvalidArgument naming the axis and field otherwise.
  Status configure(double cycle_time, std::span<const double> max_velocity,
                   std::span<const double> max_acceleration);
  // The same limits on every axis.
  Status configure(int axes, double cycle_time, double max_velocity, double max_acceleration);

  // The command is at `position`, at rest, with the target there too (e.g. the current drive
  // targets at the hot swap). kInvalidArgument for a wrong size or non-finite values.
  Status reset(std::span<const double> position) noexcept;
  // New target (the command keeps its velocity). kInvalidArgument for a wrong size or non-finite
  // values (the target is then unchanged).
  Status set_target(std::span<const double> target) noexcept;

  // One cycle: every axis moves toward its target within its limits.
  void step() noexcept;
  // Every axis is on its target, at rest.
  bool done() const noexcept;

  int axes() const noexcept { return axes_; }
  double cycle_time() const noexcept { return dt_; }
  std::span<const double> command() const noexcept { return {command_.data(), size()}; }
  std::span<const double> velocity() const noexcept { return {velocity_.data(), size()}; }
  std::span<const double> target() const noexcept { return {target_.data(), size()}; }

  // v_stop(d) of the file comment: the largest velocity from which a distance d >= 0 can still be
  // stopped exactly, for a velocity change of at most dv (> 0) per cycle of dt (> 0).
  static double stopping_velocity(double distance, double dv, double dt) noexcept;

 private:
  std::size_t size() const noexcept { return static_cast<std::size_t>(axes_); }

  int axes_ = 0;
  double dt_ = 0.0;
  std::array<double, kMaxSlewAxes> max_velocity_{};
  std::array<double, kMaxSlewAxes> max_dv_{};  // a_max dt
  std::array<double, kMaxSlewAxes> command_{};
  std::array<double, kMaxSlewAxes> velocity_{};
  std::array<double, kMaxSlewAxes> target_{};
};

// Per-cable limits in encoder counts (counts/s, counts/s^2) equivalent to the task-space motion
// limits, for slewing drive targets: a cable's length changes no faster than its platform anchor
// moves, |dl/dt| <= v + |b_i| w (v, w: the linear and angular velocity limits, |b_i| the anchor's
// distance from the platform origin), and the same bound is used for the acceleration (the terms
// of the turning cable direction are left out: the slew moves in joint space, these are
// equivalent rates, not a bound on the platform's acceleration). Converted with each winch's
// counts per metre. kInvalidArgument for invalid limits, a model with more than kMaxSlewAxes
// cables or output spans of another size.
Status cable_count_limits(const RobotModel& model, const MotionLimits& limits,
                          std::span<double> max_velocity, std::span<double> max_acceleration);

}  // namespace cdpr
