#include "cdpr/controller/canopen_robot_io.hpp"

#include <chrono>

namespace cdpr::controller {
namespace {

// Whether a PDO of `node` in `direction` maps index:sub.
bool maps(const canopen::NodeConfig& node, canopen::PdoDirection direction, std::uint16_t index,
          std::uint8_t sub) {
  const auto& pdos = direction == canopen::PdoDirection::kTpdo ? node.tpdos : node.rpdos;
  for (const canopen::PdoConfig& p : pdos) {
    for (const canopen::PdoEntry& e : p.entries) {
      if (e.object.index == index && e.object.sub == sub) return true;
    }
  }
  return false;
}

}  // namespace

Status check_safety_io(const SafetySettings& safety, const canopen::MasterConfig& network) {
  for (const EStopSource& s : safety.estop) {
    const EStopSourceKind& kind = estop_source_kinds()[static_cast<std::size_t>(s.kind)];
    const canopen::NodeConfig* n = network.find(static_cast<canopen::NodeId>(s.node));
    if (n == nullptr) {
      return Status::error(ErrorCode::kInvalidArgument, "%s: node %d is not in the CANopen network",
                           s.where.c_str(), s.node);
    }
    if (kind.drive && n->kind != canopen::NodeKind::kCia402Drive) {
      return Status::error(ErrorCode::kInvalidArgument, "%s: node %d (%s) is not a cia402 drive",
                           s.where.c_str(), s.node, n->name.c_str());
    }
    if (!maps(*n, canopen::PdoDirection::kTpdo, s.index, s.sub)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: no TPDO of node %d (%s) maps 0x%04X:%02X: add it to the node's "
                           "tpdo map in the network YAML",
                           s.where.c_str(), s.node, n->name.c_str(), unsigned{s.index},
                           unsigned{s.sub});
    }
  }
  const BrakeSettings& b = safety.brakes;
  if (b.control != BrakeControl::kOutput) return Status::success();
  for (const canopen::NodeConfig& n : network.nodes) {
    if (n.kind != canopen::NodeKind::kCia402Drive) continue;
    if (!maps(n, canopen::PdoDirection::kRpdo, b.index, b.sub)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: no RPDO of drive %d (%s) maps the brake output 0x%04X:%02X",
                           b.where.c_str(), int{n.id}, n.name.c_str(), unsigned{b.index},
                           unsigned{b.sub});
    }
  }
  return Status::success();
}

Result<std::unique_ptr<CanopenRobotIO>> CanopenRobotIO::create(canopen::Master& master,
                                                               const modbus::LaserSensor* laser,
                                                               const SafetySettings& safety) {
  if (master.drives().size() > static_cast<std::size_t>(kMaxAxes)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "the CANopen network has %d drives (at most %d supported)",
                         static_cast<int>(master.drives().size()), kMaxAxes);
  }
  CDPR_RETURN_IF_ERROR(check_safety_io(safety, master.config()));
  std::unique_ptr<CanopenRobotIO> io(new CanopenRobotIO(master, laser));
  CDPR_RETURN_IF_ERROR(io->bind_safety(safety));
  return io;
}

Status CanopenRobotIO::bind_safety(const SafetySettings& safety) {
  if (safety.estop.size() > safety_.size()) {
    return Status::error(ErrorCode::kInvalidArgument, "%zu e-stop sources (at most %zu)",
                         safety.estop.size(), safety_.size());
  }
  for (const EStopSource& s : safety.estop) {
    const auto id = static_cast<canopen::NodeId>(s.node);
    const canopen::ProcessImage* image = master_.image(id);
    const int slot = image != nullptr ? image->find({s.index, s.sub}) : -1;
    if (slot < 0) {
      return Status::error(ErrorCode::kInvalidArgument, "%s: 0x%04X:%02X of node %d not bound",
                           s.where.c_str(), unsigned{s.index}, unsigned{s.sub}, s.node);
    }
    SafetyInput& in = safety_[static_cast<std::size_t>(num_safety_++)];
    in.node = s.node;
    in.image = image;
    in.slot = static_cast<std::uint16_t>(slot);
    in.bit = s.bit;
    in.stale =
        std::chrono::duration_cast<canopen::Timestamp>(std::chrono::duration<double>(s.stale_s));
  }
  if (safety.brakes.control != BrakeControl::kOutput) return Status::success();
  brake_bit_ = safety.brakes.bit;
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    canopen::ProcessImage* image = master_.image(drives_[k]->node());
    const int slot = image != nullptr ? image->find({safety.brakes.index, safety.brakes.sub}) : -1;
    if (slot < 0) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: the brake output of drive %d not bound",
                           safety.brakes.where.c_str(), int{drives_[k]->node()});
    }
    brake_image_[k] = image;
    brake_slot_[k] = static_cast<std::uint16_t>(slot);
    // Applied from the first RPDO on: only the RT cycle releases a brake.
    image->set(brake_slot_[k], image->get(brake_slot_[k]) | (std::int64_t{1} << brake_bit_));
  }
  return Status::success();
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
  read_safety(r);
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

// A source is closed while its bit reads 1, its node is not lost and a TPDO of it is fresh.
void CanopenRobotIO::read_safety(RobotReading& r) noexcept {
  r.num_safety_inputs = num_safety_;
  r.safety_open = safety_open(now_);
}

std::uint32_t CanopenRobotIO::safety_open(canopen::Timestamp now) const noexcept {
  std::uint32_t open = 0;
  for (int j = 0; j < num_safety_; ++j) {
    const SafetyInput& in = safety_[static_cast<std::size_t>(j)];
    const auto id = static_cast<canopen::NodeId>(in.node);
    const canopen::Timestamp last = master_.last_tpdo(id);
    const bool fresh = last.count() != 0 && now - last <= in.stale;
    const bool lost = master_.nodes().state(id) == canopen::NmtState::kLost;
    const bool closed = ((in.image->get(in.slot) >> in.bit) & 1) != 0;
    if (!fresh || lost || !closed) open |= 1u << j;
  }
  return open;
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
  for (int i = 0; i < n_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (c.disable) drives_[k]->disable();
    canopen::ProcessImage* image = brake_image_[k];
    if (image == nullptr) continue;
    const auto bit = std::int64_t{1} << brake_bit_;
    const std::int64_t v = image->get(brake_slot_[k]);
    image->set(brake_slot_[k], c.release_brake[k] ? (v & ~bit) : (v | bit));
  }
  if (c.send_targets) {
    for (int i = 0; i < n_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      drives_[k]->set_target_counts(c.target_counts[k]);
    }
  }
  master_.transmit(now_);
}

}  // namespace cdpr::controller
