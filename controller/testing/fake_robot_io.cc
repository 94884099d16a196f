#include "fake_robot_io.hpp"

#include <chrono>
#include <cmath>

namespace cdpr::controller::testing {

FakeRobotIO::FakeRobotIO(int axes, bool with_tensions) : n_(axes), with_tensions_(with_tensions) {
  state.fill(DriveState::kEnabled);
}

void FakeRobotIO::fault(int axis, std::uint16_t emcy_code) {
  const auto k = static_cast<std::size_t>(axis);
  state[k] = DriveState::kFault;
  emcy_[k] = emcy_code;
  master_faulted = true;
  canopen::Event e;
  e.type = canopen::EventType::kDriveFault;
  e.node = static_cast<canopen::NodeId>(axis + 1);
  push_event(e);
  e.type = canopen::EventType::kEmcy;
  e.emcy.node = e.node;
  e.emcy.code = emcy_code;
  e.value = emcy_code;
  push_event(e);
}

void FakeRobotIO::push_event(const canopen::Event& e) {
  if (num_pending_ < RobotReading::kMaxEvents)
    pending_[static_cast<std::size_t>(num_pending_++)] = e;
}

Status FakeRobotIO::fits(const RobotModel& model) const {
  if (model.num_cables() != n_) {
    return Status::error(ErrorCode::kInvalidArgument, "fake robot I/O: %d axes, %d cables", n_,
                         model.num_cables());
  }
  return Status::success();
}

void FakeRobotIO::read(canopen::Timestamp now, RobotReading& r) noexcept {
  const double dt = have_time_ ? std::chrono::duration<double>(now - now_).count() : 0.0;
  const double follow = dt > 0.0 ? 1.0 - std::exp(-dt / tau_s) : 0.0;
  have_time_ = true;
  now_ = now;
  r.now = now;
  r.num_axes = n_;
  r.have_tensions = with_tensions_;
  r.tensions_fresh = with_tensions_ && tensions_arrive;
  if (r.tensions_fresh) {
    ++tension_updates_;
    r.tensions_time = now;
  }
  r.tension_updates = tension_updates_;
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double before = position[k];
    if (!has_target_[k]) target_[k] = static_cast<std::int32_t>(std::lround(position[k]));
    const bool braked = brakes && !last_.release_brake[k];
    if (state[k] == DriveState::kEnabled && !braked) {
      position[k] += (target_[k] - position[k]) * follow;
    }
    DriveReading& d = r.drives[k];
    d.node = i + 1;
    d.received = true;
    d.enabled = state[k] == DriveState::kEnabled;
    d.fault = state[k] == DriveState::kFault;
    d.emcy_code = emcy_[k];
    d.actual_counts = static_cast<std::int32_t>(std::lround(position[k]));
    d.velocity = dt > 0.0 ? (position[k] - before) / dt : 0.0;
    if (r.tensions_fresh && !frozen[k]) {
      raw_[k] = std::llround(gain * tension[k]) + static_cast<std::int64_t>(tension_updates_ % 2);
    }
    r.raw[k] = raw_[k];
    r.gain[k] = gain;
    r.tensions[k] = static_cast<double>(raw_[k]) / gain;
  }
  r.have_laser = false;
  r.master_faulted = master_faulted;
  r.bus_off = false;
  r.lost_node = 0;
  r.num_safety_inputs = safety_inputs;
  r.safety_open = safety_open;
  r.num_events = num_pending_;
  for (int j = 0; j < num_pending_; ++j) {
    r.events[static_cast<std::size_t>(j)] = pending_[static_cast<std::size_t>(j)];
  }
  num_pending_ = 0;
}

void FakeRobotIO::write(const RobotCommand& c) noexcept {
  last_ = c;
  ++writes_;
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (c.fault_reset && state[k] == DriveState::kFault) state[k] = DriveState::kDisabled;
    if (c.enable && state[k] != DriveState::kFault) state[k] = DriveState::kEnabled;
    if (c.disable && state[k] != DriveState::kFault) state[k] = DriveState::kDisabled;
    if (c.quick_stop && state[k] == DriveState::kEnabled) state[k] = DriveState::kQuickStop;
    if (c.disable && state[k] != DriveState::kFault) state[k] = DriveState::kDisabled;
    // A drive that is not enabled keeps its target at its position (enabling never jumps).
    if (state[k] != DriveState::kEnabled) {
      has_target_[k] = false;
    } else if (c.send_targets) {
      target_[k] = c.target_counts[k];
      has_target_[k] = true;
    }
  }
  if (c.fault_reset) {
    master_faulted = false;
    emcy_.fill(0);
    ++fault_resets_;
  }
  if (c.quick_stop) ++quick_stops_;
}

}  // namespace cdpr::controller::testing
