#include "cdpr/canopen/slave/slave.hpp"

#include <algorithm>
#include <cmath>

#include "cdpr/canopen/codes.hpp"
#include "cdpr/canopen/eds.hpp"

namespace cdpr::canopen::slave {

// ---------------------------------------------------------------------------------------------
// Object dictionary
// ---------------------------------------------------------------------------------------------

Entry& ObjectDictionary::add(ObjectAddress a, DataType type, std::int64_t value, Access access) {
  Entry& e = entries_[a.key()];
  e.data.assign(size_of(type), 0);
  put_le(e.data.data(), static_cast<std::uint32_t>(value), size_of(type));
  e.default_data = e.data;
  e.access = access;
  e.variable_size = false;
  return e;
}

Entry& ObjectDictionary::add_raw(ObjectAddress a, std::vector<std::uint8_t> bytes, Access access) {
  Entry& e = entries_[a.key()];
  e.data = std::move(bytes);
  e.default_data = e.data;
  e.access = access;
  e.variable_size = false;
  return e;
}

Entry& ObjectDictionary::add_string(ObjectAddress a, std::string_view value, Access access) {
  Entry& e = entries_[a.key()];
  e.data.assign(value.begin(), value.end());
  e.default_data = e.data;
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

void ObjectDictionary::set_default(ObjectAddress a, std::int64_t value) {
  set(a, value);
  if (Entry* e = find(a)) e->default_data = e->data;
}

void ObjectDictionary::restore_defaults(std::uint16_t lo, std::uint16_t hi) {
  for (auto& [key, e] : entries_) {
    const auto index = static_cast<std::uint16_t>(key >> 8);
    if (index >= lo && index <= hi) e.data = e.default_data;
  }
}

std::vector<ObjectAddress> ObjectDictionary::addresses() const {
  std::vector<ObjectAddress> out;
  out.reserve(entries_.size());
  for (const auto& [key, e] : entries_) {
    out.push_back({static_cast<std::uint16_t>(key >> 8), static_cast<std::uint8_t>(key & 0xFF)});
  }
  return out;
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
  // COB-ID EMCY (CiA 301, 7.5.2.16): bit 31 set = no EMCY; the CAN-ID may change only while
  // bit 31 is set; 29-bit ids are not supported.
  Entry& emcy = od_.add({0x1014, 0}, DataType::kU32, cob::kEmcy + id);
  emcy.validate = [this](std::span<const std::uint8_t> d) -> std::uint32_t {
    const std::uint32_t v = get_u32(d.data());
    const auto old = static_cast<std::uint32_t>(od_.get({0x1014, 0}));
    if (v & 0x3FFFF800u) return abort_code::kValueRange;
    if (!(old & cob::kInvalidBit) && !(v & cob::kInvalidBit) && (v & 0x7FF) != (old & 0x7FF)) {
      return abort_code::kValueRange;
    }
    return 0;
  };
  od_.add({0x1016, 0}, DataType::kU8, 1, Access::kRo);
  od_.add({0x1016, 1}, DataType::kU32, 0);
  od_.add({0x1017, 0}, DataType::kU16, 0);
  od_.add({0x1018, 0}, DataType::kU8, 4, Access::kRo);
  od_.add({0x1018, 1}, DataType::kU32, 0x00CD9001, Access::kRo);
  // Synchronous counter overflow value (CiA 301, 7.5.2.22): 0 = SYNC without data, 2..240 =
  // SYNC with a counter byte. Writable only while the communication cycle period is 0.
  Entry& overflow = od_.add({0x1019, 0}, DataType::kU8, 0);
  overflow.validate = [this](std::span<const std::uint8_t> d) -> std::uint32_t {
    if (d[0] == 1 || d[0] > 240) return abort_code::kValueRange;
    if (od_.find({0x1006, 0}) != nullptr && od_.get({0x1006, 0}) != 0) {
      return abort_code::kDeviceState;
    }
    return 0;
  };
  for (int n = 0; n < kPdos; ++n) {
    for (int dir = 0; dir < 2; ++dir) {
      const bool tpdo = dir == 1;
      const auto comm = static_cast<std::uint16_t>((dir == 0 ? 0x1400 : 0x1800) + n);
      const auto map = static_cast<std::uint16_t>((dir == 0 ? 0x1600 : 0x1A00) + n);
      const std::uint32_t cob = dir == 0 ? cob::rpdo(n + 1, id) : cob::tpdo(n + 1, id);
      auto refresh = [this, tpdo, n] { refresh_pdo(tpdo, n); };
      auto disabled = [this, comm] { return (od_.get({comm, 1}) & cob::kInvalidBit) != 0; };
      od_.add({comm, 0}, DataType::kU8, dir == 0 ? 2 : 5, Access::kRo);
      // COB-ID (CiA 301, 7.5.2.35/37): bit 31 creates (0) or deletes (1) the PDO at once; bits
      // 0..29 may change only while the PDO is deleted; 29-bit ids are not supported.
      Entry& cob_entry = od_.add({comm, 1}, DataType::kU32, cob::kInvalidBit | cob);
      cob_entry.validate = [this, comm](std::span<const std::uint8_t> d) -> std::uint32_t {
        const std::uint32_t v = get_u32(d.data());
        const auto old = static_cast<std::uint32_t>(od_.get({comm, 1}));
        if (v & 0x3FFFF800u) return abort_code::kValueRange;
        const bool was_valid = !(old & cob::kInvalidBit);
        const bool valid = !(v & cob::kInvalidBit);
        if (was_valid && valid && (v & 0x3FFFFFFFu) != (old & 0x3FFFFFFFu)) {
          return abort_code::kValueRange;
        }
        return 0;
      };
      cob_entry.on_write = refresh;
      // Transmission type: 241..251 reserved, 252/253 (RTR only) not supported.
      Entry& type = od_.add({comm, 2}, DataType::kU8, 255);
      type.validate = [](std::span<const std::uint8_t> d) -> std::uint32_t {
        return d[0] > 240 && d[0] < 254 ? abort_code::kValueRange : 0;
      };
      type.on_write = refresh;
      if (tpdo) {
        // The inhibit time may change only while the PDO is deleted.
        Entry& inhibit = od_.add({comm, 3}, DataType::kU16, 0);
        inhibit.validate = [disabled](std::span<const std::uint8_t>) -> std::uint32_t {
          return disabled() ? 0 : abort_code::kValueRange;
        };
        inhibit.on_write = refresh;
        Entry& timer = od_.add({comm, 5}, DataType::kU16, 0);
        timer.on_write = refresh;
      }
      // Mapping may change only while the PDO is disabled (CiA 301, 7.5.2.36), and the count
      // only to entries that exist, may be mapped (RPDO: and written) and fit 8 bytes.
      Entry& count = od_.add({map, 0}, DataType::kU8, 0);
      count.validate = [this, map, tpdo,
                        disabled](std::span<const std::uint8_t> d) -> std::uint32_t {
        if (!disabled()) return abort_code::kDeviceState;
        if (d[0] > 8) return abort_code::kValueTooHigh;
        unsigned bits = 0;
        for (std::uint8_t i = 1; i <= d[0]; ++i) {
          const auto v = static_cast<std::uint32_t>(od_.get({map, i}));
          const ObjectAddress obj{static_cast<std::uint16_t>(v >> 16),
                                  static_cast<std::uint8_t>(v >> 8)};
          const Entry* e = od_.find(obj);
          if (e == nullptr || e->variable_size || !e->mappable ||
              e->data.size() * 8 != (v & 0xFF)) {
            return abort_code::kNotMappable;
          }
          if (!tpdo && (e->access == Access::kRo || e->access == Access::kConst)) {
            return abort_code::kNotMappable;
          }
          bits += v & 0xFF;
        }
        return bits > 64 ? abort_code::kPdoLength : 0;
      };
      count.on_write = refresh;
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

Status SlaveNode::load_eds(const eds::Eds& description) {
  std::map<std::uint32_t, bool> described;
  for (const auto& [index, object] : description.objects()) {
    if (index < 0x1000) continue;  // data type definitions
    for (const eds::SubObject& sub : object.subs) {
      const int size = eds::type_size(sub.data_type);
      Access access = Access::kRw;
      switch (sub.access) {
        case eds::Access::kRo:
          access = Access::kRo;
          break;
        case eds::Access::kWo:
          access = Access::kWo;
          break;
        case eds::Access::kConst:
          access = Access::kConst;
          break;
        default:
          access = Access::kRw;
          break;
      }
      std::vector<std::uint8_t> bytes;
      if (size == 0) {
        bytes.assign(sub.default_value.begin(), sub.default_value.end());
      } else if (sub.data_type == eds::type::kReal32 || sub.data_type == eds::type::kReal64) {
        bytes.assign(static_cast<std::size_t>(size), 0);
      } else {
        auto v = description.value(sub, id_);
        if (!v.ok()) return v.status();
        bytes.assign(static_cast<std::size_t>(size), 0);
        for (int i = 0; i < size; ++i) {
          bytes[static_cast<std::size_t>(i)] =
              static_cast<std::uint8_t>(static_cast<std::uint64_t>(*v) >> (8 * i));
        }
      }
      Entry* e = od_.find(sub.address);
      if (e == nullptr) {
        e = size == 0 ? &od_.add_string(sub.address, sub.default_value, access)
                      : &od_.add_raw(sub.address, bytes, access);
      } else if (size != 0 && (e->variable_size || e->data.size() != bytes.size())) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "%s: node %u: the device model has %zu bytes here, the EDS says %s",
                             description.where(sub).c_str(), unsigned{id_}, e->data.size(),
                             std::string(eds::type_name(sub.data_type)).c_str());
      }
      e->access = access;
      e->mappable = sub.pdo_mapping;
      e->variable_size = size == 0;
      e->data = bytes;
      e->default_data = bytes;
      described[sub.address.key()] = true;
    }
  }
  for (const ObjectAddress a : od_.addresses()) {
    if (described.count(a.key()) == 0) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: node %u: the device model needs 0x%04X:%02X, which the EDS does "
                           "not describe",
                           description.source().c_str(), unsigned{id_}, unsigned{a.index},
                           unsigned{a.sub});
    }
  }
  refresh_pdos();
  return Status::success();
}

void SlaveNode::send(const can::Frame& f) {
  if (faults_.silent) return;
  (void)bus_.send(f);
}

void SlaveNode::power_on(Timestamp now) {
  od_.restore_defaults(0x2000, 0xFFFF);
  on_reset_application();
  reset_communication(now);
}

void SlaveNode::reset_communication(Timestamp now) {
  sdo_state_ = SdoState::kIdle;
  held_sdo_.clear();
  // The communication profile area returns to its defaults (CiA 301, 7.3.2.2.2): default PDO
  // mappings are back, as on a real device.
  od_.restore_defaults(0x1000, 0x1FFF);
  refresh_pdos();
  master_heard_ = false;
  master_lost_ = false;
  comm_error_ = false;  // 0x1001 is back at its default
  state_ = NmtState::kPreOperational;
  send(heartbeat_frame(id_, NmtState::kBootUp));
  next_heartbeat_ = now;
}

void SlaveNode::send_emcy(std::uint16_t code, std::uint8_t error_register,
                          std::array<std::uint8_t, 5> manufacturer) {
  od_.set({0x1001, 0}, error_register);
  const auto cob_id = static_cast<std::uint32_t>(od_.get({0x1014, 0}));
  if (cob_id & cob::kInvalidBit) return;
  can::Frame f = make_frame(cob_id & 0x7FF, 8);
  put_u16(&f.data[0], code);
  f.data[2] = error_register;
  std::copy(manufacturer.begin(), manufacturer.end(), f.data.begin() + 3);
  ++emcys_sent_;
  send(f);
}

void SlaveNode::clear_errors() {
  comm_error_ = false;
  send_emcy(0x0000, 0x00);
}

void SlaveNode::acknowledge_communication_error() {
  if (comm_error_) clear_errors();
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
    // On absolute times: a step that comes late does not delay the next heartbeat (the period
    // stays exact on average); a schedule a whole period behind (0x1017 just set, a stalled
    // node) restarts from now.
    const auto period = std::chrono::milliseconds(hb_ms);
    next_heartbeat_ += period;
    if (next_heartbeat_ <= now) next_heartbeat_ = now + period;
  }
  const auto consumer = static_cast<std::uint32_t>(od_.get({0x1016, 1}));
  const auto timeout = std::chrono::milliseconds(consumer & 0xFFFF);
  if (timeout.count() > 0 && master_heard_ && !master_lost_ && now - master_last_ > timeout) {
    master_lost_ = true;
    send_emcy(0x8130, 0x11);
    on_master_lost(now);
  }
  on_step(now);
  if (state_ == NmtState::kOperational) send_event_tpdos(now);
}

