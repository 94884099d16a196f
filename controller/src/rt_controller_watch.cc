// RtController's watches (faults from the bus and the drives, the cable tensions, a stuck force
// reading) and its stillness window: the stages that judge this cycle's readings.
#include <algorithm>
#include <cmath>

#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/rt_controller.hpp"

namespace cdpr::controller {

void RtController::watch_faults(canopen::Timestamp now) noexcept {
  watch_events(now);
  watch_safety(now);
  watch_tensions(now);
  watch_stuck(now);
}

void RtController::watch_events(canopen::Timestamp now) noexcept {
  for (int j = 0; j < in_.num_events; ++j) {
    const canopen::Event& e = in_.events[static_cast<std::size_t>(j)];
    events_.push(RtEvent{e});
    switch (e.type) {
      case canopen::EventType::kDriveFault:
        set_fault({FaultKind::kDriveFault, e.node, -1, 0, 0.0, now.count()});
        break;
      case canopen::EventType::kEmcy:
        if (fault_.kind == FaultKind::kDriveFault && fault_.node == e.node && fault_.code == 0) {
          fault_.code = e.emcy.code;
        }
        break;
      case canopen::EventType::kHeartbeatLost:
        set_fault({FaultKind::kNodeLost, e.node, -1, 0, 0.0, now.count()});
        break;
      case canopen::EventType::kBusOff:
        set_fault({FaultKind::kBusOff, 0, -1, 0, 0.0, now.count()});
        break;
      default:
        break;
    }
  }
  // The latched fault of the bus was read before a fault reset of this cycle is written.
  if (in_.master_faulted && !out_.fault_reset && fault_.kind == FaultKind::kNone) {
    set_fault({FaultKind::kDriveFault, 0, -1, 0, 0.0, now.count()});
  }
}

// Cable tensions against the slack and overload limits while the drives hold the cables.
void RtController::watch_tensions(canopen::Timestamp now) noexcept {
  snap_.have_tensions = in_.have_tensions;
  if (!in_.have_tensions) return;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double f = in_.tensions[k];
    snap_.tensions[k] = f;
    if (!active()) {
      slack_count_[k] = overload_count_[k] = 0;
      continue;
    }
    const double fmax = geometry_->model.cables[k].f_max;
    const double over = options_.overload_above > 0.0 ? options_.overload_above : 1.1 * fmax;
    slack_count_[k] = f < options_.slack_below ? slack_count_[k] + 1 : 0;
    overload_count_[k] = f > over ? overload_count_[k] + 1 : 0;
    snap_.slack_cycles[k] = slack_count_[k];
    // A slack cable is reported (the supervisor holds or stops the sequence); an overload
    // quick-stops at once.
    if (overload_count_[k] >= options_.watch_cycles) {
      set_fault({FaultKind::kOverload, 0, i, 0, f, now.count()});
    }
  }
}

// What a cable's tension is made to do, from the commands alone: (1) the planned tension at the
// commanded pose (the compensated inverse kinematics stretches the cable to it, and the plan is
// in equilibrium with the platform, so the real tension follows it up to the model's errors);
// (2) while holding, the tension-regulation trims, as the cable's own stiffness (EA over the
// loaded length) times the trimmed length. The platform yields to a trim of one cable and the
// others share it, so a trim changes the real tension by less than that (a third of it at home
// on the MINI, less elsewhere): trims count against kStuckTrimFactor times the threshold. The
// plan's own threshold is wide too: with the nominal geometry (anchors 14.5 mm from the truth) a
// real tension was seen to stay on one raw value while its plan moved 4.2 N. (A fading trim
// during a move is not counted, and while it fades the plan is no evidence for that cable
// either: the two may cancel.) A reading that keeps its raw value while (1) or (2) spans more
// than its threshold for stuck_confirm_cycles cycles is stuck. On a still robot without trims
// neither changes: noise, or a reading that happens to stay bit-identical for a long time, cannot
// raise it. A slack cable (below the slack limit) follows neither, so the watch starts again
// there.
void RtController::watch_stuck(canopen::Timestamp now) noexcept {
  const bool applies = options_.stuck_raw_units > 0.0 && in_.have_tensions &&
                       fault_.kind == FaultKind::kNone && active();
  if (!applies) {
    reset_stuck_watch();
    snap_.unchanged_span.fill(0.0);
    return;
  }
  // Only a reading that arrived this cycle can be unchanged: when the node's PDOs stop (the
  // node is gone) the readings are old, which is the heartbeat watch's fault to name.
  const bool fresh = in_.tension_updates != force_pdos_;
  force_pdos_ = in_.tension_updates;
  if (restart_plan_window_) {
    restart_plan_window_ = false;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      plan_min_[k] = plan_max_[k] = snap_.planned[k];
    }
  }
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double evidence = stuck_evidence(i);
    snap_.unchanged_span[k] = evidence;
    if (evidence <= 1.0) {
      stuck_count_[k] = 0;
      continue;
    }
    if (!fresh || ++stuck_count_[k] < options_.stuck_confirm_cycles) continue;
    // Still: hold (the robot is safe where it is; the measurement is refused); moving or
    // slewing: quick stop (the overload watch of this cable is blind).
    const RtFault f{FaultKind::kForceStuck, 0, i, 0, snap_.tensions[k], now.count()};
    if (mode_ == RtMode::kHolding) {
      hold_fault(f);
    } else {
      set_fault(f);
    }
    return;
  }
}

