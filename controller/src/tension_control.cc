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
      bad(o.stale_s) || bad(o.hold_s) || bad(o.filter_s) || bad(o.guard) ||
      !std::isfinite(o.slack_below) || !std::isfinite(o.decay_s) || o.decay_s <= 0.0) {
    return Status(ErrorCode::kInvalidArgument,
                  "tension control: gain, margin, deadband, max_rate, max_trim, stale_s, hold_s, "
                  "filter_s and guard must be finite and >= 0, slack_below finite, decay_s > 0");
  }
  return Status::success();
}

void TensionControl::reset() noexcept {
  status_ = TensionControlStatus{};
  seen_any_ = false;
  filtered_valid_ = false;
  stale_cycles_ = unusable_cycles_ = 0;
  force_.fill(0.0);
  take_up_.fill(0.0);
  edge_.fill(false);
}

void TensionControl::step(bool run, bool hold, bool sensor_fault, const RobotReading& in,
                          const RobotModel& model, const CommandData& data) noexcept {
  if (!run || !enabled()) {
    reset();
    return;
  }
  ++cycles_;
  const int m = model.num_cables();
  if (readings_usable(sensor_fault, in, m)) {
    unusable_cycles_ = 0;
    measure(in, model, data);
    if (hold) {  // the trims stay; the readings still filtered and the band still watched
      status_.state = TensionControlState::kHeld;
      return;
    }
    status_.state = TensionControlState::kActive;
    if (follow(model, data)) map_trims(model, data, true);
    return;
  }
  status_.in_band = false;
  filtered_valid_ = false;
  ++unusable_cycles_;
  if (unusable_cycles_ * cycle_s_ <= options_.hold_s) {
    status_.state = TensionControlState::kFrozen;
  } else {
    status_.state = TensionControlState::kDecaying;
    const double a = std::min(1.0, cycle_s_ / options_.decay_s);
    std::array<double, kMaxAxes> df{}, dt{};
    for (int i = 0; i < m; ++i) {
      const auto k = static_cast<std::size_t>(i);
      df[k] = -a * force_[k];
      dt[k] = -a * take_up_[k];
    }
    if (update_compliances(model, data)) integrate(model, df, dt);
  }
  map_trims(model, data, false);  // the frozen (decaying) correction on the pose commanded now
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

// 1 far inside the band, rising quadratically to kEdgeWeight at its edges over `guard`.
double TensionControl::guard_weight(double f, double lo, double hi) const noexcept {
  const double guard = options_.guard;
  if (!(guard > 0.0)) return 1.0;
  const double near = std::clamp(1.0 - std::min(f - lo, hi - f) / guard, 0.0, 1.0);
  return 1.0 + (kEdgeWeight - 1.0) * near * near;
}

void TensionControl::measure(const RobotReading& in, const RobotModel& model,
                             const CommandData& data) noexcept {
  const int m = model.num_cables();
  const bool planned = data.plan.tensions.size() == m;
  bool in_band = true;
  double largest = 0.0;
  const double a = options_.filter_s > 0.0 ? std::min(1.0, cycle_s_ / options_.filter_s) : 1.0;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const CableModel& c = model.cables[k];
    const double lo = c.f_min + options_.margin;
    const double hi = std::max(lo, c.f_max - options_.margin);
    double& f = filtered_[k];
    f = filtered_valid_ ? f + a * (in.tensions[k] - f) : in.tensions[k];
    const double tlo = std::min(lo + options_.deadband, 0.5 * (lo + hi));
    const double thi = std::max(hi - options_.deadband, tlo);
    // Hysteresis: a cable is at the edge once outside [lo, hi], until back inside [tlo, thi].
    bool& edge = edge_[k];
    edge = f < lo || f > hi || (edge && (f < tlo || f > thi));
    // The target: at the edge, the nearest point of [tlo, thi]; otherwise the plan clamped into it.
    const double target =
        edge ? std::clamp(f, tlo, thi)
             : std::clamp(planned ? data.plan.tensions(i) : 0.5 * (lo + hi), tlo, thi);
    const double err = target - f;
    largest = std::max(largest, std::abs(err));
    in_band = in_band && f >= lo && f <= hi;
    slack_[k] = f < options_.slack_below;
    error_[k] = err;
    weight_[k] = slack_[k] ? kSlackWeight : (edge ? kEdgeWeight : guard_weight(f, lo, hi));
  }
  filtered_valid_ = true;
  status_.in_band = in_band;
  status_.largest_error = largest;
}

