#include "cdpr/controller/rt_controller.hpp"

#include <algorithm>
#include <cmath>

#include "cdpr/calibration/winch.hpp"

namespace cdpr::controller {

const char* to_string(RtMode m) {
  switch (m) {
    case RtMode::kDisabled:
      return "disabled";
    case RtMode::kHolding:
      return "holding";
    case RtMode::kMoving:
      return "moving";
    case RtMode::kSlewing:
      return "slewing";
  }
  return "?";
}

const char* to_string(FaultKind f) {
  switch (f) {
    case FaultKind::kNone:
      return "none";
    case FaultKind::kDriveFault:
      return "drive_fault";
    case FaultKind::kNodeLost:
      return "node_lost";
    case FaultKind::kBusOff:
      return "bus_off";
    case FaultKind::kSlackCable:
      return "slack_cable";
    case FaultKind::kOverload:
      return "cable_overload";
    case FaultKind::kCommand:
      return "command_failed";
    case FaultKind::kQuickStop:
      return "quick_stop";
    case FaultKind::kForceSensor:
      return "force_sensor";
    case FaultKind::kForceStuck:
      return "force_stuck";
  }
  return "?";
}

Result<std::unique_ptr<RtController>> RtController::create(canopen::Master& master,
                                                           const Geometry& initial,
                                                           const RtControllerOptions& options) {
  const int m = initial.model.num_cables();
  if (m < 1 || m > kMaxAxes) {
    return Status::error(ErrorCode::kInvalidArgument, "the robot has %d cables (1..%d supported)",
                         m, kMaxAxes);
  }
  if (static_cast<int>(master.drives().size()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "the CANopen network has %d drives, the robot '%s' has %d cables",
                         static_cast<int>(master.drives().size()), initial.model.name.c_str(), m);
  }
  if (!master.force_sensors().empty() &&
      static_cast<int>(master.force_sensors()[0].channels()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "force node %d has %d channels, the robot has %d cables",
                         int{master.force_sensors()[0].node()},
                         static_cast<int>(master.force_sensors()[0].channels()), m);
  }
  if (options.settle_cycles < 1 || options.settle_cycles > kMaxWindow) {
    return Status::error(ErrorCode::kInvalidArgument, "settle window of %d cycles (1..%d)",
                         options.settle_cycles, kMaxWindow);
  }
  return std::unique_ptr<RtController>(new RtController(master, initial, options));
}

RtController::RtController(canopen::Master& master, const Geometry& initial,
                           const RtControllerOptions& options)
    : master_(master),
      options_(options),
      m_(initial.model.num_cables()),
      geometry_(&initial),
      command_data_(initial.model),
      slew_() {
  for (int i = 0; i < m_; ++i) drives_[static_cast<std::size_t>(i)] = &master.drives()[i];
  if (!master.force_sensors().empty()) force_ = &master.force_sensors()[0];
  hold_pose_ = pose_ = initial.model.home;
  ref_tension_ = initial.reference_tension;
  in_use_geometry_.store(initial.version, std::memory_order_release);
  snap_.num_cables = m_;
  snap_.geometry_version = initial.version;
  for (int j = 0; j < 3; ++j) {
    snap_.pose_vector[static_cast<std::size_t>(j)] = pose_.position(j);
    snap_.pose_vector[static_cast<std::size_t>(j + 3)] = pose_.rpy(j);
  }
  published_.store(snap_);
}

double RtController::cable_counts_per_metre(int i) const noexcept {
  return 1.0 / winch_metres_per_count(geometry_->model.winches[static_cast<std::size_t>(i)]);
}

void RtController::set_fault(const RtFault& f) noexcept {
  if (fault_.kind == FaultKind::kNone) fault_ = f;  // the first fault is the one that counts
  // A fault that only held the robot (hold_fault) does not stand in the way of a quick stop.
  if (mode_ == RtMode::kDisabled) return;
  master_.quick_stop_all();
  mode_ = RtMode::kDisabled;
}

void RtController::hold_fault(const RtFault& f) noexcept {
  if (fault_.kind != FaultKind::kNone) return;
  fault_ = f;
  // Latched like any fault (no command is taken until fault_reset); the drives keep holding the
  // pose, a trim in progress stops where it is.
  trim_goal_ = trim_;
}

bool RtController::compute_targets(const Pose& pose) noexcept {
  const Status s = command_counts(geometry_->model, pose, ref_tension_, command_data_);
  if (!s.ok()) return false;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    desired_[k] = command_data_.cable.counts(i) + offsets_[k];
    snap_.planned[k] = command_data_.plan.tensions(i);
  }
  return true;
}

