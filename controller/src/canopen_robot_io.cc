#include "cdpr/controller/canopen_robot_io.hpp"

#include <chrono>

namespace cdpr::controller {

Result<std::unique_ptr<CanopenRobotIO>> CanopenRobotIO::create(canopen::Master& master,
                                                               const modbus::LaserSensor* laser) {
  if (master.drives().size() > static_cast<std::size_t>(kMaxAxes)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "the CANopen network has %d drives (at most %d supported)",
                         static_cast<int>(master.drives().size()), kMaxAxes);
  }
  return std::unique_ptr<CanopenRobotIO>(new CanopenRobotIO(master, laser));
}

CanopenRobotIO::CanopenRobotIO(canopen::Master& master, const modbus::LaserSensor* laser)
    : master_(master), laser_(laser), n_(static_cast<int>(master.drives().size())) {
  for (int i = 0; i < n_; ++i) drives_[static_cast<std::size_t>(i)] = &master.drives()[i];
  if (!master.force_sensors().empty()) force_ = &master.force_sensors()[0];
}

Status CanopenRobotIO::fits(const RobotModel& model) const {
  const int m = model.num_cables();
  if (n_ != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "the CANopen network has %d drives, the robot '%s' has %d cables", n_,
                         model.name.c_str(), m);
  }
  if (force_ != nullptr && static_cast<int>(force_->channels()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "force node %d has %d channels, the robot has %d cables",
                         int{force_->node()}, static_cast<int>(force_->channels()), m);
  }
  return Status::success();
}

void CanopenRobotIO::read(canopen::Timestamp now, RobotReading& r) noexcept {
  master_.receive(now);
  now_ = now;
  r.now = now;
  r.num_axes = n_;
  read_health(r);  // first: the EMCY codes of the drives come with the events
  read_drives(r);
  read_tensions(r);
  r.have_laser = laser_ != nullptr;
  if (laser_ != nullptr) {
    const modbus::LaserReading l = laser_->latest();
    r.laser_valid = l.ok();
    r.laser_m = l.distance_m;
    r.laser_stamp_ns = l.stamp_ns;
  }
  previous_ = now;
  have_previous_ = true;
}

void CanopenRobotIO::read_drives(RobotReading& r) noexcept {
  const double dt = std::chrono::duration<double>(now_ - previous_).count();
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const canopen::Drive& d = *drives_[k];
    DriveReading& out = r.drives[k];
    out.node = d.node();
    out.received = d.received();
    out.enabled = d.enabled();
    out.fault = d.supervisor().in_fault();
    out.statusword = d.statusword();
    out.emcy_code = emcy_[k];
    out.actual_counts = d.actual_counts();
    out.velocity = have_previous_ && dt > 0.0
                       ? static_cast<double>(out.actual_counts - previous_counts_[k]) / dt
                       : 0.0;
    previous_counts_[k] = out.actual_counts;
  }
}

void CanopenRobotIO::read_tensions(RobotReading& r) noexcept {
  r.have_tensions = force_ != nullptr;
  if (force_ == nullptr) return;
  const std::uint64_t pdos = force_->pdos_received();
  r.tensions_fresh = pdos != force_pdos_;
  force_pdos_ = pdos;
  if (r.tensions_fresh) tensions_time_ = now_;
  r.tension_updates = pdos;
  r.tensions_time = tensions_time_;
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    r.raw[k] = force_->raw(k);
    r.gain[k] = force_->gain(k);
    r.tensions[k] = force_->tension(k);
  }
}

void CanopenRobotIO::read_health(RobotReading& r) noexcept {
  r.master_faulted = master_.faulted();
  r.bus_off = master_.bus().state() == canopen::BusState::kBusOff;
  r.lost_node = 0;
  for (const canopen::NodeConfig& c : master_.config().nodes) {
    if (master_.nodes().state(c.id) == canopen::NmtState::kLost) {
      r.lost_node = c.id;
      break;
    }
  }
  r.num_events = 0;
  canopen::Event e;
  while (r.num_events < RobotReading::kMaxEvents && master_.events().pop(e)) {
    r.events[static_cast<std::size_t>(r.num_events++)] = e;
    if (e.type != canopen::EventType::kEmcy) continue;
    for (int i = 0; i < n_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (drives_[k]->node() == e.node) emcy_[k] = e.emcy.code;
    }
  }
}

void CanopenRobotIO::write(const RobotCommand& c) noexcept {
  if (c.fault_reset) {
    master_.clear_fault();
    emcy_.fill(0);
    for (int i = 0; i < n_; ++i) {
      canopen::Drive& d = *drives_[static_cast<std::size_t>(i)];
      if (d.state() == canopen::cia402::State::kFault) d.reset_fault();
    }
  }
  if (c.enable) {
    for (int i = 0; i < n_; ++i) drives_[static_cast<std::size_t>(i)]->enable();
  }
  if (c.disable) {
    for (int i = 0; i < n_; ++i) drives_[static_cast<std::size_t>(i)]->disable();
  }
  if (c.quick_stop) master_.quick_stop_all();
  if (c.send_targets) {
    for (int i = 0; i < n_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      drives_[k]->set_target_counts(c.target_counts[k]);
    }
  }
  master_.transmit(now_);
}

}  // namespace cdpr::controller
