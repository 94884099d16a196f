#include "cdpr/controller/rt_controller.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <span>

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
    case RtMode::kHoldingCounts:
      return "holding_counts";
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
    case FaultKind::kEStop:
      return "estop";
    case FaultKind::kCableLimit:
      return "cable_limit";
    case FaultKind::kWorkspace:
      return "workspace";
  }
  return "?";
}

Result<std::unique_ptr<RtController>> RtController::create(RobotIO& io, const Geometry& initial,
                                                           const RtControllerOptions& options) {
  const int m = initial.model.num_cables();
  if (m < 1 || m > kMaxAxes) {
    return Status::error(ErrorCode::kInvalidArgument, "the robot has %d cables (1..%d supported)",
                         m, kMaxAxes);
  }
  CDPR_RETURN_IF_ERROR(io.fits(initial.model));
  CDPR_RETURN_IF_ERROR(TensionControl::validate(options.tension_control, options.cycle_s));
  CDPR_RETURN_IF_ERROR(options.stop_limits.validate());
  if (!(options.stream_max_step > 0.0) || !(options.stream_max_step_angle > 0.0) ||
      options.stream_deadline_cycles < 1) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "stream step limits must be > 0 and the deadline at least 1 cycle");
  }
  if (options.settle_cycles < 1 || options.settle_cycles > kMaxWindow) {
    return Status::error(ErrorCode::kInvalidArgument, "settle window of %d cycles (1..%d)",
                         options.settle_cycles, kMaxWindow);
  }
  return std::unique_ptr<RtController>(new RtController(io, initial, options));
}

RtController::RtController(RobotIO& io, const Geometry& initial, const RtControllerOptions& options)
    : io_(io),
      options_(options),
      m_(initial.model.num_cables()),
      geometry_(&initial),
      command_data_(initial.model),
      slew_() {
  TensionControlOptions tension = options.tension_control;
  tension.slack_below = options.slack_below;  // one slack limit: the watch's
  tension_.configure(tension, options.cycle_s);
  const MotionLimits& l = options.stop_limits;
  const double rate = std::min(l.max_linear_acceleration / l.max_linear_velocity,
                               l.max_angular_acceleration / l.max_angular_velocity);
  const double rate2 = std::min(l.max_linear_jerk / l.max_linear_velocity,
                                l.max_angular_jerk / l.max_angular_velocity);
  const double rate3 = std::min(l.max_linear_jerk / l.max_linear_acceleration,
                                l.max_angular_jerk / l.max_angular_acceleration) *
                       rate2;
  // (validated limits: the plan cannot fail)
  if (auto p = DoubleSProfile::plan(1.0, rate, rate2, rate3); p.ok()) stop_profile_ = *p;
  out_.num_axes = m_;
  hold_pose_ = pose_ = initial.model.home;
  ref_tension_ = initial.reference_tension;
  snap_.brakes_released = !options.brakes;  // without brakes nothing holds a command back
  in_use_geometry_.store(initial.version, std::memory_order_release);
  snap_.num_cables = m_;
  snap_.geometry_version = initial.version;
  for (int j = 0; j < 3; ++j) {
    snap_.pose_vector[static_cast<std::size_t>(j)] = pose_.position(j);
    snap_.pose_vector[static_cast<std::size_t>(j + 3)] = pose_.rpy(j);
  }
  published_.store(snap_);
}

// The servo cycle: read, update, write, on this cycle's readings.
void RtController::cycle(canopen::Timestamp now) noexcept {
  read_inputs(now);
  take_requests(now);
  watch_faults(now);
  take_command(now);
  sample_trajectory(now);
  control_tensions();
  compute_targets(now);
  check_limits(now);
  sequence_brakes();
  write_outputs();
  update_settle();
  publish(now);
}

double RtController::cable_counts_per_metre(int i) const noexcept {
  return 1.0 / winch_metres_per_count(geometry_->model.winches[static_cast<std::size_t>(i)]);
}

void RtController::set_fault(const RtFault& f) noexcept {
  if (fault_.kind == FaultKind::kNone) fault_ = f;  // the first fault is the one that counts
  // A fault that only held the robot (hold_fault) does not stand in the way of a quick stop.
  if (mode_ == RtMode::kDisabled) return;
  out_.quick_stop = true;
  mode_ = RtMode::kDisabled;
}

void RtController::hold_fault(const RtFault& f) noexcept {
  if (fault_.kind != FaultKind::kNone) return;
  fault_ = f;
  // Latched like any fault (no command is taken until fault_reset); the drives keep holding the
  // pose, a trim in progress stops where it is.
  trim_goal_ = trim_;
}