// How far cable i's tension was made to change since its raw reading last changed, in units of
// the threshold (0 when the reading changed: the window starts again).
double RtController::stuck_evidence(int i) noexcept {
  const auto k = static_cast<std::size_t>(i);
  const std::int64_t raw = in_.raw[k];
  const double planned = snap_.planned[k];
  double trimmed = 0.0;  // N
  if (mode_ == RtMode::kHolding) {
    const CableModel& cable = geometry_->model.cables[k];
    const WinchModel& winch = geometry_->model.winches[k];
    const double loaded = command_data_.cable.loaded_lengths(i);
    const double stiffness = cable.ea > 0.0 && loaded > 0.0 ? cable.ea / loaded : 0.0;  // N/m
    trimmed = -stiffness * trim_[k] * winch.direction * winch_metres_per_count(winch);
  }
  if (!stuck_valid_[k] || raw != stuck_raw_[k] || snap_.tensions[k] < options_.slack_below) {
    stuck_valid_[k] = true;
    stuck_raw_[k] = raw;
    plan_min_[k] = plan_max_[k] = planned;
    trim_min_[k] = trim_max_[k] = trimmed;
    return 0.0;
  }
  if (mode_ != RtMode::kHolding) trim_min_[k] = trim_max_[k] = trimmed;
  if (mode_ == RtMode::kMoving && trim_at_move_[k] != 0.0) {
    // A trim fading out during the move changes the tension too, by an amount the platform's
    // motion makes unknown: it may cancel the plan's change, so the plan is no evidence here.
    plan_min_[k] = plan_max_[k] = planned;
  }
  plan_min_[k] = std::min(plan_min_[k], planned);
  plan_max_[k] = std::max(plan_max_[k], planned);
  trim_min_[k] = std::min(trim_min_[k], trimmed);
  trim_max_[k] = std::max(trim_max_[k], trimmed);
  // While the trims of other cables fade during a move, the platform yields to them and every
  // tension changes by up to their worth: the plan is evidence only beyond it, and the plan's
  // window starts again when that move ends. (With the nominal geometry 14.5 mm off the virtual
  // MINI's, regulation trims of other cables held cable 8's real tension on one raw value while
  // its plan moved more than the threshold.)
  const double plan_span = std::max(
      0.0, plan_max_[k] - plan_min_[k] - (mode_ == RtMode::kMoving ? fading_trim_worth_ : 0.0));
  const double gain = std::abs(in_.gain[k]);
  return std::max(plan_span, (trim_max_[k] - trim_min_[k]) / kStuckTrimFactor) * gain /
         options_.stuck_raw_units;
}

// The stillness window (every encoder and tension within its spread, each drive at its target),
// then the averages the sequence asked for.
void RtController::update_settle() noexcept {
  auto& c = win_counts_[static_cast<std::size_t>(win_head_)];
  auto& t = win_tensions_[static_cast<std::size_t>(win_head_)];
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    c[k] = static_cast<double>(in_.drives[k].actual_counts);
    t[k] = snap_.tensions[k];
  }
  win_head_ = (win_head_ + 1) % options_.settle_cycles;
  win_size_ = std::min(win_size_ + 1, options_.settle_cycles);
  bool still = mode_ == RtMode::kHolding && win_size_ >= options_.settle_cycles;
  for (int i = 0; i < m_ && still; ++i) {
    const auto k = static_cast<std::size_t>(i);
    double cmin = c[k], cmax = c[k], tmin = t[k], tmax = t[k];
    for (int w = 0; w < win_size_; ++w) {
      const auto j = static_cast<std::size_t>(w);
      cmin = std::min(cmin, win_counts_[j][k]);
      cmax = std::max(cmax, win_counts_[j][k]);
      tmin = std::min(tmin, win_tensions_[j][k]);
      tmax = std::max(tmax, win_tensions_[j][k]);
    }
    // The drive must also have reached its target.
    still = cmax - cmin <= options_.settle_counts &&
            std::abs(c[k] - target_[k]) <= options_.settle_counts + 1.0 &&
            (!in_.have_tensions || tmax - tmin <= options_.settle_tension);
  }
  settled_ = still;
  update_average();
}

// Averages of counts and tensions for the measuring sequence (only while settled).
void RtController::update_average() noexcept {
  const std::uint64_t req = average_request_.load(std::memory_order_acquire);
  if (req != average_taken_) {
    average_taken_ = req;
    snap_.average_id = req;
    snap_.average_cycles = 0;
    snap_.average_counts.fill(0.0);
    snap_.average_tensions.fill(0.0);
  }
  if (!settled_ || snap_.average_id == 0) return;
  const double n = snap_.average_cycles;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double c = static_cast<double>(in_.drives[k].actual_counts);
    snap_.average_counts[k] = (snap_.average_counts[k] * n + c) / (n + 1.0);
    snap_.average_tensions[k] = (snap_.average_tensions[k] * n + snap_.tensions[k]) / (n + 1.0);
  }
  ++snap_.average_cycles;
}

}  // namespace cdpr::controller
