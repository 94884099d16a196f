// RtController's safety chain: the e-stop / STO inputs, the software limits of each winch and the
// workspace box, and the holding brakes' sequence on enable and disable (rt_controller.hpp).
#include <cmath>

#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/rt_controller.hpp"

namespace cdpr::controller {

// An input of the chain that reads open (or whose node is silent or stale) latches a quick stop;
// take_requests refuses its fault reset until every input reads closed.
void RtController::watch_safety(canopen::Timestamp now) noexcept {
  snap_.safety_open = in_.safety_open;
  if (in_.safety_open == 0) return;
  int source = 0;
  while (source < 31 && ((in_.safety_open >> source) & 1u) == 0) ++source;
  set_fault({FaultKind::kEStop, 0, -1, static_cast<std::uint16_t>(source + 1), 0.0, now.count()});
}

// The operator's disable (brakes first, see sequence_brakes) and enable (also of drives that were
// never enabled: a start without `start.enable: at-start`). A disable stops a trim where it is.
void RtController::take_enable_requests() noexcept {
  if (disable_.exchange(false, std::memory_order_acq_rel)) {
    disable_requested_ = true;
    applied_cycles_ = 0;
    mode_ = RtMode::kDisabled;
    trim_.fill(0.0);
    trim_goal_.fill(0.0);
  }
  if (enable_.exchange(false, std::memory_order_acq_rel)) {
    disable_requested_ = false;
    out_.enable = fault_.kind == FaultKind::kNone;
  }
}

// The commanded pose's cable lengths and position (this cycle's inverse kinematics) inside the
// limits, and each actual length (the commanded one plus how far the drive stands from the
// commanded pose's target) within the tolerance of them. A violation names the winch; its target is
// not sent.
void RtController::check_limits(canopen::Timestamp now) noexcept {
  // Holding counts, the pose is not known (the drives hold where they are and no motion is
  // taken): there are no lengths or position to check, only counts held still.
  if (!out_.send_targets || mode_ == RtMode::kHoldingCounts) return;
  const Eigen::Vector3d& p = pose_.position;
  for (int j = 0; options_.workspace_box && j < 3; ++j) {
    const auto a = static_cast<std::size_t>(j);
    if (p(j) < options_.box_min[a] || p(j) > options_.box_max[a]) {
      set_fault({FaultKind::kWorkspace, 0, -1, static_cast<std::uint16_t>(j), p(j), now.count()});
      out_.send_targets = false;
      return;
    }
  }
  const double tol = options_.cable_length_tolerance;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double commanded = command_data_.kinematics.lengths(i);
    // (While slewing the drives are on their way to the commanded pose's lengths: only those
    // are checked.)
    const double actual =
        mode_ == RtMode::kSlewing
            ? commanded
            : commanded + winch_length_change(
                              geometry_->model.winches[k],
                              static_cast<double>(in_.drives[k].actual_counts) - desired_[k]);
    const double lo = options_.min_cable_length[k], hi = options_.max_cable_length[k];
    double bad = std::nan("");
    if (commanded < lo || commanded > hi) bad = commanded;
    if (actual < lo - tol || actual > hi + tol) bad = actual;
    if (!std::isnan(bad)) {
      set_fault({FaultKind::kCableLimit, in_.drives[k].node, i, 0, bad, now.count()});
      out_.send_targets = false;
      return;
    }
  }
}

// Brake k is released once drive k has been OPERATION_ENABLED (holding torque) for the release
// delay, with no fault latched and no disable requested; otherwise it is applied at once. After a
// disable request the drives are disabled once the brakes have been applied for the apply delay.
void RtController::sequence_brakes() noexcept {
  const bool hold = fault_.kind == FaultKind::kNone && !disable_requested_;
  bool all = true;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const bool torque = hold && in_.drives[k].enabled && !out_.quick_stop;
    enabled_cycles_[k] = torque ? enabled_cycles_[k] + 1 : 0;
    const bool release = !options_.brakes || enabled_cycles_[k] > options_.brake_release_cycles;
    out_.release_brake[k] = release;
    all = all && release;
  }
  snap_.brakes_released = all;
  if (disable_requested_) {
    mode_ = RtMode::kDisabled;  // the targets follow the actual positions
    out_.disable = !options_.brakes || applied_cycles_ >= options_.brake_apply_cycles;
    if (applied_cycles_ < options_.brake_apply_cycles) ++applied_cycles_;
    if (out_.disable) out_.enable = false;
  }
  snap_.disabled = disable_requested_ && out_.disable;
}

}  // namespace cdpr::controller