bool RtController::solve(const Pose& pose) noexcept {
  // With tension control the plan (its target) keeps the band's margin and the guard inside it
  // where the pose allows it, else the margin (the path check asks as much); elsewhere, and
  // without tension control, the planner's band.
  if (solved_.valid && solved_.geometry == geometry_ && solved_.reference == ref_tension_ &&
      solved_.pose.position == pose.position && solved_.pose.rpy == pose.rpy &&
      plan_reference_ == command_data_.plan.reference) {
    for (int i = 0; i < m_; ++i) {
      desired_[static_cast<std::size_t>(i)] =
          command_data_.cable.counts(i) + offsets_[static_cast<std::size_t>(i)];
    }
    return true;
  }
  solved_.valid = false;
  const TensionControlOptions& tc = tension_.options();
  const std::array<double, 3> margins{tc.margin + tc.guard, tc.margin, 0.0};
  const std::size_t first = tension_.enabled() ? 0 : 2;
  int chosen = -1;
  (void)command_counts(geometry_->model, pose, ref_tension_, command_data_,
                       std::span<const double>(margins).subspan(first), &chosen);
  if (chosen < 0) return false;
  follow_plan_reference(margins[first + static_cast<std::size_t>(chosen)]);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    desired_[k] = command_data_.cable.counts(i) + offsets_[k];
    snap_.planned[k] = command_data_.plan.tensions(i);
  }
  solved_ = Solved{true, pose, ref_tension_, geometry_};
  return true;
}

// The planner's choice of reference (1x, 2x or 4x ref_tension_, command_data_.plan.reference)
// steps where a cable reaches the band's edge; the plan is made at a reference following it by
// at most ref_tension_ per kPlanSwitchS (one plan more per cycle while they differ). The plan at
// one reference is continuous along the path, so the tensions planned and the lengths that
// compensate their elongation change smoothly (a step of 60 N in every cable's plan, 4 mm of
// cable, made a cable of the uncalibrated MINI drop to 8.5 N mid-move).
void RtController::follow_plan_reference(double margin) noexcept {
  constexpr double kPlanSwitchS = 0.5;  // s from 1x to 2x the reference
  const double goal = command_data_.plan.reference;
  if (std::isnan(plan_reference_)) plan_reference_ = goal;
  const double dmax = ref_tension_ * options_.cycle_s / kPlanSwitchS;
  plan_reference_ += std::clamp(goal - plan_reference_, -dmax, dmax);
  if (plan_reference_ == goal) return;
  if (plan_tensions_at(geometry_->model, command_data_.kinematics, command_data_.factor,
                       plan_reference_, margin, command_data_.plan)
          .ok()) {
    compensate_lengths(geometry_->model, command_data_.kinematics, command_data_.plan.tensions,
                       command_data_.cable);
    return;
  }
  // (the planner's own choice is feasible: back to it)
  (void)plan_tensions(geometry_->model, command_data_.kinematics, command_data_.factor,
                      ref_tension_, margin, command_data_.plan);
  plan_reference_ = command_data_.plan.reference;
}

void RtController::read_inputs(canopen::Timestamp now) noexcept {
  io_.read(now, in_);
  out_.send_targets = out_.fault_reset = out_.enable = out_.disable = out_.quick_stop = false;
  snap_.all_enabled = true;
  for (int i = 0; i < m_; ++i) {
    snap_.all_enabled = snap_.all_enabled && in_.drives[static_cast<std::size_t>(i)].enabled;
  }
}

void RtController::take_requests(canopen::Timestamp now) noexcept {
  if (quick_stop_.exchange(false, std::memory_order_acq_rel)) {
    set_fault({FaultKind::kQuickStop, 0, -1, 0, 0.0, now.count()});
  }
  take_enable_requests();
  // While an e-stop input reads open a fault reset is refused: the fault stays latched.
  if (fault_reset_.exchange(false, std::memory_order_acq_rel) && fault_.kind != FaultKind::kNone &&
      in_.safety_open == 0) {
    fault_ = RtFault{};
    // The reset supersedes a quick stop requested before it in this cycle; a fault watched
    // after it quick-stops again.
    out_.quick_stop = false;
    out_.fault_reset = true;
    out_.enable = !disable_requested_;
    slack_count_.fill(0);
    overload_count_.fill(0);
    reset_stuck_watch();
  }
}

