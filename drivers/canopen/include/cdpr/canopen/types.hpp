// CANopen (CiA 301) basics shared by the master and the simulated slaves: node ids, COB-IDs of the
// pre-defined connection set, NMT states, object addresses and little-endian byte access.
// Everything here is constexpr or inline and never allocates.
#pragma once

#include <chrono>
#include <cstdint>
#include <cstring>
#include <span>
#include <string_view>

#include "cdpr/can/can_bus.hpp"

namespace cdpr::canopen {

using can::Timestamp;
using NodeId = std::uint8_t;  // 1..127; 0 addresses all nodes in NMT commands
inline constexpr NodeId kMaxNodeId = 127;

constexpr bool valid_node_id(int id) {
  return id >= 1 && id <= kMaxNodeId;
}

// Function codes of the pre-defined connection set (CiA 301, 7.3.5): COB-ID = base + node id.
namespace cob {
inline constexpr std::uint32_t kNmt = 0x000;
inline constexpr std::uint32_t kSync = 0x080;
inline constexpr std::uint32_t kEmcy = 0x080;  // + node id (1..127)
inline constexpr std::uint32_t kTime = 0x100;
inline constexpr std::uint32_t kTpdo1 = 0x180;
inline constexpr std::uint32_t kRpdo1 = 0x200;
inline constexpr std::uint32_t kSdoTx = 0x580;  // server -> client (answers)
inline constexpr std::uint32_t kSdoRx = 0x600;  // client -> server (requests)
inline constexpr std::uint32_t kHeartbeat = 0x700;
// Default COB-ID of TPDO/RPDO n (1..4) of a node.
constexpr std::uint32_t tpdo(int n, NodeId node) {
  return 0x180u + 0x100u * (n - 1) + node;
}
constexpr std::uint32_t rpdo(int n, NodeId node) {
  return 0x200u + 0x100u * (n - 1) + node;
}
// Bit 31 of a PDO/SYNC/EMCY COB-ID object: the object is invalid (disabled).
inline constexpr std::uint32_t kInvalidBit = 0x80000000u;
}  // namespace cob

// NMT states as sent in heartbeat/boot-up messages, plus two states only the master knows.
enum class NmtState : std::uint8_t {
  kBootUp = 0x00,
  kStopped = 0x04,
  kOperational = 0x05,
  kPreOperational = 0x7F,
  kUnknown = 0xF0,  // never heard from
  kLost = 0xF1,     // heartbeat consumer timed out
};

constexpr std::string_view to_string(NmtState s) {
  switch (s) {
    case NmtState::kBootUp:
      return "BOOT_UP";
    case NmtState::kStopped:
      return "STOPPED";
    case NmtState::kOperational:
      return "OPERATIONAL";
    case NmtState::kPreOperational:
      return "PRE_OPERATIONAL";
    case NmtState::kUnknown:
      return "UNKNOWN";
    case NmtState::kLost:
      return "LOST";
  }
  return "INVALID";
}

// NMT command specifiers (CiA 301, 7.2.8.3.1).
enum class NmtCommand : std::uint8_t {
  kStart = 0x01,
  kStop = 0x02,
  kEnterPreOperational = 0x80,
  kResetNode = 0x81,
  kResetCommunication = 0x82,
};

constexpr std::string_view to_string(NmtCommand c) {
  switch (c) {
    case NmtCommand::kStart:
      return "start";
    case NmtCommand::kStop:
      return "stop";
    case NmtCommand::kEnterPreOperational:
      return "enter pre-operational";
    case NmtCommand::kResetNode:
      return "reset node";
    case NmtCommand::kResetCommunication:
      return "reset communication";
  }
  return "invalid";
}

// index:subindex of an object dictionary entry.
struct ObjectAddress {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  constexpr std::uint32_t key() const { return (std::uint32_t{index} << 8) | sub; }
  friend constexpr bool operator==(ObjectAddress, ObjectAddress) = default;
};

// Little-endian access (CANopen is little-endian on the wire).
inline std::uint32_t get_le(const std::uint8_t* p, std::size_t n) {
  std::uint32_t v = 0;
  for (std::size_t i = 0; i < n; ++i) v |= std::uint32_t{p[i]} << (8 * i);
  return v;
}
inline std::uint16_t get_u16(const std::uint8_t* p) {
  return static_cast<std::uint16_t>(get_le(p, 2));
}
inline std::uint32_t get_u32(const std::uint8_t* p) {
  return get_le(p, 4);
}
inline void put_le(std::uint8_t* p, std::uint32_t v, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i) p[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
inline void put_u16(std::uint8_t* p, std::uint16_t v) {
  put_le(p, v, 2);
}
inline void put_u32(std::uint8_t* p, std::uint32_t v) {
  put_le(p, v, 4);
}

// Builders for the few fixed-format frames.
inline can::Frame make_frame(std::uint32_t id, std::uint8_t dlc) {
  can::Frame f;
  f.id = id;
  f.dlc = dlc;
  return f;
}
inline can::Frame nmt_frame(NmtCommand cmd, NodeId node) {
  can::Frame f = make_frame(cob::kNmt, 2);
  f.data[0] = static_cast<std::uint8_t>(cmd);
  f.data[1] = node;
  return f;
}
inline can::Frame heartbeat_frame(NodeId node, NmtState state) {
  can::Frame f = make_frame(cob::kHeartbeat + node, 1);
  f.data[0] = static_cast<std::uint8_t>(state);
  return f;
}

// Durations in the configuration are milliseconds on the wire (0x1016/0x1017) but SI in code.
inline constexpr std::chrono::nanoseconds from_ms(double ms) {
  return std::chrono::nanoseconds(static_cast<std::int64_t>(ms * 1e6));
}
inline constexpr double to_ms(std::chrono::nanoseconds d) {
  return static_cast<double>(d.count()) / 1e6;
}

}  // namespace cdpr::canopen
