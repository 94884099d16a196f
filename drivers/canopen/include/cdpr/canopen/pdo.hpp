// Process data objects: the configuration of one PDO (what the drive maps, written at start-up
// through SDO) and its compiled layout (byte offsets and sizes into a node's process image) that
// encodes and decodes frames in the RT cycle without allocation or lookups.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "cdpr/canopen/types.hpp"
#include "cdpr/status.hpp"

namespace cdpr::canopen {

class SdoClient;
class Pump;

enum class DataType : std::uint8_t { kI8, kU8, kI16, kU16, kI32, kU32 };

constexpr std::uint8_t size_of(DataType t) {
  switch (t) {
    case DataType::kI8:
    case DataType::kU8:
      return 1;
    case DataType::kI16:
    case DataType::kU16:
      return 2;
    case DataType::kI32:
    case DataType::kU32:
      return 4;
  }
  return 0;
}
constexpr bool is_signed(DataType t) {
  return t == DataType::kI8 || t == DataType::kI16 || t == DataType::kI32;
}
std::string_view to_string(DataType t);
// "i16", "u32", ...; false if unknown.
bool parse_data_type(std::string_view s, DataType& out);

struct PdoEntry {
  ObjectAddress object;
  DataType type = DataType::kU8;
  // Mapping entry value of 0x1600/0x1A00 sub n: index << 16 | sub << 8 | length in bits.
  constexpr std::uint32_t mapping_value() const {
    return (std::uint32_t{object.index} << 16) | (std::uint32_t{object.sub} << 8) |
           (8u * size_of(type));
  }
};

// Direction as seen from the node: an RPDO is received by the node (master -> node), a TPDO is
// transmitted by the node (node -> master).
enum class PdoDirection : std::uint8_t { kRpdo, kTpdo };

struct PdoConfig {
  PdoDirection direction = PdoDirection::kRpdo;
  int number = 1;                        // 1..512 (PDO n uses 0x1400/0x1600/0x1800/0x1A00 + n-1)
  std::uint32_t cob_id = 0;              // 0 = default of the pre-defined connection set (n <= 4)
  std::uint8_t transmission_type = 1;    // 1..240: every n-th SYNC; 254/255: event driven
  std::uint16_t inhibit_time_100us = 0;  // TPDO only, 0 = not written
  std::uint16_t event_timer_ms = 0;      // TPDO only, 0 = not written
  std::vector<PdoEntry> entries;

  std::uint16_t comm_index() const {
    return static_cast<std::uint16_t>((direction == PdoDirection::kRpdo ? 0x1400 : 0x1800) +
                                      number - 1);
  }
  std::uint16_t mapping_index() const {
    return static_cast<std::uint16_t>((direction == PdoDirection::kRpdo ? 0x1600 : 0x1A00) +
                                      number - 1);
  }
  // The COB-ID in use (the default one when cob_id is 0).
  std::uint32_t effective_cob_id(NodeId node) const;
  std::size_t byte_size() const;
};

// One mapped value of a node, in a flat array the PDO layouts index into.
struct ProcessVar {
  ObjectAddress object;
  DataType type = DataType::kU8;
  std::int64_t value = 0;
};

// A node's process image: every object any of its PDOs maps, once.
class ProcessImage {
 public:
  // Adds (or finds) the variable; returns its slot. Start-up only (allocates).
  std::uint16_t add(ObjectAddress obj, DataType type);
  // Slot of an object, or -1.
  int find(ObjectAddress obj) const;
  std::int64_t get(std::size_t slot) const { return vars_[slot].value; }
  void set(std::size_t slot, std::int64_t v) { vars_[slot].value = v; }
  std::span<ProcessVar> vars() { return vars_; }
  std::span<const ProcessVar> vars() const { return vars_; }

 private:
  std::vector<ProcessVar> vars_;
};

// A PDO compiled to offsets: encode/decode are a handful of shifts per field.
class PdoLayout {
 public:
  struct Field {
    std::uint8_t offset = 0;
    std::uint8_t size = 0;
    bool is_signed = false;
    std::uint16_t slot = 0;
  };

  // Adds the mapped objects to `image` and records where each goes. Fails if the mapping exceeds
  // 8 bytes or 8 entries; the message names node and PDO.
  static Result<PdoLayout> compile(const PdoConfig& config, NodeId node, ProcessImage& image);

  std::uint32_t cob_id() const { return cob_id_; }
  std::uint8_t dlc() const { return dlc_; }
  std::span<const Field> fields() const { return {fields_.data(), count_}; }

  void encode(const ProcessImage& image, can::Frame& frame) const;
  // False (and nothing written) if the frame is shorter than the mapping (CiA 301: such a PDO
  // is not processed; the node would send EMCY 0x8210).
  bool decode(const can::Frame& frame, ProcessImage& image) const;

 private:
  std::uint32_t cob_id_ = 0;
  std::uint8_t dlc_ = 0;
  std::uint8_t count_ = 0;
  std::array<Field, 8> fields_{};
};

// Writes one PDO's communication and mapping parameters through SDO in the order CiA 301
// requires: disable (COB-ID bit 31), mapping count 0, entries, count, transmission type, (TPDO:
// inhibit time, event timer), enable. An empty mapping leaves the PDO disabled.
Status configure_pdo(SdoClient& sdo, Pump& pump, const PdoConfig& config);

}  // namespace cdpr::canopen
