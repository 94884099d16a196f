#include "cdpr/controller/tension_control.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/winch.hpp"

namespace cdpr::controller {

const char* to_string(TensionControlState s) {
  switch (s) {
    case TensionControlState::kOff:
      return "off";
    case TensionControlState::kActive:
      return "active";
    case TensionControlState::kHeld:
      return "held";
    case TensionControlState::kFrozen:
      return "frozen";
    case TensionControlState::kDecaying:
      return "decaying";
  }
  return "?";
}

Status TensionControl::validate(const TensionControlOptions& o, double cycle_s) {
  const auto bad = [](double v) { return !std::isfinite(v) || v < 0.0; };
  if (!std::isfinite(cycle_s) || cycle_s <= 0.0) {
    return Status::error(ErrorCode::kInvalidArgument, "tension control: cycle of %g s", cycle_s);
  }
  if (bad(o.gain) || bad(o.margin) || bad(o.deadband) || bad(o.max_rate) || bad(o.max_trim) ||
      bad(o.stale_s) || bad(o.hold_s) || bad(o.filter_s) || !std::isfinite(o.slack_below) ||
      !std::isfinite(o.decay_s) || o.decay_s <= 0.0) {
    return Status(ErrorCode::kInvalidArgument,
                  "tension control: gain, margin, deadband, max_rate, max_trim, stale_s, hold_s "
                  "and filter_s must be finite and >= 0, slack_below finite, decay_s > 0");
  }
  return Status::success();
}

void TensionControl::reset() noexcept {
  status_ = TensionControlStatus{};
  seen_any_ = false;
  filtered_valid_ = false;
  stale_cycles_ = unusable_cycles_ = 0;
}

void TensionControl::step(bool run, bool hold, bool sensor_fault, const RobotReading& in,
                          const RobotModel& model, const CommandData& data) noexcept {
  if (!run || !enabled()) {
    reset();
    return;
  }
  const int m = model.num_cables();
  if (readings_usable(sensor_fault, in, m)) {
    unusable_cycles_ = 0;
    if (hold) {  // the trims stay; the readings still filtered and the band still watched
      status_.state = TensionControlState::kHeld;
      std::array<double, kMaxAxes> step{};
      follow(in, model, data, step);
      return;
    }
    status_.state = TensionControlState::kActive;
    std::array<double, kMaxAxes> step{};
    if (follow(in, model, data, step)) apply(step, model);
    return;
  }
  status_.in_band = false;
  filtered_valid_ = false;
  ++unusable_cycles_;
  if (unusable_cycles_ * cycle_s_ <= options_.hold_s) {
    status_.state = TensionControlState::kFrozen;
  } else {
    status_.state = TensionControlState::kDecaying;
    decay(model);
  }
}

// Fresh (within stale_s), finite, from every channel, and no force fault latched.
bool TensionControl::readings_usable(bool sensor_fault, const RobotReading& in, int m) noexcept {
  if (!in.have_tensions) return false;
  if (!seen_any_ || in.tension_updates != updates_seen_) {
    seen_any_ = true;
    updates_seen_ = in.tension_updates;
    stale_cycles_ = 0;
  } else {
    ++stale_cycles_;
  }
  if (sensor_fault || stale_cycles_ * cycle_s_ > options_.stale_s) return false;
  for (int i = 0; i < m; ++i) {
    if (!std::isfinite(in.tensions[static_cast<std::size_t>(i)])) return false;
  }
  return true;
}

// The tension errors outside the band into a trim step (see the header).
bool TensionControl::follow(const RobotReading& in, const RobotModel& model,
                            const CommandData& data, std::array<double, kMaxAxes>& step) noexcept {
  const int m = model.num_cables();
  std::array<double, kMaxAxes> e{}, w{}, direct{};
  bool any = false, in_band = true;
  double largest = 0.0;
  const double a = options_.filter_s > 0.0 ? std::min(1.0, cycle_s_ / options_.filter_s) : 1.0;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const CableModel& c = model.cables[k];
    const double lo = c.f_min + options_.margin;
    const double hi = std::max(lo, c.f_max - options_.margin);
    double& f = filtered_[k];
    f = filtered_valid_ ? f + a * (in.tensions[k] - f) : in.tensions[k];
    // The target: the band shrunk by the deadband; inside it, nothing to do.
    const double tlo = std::min(lo + options_.deadband, 0.5 * (lo + hi));
    const double thi = std::max(hi - options_.deadband, tlo);
    // Hysteresis: a cable acts once outside [lo, hi] and until it is back inside [tlo, thi].
    bool& act = acting_[k];
    act = f < lo || f > hi || (act && (f < tlo || f > thi));
    const double err = act ? std::clamp(f, tlo, thi) - f : 0.0;
    largest = std::max(largest, std::abs(err));
    in_band = in_band && f >= lo && f <= hi;
    w[k] = f < lo || f > hi ? kEdgeWeight : 1.0;
    if (act) {
      // Outside the band: taken up (or paid out) on its own; the platform yields to the part of
      // the change outside the true kernel. The kernel step leaves it alone (largest weight).
      direct[k] = err;
      w[k] = kSlackWeight;
    } else {
      e[k] = err;
    }
    any = any || err != 0.0;
  }
  filtered_valid_ = true;
  status_.in_band = in_band;
  status_.largest_error = largest;
  const auto& s = data.kinematics.structure_matrix;  // A^T, 6 x m
  if (!any || s.cols() != m) return false;
  // df = e - W^-1 A (A^T W^-1 A)^-1 A^T e: the tension change in the kernel nearest to e with
  // the weights W (fixed-size 6 x 6 normal matrix: no allocation). No kernel (m <= 6): none.
  Eigen::Matrix<double, 6, 1> z = Eigen::Matrix<double, 6, 1>::Zero();
  bool project = m > 6;
  if (project) {
    Eigen::Matrix<double, 6, 6> normal = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> rhs = Eigen::Matrix<double, 6, 1>::Zero();
    for (int i = 0; i < m; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const Eigen::Matrix<double, 6, 1> col = s.col(i);
      normal += col * col.transpose() / w[k];
      rhs += col * e[k];
    }
    const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(normal);
    project = llt.info() == Eigen::Success;  // rank < 6: no kernel to speak of
    if (project) z = llt.solve(rhs);
  }
  const double g = options_.gain * cycle_s_;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double df = (project ? e[k] - s.col(i).dot(z) / w[k] : 0.0) + direct[k];
    const double compliance =  // m/N at the planned tension
        cable_elongation_derivatives(model.cables[k], data.cable.loaded_lengths(i),
                                     data.plan.tensions(i))
            .d_tension;
    if (!std::isfinite(compliance) || compliance <= 0.0) continue;
    step[k] = g * winch_counts_change<double>(model.winches[k], -compliance * df);
  }
  return true;
}

void TensionControl::decay(const RobotModel& model) noexcept {
  std::array<double, kMaxAxes> step{};
  const double a = std::min(1.0, cycle_s_ / options_.decay_s);
  for (int i = 0; i < model.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    step[k] = -a * status_.trim_counts[k];
  }
  apply(step, model);
}

void TensionControl::apply(std::array<double, kMaxAxes>& step, const RobotModel& model) noexcept {
  const int m = model.num_cables();
  // One scale for every cable keeps the step's direction (in the kernel) under the rate limit.
  double scale = 1.0;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double per_metre = 1.0 / winch_metres_per_count(model.winches[k]);
    const double dmax = options_.max_rate * cycle_s_ * per_metre;
    if (std::abs(step[k]) > dmax) scale = std::min(scale, dmax / std::abs(step[k]));
  }
  status_.saturated = false;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double bound = options_.max_trim / winch_metres_per_count(model.winches[k]);
    double& t = status_.trim_counts[k];
    t = std::clamp(t + scale * step[k], -bound, bound);
    status_.saturated = status_.saturated || std::abs(t) >= bound;
  }
}

}  // namespace cdpr::controller