void SlaveNode::handle(const can::Frame& f, Timestamp now) {
  if (f.error || f.extended || f.rtr || state_ == NmtState::kUnknown) return;
  if (f.id == cob::kNmt && f.dlc >= 2 && (f.data[1] == 0 || f.data[1] == id_)) {
    switch (static_cast<NmtCommand>(f.data[0])) {
      case NmtCommand::kStart:
        // Event-driven TPDOs report their values once on entering OPERATIONAL.
        if (state_ != NmtState::kOperational) {
          for (Pdo& p : tpdos_) p.sent = false;
        }
        state_ = NmtState::kOperational;
        break;
      case NmtCommand::kStop:
        state_ = NmtState::kStopped;
        break;
      case NmtCommand::kEnterPreOperational:
        state_ = NmtState::kPreOperational;
        break;
      case NmtCommand::kResetNode:
        od_.restore_defaults(0x2000, 0xFFFF);
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
    // The SYNC's length must agree with 0x1019 (0: no data, 2..240: a counter byte); otherwise
    // EMCY 0x8240 "unexpected SYNC data length" and, as 0x1029:01 = 0 prescribes for a
    // communication error, PRE-OPERATIONAL (CiA 301, 7.2.5.2 and 7.5.2.32).
    const auto overflow = od_.get({0x1019, 0});
    if (f.dlc != (overflow >= 2 ? 1 : 0)) {
      send_emcy(0x8240, 0x11);
      comm_error_ = true;
      state_ = NmtState::kPreOperational;
      return;
    }
    ++syncs_;
    bool applied = false;
    for (std::size_t i = 0; i < rpdos_.size(); ++i) {
      if (rpdos_[i].valid && rpdos_[i].has_pending && rpdos_[i].type <= 240) {
        apply_rpdo(i, now);
        applied = true;
      }
    }
    if (applied) on_rpdo_applied(now);
    on_sync(now);
    send_sync_tpdos();
    return;
  }
  for (std::size_t i = 0; i < rpdos_.size(); ++i) {
    Pdo& p = rpdos_[i];
    if (!p.valid || f.id != p.cob_id) continue;
    std::size_t need = 0;
    for (const auto& m : p.map) need += m.second;
    if (f.dlc < need) {
      send_emcy(0x8210, 0x11);
      comm_error_ = true;
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

// An RPDO writes its objects with the checks and side effects of an SDO write: a value the
// object's check refuses is not stored (there is no abort to send; the object keeps its value,
// e.g. 0x6061 keeps showing the old mode), and on_write follows a change.
void SlaveNode::apply_rpdo(std::size_t i, Timestamp) {
  Pdo& p = rpdos_[i];
  std::size_t off = 0;
  std::vector<Entry*> changed;
  for (const auto& [obj, bytes] : p.map) {
    const std::span<const std::uint8_t> value(&p.pending[off], bytes);
    off += bytes;
    Entry* e = od_.find(obj);
    if (e == nullptr) continue;
    if (e->validate && e->data.size() == bytes && e->validate(value) != 0) {
      ++rpdo_values_refused_;
      continue;
    }
    const bool differs = !std::equal(value.begin(), value.end(), e->data.begin(), e->data.end());
    od_.set(obj, get_le(value.data(), bytes));
    if (differs && e->on_write && e->on_write_from_pdo) changed.push_back(e);
  }
  for (Entry* e : changed) e->on_write();
  p.has_pending = false;
  ++rpdos_applied_;
}

std::uint8_t SlaveNode::tpdo_data(const Pdo& p, std::array<std::uint8_t, 8>& out) const {
  out.fill(0);
  std::size_t off = 0;
  for (const auto& [obj, bytes] : p.map) {
    put_le(&out[off], static_cast<std::uint32_t>(od_.get(obj)), bytes);
    off += bytes;
  }
  return static_cast<std::uint8_t>(off);
}

void SlaveNode::transmit_tpdo(Pdo& p, const std::array<std::uint8_t, 8>& data, std::uint8_t dlc,
                              Timestamp now) {
  can::Frame f = make_frame(p.cob_id, dlc);
  std::copy(data.begin(), data.end(), f.data.begin());
  p.sent = true;
  p.last = data;
  p.last_dlc = dlc;
  p.last_time = now;
  ++tpdos_sent_;
  send(f);
}

void SlaveNode::send_sync_tpdos() {
  std::array<std::uint8_t, 8> data{};
  for (Pdo& p : tpdos_) {
    if (!p.valid || p.type > 240) continue;
    if (p.type == 0) {  // acyclic synchronous: at the SYNC after a change
      const std::uint8_t dlc = tpdo_data(p, data);
      if (p.sent && data == p.last && dlc == p.last_dlc) continue;
      transmit_tpdo(p, data, dlc, now_);
      continue;
    }
    if (++p.sync_count < p.type) continue;
    p.sync_count = 0;
    const std::uint8_t dlc = tpdo_data(p, data);
    transmit_tpdo(p, data, dlc, now_);
  }
}

// Event-driven TPDOs (254/255): sent when a mapped value changed, and when the event timer ran
// out since the last transmission; never two within the inhibit time (CiA 301, 7.2.2.2).
void SlaveNode::send_event_tpdos(Timestamp now) {
  std::array<std::uint8_t, 8> data{};
  for (Pdo& p : tpdos_) {
    if (!p.valid || p.type < 254) continue;
    const std::uint8_t dlc = tpdo_data(p, data);
    const bool changed = !p.sent || data != p.last || dlc != p.last_dlc;
    const bool timer = p.sent && p.event_timer.count() > 0 && now - p.last_time >= p.event_timer;
    const bool inhibited = p.sent && now - p.last_time < p.inhibit;
    if ((changed || timer) && !inhibited) transmit_tpdo(p, data, dlc, now);
  }
}

void SlaveNode::refresh_pdo(bool tpdo, int n) {
  Pdo& p = (tpdo ? tpdos_ : rpdos_)[static_cast<std::size_t>(n)];
  const auto comm = static_cast<std::uint16_t>((tpdo ? 0x1800 : 0x1400) + n);
  const auto map = static_cast<std::uint16_t>((tpdo ? 0x1A00 : 0x1600) + n);
  const auto cob_id = static_cast<std::uint32_t>(od_.get({comm, 1}));
  Pdo fresh;
  fresh.valid = (cob_id & cob::kInvalidBit) == 0;
  fresh.cob_id = cob_id & 0x7FF;
  fresh.type = static_cast<std::uint8_t>(od_.get({comm, 2}));
  if (tpdo) {
    fresh.inhibit = std::chrono::microseconds(100 * od_.get({comm, 3}));
    fresh.event_timer = std::chrono::milliseconds(od_.get({comm, 5}));
  }
  const auto count = od_.get({map, 0});
  for (std::uint8_t s = 1; s <= count && s <= 8; ++s) {
    const auto v = static_cast<std::uint32_t>(od_.get({map, s}));
    fresh.map.emplace_back(
        ObjectAddress{static_cast<std::uint16_t>(v >> 16), static_cast<std::uint8_t>(v >> 8)},
        static_cast<std::uint8_t>((v & 0xFF) / 8));
  }
  // A PDO that stays the same keeps its transmission state (an event timer written while it
  // runs takes effect from the last transmission).
  if (p.valid && fresh.valid && p.cob_id == fresh.cob_id && p.map == fresh.map) {
    fresh.sent = p.sent;
    fresh.last = p.last;
    fresh.last_dlc = p.last_dlc;
    fresh.last_time = p.last_time;
    fresh.sync_count = p.sync_count;
  }
  p = std::move(fresh);
}

void SlaveNode::refresh_pdos() {
  for (int n = 0; n < kPdos; ++n) {
    refresh_pdo(false, n);
    refresh_pdo(true, n);
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
        // Without the size indicated (0x22) the data is as long as the object (CiA 301,
        // 7.2.4.3.3: "the number of bytes is unspecified"); 4 bytes for a variable-size one.
        std::size_t n = 4;
        if (cmd & 0x01) {
          n = 4u - ((cmd >> 2) & 0x03u);
        } else if (const Entry* e = od_.find(mux); e != nullptr && !e->variable_size) {
          n = std::min<std::size_t>(4, e->data.size());
        }
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
  cw.on_write_from_pdo = false;  // on_rpdo_applied takes it from every RPDO
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
  // Supported drive modes (CiA 402): bit 0 profile position, bit 5 homing, bit 7 CSP.
  d.add({0x6502, 0}, DataType::kU32, (1u << 0) | (1u << 5) | (1u << 7), Access::kRo);
  d.add({0x60FD, 0}, DataType::kU32, std::int64_t{1} << kSafetyInputBit, Access::kRo);
  d.add({0x60FE, 0}, DataType::kU8, 1, Access::kRo);
  d.add({0x60FE, 1}, DataType::kU32, 0);
  publish();
}

void Drive402::on_reset_application() {
  s_ = S::kNotReady;
  last_cw_ = 0;
  mode_pending_ = false;
  homing_running_ = false;
  publish();
}

// Methods 35/37: the current position becomes the home offset; the shaft stays where it is.
void Drive402::home_here() {
  const auto home = static_cast<std::int32_t>(od().get({0x607C, 0}, true));
  home_shift_ += std::int64_t{home} - position_;
  position_ = home;
}

void Drive402::on_step(Timestamp now) {
  // The drive's own initialisation is over once it runs: NOT_READY_TO_SWITCH_ON passes by
  // itself to SWITCH_ON_DISABLED (CiA 402 transition 1), in any NMT state, without a SYNC.
  bool changed = s_ == S::kNotReady;
  if (s_ == S::kNotReady) s_ = S::kSwitchOnDisabled;
  if (mode_pending_ && now >= mode_due_) {
    mode_pending_ = false;
    od().set({0x6061, 0}, od().get({0x6060, 0}));
    changed = true;
  }
  if (homing_running_ && now >= homing_until_) {
    homing_running_ = false;
    home_here();
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
      if ((cw & 0x80) && !(prev & 0x80)) {  // rising edge only
        s_ = S::kSwitchOnDisabled;
        clear_errors();  // the fault is gone: 0x1001 = 0 and EMCY 0x0000
      }
      break;
  }
  // A fault reset outside FAULT acknowledges a communication error (0x8210, 0x8240).
  if (s_ != S::kFault && (cw & 0x80) && !(prev & 0x80)) acknowledge_communication_error();
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
        home_here();
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

void Drive402::set_digital_input(int bit, bool on) {
  const std::int64_t v = od().get({0x60FD, 0});
  const std::int64_t b = std::int64_t{1} << bit;
  od().set({0x60FD, 0}, on ? (v | b) : (v & ~b));
}

bool Drive402::brake_applied() const {
  return (od().get({0x60FE, 1}) & 1) != 0;
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
      if (brake_applied()) {
        if (target != position_) ++braked_syncs_;
      } else {
        position_ = target;
      }
    } else if (mode == 1 && pp_moving_ && !brake_applied()) {
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
    // CSP: bit 12 "target position used as input to the position loop" while enabled.
    if (mode == 8 && s_ == S::kEnabled) sw |= 0x1000;
  }
  statusword_ = sw;
  od().set({0x6041, 0}, sw);
  od().set({0x6064, 0}, position_);
}

}  // namespace cdpr::canopen::slave
