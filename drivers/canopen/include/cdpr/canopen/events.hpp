// What the master reports to the non-real-time side: a fixed-capacity ring of events that the RT
// loop fills without allocating and a logger thread (or the same thread, later) drains.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "cdpr/canopen/types.hpp"

namespace cdpr::canopen {

// One decoded emergency message (CiA 301, 7.2.7).
struct Emcy {
  NodeId node = 0;
  std::uint16_t code = 0;           // emergency error code
  std::uint8_t error_register = 0;  // copy of 0x1001
  std::array<std::uint8_t, 5> manufacturer{};
  Timestamp time{0};
};

// Decodes an EMCY frame (COB-ID 0x80 + node, 8 bytes; shorter frames are zero-padded as some
// devices send them). Returns false if the frame is not an EMCY.
bool decode_emcy(const can::Frame& frame, Emcy& out);

enum class EventType : std::uint8_t {
  kBootUp,             // node sent a boot-up message
  kNmtStateChanged,    // heartbeat reports a different state (nmt)
  kHeartbeatLost,      // consumer timeout (node)
  kHeartbeatRegained,  // a lost node is heard again
  kEmcy,               // emcy holds the message
  kBusErrorWarning,    // controller reached the warning limit
  kBusErrorPassive,    // controller is error passive
  kBusOff,             // controller is bus-off; transmission suspended
  kBusRecovered,       // transmission resumed after bus-off
  kRxOverflow,         // value = frames the receive queue dropped since the last report
  kDriveFault,         // node's drive entered FAULT
  kDriveStuck,         // node's drive did not follow (supervisor timeout)
  kSyncOverrun,        // value = SYNC periods missed because cycle() came late
  kTxFailed,           // value = frame id that could not be queued
  kLinkRestarted,      // bus-off recovery through the link; value = can::RecoveryOutcome action
  kLinkRestartFailed,  // value = errno of the last attempt
};

std::string_view to_string(EventType t);

struct Event {
  EventType type = EventType::kBootUp;
  NodeId node = 0;
  NmtState nmt = NmtState::kUnknown;
  std::uint32_t value = 0;
  Emcy emcy{};
  Timestamp time{0};
};

// Single-threaded fixed ring: when full, the oldest event is overwritten and `dropped` counts it
// (the RT loop must never block on a slow reader).
template <std::size_t N>
class EventRing {
 public:
  void push(const Event& e) {
    if (size_ == N) {
      head_ = (head_ + 1) % N;
      --size_;
      ++dropped_;
    }
    buf_[(head_ + size_) % N] = e;
    ++size_;
  }
  bool pop(Event& out) {
    if (size_ == 0) return false;
    out = buf_[head_];
    head_ = (head_ + 1) % N;
    --size_;
    return true;
  }
  std::size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  std::uint64_t dropped() const { return dropped_; }
  void clear() { head_ = size_ = 0; }

 private:
  std::array<Event, N> buf_{};
  std::size_t head_ = 0;
  std::size_t size_ = 0;
  std::uint64_t dropped_ = 0;
};

using Events = EventRing<256>;

}  // namespace cdpr::canopen