void RtController::take_command(canopen::Timestamp now) noexcept {
  MotionCommand* c = inbox_.load(std::memory_order_acquire);
  if (c == nullptr || fault_.kind != FaultKind::kNone) return;  // a faulted loop takes nothing
  // A move or a trim starts from holding; a re-reference only while holding still, or while
  // disabled from the actual positions once every drive is enabled. Otherwise the command
  // waits in the inbox for a later cycle.
  bool take = false;
  switch (c->type) {
    case MotionCommand::Type::kMove:
    case MotionCommand::Type::kTrim:
      take = mode_ == RtMode::kHolding;
      break;
    case MotionCommand::Type::kReference:
      take = (mode_ == RtMode::kHolding && settled_) ||
             (mode_ == RtMode::kDisabled && c->from_actual && snap_.all_enabled);
      break;
  }
  if (!take) return;
  if (!inbox_.compare_exchange_strong(c, nullptr)) return;  // replaced meanwhile: next cycle
  active_ = c;
  in_use_command_.store(c->seq, std::memory_order_release);
  settled_ = false;
  win_size_ = 0;
  if (c->type == MotionCommand::Type::kMove) {
    move_start_ = now;
    mode_ = RtMode::kMoving;
    snap_.largest_move_step = 0.0;
    trim_at_move_ = trim_;
    fading_trim_worth_ = 0.0;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const double loaded = command_data_.cable.loaded_lengths(i);
      const double ea = geometry_->model.cables[k].ea;
      if (ea > 0.0 && loaded > 0.0) {
        fading_trim_worth_ += ea / loaded * std::abs(trim_at_move_[k]) *
                              winch_metres_per_count(geometry_->model.winches[k]);
      }
    }
    trim_goal_.fill(0.0);
    ref_start_ = ref_tension_;
    ref_goal_ =
        std::isnan(c->reference_tension) ? geometry_->reference_tension : c->reference_tension;
    return;
  }
  if (c->type == MotionCommand::Type::kTrim) {
    for (int i = 0; i < m_; ++i)
      trim_goal_[static_cast<std::size_t>(i)] = c->trim[static_cast<std::size_t>(i)];
    return;
  }
  // Re-reference: new geometry (if any), new hold pose, no trims, targets start where they are.
  if (c->geometry != nullptr) {
    geometry_ = c->geometry;
    in_use_geometry_.store(geometry_->version, std::memory_order_release);
  }
  ref_tension_ = geometry_->reference_tension;
  hold_pose_ = pose_ = c->pose;
  reset_stuck_watch();  // the commanded lengths are derived again: the expected tensions jump
  trim_.fill(0.0);
  trim_goal_.fill(0.0);
  std::array<double, kMaxAxes> start{};
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    start[k] = c->from_actual ? static_cast<double>(drives_[k]->actual_counts()) : target_[k];
  }
  if (!compute_targets(pose_)) {
    set_fault({FaultKind::kCommand, 0, -1, 0, 0.0, now.count()});
    return;
  }
  std::array<double, kMaxAxes> vmax{}, amax{};
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    vmax[k] = options_.slew_velocity * cable_counts_per_metre(i);
    amax[k] = options_.slew_acceleration * cable_counts_per_metre(i);
  }
  if (!slew_
           .configure(options_.cycle_s,
                      std::span<const double>(vmax.data(), static_cast<std::size_t>(m_)),
                      std::span<const double>(amax.data(), static_cast<std::size_t>(m_)))
           .ok() ||
      !slew_.reset(std::span<const double>(start.data(), static_cast<std::size_t>(m_))).ok() ||
      !slew_.set_target(std::span<const double>(desired_.data(), static_cast<std::size_t>(m_)))
           .ok()) {
    set_fault({FaultKind::kCommand, 0, -1, 0, 0.0, now.count()});
    return;
  }
  target_ = start;
  snap_.largest_reference_step = 0.0;
  mode_ = RtMode::kSlewing;
}

