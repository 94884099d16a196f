// RtController's moves, paths and setpoint stream (rt_controller.hpp): the time of a move (slowed
// to rest by a stop request), sampling a trajectory or a path, and following the stream with its
// smooth hold. Allocation-free, like every stage of the cycle.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>

#include "cdpr/controller/rt_controller.hpp"

namespace cdpr::controller {

namespace {

using Seconds = std::chrono::duration<double>;

// The trims in force when a stream starts fade out over this time (a move fades them over its
// duration).
constexpr double kStreamTrimFadeS = 1.0;

double wrapped(double a) {
  return std::remainder(a, 2.0 * std::numbers::pi);
}

}  // namespace

const char* to_string(StreamState s) {
  switch (s) {
    case StreamState::kOff:
      return "off";
    case StreamState::kFollowing:
      return "following";
    case StreamState::kHolding:
      return "holding";
    case StreamState::kStopping:
      return "stopping";
  }
  return "?";
}

const char* to_string(StreamEnd e) {
  switch (e) {
    case StreamEnd::kNone:
      return "none";
    case StreamEnd::kStopped:
      return "stopped";
    case StreamEnd::kStepRefused:
      return "step_refused";
    case StreamEnd::kResumeRefused:
      return "resume_refused";
    case StreamEnd::kRefused:
      return "refused";
    case StreamEnd::kFault:
      return "fault";
  }
  return "?";
}

// The move's time: the clock's since its start, or, once a stop is requested, the integral of
// the rate r = 1 - s(t) (stop_profile_) from then on; the move is over when r reached 0.
double RtController::move_time(canopen::Timestamp now) noexcept {
  if (!stopping_ && stop_requested()) {
    stopping_ = true;
    stop_start_ = last_now_ = now;
    move_t_ = Seconds(now - move_start_).count();
  }
  if (!stopping_) {
    move_t_ = Seconds(now - move_start_).count();
  } else {
    const double e = Seconds(now - stop_start_).count();
    const double dt = Seconds(now - last_now_).count();
    last_now_ = now;
    if (dt > 0.0) {
      const double rate = 1.0 - stop_profile_.sample(e - 0.5 * dt).s;
      move_t_ += std::max(0.0, rate) * dt;
    }
    snap_.move.stopped = e >= stop_profile_.duration();
  }
  snap_.move.elapsed_s = std::min(move_t_, move_duration());
  snap_.move.stopping = stopping_ && !snap_.move.stopped;
  return move_t_;
}

double RtController::move_duration() const noexcept {
  if (active_ == nullptr) return 0.0;
  if (active_->path) return active_->path->duration();
  return active_->trajectory ? active_->trajectory->duration() : 0.0;
}

void RtController::sample_move(double t) noexcept {
  snap_.move.duration_s = move_duration();
  if (active_->path) {
    active_->path->sample(t, pose_);
    snap_.move.line = active_->path->line_at(active_->path->sigma_at(t));
  } else if (active_->trajectory) {
    active_->trajectory->sample(t, pose_);
  }
}

void RtController::start_stream(const MotionCommand& c, canopen::Timestamp now) noexcept {
  StreamSetpoint stale;
  while (stream_in_.pop(stale)) {
  }
  start_move(c, now);  // the trims fade out, the planner's pretension as for a move
  if (mode_ != RtMode::kMoving) return;  // stopped before it started
  streaming_ = true;
  last_setpoint_ = last_now_ = now;
  stream_velocity_.setZero();
  last_applied_ << pose_.position, pose_.rpy;
  st_resumed_ = true;
  decel_linear_ = decel_angular_ = 0.0;
  const std::uint64_t holds = snap_.stream.holds;
  snap_.stream = StreamStatus{};
  snap_.stream.holds = holds;
  snap_.stream.state = StreamState::kHolding;  // until the first setpoint
}

void RtController::end_stream(StreamEnd why, std::uint64_t seq, double value) noexcept {
  if (snap_.stream.state == StreamState::kStopping) return;
  snap_.stream.state = StreamState::kStopping;
  snap_.stream.end = why;
  snap_.stream.end_seq = seq;
  snap_.stream.end_value = value;
}

// Every setpoint waiting is taken, the newest applied when it is within the step limits of the
// commanded pose (the receiver already refused reordered ones and checked each).
bool RtController::take_setpoint(canopen::Timestamp now) noexcept {
  StreamSetpoint sp, newest;
  bool got = false;
  while (stream_in_.pop(sp)) {
    newest = sp;
    got = true;
  }
  if (!got) return false;
  if (newest.verdict != StreamSetpoint::Verdict::kOk) {
    end_stream(StreamEnd::kRefused, newest.seq, 0.0);
    return false;
  }
  Eigen::Matrix<double, 6, 1> d;
  for (int j = 0; j < 3; ++j) {
    d(j) = newest.pose[static_cast<std::size_t>(j)] - pose_.position(j);
    d(j + 3) = wrapped(newest.pose[static_cast<std::size_t>(j + 3)] - pose_.rpy(j));
  }
  const double step = d.head<3>().norm(), angle = d.tail<3>().cwiseAbs().maxCoeff();
  // From rest (the start, after a hold) a setpoint is a step of the pose: at most what the
  // acceleration limits cover in one cycle from rest (a dt^2 / 2), else the stream ends. An
  // application resumes from the held pose (status: rt.commanded_pose).
  const MotionLimits& l = options_.stop_limits;
  const double dt2 = 0.5 * options_.cycle_s * options_.cycle_s;
  const StreamEnd why = st_resumed_ ? StreamEnd::kResumeRefused : StreamEnd::kStepRefused;
  const double max_step = st_resumed_ ? l.max_linear_acceleration * dt2 : options_.stream_max_step;
  const double max_angle =
      st_resumed_ ? l.max_angular_acceleration * dt2 : options_.stream_max_step_angle;
  if (step > max_step) {
    end_stream(why, newest.seq, step);
    return false;
  }
  if (angle > max_angle) {
    end_stream(why, newest.seq, angle);
    return false;
  }
  // The velocity from the last applied setpoint (not from the pose coasted since).
  Eigen::Matrix<double, 6, 1> next;
  next << pose_.position + d.head<3>(), pose_.rpy + d.tail<3>();
  const double dt = std::max(options_.cycle_s, Seconds(now - last_setpoint_).count());
  stream_velocity_ = st_resumed_ ? Eigen::Matrix<double, 6, 1>::Zero().eval()
                                 : ((next - last_applied_) / dt).eval();
  st_resumed_ = false;
  last_applied_ = next;
  decel_linear_ = decel_angular_ = 0.0;
  pose_.position = next.head<3>();
  pose_.rpy = next.tail<3>();
  last_setpoint_ = now;
  snap_.stream.state = StreamState::kFollowing;
  ++snap_.stream.applied;
  snap_.stream.last_seq = newest.seq;
  snap_.stream.latency_ns = now.count() - newest.sent_ns;
  snap_.stream.queue_ns = now.count() - newest.received_ns;
  StreamStatus& st = snap_.stream;
  const std::int64_t lat = st.latency_ns;
  st.latency_min_ns = st.latency_count == 0 ? lat : std::min(st.latency_min_ns, lat);
  st.latency_max_ns = st.latency_count == 0 ? lat : std::max(st.latency_max_ns, lat);
  ++st.latency_count;
  st.latency_sum += static_cast<double>(lat);
  st.latency_sum_sq += static_cast<double>(lat) * static_cast<double>(lat);
  return true;
}

// The commanded pose coasts on its velocity, braked at a deceleration that ramps up at the jerk
// limit to the acceleration limit and down again as the speed goes to zero (a <= sqrt(2 j v)),
// linear and angular (rpy rates) each with their limits.
void RtController::decelerate(double dt) noexcept {
  if (dt <= 0.0) return;
  const MotionLimits& l = options_.stop_limits;
  const auto brake = [dt](auto v, double& decel, double a_max, double j_max) {
    const double speed = v.norm();
    if (speed <= 0.0) {
      decel = 0.0;
      return;
    }
    decel = std::min({a_max, decel + j_max * dt, std::sqrt(2.0 * j_max * speed)});
    const double next = std::max(0.0, speed - decel * dt);
    v *= next / speed;
  };
  brake(stream_velocity_.head<3>(), decel_linear_, l.max_linear_acceleration, l.max_linear_jerk);
  brake(stream_velocity_.tail<3>(), decel_angular_, l.max_angular_acceleration, l.max_angular_jerk);
  pose_.position += stream_velocity_.head<3>() * dt;
  pose_.rpy += stream_velocity_.tail<3>() * dt;
}

void RtController::sample_stream(canopen::Timestamp now) noexcept {
  StreamStatus& st = snap_.stream;
  if (mode_ != RtMode::kMoving) {  // a fault ended it
    streaming_ = false;
    st.state = StreamState::kOff;
    if (st.end == StreamEnd::kNone) st.end = StreamEnd::kFault;
    return;
  }
  const double dt = Seconds(now - last_now_).count();
  last_now_ = now;
  const double fade = std::max(0.0, 1.0 - Seconds(now - move_start_).count() / kStreamTrimFadeS);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    trim_[k] = trim_at_move_[k] * fade;
  }
  ref_tension_ = ref_goal_ + (ref_start_ - ref_goal_) * fade;
  if (stop_requested()) end_stream(StreamEnd::kStopped, 0, 0.0);
  if (st.state != StreamState::kStopping && take_setpoint(now)) return;
  if (st.state == StreamState::kFollowing &&
      Seconds(now - last_setpoint_).count() >
          (options_.stream_deadline_cycles + 0.5) * options_.cycle_s) {
    st.state = StreamState::kHolding;
    ++st.holds;
  }
  if (st.state == StreamState::kFollowing) {  // within the deadline: coasting
    pose_.position += stream_velocity_.head<3>() * dt;
    pose_.rpy += stream_velocity_.tail<3>() * dt;
    return;
  }
  decelerate(dt);
  st_resumed_ = true;  // the next setpoint starts from rest
  if (st.state == StreamState::kStopping && stream_velocity_.isZero(0.0)) {
    streaming_ = false;
    st.state = StreamState::kOff;
    hold_pose_ = pose_;
    mode_ = RtMode::kHolding;
    done_ = active_->seq;
    restart_plan_window_ = fading_trim_worth_ > 0.0;
    fading_trim_worth_ = 0.0;
  }
}

}  // namespace cdpr::controller
