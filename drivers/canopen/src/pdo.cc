#include "cdpr/canopen/pdo.hpp"

#include "cdpr/canopen/sdo_client.hpp"

namespace cdpr::canopen {

std::string_view to_string(DataType t) {
  switch (t) {
    case DataType::kI8:
      return "i8";
    case DataType::kU8:
      return "u8";
    case DataType::kI16:
      return "i16";
    case DataType::kU16:
      return "u16";
    case DataType::kI32:
      return "i32";
    case DataType::kU32:
      return "u32";
  }
  return "?";
}

bool parse_data_type(std::string_view s, DataType& out) {
  constexpr std::array kAll{DataType::kI8,  DataType::kU8,  DataType::kI16,
                            DataType::kU16, DataType::kI32, DataType::kU32};
  for (DataType t : kAll) {
    if (to_string(t) == s) {
      out = t;
      return true;
    }
  }
  return false;
}

std::uint32_t PdoConfig::effective_cob_id(NodeId node) const {
  if (cob_id != 0) return cob_id;
  return direction == PdoDirection::kRpdo ? cob::rpdo(number, node) : cob::tpdo(number, node);
}

std::size_t PdoConfig::byte_size() const {
  std::size_t n = 0;
  for (const auto& e : entries) n += size_of(e.type);
  return n;
}

std::uint16_t ProcessImage::add(ObjectAddress obj, DataType type) {
  const int found = find(obj);
  if (found >= 0) return static_cast<std::uint16_t>(found);
  vars_.push_back(ProcessVar{obj, type, 0});
  return static_cast<std::uint16_t>(vars_.size() - 1);
}

int ProcessImage::find(ObjectAddress obj) const {
  for (std::size_t i = 0; i < vars_.size(); ++i) {
    if (vars_[i].object == obj) return static_cast<int>(i);
  }
  return -1;
}

Result<PdoLayout> PdoLayout::compile(const PdoConfig& config, NodeId node, ProcessImage& image) {
  const char* dir = config.direction == PdoDirection::kRpdo ? "RPDO" : "TPDO";
  if (config.entries.size() > 8 || config.byte_size() > 8) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "node %u: %s%d maps %zu entries of %zu bytes (at most 8 bytes)",
                         unsigned{node}, dir, config.number, config.entries.size(),
                         config.byte_size());
  }
  if (config.number < 1 || config.number > 512) {
    return Status::error(ErrorCode::kInvalidArgument, "node %u: %s number %d not in 1..512",
                         unsigned{node}, dir, config.number);
  }
  if (config.cob_id == 0 && config.number > 4) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "node %u: %s%d needs an explicit cob_id (defaults exist for 1..4)",
                         unsigned{node}, dir, config.number);
  }
  PdoLayout l;
  l.cob_id_ = config.effective_cob_id(node);
  std::uint8_t offset = 0;
  for (const auto& e : config.entries) {
    Field& f = l.fields_[l.count_++];
    f.offset = offset;
    f.size = size_of(e.type);
    f.is_signed = is_signed(e.type);
    f.slot = image.add(e.object, e.type);
    offset = static_cast<std::uint8_t>(offset + f.size);
  }
  l.dlc_ = offset;
  return l;
}

void PdoLayout::encode(const ProcessImage& image, can::Frame& frame) const {
  frame.id = cob_id_;
  frame.extended = false;
  frame.rtr = false;
  frame.error = false;
  frame.dlc = dlc_;
  for (std::size_t i = 0; i < count_; ++i) {
    const Field& f = fields_[i];
    put_le(&frame.data[f.offset], static_cast<std::uint32_t>(image.get(f.slot)), f.size);
  }
}

bool PdoLayout::decode(const can::Frame& frame, ProcessImage& image) const {
  if (frame.dlc < dlc_) return false;
  for (std::size_t i = 0; i < count_; ++i) {
    const Field& f = fields_[i];
    std::uint32_t raw = get_le(&frame.data[f.offset], f.size);
    std::int64_t v = raw;
    if (f.is_signed) {
      const unsigned bits = 8u * f.size;
      const std::uint32_t sign = 1u << (bits - 1);
      if (raw & sign) v = static_cast<std::int64_t>(raw) - (std::int64_t{1} << bits);
    }
    image.set(f.slot, v);
  }
  return true;
}

Status configure_pdo(SdoClient& sdo, Pump& pump, const PdoConfig& config) {
  const std::uint16_t comm = config.comm_index();
  const std::uint16_t map = config.mapping_index();
  const std::uint32_t cob_id = config.effective_cob_id(sdo.node());
  Status s = sdo.write<std::uint32_t>({comm, 1}, cob_id | cob::kInvalidBit, pump);
  if (!s.ok()) return s;
  s = sdo.write<std::uint8_t>({map, 0}, 0, pump);
  if (!s.ok()) return s;
  for (std::size_t i = 0; i < config.entries.size(); ++i) {
    s = sdo.write<std::uint32_t>({map, static_cast<std::uint8_t>(i + 1)},
                                 config.entries[i].mapping_value(), pump);
    if (!s.ok()) return s;
  }
  s = sdo.write<std::uint8_t>({map, 0}, static_cast<std::uint8_t>(config.entries.size()), pump);
  if (!s.ok()) return s;
  s = sdo.write<std::uint8_t>({comm, 2}, config.transmission_type, pump);
  if (!s.ok()) return s;
  if (config.direction == PdoDirection::kTpdo) {
    if (config.inhibit_time_100us != 0) {
      s = sdo.write<std::uint16_t>({comm, 3}, config.inhibit_time_100us, pump);
      if (!s.ok()) return s;
    }
    if (config.event_timer_ms != 0) {
      s = sdo.write<std::uint16_t>({comm, 5}, config.event_timer_ms, pump);
      if (!s.ok()) return s;
    }
  }
  if (config.entries.empty()) return Status::success();
  return sdo.write<std::uint32_t>({comm, 1}, cob_id, pump);
}

}  // namespace cdpr::canopen