void RtController::watch(canopen::Timestamp now) noexcept {
  canopen::Event e;
  while (master_.events().pop(e)) {
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
  if (master_.faulted() && fault_.kind == FaultKind::kNone) {
    set_fault({FaultKind::kDriveFault, 0, -1, 0, 0.0, now.count()});
  }
  // Cable tensions against the slack and overload limits while the drives hold the cables.
  snap_.have_tensions = force_ != nullptr;
  if (force_ == nullptr) return;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double f = force_->tension(k);
    snap_.tensions[k] = f;
    if (mode_ != RtMode::kMoving && mode_ != RtMode::kHolding && mode_ != RtMode::kSlewing) {
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
  watch_stuck(now);
}

void RtController::watch_stuck(canopen::Timestamp now) noexcept {
  // What a cable's tension is made to do, from the commands alone: (1) the planned tension at
  // the commanded pose (the compensated inverse kinematics stretches the cable to it, and the
  // plan is in equilibrium with the platform, so the real tension follows it up to the model's
  // errors); (2) while holding, the tension-regulation trims, as the cable's own stiffness (EA
  // over the loaded length) times the trimmed length. The platform yields to a trim of one
  // cable and the others share it, so a trim changes the real tension by less than that (a
  // third of it at home on the MINI, less elsewhere): trims count against
  // kStuckTrimFactor times the threshold. The plan's own threshold is wide too: with the nominal
  // geometry (anchors 14.5 mm from the truth) a real tension was seen to stay on one raw value
  // while its plan moved 4.2 N. (A fading trim during a move is not counted, and
  // while it fades the plan is no evidence for that cable either: the two may cancel.) A reading
  // that keeps its raw value while (1) or (2) spans more than its threshold for
  // stuck_confirm_cycles cycles is stuck. On a still robot without trims neither changes: noise, or
  // a reading that happens to stay bit-identical for a long time, cannot raise it. A slack cable
  // (below the slack limit) follows neither, so the watch starts again there.
  const bool applies =
      options_.stuck_raw_units > 0.0 && force_ != nullptr && fault_.kind == FaultKind::kNone &&
      (mode_ == RtMode::kMoving || mode_ == RtMode::kHolding || mode_ == RtMode::kSlewing);
  if (!applies) {
    reset_stuck_watch();
    snap_.unchanged_span.fill(0.0);
    return;
  }
  // Only a reading that arrived this cycle can be unchanged: when the node's PDOs stop (the
  // node is gone) the readings are old, which is the heartbeat watch's fault to name.
  const std::uint64_t pdos = force_->pdos_received();
  const bool fresh = pdos != force_pdos_;
  force_pdos_ = pdos;
  if (restart_plan_window_) {
    restart_plan_window_ = false;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      plan_min_[k] = plan_max_[k] = snap_.planned[k];
    }
  }
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const std::int64_t raw = force_->raw(k);
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
      stuck_count_[k] = 0;
      snap_.unchanged_span[k] = 0.0;
      continue;
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
    // In threshold units: > 1 is evidence enough.
    const double gain = std::abs(force_->gain(k));
    const double evidence = std::max(plan_span, (trim_max_[k] - trim_min_[k]) / kStuckTrimFactor) *
                            gain / options_.stuck_raw_units;
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

void RtController::update_settle() noexcept {
  auto& c = win_counts_[static_cast<std::size_t>(win_head_)];
  auto& t = win_tensions_[static_cast<std::size_t>(win_head_)];
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    c[k] = static_cast<double>(drives_[k]->actual_counts());
    t[k] = snap_.tensions[k];
  }
  win_head_ = (win_head_ + 1) % options_.settle_cycles;
  win_size_ = std::min(win_size_ + 1, options_.settle_cycles);
  if (mode_ != RtMode::kHolding || win_size_ < options_.settle_cycles) {
    settled_ = false;
    return;
  }
  bool still = true;
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
            (force_ == nullptr || tmax - tmin <= options_.settle_tension);
  }
  settled_ = still;
}

