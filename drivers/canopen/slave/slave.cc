#include "cdpr/canopen/slave/slave.hpp"

#include <algorithm>
#include <cmath>

#include "cdpr/canopen/codes.hpp"

namespace cdpr::canopen::slave {

// ---------------------------------------------------------------------------------------------
// Object dictionary
// ---------------------------------------------------------------------------------------------

Entry& ObjectDictionary::add(ObjectAddress a, DataType type, std::int64_t value, Access access) {
  Entry& e = entries_[a.key()];
  e.data.assign(size_of(type), 0);
  put_le(e.data.data(), static_cast<std::uint32_t>(value), size_of(type));
  e.access = access;
  return e;
}

Entry& ObjectDictionary::add_string(ObjectAddress a, std::string_view value, Access access) {
  Entry& e = entries_[a.key()];
  e.data.assign(value.begin(), value.end());
  e.access = access;
  e.variable_size = true;
  return e;
}

bool ObjectDictionary::has_index(std::uint16_t index) const {
  auto it = entries_.lower_bound(std::uint32_t{index} << 8);
  return it != entries_.end() && (it->first >> 8) == index;
}

Entry* ObjectDictionary::find(ObjectAddress a) {
  auto it = entries_.find(a.key());
  return it == entries_.end() ? nullptr : &it->second;
}
const Entry* ObjectDictionary::find(ObjectAddress a) const {
  auto it = entries_.find(a.key());
  return it == entries_.end() ? nullptr : &it->second;
}

std::int64_t ObjectDictionary::get(ObjectAddress a, bool is_signed) const {
  const Entry* e = find(a);
  if (e == nullptr || e->data.empty() || e->data.size() > 4) return 0;
  const std::uint32_t raw = get_le(e->data.data(), e->data.size());
  if (!is_signed) return raw;
  const unsigned bits = 8u * static_cast<unsigned>(e->data.size());
  if (bits < 32 && (raw & (1u << (bits - 1)))) return std::int64_t{raw} - (std::int64_t{1} << bits);
  if (bits == 32) return static_cast<std::int32_t>(raw);
  return raw;
}

void ObjectDictionary::set(ObjectAddress a, std::int64_t value) {
  Entry* e = find(a);
  if (e == nullptr || e->data.size() > 4) return;
  put_le(e->data.data(), static_cast<std::uint32_t>(value), e->data.size());
}

std::uint32_t ObjectDictionary::read(ObjectAddress a, std::vector<std::uint8_t>& out) const {
  const Entry* e = find(a);
  if (e == nullptr) return has_index(a.index) ? abort_code::kNoSubIndex : abort_code::kNoObject;
  if (e->access == Access::kWo) return abort_code::kWriteOnly;
  out = e->data;
  return 0;
}

std::uint32_t ObjectDictionary::write(ObjectAddress a, std::span<const std::uint8_t> data) {
  Entry* e = find(a);
  if (e == nullptr) return has_index(a.index) ? abort_code::kNoSubIndex : abort_code::kNoObject;
  if (e->access == Access::kRo || e->access == Access::kConst) return abort_code::kReadOnly;
  if (!e->variable_size && data.size() != e->data.size()) {
    return data.size() > e->data.size() ? abort_code::kLengthTooHigh : abort_code::kLengthTooLow;
  }
  if (e->validate) {
    const std::uint32_t code = e->validate(data);
    if (code != 0) return code;
  }
  e->data.assign(data.begin(), data.end());
  if (e->on_write) e->on_write();
  return 0;
}

// ---------------------------------------------------------------------------------------------
// Slave node
// ---------------------------------------------------------------------------------------------

SlaveNode::SlaveNode(can::CanBus& bus, NodeId id) : bus_(bus), id_(id) {
  od_.add({0x1000, 0}, DataType::kU32, 0x00020192, Access::kRo);  // device type (402)
  od_.add({0x1001, 0}, DataType::kU8, 0, Access::kRo);
  od_.add_string({0x1008, 0}, "cdpr simulated CANopen node", Access::kConst);
  od_.add({0x1016, 0}, DataType::kU8, 1, Access::kRo);
  od_.add({0x1016, 1}, DataType::kU32, 0);
  od_.add({0x1017, 0}, DataType::kU16, 0);
  od_.add({0x1018, 0}, DataType::kU8, 4, Access::kRo);
  od_.add({0x1018, 1}, DataType::kU32, 0x00CD9001, Access::kRo);
  for (int n = 0; n < 4; ++n) {
    for (int dir = 0; dir < 2; ++dir) {
      const auto comm = static_cast<std::uint16_t>((dir == 0 ? 0x1400 : 0x1800) + n);
      const auto map = static_cast<std::uint16_t>((dir == 0 ? 0x1600 : 0x1A00) + n);
      const std::uint32_t cob = dir == 0 ? cob::rpdo(n + 1, id) : cob::tpdo(n + 1, id);
      od_.add({comm, 0}, DataType::kU8, dir == 0 ? 2 : 5, Access::kRo);
      od_.add({comm, 1}, DataType::kU32, cob::kInvalidBit | cob);
      od_.add({comm, 2}, DataType::kU8, 255);
      if (dir == 1) {
        od_.add({comm, 3}, DataType::kU16, 0);
        od_.add({comm, 5}, DataType::kU16, 0);
      }
      // Mapping may change only while the PDO is disabled (CiA 301, 7.5.2.36), and the count
      // only to entries that exist and fit 8 bytes.
      auto disabled = [this, comm] { return (od_.get({comm, 1}) & cob::kInvalidBit) != 0; };
      Entry& count = od_.add({map, 0}, DataType::kU8, 0);
      count.validate = [this, map, disabled](std::span<const std::uint8_t> d) -> std::uint32_t {
        if (!disabled()) return abort_code::kDeviceState;
        if (d[0] > 8) return abort_code::kValueTooHigh;
        unsigned bits = 0;
        for (std::uint8_t i = 1; i <= d[0]; ++i) {
          const auto v = static_cast<std::uint32_t>(od_.get({map, i}));
          const ObjectAddress obj{static_cast<std::uint16_t>(v >> 16),
                                  static_cast<std::uint8_t>(v >> 8)};
          const Entry* e = od_.find(obj);
          if (e == nullptr || e->variable_size || e->data.size() * 8 != (v & 0xFF)) {
            return abort_code::kNotMappable;
          }
          bits += v & 0xFF;
        }
        return bits > 64 ? abort_code::kPdoLength : 0;
      };
      for (std::uint8_t s = 1; s <= 8; ++s) {
        Entry& e = od_.add({map, s}, DataType::kU32, 0);
        e.validate = [this, map, disabled](std::span<const std::uint8_t>) -> std::uint32_t {
          if (!disabled() || od_.get({map, 0}) != 0) return abort_code::kDeviceState;
          return 0;
        };
      }
    }
  }
}

void SlaveNode::send(const can::Frame& f) {
  if (faults_.silent) return;
  (void)bus_.send(f);
}

void SlaveNode::power_on(Timestamp now) {
  on_reset_application();
  reset_communication(now);
}

void SlaveNode::reset_communication(Timestamp now) {
  sdo_state_ = SdoState::kIdle;
  held_sdo_.clear();
  rpdos_.clear();
  tpdos_.clear();
  master_heard_ = false;
  master_lost_ = false;
  state_ = NmtState::kPreOperational;
  send(heartbeat_frame(id_, NmtState::kBootUp));
  next_heartbeat_ = now;
}

void SlaveNode::send_emcy(std::uint16_t code, std::uint8_t error_register,
                          std::array<std::uint8_t, 5> manufacturer) {
  can::Frame f = make_frame(cob::kEmcy + id_, 8);
  put_u16(&f.data[0], code);
  f.data[2] = error_register;
  std::copy(manufacturer.begin(), manufacturer.end(), f.data.begin() + 3);
  od_.set({0x1001, 0}, error_register);
  send(f);
}

void SlaveNode::step(Timestamp now) {
  now_ = now;
  can::Frame f;
  while (bus_.receive(f, std::chrono::nanoseconds(0)).ok()) handle(f, now);
  // A stalled SDO server catches up: held requests in order.
  while (!held_sdo_.empty() && held_sdo_.front().due <= now) {
    const can::Frame held = held_sdo_.front().frame;
    held_sdo_.pop_front();
    handle_sdo(held);
  }
  if (state_ == NmtState::kUnknown) return;
  const auto hb_ms = od_.get({0x1017, 0});
  if (hb_ms > 0 && now >= next_heartbeat_) {
    send(heartbeat_frame(id_, state_));
    next_heartbeat_ = now + std::chrono::milliseconds(hb_ms);
  }
  const auto consumer = static_cast<std::uint32_t>(od_.get({0x1016, 1}));
  const auto timeout = std::chrono::milliseconds(consumer & 0xFFFF);
  if (timeout.count() > 0 && master_heard_ && !master_lost_ && now - master_last_ > timeout) {
    master_lost_ = true;
    send_emcy(0x8130, 0x11);
    on_master_lost(now);
  }
  on_step(now);
}

void SlaveNode::handle(const can::Frame& f, Timestamp now) {
  if (f.error || f.extended || f.rtr || state_ == NmtState::kUnknown) return;
  if (f.id == cob::kNmt && f.dlc >= 2 && (f.data[1] == 0 || f.data[1] == id_)) {
    switch (static_cast<NmtCommand>(f.data[0])) {
      case NmtCommand::kStart:
        build_pdos();
        state_ = NmtState::kOperational;
        break;
      case NmtCommand::kStop:
        state_ = NmtState::kStopped;
        break;
      case NmtCommand::kEnterPreOperational:
        state_ = NmtState::kPreOperational;
        break;
      case NmtCommand::kResetNode:
        on_reset_application();
        reset_communication(now);
        break;
      case NmtCommand::kResetCommunication:
        reset_communication(now);
        break;
    }
    return;
  }
  const auto consumer = static_cast<std::uint32_t>(od_.get({0x1016, 1}));
  const auto watched = static_cast<NodeId>((consumer >> 16) & 0x7F);
  if (watched != 0 && f.id == cob::kHeartbeat + watched) {
    master_heard_ = true;
    master_last_ = now;
    return;
  }
  if (state_ == NmtState::kStopped) return;  // only NMT and heartbeats in STOPPED
  if (f.id == cob::kSdoRx + id_) {
    receive_sdo(f, now);
    return;
  }
  if (state_ != NmtState::kOperational) return;
  if (f.id == cob::kSync) {
    ++syncs_;
    bool applied = false;
    for (std::size_t i = 0; i < rpdos_.size(); ++i) {
      if (rpdos_[i].has_pending && rpdos_[i].type <= 240) {
        apply_rpdo(i, now);
        applied = true;
      }
    }
    if (applied) on_rpdo_applied(now);
    on_sync(now);
    send_tpdos();
    return;
  }
  for (std::size_t i = 0; i < rpdos_.size(); ++i) {
    Pdo& p = rpdos_[i];
    if (f.id != p.cob_id) continue;
    std::size_t need = 0;
    for (const auto& m : p.map) need += m.second;
    if (f.dlc < need) {
      send_emcy(0x8210, 0x11);
      return;
    }
    p.pending = f.data;
    p.has_pending = true;
    if (p.type >= 254) {
      apply_rpdo(i, now);
      on_rpdo_applied(now);
    }
    return;
  }
}

void SlaveNode::apply_rpdo(std::size_t i, Timestamp) {
  Pdo& p = rpdos_[i];
  std::size_t off = 0;
  for (const auto& [obj, bytes] : p.map) {
    od_.set(obj, get_le(&p.pending[off], bytes));
    off += bytes;
  }
  p.has_pending = false;
  ++rpdos_applied_;
}

void SlaveNode::send_tpdos() {
  for (Pdo& p : tpdos_) {
    if (p.type == 0 || p.type > 240) continue;
    if (++p.sync_count < p.type) continue;
    p.sync_count = 0;
    can::Frame f = make_frame(p.cob_id, 0);
    std::size_t off = 0;
    for (const auto& [obj, bytes] : p.map) {
      put_le(&f.data[off], static_cast<std::uint32_t>(od_.get(obj)), bytes);
      off += bytes;
    }
    f.dlc = static_cast<std::uint8_t>(off);
    send(f);
  }
}

void SlaveNode::build_pdos() {
  rpdos_.clear();
  tpdos_.clear();
  for (int dir = 0; dir < 2; ++dir) {
    for (int n = 0; n < 4; ++n) {
      const auto comm = static_cast<std::uint16_t>((dir == 0 ? 0x1400 : 0x1800) + n);
      const auto map = static_cast<std::uint16_t>((dir == 0 ? 0x1600 : 0x1A00) + n);
      const auto cob_id = static_cast<std::uint32_t>(od_.get({comm, 1}));
      if (cob_id & cob::kInvalidBit) continue;
      Pdo p;
      p.cob_id = cob_id & 0x7FF;
      p.type = static_cast<std::uint8_t>(od_.get({comm, 2}));
      const auto count = od_.get({map, 0});
      for (std::uint8_t s = 1; s <= count; ++s) {
        const auto v = static_cast<std::uint32_t>(od_.get({map, s}));
        p.map.emplace_back(
            ObjectAddress{static_cast<std::uint16_t>(v >> 16), static_cast<std::uint8_t>(v >> 8)},
            static_cast<std::uint8_t>((v & 0xFF) / 8));
      }
      (dir == 0 ? rpdos_ : tpdos_).push_back(std::move(p));
    }
  }
}

void SlaveNode::sdo_send(can::Frame& f) {
  f.id = cob::kSdoTx + id_;
  f.dlc = 8;
  send(f);
}

void SlaveNode::sdo_abort(ObjectAddress a, std::uint32_t code) {
  can::Frame f;
  f.data[0] = 0x80;
  put_u16(&f.data[1], a.index);
  f.data[3] = a.sub;
  put_u32(&f.data[4], code);
  sdo_state_ = SdoState::kIdle;
  sdo_send(f);
}

void SlaveNode::receive_sdo(const can::Frame& rx, Timestamp now) {
  if (rx.dlc < 8) return;
  if (faults_.delay_sdo_answers > 0) {
    if (faults_.delay_sdo_after > 0) {
      --faults_.delay_sdo_after;
    } else {
      --faults_.delay_sdo_answers;
      held_sdo_.push_back({now + faults_.sdo_answer_delay, rx});
      return;
    }
  }
  // Behind a held request: keep the order.
  if (!held_sdo_.empty()) {
    held_sdo_.push_back({held_sdo_.back().due, rx});
    return;
  }
  handle_sdo(rx);
}

void SlaveNode::handle_sdo(const can::Frame& rx) {
  if (rx.dlc < 8) return;
  if (faults_.drop_sdo_requests > 0) {
    --faults_.drop_sdo_requests;
    return;
  }
  ++sdo_requests_;
  const std::uint8_t cmd = rx.data[0];
  const ObjectAddress mux{get_u16(&rx.data[1]), rx.data[3]};
  can::Frame tx;
  switch (cmd & 0xE0) {
    case 0x20: {  // initiate download
      auto forced = faults_.abort_on.find(mux.key());
      if (forced != faults_.abort_on.end()) return sdo_abort(mux, forced->second);
      put_u16(&tx.data[1], mux.index);
      tx.data[3] = mux.sub;
      tx.data[0] = 0x60;
      if (cmd & 0x02) {  // expedited
        const std::size_t n = (cmd & 0x01) ? 4u - ((cmd >> 2) & 0x03u) : 4u;
        const std::uint32_t code = od_.write(mux, std::span<const std::uint8_t>(&rx.data[4], n));
        if (code != 0) return sdo_abort(mux, code);
        sdo_state_ = SdoState::kIdle;
        return sdo_send(tx);
      }
      if (od_.find(mux) == nullptr) {
        return sdo_abort(
            mux, od_.has_index(mux.index) ? abort_code::kNoSubIndex : abort_code::kNoObject);
      }
      sdo_state_ = SdoState::kDownload;
      sdo_addr_ = mux;
      sdo_buf_.clear();
      sdo_toggle_ = false;
      return sdo_send(tx);
    }
    case 0x00: {  // download segment
      if (sdo_state_ != SdoState::kDownload) return sdo_abort(mux, abort_code::kCommandSpecifier);
      if (((cmd & 0x10) != 0) != sdo_toggle_) return sdo_abort(sdo_addr_, abort_code::kToggleBit);
      const std::size_t n = 7u - ((cmd >> 1) & 0x07u);
      sdo_buf_.insert(sdo_buf_.end(), rx.data.begin() + 1,
                      rx.data.begin() + 1 + static_cast<std::ptrdiff_t>(n));
      const bool bad = faults_.bad_toggle;
      faults_.bad_toggle = false;
      tx.data[0] = static_cast<std::uint8_t>(0x20 | ((sdo_toggle_ != bad) ? 0x10 : 0));
      sdo_toggle_ = !sdo_toggle_;
      if (cmd & 0x01) {
        const std::uint32_t code = od_.write(sdo_addr_, sdo_buf_);
        if (code != 0) return sdo_abort(sdo_addr_, code);
        sdo_state_ = SdoState::kIdle;
      }
      return sdo_send(tx);
    }
    case 0x40: {  // initiate upload
      auto forced = faults_.abort_on.find(mux.key());
      if (forced != faults_.abort_on.end()) return sdo_abort(mux, forced->second);
      std::vector<std::uint8_t> data;
      const std::uint32_t code = od_.read(mux, data);
      if (code != 0) return sdo_abort(mux, code);
      put_u16(&tx.data[1], mux.index);
      tx.data[3] = mux.sub;
      if (data.size() <= 4 && !data.empty()) {
        tx.data[0] = static_cast<std::uint8_t>(0x43 | ((4 - data.size()) << 2));
        std::copy(data.begin(), data.end(), tx.data.begin() + 4);
        sdo_state_ = SdoState::kIdle;
        return sdo_send(tx);
      }
      tx.data[0] = 0x41;
      put_u32(&tx.data[4], static_cast<std::uint32_t>(data.size()));
      sdo_state_ = SdoState::kUpload;
      sdo_addr_ = mux;
      sdo_buf_ = std::move(data);
      sdo_offset_ = 0;
      sdo_toggle_ = false;
      return sdo_send(tx);
    }
    case 0x60: {  // upload segment
      if (sdo_state_ != SdoState::kUpload) return sdo_abort(mux, abort_code::kCommandSpecifier);
      if (((cmd & 0x10) != 0) != sdo_toggle_) return sdo_abort(sdo_addr_, abort_code::kToggleBit);
      const std::size_t k = std::min<std::size_t>(7, sdo_buf_.size() - sdo_offset_);
      const bool last = sdo_offset_ + k == sdo_buf_.size();
      const bool bad = faults_.bad_toggle;
      faults_.bad_toggle = false;
      tx.data[0] = static_cast<std::uint8_t>(((sdo_toggle_ != bad) ? 0x10 : 0) | ((7 - k) << 1) |
                                             (last ? 1 : 0));
      std::copy_n(sdo_buf_.begin() + static_cast<std::ptrdiff_t>(sdo_offset_), k,
                  tx.data.begin() + 1);
      sdo_offset_ += k;
      sdo_toggle_ = !sdo_toggle_;
      if (last) sdo_state_ = SdoState::kIdle;
      return sdo_send(tx);
    }
    case 0x80:  // abort from the client
      sdo_state_ = SdoState::kIdle;
      return;
    default:
      return sdo_abort(mux, abort_code::kCommandSpecifier);
  }
}

// ---------------------------------------------------------------------------------------------
// CiA 402 drive model
// ---------------------------------------------------------------------------------------------

Drive402::Drive402(can::CanBus& bus, NodeId id, std::int32_t initial_position)
    : SlaveNode(bus, id), position_(initial_position) {
  auto& d = od();
  d.add({0x6007, 0}, DataType::kI16, 1);
  Entry& cw = d.add({0x6040, 0}, DataType::kU16, 0);
  cw.on_write = [this] { apply_controlword(static_cast<std::uint16_t>(od().get({0x6040, 0}))); };
  d.add({0x6041, 0}, DataType::kU16, 0, Access::kRo);
  d.add({0x605A, 0}, DataType::kI16, 2);
  Entry& mode = d.add({0x6060, 0}, DataType::kI8, 0);
  mode.validate = [](std::span<const std::uint8_t> v) -> std::uint32_t {
    const auto m = static_cast<std::int8_t>(v[0]);
    return (m == 0 || m == 1 || m == 6 || m == 8) ? 0 : abort_code::kValueRange;
  };
  mode.on_write = [this] {
    if (ignore_mode_switch_) return;
    if (mode_delay_.count() <= 0) {
      od().set({0x6061, 0}, od().get({0x6060, 0}));
      publish();
      return;
    }
    mode_pending_ = true;
    mode_due_ = now() + mode_delay_;
  };
  d.add({0x6061, 0}, DataType::kI8, 0, Access::kRo);
  d.add({0x6064, 0}, DataType::kI32, position_, Access::kRo);
  d.add({0x606C, 0}, DataType::kI32, 0, Access::kRo);
  d.add({0x607A, 0}, DataType::kI32, 0);
  d.add({0x607C, 0}, DataType::kI32, 0);
  d.add({0x6081, 0}, DataType::kU32, 0);
  d.add({0x6083, 0}, DataType::kU32, 0);
  d.add({0x6084, 0}, DataType::kU32, 0);
  d.add({0x6098, 0}, DataType::kI8, 37);
  d.add({0x60C2, 0}, DataType::kU8, 2, Access::kRo);
  Entry& ip = d.add({0x60C2, 1}, DataType::kU8, 4);
  ip.on_write = [this] {
    sync_period_s_ = static_cast<double>(od().get({0x60C2, 1})) *
                     std::pow(10.0, static_cast<double>(od().get({0x60C2, 2}, true)));
  };
  Entry& ipi = d.add({0x60C2, 2}, DataType::kI8, -3);
  ipi.on_write = ip.on_write;
  publish();
}

void Drive402::on_reset_application() {
  s_ = S::kNotReady;
  last_cw_ = 0;
  mode_pending_ = false;
  homing_running_ = false;
  publish();
}

void Drive402::on_step(Timestamp now) {
  bool changed = false;
  if (mode_pending_ && now >= mode_due_) {
    mode_pending_ = false;
    od().set({0x6061, 0}, od().get({0x6060, 0}));
    changed = true;
  }
  if (homing_running_ && now >= homing_until_) {
    homing_running_ = false;
    position_ = static_cast<std::int32_t>(od().get({0x607C, 0}, true));
    homing_attained_ = true;
    changed = true;
  }
  if (changed) publish();
}

void Drive402::inject_fault(std::uint16_t emcy_code) {
  s_ = S::kFaultReaction;
  fault_reaction_syncs_ = 1;
  send_emcy(emcy_code, 0x01);
  publish();
}

void Drive402::on_master_lost(Timestamp) {
  switch (od().get({0x6007, 0}, true)) {
    case 1:
      inject_fault(0x8130);
      break;
    case 2:
      s_ = S::kSwitchOnDisabled;
      break;
    case 3:
      if (s_ == S::kEnabled) s_ = S::kQuickStop;
      break;
    default:
      break;
  }
  publish();
}

void Drive402::apply_controlword(std::uint16_t cw) {
  const std::uint16_t prev = last_cw_;
  last_cw_ = cw;
  if (ignore_cw_) return;
  const bool voltage_off = (cw & 0x02) == 0;
  const bool quick_stop = (cw & 0x06) == 0x02;
  const std::uint16_t cmd = cw & 0x8F;
  const S before = s_;
  switch (s_) {
    case S::kNotReady:
      break;
    case S::kSwitchOnDisabled:
      if ((cw & 0x87) == 0x06) s_ = S::kReady;
      break;
    case S::kReady:
      if (voltage_off || quick_stop) {
        s_ = S::kSwitchOnDisabled;
      } else if ((cw & 0x8F) == 0x07 || cmd == 0x0F) {
        s_ = S::kSwitchedOn;
      }
      break;
    case S::kSwitchedOn:
      if (voltage_off || quick_stop) {
        s_ = S::kSwitchOnDisabled;
      } else if (cmd == 0x06) {
        s_ = S::kReady;
      } else if (cmd == 0x0F) {
        s_ = S::kEnabled;
      }
      break;
    case S::kEnabled:
      if (voltage_off) {
        s_ = S::kSwitchOnDisabled;
      } else if (quick_stop) {
        s_ = S::kQuickStop;
      } else if (cmd == 0x06) {
        s_ = S::kReady;
      } else if (cmd == 0x07) {
        s_ = S::kSwitchedOn;
      }
      break;
    case S::kQuickStop:
      if (voltage_off) s_ = S::kSwitchOnDisabled;
      break;
    case S::kFaultReaction:
      break;
    case S::kFault:
      if ((cw & 0x80) && !(prev & 0x80)) s_ = S::kSwitchOnDisabled;  // rising edge only
      break;
  }
  if (s_ == S::kEnabled && before != S::kEnabled) {
    ++enable_count_;
    enable_sync_pending_ = true;
  }
  const auto mode = od().get({0x6061, 0}, true);
  if (s_ == S::kEnabled && before == S::kEnabled) {
    if (mode == 1) {  // profile position: new set-point on the rising edge of bit 4
      if ((cw & 0x10) && !(prev & 0x10) && !set_point_ack_) {
        const auto t = static_cast<std::int32_t>(od().get({0x607A, 0}, true));
        pp_target_ = (cw & 0x40) ? position_ + t : t;
        pp_moving_ = true;
        set_point_ack_ = true;
      }
      if (!(cw & 0x10)) set_point_ack_ = false;
    } else if (mode == 6 && (cw & 0x10) && !(prev & 0x10)) {
      ++homings_;
      homing_attained_ = homing_error_ = false;
      const auto method = od().get({0x6098, 0}, true);
      if (method != 35 && method != 37) {
        homing_error_ = true;  // the model knows only "the current position is home"
      } else if (homing_duration_.count() <= 0) {
        position_ = static_cast<std::int32_t>(od().get({0x607C, 0}, true));
        homing_attained_ = true;
      } else {
        homing_running_ = true;
        homing_until_ = now() + homing_duration_;
      }
    }
  }
  if (s_ != S::kEnabled) {
    set_point_ack_ = false;
    pp_moving_ = false;
    homing_running_ = false;  // interrupted (attained stays false)
  }
  publish();
}

void Drive402::on_rpdo_applied(Timestamp) {
  apply_controlword(static_cast<std::uint16_t>(od().get({0x6040, 0})));
}

void Drive402::on_sync(Timestamp) {
  if (s_ == S::kNotReady) s_ = S::kSwitchOnDisabled;
  if (s_ == S::kFaultReaction && --fault_reaction_syncs_ <= 0) s_ = S::kFault;
  if (s_ == S::kQuickStop && od().get({0x605A, 0}, true) < 5) s_ = S::kSwitchOnDisabled;
  const auto mode = od().get({0x6061, 0}, true);
  if (s_ == S::kEnabled) {
    if (mode == 8) {
      const auto target = static_cast<std::int32_t>(od().get({0x607A, 0}, true));
      const std::int64_t jump = std::llabs(std::int64_t{target} - position_);
      // The first SYNC after an enable shows whether the master commanded a jump.
      if (enable_sync_pending_) {
        if (jump > max_jump_on_enable_) max_jump_on_enable_ = jump;
        enable_sync_pending_ = false;
      }
      position_ = target;
    } else if (mode == 1 && pp_moving_) {
      const double v = static_cast<double>(od().get({0x6081, 0}));
      const auto step =
          v > 0 ? static_cast<std::int64_t>(std::ceil(v * sync_period_s_)) : std::int64_t{1} << 40;
      const std::int64_t d = std::int64_t{pp_target_} - position_;
      position_ = static_cast<std::int32_t>(
          std::llabs(d) <= step ? pp_target_ : position_ + (d > 0 ? step : -step));
      if (position_ == pp_target_) pp_moving_ = false;
    }
  }
  publish();
}

void Drive402::publish() {
  std::uint16_t sw = 0;
  switch (s_) {
    case S::kNotReady:
      sw = 0x0000;
      break;
    case S::kSwitchOnDisabled:
      sw = 0x0040;
      break;
    case S::kReady:
      sw = 0x0031;
      break;
    case S::kSwitchedOn:
      sw = 0x0033;
      break;
    case S::kEnabled:
      sw = 0x0037;
      break;
    case S::kQuickStop:
      sw = 0x0017;
      break;
    case S::kFaultReaction:
      sw = 0x001F;
      break;
    case S::kFault:
      sw = 0x0008;
      break;
  }
  sw |= 0x0200;  // remote
  const auto mode = od().get({0x6061, 0}, true);
  if (mode == 1) {
    if (set_point_ack_) sw |= 0x1000;
    if (!pp_moving_) sw |= 0x0400;
  } else if (mode == 6) {
    if (homing_attained_) sw |= 0x1400;
    if (homing_error_) sw |= 0x2000;
  } else {
    sw |= 0x0400;
  }
  statusword_ = sw;
  od().set({0x6041, 0}, sw);
  od().set({0x6064, 0}, position_);
}

}  // namespace cdpr::canopen::slave