void RtController::take_command(canopen::Timestamp now) noexcept {
  std::atomic<MotionCommand*>& box =
      first_.load(std::memory_order_acquire) != nullptr ? first_ : inbox_;
  MotionCommand* c = box.load(std::memory_order_acquire);
  if (c == nullptr || fault_.kind != FaultKind::kNone) return;  // a faulted loop takes nothing
  if (!snap_.brakes_released) return;  // no motion against an applied brake
  // A move or a trim starts from holding; a re-reference only while holding still, or while
  // disabled from the actual positions once every drive is enabled. Otherwise the command
  // waits in the inbox for a later cycle.
  bool take = false;
  switch (c->type) {
    case MotionCommand::Type::kMove:
    case MotionCommand::Type::kTrim:
    case MotionCommand::Type::kStream:
      take = mode_ == RtMode::kHolding;
      break;
    case MotionCommand::Type::kReference:
      take = (mode_ == RtMode::kHolding && settled_) ||
             (mode_ == RtMode::kDisabled && c->from_actual && snap_.all_enabled) ||
             (c->hold_actual && (mode_ == RtMode::kHolding || mode_ == RtMode::kHoldingCounts));
      break;
  }
  if (!take) return;
  if (!box.compare_exchange_strong(c, nullptr)) return;  // replaced meanwhile: next cycle
  active_ = c;
  in_use_command_.store(c->seq, std::memory_order_release);
  settled_ = false;
  win_size_ = 0;
  switch (c->type) {
    case MotionCommand::Type::kMove:
      start_move(*c, now);
      break;
    case MotionCommand::Type::kTrim:
      for (int i = 0; i < m_; ++i) {
        trim_goal_[static_cast<std::size_t>(i)] = c->trim[static_cast<std::size_t>(i)];
      }
      break;
    case MotionCommand::Type::kReference:
      start_reference(*c, now);
      break;
    case MotionCommand::Type::kStream:
      start_stream(*c, now);
      break;
  }
}

void RtController::start_move(const MotionCommand& c, canopen::Timestamp now) noexcept {
  snap_.move = MoveProgress{};
  stopping_ = false;
  if (stop_requested()) {  // stopped before it started: it never moves
    done_ = c.seq;
    snap_.move.stopped = true;
    return;
  }
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
  ref_goal_ = std::isnan(c.reference_tension) ? geometry_->reference_tension : c.reference_tension;
}

// Re-reference: new geometry (if any), new hold pose, no trims, targets start where they are.
void RtController::start_reference(const MotionCommand& c, canopen::Timestamp now) noexcept {
  if (c.geometry != nullptr) {
    geometry_ = c.geometry;
    in_use_geometry_.store(geometry_->version, std::memory_order_release);
  }
  if (c.hold_actual) {
    hold_actual(c);
    return;
  }
  ref_tension_ = geometry_->reference_tension;
  plan_reference_ = std::numeric_limits<double>::quiet_NaN();
  hold_pose_ = pose_ = c.pose;
  reset_stuck_watch();  // the commanded lengths are derived again: the expected tensions jump
  trim_.fill(0.0);
  trim_goal_.fill(0.0);
  tension_.reset();
  std::array<double, kMaxAxes> start{};
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    start[k] = c.from_actual ? static_cast<double>(in_.drives[k].actual_counts) : target_[k];
  }
  if (!solve(pose_)) {
    set_fault({FaultKind::kCommand, 0, -1, 0, 0.0, now.count()});
    return;
  }
  std::array<double, kMaxAxes> vmax{}, amax{};
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    vmax[k] = options_.slew_velocity * cable_counts_per_metre(i);
    amax[k] = options_.slew_acceleration * cable_counts_per_metre(i);
  }
  const auto n = static_cast<std::size_t>(m_);
  if (!slew_
           .configure(options_.cycle_s, std::span<const double>(vmax.data(), n),
                      std::span<const double>(amax.data(), n))
           .ok() ||
      !slew_.reset(std::span<const double>(start.data(), n)).ok() ||
      !slew_.set_target(std::span<const double>(desired_.data(), n)).ok()) {
    set_fault({FaultKind::kCommand, 0, -1, 0, 0.0, now.count()});
    return;
  }
  target_ = start;
  snap_.largest_reference_step = 0.0;
  mode_ = RtMode::kSlewing;
}

// Hold where the drives are: targets = actual counts; the pose's targets plus trims equal them.
void RtController::hold_actual(const MotionCommand& c) noexcept {
  if (c.offsets) offsets_ = *c.offsets;
  ref_tension_ = geometry_->reference_tension;
  plan_reference_ = std::numeric_limits<double>::quiet_NaN();
  hold_pose_ = pose_ = c.pose;
  reset_stuck_watch();
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    target_[k] = static_cast<double>(in_.drives[k].actual_counts);
  }
  snap_.largest_reference_step = 0.0;
  done_ = c.seq;
  if (c.counts_only || !solve(pose_)) {
    trim_.fill(0.0);
    trim_goal_.fill(0.0);
    mode_ = RtMode::kHoldingCounts;
    return;
  }
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    trim_[k] = target_[k] - desired_[k];
  }
  trim_goal_ = trim_;
  mode_ = RtMode::kHolding;
}