void RtController::cycle(canopen::Timestamp now) noexcept {
  snap_.all_enabled = true;
  for (int i = 0; i < m_; ++i) {
    snap_.all_enabled = snap_.all_enabled && drives_[static_cast<std::size_t>(i)]->enabled();
  }
  if (quick_stop_.exchange(false, std::memory_order_acq_rel)) {
    set_fault({FaultKind::kQuickStop, 0, -1, 0, 0.0, now.count()});
  }
  if (fault_reset_.exchange(false, std::memory_order_acq_rel) && fault_.kind != FaultKind::kNone) {
    fault_ = RtFault{};
    master_.clear_fault();
    for (int i = 0; i < m_; ++i) {
      canopen::Drive& d = *drives_[static_cast<std::size_t>(i)];
      if (d.state() == canopen::cia402::State::kFault) d.reset_fault();
      d.enable();
    }
    slack_count_.fill(0);
    overload_count_.fill(0);
    reset_stuck_watch();
  }
  take_command(now);

  // Update: the pose to command this cycle and the drive targets.
  if (mode_ == RtMode::kMoving && active_ != nullptr) {
    const double t = std::chrono::duration<double>(now - move_start_).count();
    active_->trajectory->sample(t, pose_);
    const double T = active_->trajectory->duration();
    const double fade = T > 0.0 ? std::max(0.0, 1.0 - t / T) : 0.0;
    ref_tension_ = ref_goal_ + (ref_start_ - ref_goal_) * fade;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      trim_[k] = trim_at_move_[k] * fade;
    }
    if (t >= T) {
      hold_pose_ = pose_;
      mode_ = RtMode::kHolding;
      done_ = active_->seq;
      restart_plan_window_ = fading_trim_worth_ > 0.0;
      fading_trim_worth_ = 0.0;
    }
  } else if (mode_ == RtMode::kHolding || mode_ == RtMode::kSlewing) {
    pose_ = hold_pose_;
  }
  if (mode_ == RtMode::kMoving || mode_ == RtMode::kHolding || mode_ == RtMode::kSlewing) {
    if (!compute_targets(pose_)) {
      set_fault({FaultKind::kCommand, 0, -1, 0, 0.0, now.count()});
    } else {
      double step = 0.0;
      if (mode_ == RtMode::kSlewing) {
        (void)slew_.set_target(
            std::span<const double>(desired_.data(), static_cast<std::size_t>(m_)));
        slew_.step();
        const std::span<const double> cur = slew_.command();
        for (int i = 0; i < m_; ++i) {
          const auto k = static_cast<std::size_t>(i);
          step = std::max(step, std::abs(cur[k] - target_[k]));
          target_[k] = cur[k];
        }
        snap_.largest_reference_step = std::max(snap_.largest_reference_step, step);
        if (slew_.done()) {
          mode_ = RtMode::kHolding;
          if (active_ != nullptr) done_ = active_->seq;
        }
      } else {
        if (mode_ == RtMode::kHolding) {  // trims move at a bounded rate
          for (int i = 0; i < m_; ++i) {
            const auto k = static_cast<std::size_t>(i);
            const double dmax =
                options_.trim_velocity * cable_counts_per_metre(i) * options_.cycle_s;
            const double d = trim_goal_[k] - trim_[k];
            trim_[k] = std::abs(d) <= dmax ? trim_goal_[k] : trim_[k] + std::clamp(d, -dmax, dmax);
          }
          if (active_ != nullptr && active_->type == MotionCommand::Type::kTrim &&
              trim_ == trim_goal_) {
            done_ = active_->seq;
          }
        }
        for (int i = 0; i < m_; ++i) {
          const auto k = static_cast<std::size_t>(i);
          const double goal = desired_[k] + trim_[k];
          step = std::max(step, std::abs(goal - target_[k]));
          target_[k] = goal;
        }
        if (mode_ == RtMode::kMoving || step > 0.0) {
          snap_.largest_move_step = std::max(snap_.largest_move_step, step);
        }
      }
      for (int i = 0; i < m_; ++i) {
        const auto k = static_cast<std::size_t>(i);
        drives_[k]->set_target_counts(static_cast<std::int32_t>(std::llround(target_[k])));
      }
    }
  }
  if (mode_ == RtMode::kDisabled) {
    // The drives hold their actual positions (the master keeps target = actual when disabled).
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      target_[k] = static_cast<double>(drives_[k]->actual_counts());
    }
  }

  // Write (RPDOs, SYNC) and read (TPDOs, heartbeats, EMCYs, error frames).
  master_.cycle(now);
  watch(now);
  update_settle();

  // Averages for the measuring sequence (only while settled).
  const std::uint64_t req = average_request_.load(std::memory_order_acquire);
  if (req != average_taken_) {
    average_taken_ = req;
    snap_.average_id = req;
    snap_.average_cycles = 0;
    snap_.average_counts.fill(0.0);
    snap_.average_tensions.fill(0.0);
  }
  if (settled_ && snap_.average_id != 0) {
    const double n = snap_.average_cycles;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const double c = static_cast<double>(drives_[k]->actual_counts());
      snap_.average_counts[k] = (snap_.average_counts[k] * n + c) / (n + 1.0);
      snap_.average_tensions[k] = (snap_.average_tensions[k] * n + snap_.tensions[k]) / (n + 1.0);
    }
    ++snap_.average_cycles;
  }

  // Publish.
  ++snap_.cycle;
  snap_.now_ns = now.count();
  snap_.mode = mode_;
  snap_.fault = fault_;
  snap_.command_taken = active_ != nullptr ? active_->seq : 0;
  snap_.command_done = done_;
  snap_.trim_counts = trim_;
  snap_.geometry_version = geometry_->version;
  snap_.settled = settled_;
  for (int j = 0; j < 3; ++j) {
    snap_.pose_vector[static_cast<std::size_t>(j)] = pose_.position(j);
    snap_.pose_vector[static_cast<std::size_t>(j + 3)] = pose_.rpy(j);
  }
  snap_.reference_tension = ref_tension_;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    snap_.actual_counts[k] = static_cast<double>(drives_[k]->actual_counts());
    snap_.target_counts[k] = target_[k];
  }
  snap_.overruns = overruns_;
  published_.store(snap_);
}

}  // namespace cdpr::controller