bool TensionControl::update_compliances(const RobotModel& model, const CommandData& data) noexcept {
  const int m = model.num_cables();
  if (data.kinematics.structure_matrix.cols() != m || data.plan.tensions.size() != m) return false;
  if (compliances_cycle_ == cycles_) return true;  // already this cycle
  compliances_cycle_ = cycles_;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double compliance =  // m/N at the planned tension
        cable_elongation_derivatives(model.cables[k], data.cable.loaded_lengths(i),
                                     data.plan.tensions(i))
            .d_tension;
    cpn_[k] = std::isfinite(compliance) && compliance > 0.0
                  ? winch_counts_change<double>(model.winches[k], -compliance)  // shorter: more
                  : 0.0;
  }
  return true;
}

bool TensionControl::project(const CommandData& data, int m, const std::array<double, kMaxAxes>& w,
                             std::array<double, kMaxAxes>& v) const noexcept {
  const auto& s = data.kinematics.structure_matrix;  // A^T, 6 x m
  if (m <= 6 || s.cols() != m) return false;
  // Fixed-size 6 x 6 normal matrix: no allocation.
  Eigen::Matrix<double, 6, 6> normal = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::Matrix<double, 6, 1> rhs = Eigen::Matrix<double, 6, 1>::Zero();
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const Eigen::Matrix<double, 6, 1> col = s.col(i);
    normal += col * col.transpose() / w[k];
    rhs += col * v[k];
  }
  const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(normal);
  if (llt.info() != Eigen::Success) return false;  // rank < 6: no kernel to speak of
  const Eigen::Matrix<double, 6, 1> z = llt.solve(rhs);
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    v[k] -= s.col(i).dot(z) / w[k];
  }
  return true;
}

// The errors into this cycle's step of the correction (see the header).
bool TensionControl::follow(const RobotModel& model, const CommandData& data) noexcept {
  const int m = model.num_cables();
  if (!update_compliances(model, data)) return false;
  std::array<double, kMaxAxes> df{}, dt{};
  const double g = options_.gain * cycle_s_;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    df[k] = slack_[k] ? 0.0 : error_[k];
    // A slack cable has no stiffness: shortened on its own until it carries again.
    if (slack_[k]) dt[k] = g * error_[k] * cpn_[k];
  }
  if (!project(data, m, weight_, df)) df.fill(0.0);  // no kernel: only the take-up
  // Dead zone: the part of the kernel step beyond half the deadband (largest cable), the
  // direction kept; at the optimum the readings' noise moves no trim.
  double largest = 0.0;
  for (int i = 0; i < m; ++i)
    largest = std::max(largest, std::abs(df[static_cast<std::size_t>(i)]));
  const double zone = 0.5 * options_.deadband;
  const double keep = largest > zone ? g * (1.0 - zone / largest) : 0.0;
  for (int i = 0; i < m; ++i) df[static_cast<std::size_t>(i)] *= keep;
  integrate(model, df, dt);
  return true;
}

void TensionControl::integrate(const RobotModel& model, const std::array<double, kMaxAxes>& df,
                               const std::array<double, kMaxAxes>& dt) noexcept {
  const int m = model.num_cables();
  // One scale for the whole step keeps its direction (in the kernel) under the rate limit.
  double scale = 1.0;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double step = std::abs(cpn_[k] * df[k] + dt[k]);
    const double dmax = options_.max_rate * cycle_s_ / winch_metres_per_count(model.winches[k]);
    if (step > dmax) scale = std::min(scale, dmax / step);
  }
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    force_[k] += scale * df[k];
    take_up_[k] += scale * dt[k];
  }
}

void TensionControl::map_trims(const RobotModel& model, const CommandData& data,
                               bool rebase) noexcept {
  const int m = model.num_cables();
  if (!update_compliances(model, data)) return;
  // phi on this pose's kernel (kept as the state when re-based; a frozen one stays as it is, so
  // at a still pose its trims stay bit for bit).
  std::array<double, kMaxAxes> phi = force_, unit{};
  unit.fill(1.0);
  if (!project(data, m, unit, phi)) phi.fill(0.0);
  // Anti-windup: phi and the take-up scaled together so that no trim passes its bound.
  if (rebase) force_ = phi;
  const std::array<double, kMaxAxes>& cpn = cpn_;
  double largest = 0.0;  // of |trim| / bound
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double bound = options_.max_trim / winch_metres_per_count(model.winches[k]);
    largest = std::max(largest, std::abs(cpn[k] * phi[k] + take_up_[k]) / bound);
  }
  status_.saturated = largest >= 1.0 - 1e-9;
  const double over = std::max(1.0, largest);
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (over > 1.0) {
      force_[k] = phi[k] / over;
      take_up_[k] /= over;
    }
    status_.trim_counts[k] = cpn[k] * phi[k] / over + take_up_[k];
  }
}

}  // namespace cdpr::controller
