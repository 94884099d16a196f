#include "cdpr/calibration/slew.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "cdpr/calibration/winch.hpp"

namespace cdpr {
namespace {

bool positive_finite(double x) {
  return std::isfinite(x) && x > 0.0;
}

bool all_finite(std::span<const double> x) {
  return std::all_of(x.begin(), x.end(), [](double v) { return std::isfinite(v); });
}

}  // namespace

Status SlewLimiter::configure(double cycle_time, std::span<const double> max_velocity,
                              std::span<const double> max_acceleration) {
  const std::size_t n = max_velocity.size();
  if (n < 1 || n > static_cast<std::size_t>(kMaxSlewAxes) || max_acceleration.size() != n) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "slew limiter: %zu velocity and %zu acceleration limits (1 to %d axes, "
                         "one of each per axis)",
                         n, max_acceleration.size(), kMaxSlewAxes);
  }
  if (!positive_finite(cycle_time)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "slew limiter: cycle_time must be finite and > 0 (got %g)", cycle_time);
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!positive_finite(max_velocity[i])) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "slew limiter: axis %zu: max_velocity must be finite and > 0 (got %g)",
                           i + 1, max_velocity[i]);
    }
    if (!positive_finite(max_acceleration[i])) {
      return Status::error(
          ErrorCode::kInvalidArgument,
          "slew limiter: axis %zu: max_acceleration must be finite and > 0 (got %g)", i + 1,
          max_acceleration[i]);
    }
  }
  axes_ = static_cast<int>(n);
  dt_ = cycle_time;
  for (std::size_t i = 0; i < n; ++i) {
    max_velocity_[i] = max_velocity[i];
    max_dv_[i] = max_acceleration[i] * cycle_time;
  }
  command_.fill(0.0);
  velocity_.fill(0.0);
  target_.fill(0.0);
  return Status::success();
}

Status SlewLimiter::configure(int axes, double cycle_time, double max_velocity,
                              double max_acceleration) {
  if (axes < 1 || axes > kMaxSlewAxes) {
    return Status::error(ErrorCode::kInvalidArgument, "slew limiter: %d axes (1 to %d supported)",
                         axes, kMaxSlewAxes);
  }
  std::array<double, kMaxSlewAxes> v{}, a{};
  v.fill(max_velocity);
  a.fill(max_acceleration);
  const auto n = static_cast<std::size_t>(axes);
  return configure(cycle_time, std::span<const double>(v.data(), n),
                   std::span<const double>(a.data(), n));
}

Status SlewLimiter::reset(std::span<const double> position) noexcept {
  if (position.size() != size() || axes_ == 0 || !all_finite(position)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "slew limiter: reset with %zu finite values expected (configured axes: "
                         "%d)",
                         size(), axes_);
  }
  for (std::size_t i = 0; i < size(); ++i) {
    command_[i] = position[i];
    target_[i] = position[i];
    velocity_[i] = 0.0;
  }
  return Status::success();
}

Status SlewLimiter::set_target(std::span<const double> target) noexcept {
  if (target.size() != size() || axes_ == 0 || !all_finite(target)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "slew limiter: target with %zu finite values expected (configured axes: "
                         "%d)",
                         size(), axes_);
  }
  std::copy(target.begin(), target.end(), target_.begin());
  return Status::success();
}

double SlewLimiter::stopping_velocity(double distance, double dv, double dt) noexcept {
  if (!(distance > 0.0)) return 0.0;
  const double q = distance / (dt * dv);
  // n: the largest integer with n (n + 1) / 2 <= q (rounding of the square root corrected).
  double n = std::floor(0.5 * (std::sqrt(1.0 + 8.0 * q) - 1.0));
  while (n > 0.0 && 0.5 * n * (n + 1.0) > q) n -= 1.0;
  while (0.5 * (n + 1.0) * (n + 2.0) <= q) n += 1.0;
  const double f = std::clamp(q / (n + 1.0) - 0.5 * n, 0.0, 1.0);
  return (n + f) * dv;
}

void SlewLimiter::step() noexcept {
  for (std::size_t i = 0; i < size(); ++i) {
    const double e = target_[i] - command_[i];
    if (e == 0.0 && velocity_[i] == 0.0) continue;
    const double sign = e >= 0.0 ? 1.0 : -1.0;
    const double d = std::abs(e);
    const double dv = max_dv_[i];
    const double v_prev = sign * velocity_[i];  // along the remaining distance
    const double v_stop = stopping_velocity(d, dv, dt_);
    const double v_up = std::min({max_velocity_[i], v_prev + dv, v_stop});
    const double v_lo = v_prev - dv;
    if (v_up < v_lo) {  // cannot stop in time (or slower than allowed): brake as hard as allowed
      velocity_[i] = sign * v_lo;
      command_[i] += sign * v_lo * dt_;
      continue;
    }
    // Lands on the target when the remaining distance after the step is within rounding.
    const double tolerance =
        8.0 * std::numeric_limits<double>::epsilon() *
        std::max({std::abs(command_[i]), std::abs(target_[i]), std::numeric_limits<double>::min()});
    velocity_[i] = sign * v_up;
    if (v_up > 0.0 && d - v_up * dt_ <= tolerance) {
      command_[i] = target_[i];
    } else {
      command_[i] += sign * v_up * dt_;
    }
  }
}

bool SlewLimiter::done() const noexcept {
  for (std::size_t i = 0; i < size(); ++i) {
    if (command_[i] != target_[i] || velocity_[i] != 0.0) return false;
  }
  return true;
}

Status cable_count_limits(const RobotModel& model, const MotionLimits& limits,
                          std::span<double> max_velocity, std::span<double> max_acceleration) {
  if (Status s = limits.validate(); !s.ok()) return s;
  const int m = model.num_cables();
  const auto n = static_cast<std::size_t>(m);
  if (m < 1 || m > kMaxSlewAxes || model.winches.size() != n ||
      model.platform_anchors.cols() != m || max_velocity.size() != n ||
      max_acceleration.size() != n) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cable count limits: %d cables (1 to %d), %zu winches, outputs of %zu "
                         "and %zu",
                         m, kMaxSlewAxes, model.winches.size(), max_velocity.size(),
                         max_acceleration.size());
  }
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double radius = model.platform_anchors.col(i).norm();
    const double counts_per_metre = 1.0 / winch_metres_per_count(model.winches[k]);
    if (!positive_finite(counts_per_metre)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "cable count limits: winch %d has no finite counts per metre", i + 1);
    }
    max_velocity[k] =
        (limits.max_linear_velocity + radius * limits.max_angular_velocity) * counts_per_metre;
    max_acceleration[k] =
        (limits.max_linear_acceleration + radius * limits.max_angular_acceleration) *
        counts_per_metre;
  }
  return Status::success();
}

}  // namespace cdpr