void RtController::sample_trajectory(canopen::Timestamp now) noexcept {
  if (mode_ == RtMode::kHolding || mode_ == RtMode::kSlewing) {
    pose_ = hold_pose_;
    return;
  }
  if (streaming_) {
    sample_stream(now);
    return;
  }
  if (mode_ != RtMode::kMoving || active_ == nullptr) return;
  const double t = move_time(now);
  const double T = move_duration();
  sample_move(t);
  // The planner's pretension changes linearly along the move, the trims fade out.
  const double fade = T > 0.0 ? std::max(0.0, 1.0 - t / T) : 0.0;
  ref_tension_ = ref_goal_ + (ref_start_ - ref_goal_) * fade;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    trim_[k] = trim_at_move_[k] * fade;
  }
  if (t >= T || snap_.move.stopped) {
    hold_pose_ = pose_;
    mode_ = RtMode::kHolding;
    done_ = active_->seq;
    restart_plan_window_ = fading_trim_worth_ > 0.0;
    fading_trim_worth_ = 0.0;
  }
}

void RtController::compute_targets(canopen::Timestamp now) noexcept {
  if (mode_ == RtMode::kHoldingCounts) {  // the targets stay where hold_actual put them
    out_.send_targets = true;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      out_.target_counts[k] = static_cast<std::int32_t>(std::llround(target_[k]));
    }
  } else if (active()) {
    if (solve(pose_)) {
      slew_targets();
    } else {
      set_fault({FaultKind::kCommand, 0, -1, 0, 0.0, now.count()});
    }
  }
  if (mode_ == RtMode::kDisabled) {
    // The drives hold their actual positions (a drive that is not enabled keeps target = actual).
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      target_[k] = static_cast<double>(in_.drives[k].actual_counts);
    }
  }
}

void RtController::slew_targets() noexcept {
  double step = 0.0;
  if (mode_ == RtMode::kSlewing) {
    (void)slew_.set_target(std::span<const double>(desired_.data(), static_cast<std::size_t>(m_)));
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
    if (mode_ == RtMode::kHolding) step_trims();
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const double goal = desired_[k] + trim_[k] + tension_.trim(i);
      step = std::max(step, std::abs(goal - target_[k]));
      target_[k] = goal;
    }
    if (mode_ == RtMode::kMoving || step > 0.0) {
      snap_.largest_move_step = std::max(snap_.largest_move_step, step);
    }
  }
  out_.send_targets = true;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    out_.target_counts[k] = static_cast<std::int32_t>(std::llround(target_[k]));
  }
}

// While holding, the tension-regulation trims move towards their goal at a bounded rate.
void RtController::step_trims() noexcept {
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double dmax = options_.trim_velocity * cable_counts_per_metre(i) * options_.cycle_s;
    const double d = trim_goal_[k] - trim_[k];
    trim_[k] = std::abs(d) <= dmax ? trim_goal_[k] : trim_[k] + std::clamp(d, -dmax, dmax);
  }
  if (active_ != nullptr && active_->type == MotionCommand::Type::kTrim && trim_ == trim_goal_) {
    done_ = active_->seq;
  }
}

void RtController::write_outputs() noexcept {
  io_.write(out_);
}

void RtController::publish(canopen::Timestamp now) noexcept {
  ++snap_.cycle;
  snap_.now_ns = now.count();
  snap_.mode = mode_;
  snap_.fault = fault_;
  snap_.command_taken = active_ != nullptr ? active_->seq : 0;
  snap_.command_done = done_;
  snap_.trim_counts = trim_;
  snap_.tension_control = tension_.status();
  snap_.geometry_version = geometry_->version;
  snap_.settled = settled_;
  for (int j = 0; j < 3; ++j) {
    snap_.pose_vector[static_cast<std::size_t>(j)] = pose_.position(j);
    snap_.pose_vector[static_cast<std::size_t>(j + 3)] = pose_.rpy(j);
  }
  snap_.reference_tension = ref_tension_;
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    snap_.actual_counts[k] = static_cast<double>(in_.drives[k].actual_counts);
    snap_.target_counts[k] = target_[k];
  }
  snap_.overruns = overruns_;
  published_.store(snap_);
}

}  // namespace cdpr::controller
