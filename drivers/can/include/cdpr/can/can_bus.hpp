// The CAN transport interface shared by the SocketCAN socket and the in-process virtual bus.
//
// Classic CAN only (CAN FD is out of scope). One CanBus object is one endpoint on one bus: what it
// sends is seen by every other endpoint, never by itself (like a raw socket with loopback on and
// recv_own_msgs off). Nothing here allocates after construction, so the RT loop may call send()
// and receive() directly.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <string>
#include <string_view>

#include "cdpr/status.hpp"

namespace cdpr::can {

// Timestamps come from the bus's clock: CLOCK_MONOTONIC on SocketCAN (kernel receive time), the
// injected clock on the virtual bus.
using Timestamp = std::chrono::nanoseconds;

inline constexpr std::uint32_t kMaxStandardId = 0x7FF;
inline constexpr std::uint32_t kMaxExtendedId = 0x1FFFFFFF;
inline constexpr std::uint8_t kMaxDlc = 8;

// Error classes of an error frame (the CAN_ERR_* class bits of linux/can/error.h, repeated here so
// that users of the virtual bus need no kernel header).
namespace error_class {
inline constexpr std::uint32_t kTxTimeout = 0x001;
inline constexpr std::uint32_t kLostArbitration = 0x002;
inline constexpr std::uint32_t kController = 0x004;  // data[1] holds the controller state bits
inline constexpr std::uint32_t kProtocol = 0x008;
inline constexpr std::uint32_t kTransceiver = 0x010;
inline constexpr std::uint32_t kNoAck = 0x020;
inline constexpr std::uint32_t kBusOff = 0x040;
inline constexpr std::uint32_t kBusError = 0x080;
inline constexpr std::uint32_t kRestarted = 0x100;
inline constexpr std::uint32_t kCounters = 0x200;  // data[6]/data[7] hold the TX/RX error counters
inline constexpr std::uint32_t kAll = 0x1FFFFFFF;
// data[1] bits for kController
inline constexpr std::uint8_t kCtrlRxWarning = 0x04;
inline constexpr std::uint8_t kCtrlTxWarning = 0x08;
inline constexpr std::uint8_t kCtrlRxPassive = 0x10;
inline constexpr std::uint8_t kCtrlTxPassive = 0x20;
}  // namespace error_class

struct Frame {
  std::uint32_t id = 0;   // 11-bit or 29-bit identifier, without flag bits; 0 for error frames
  bool extended = false;  // 29-bit identifier
  bool rtr = false;       // remote transmission request (data is not sent)
  bool error = false;     // error frame; error_class/data carry the details
  std::uint8_t dlc = 0;   // 0..8
  std::array<std::uint8_t, 8> data{};
  std::uint32_t error_class = 0;  // CAN_ERR_* class bits of an error frame (linux/can/error.h)
  Timestamp timestamp{0};         // receive time (set by the transport on receive)
};

// What a bus endpoint knows about its own health.
struct BusStats {
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_received = 0;
  std::uint64_t error_frames = 0;
  std::uint64_t rx_dropped = 0;  // frames the kernel (or virtual bus queue) dropped for us
};

// Checks a frame before transmission: dlc <= 8, id within 11/29 bits, error class within 29 bits.
// `where` names the interface in the message ("vcan0: dlc 9 > 8"). Never allocates.
Status check_frame(const Frame& frame, std::string_view where);

class CanBus {
 public:
  virtual ~CanBus() = default;

  // Queues one frame for transmission. Fails (without blocking) on an invalid frame (dlc > 8,
  // 11-bit id > 0x7FF, 29-bit id > 0x1FFFFFFF) or when the transmit queue is full. A frame with
  // `error` set is put on the bus as an error frame (useful in simulations and tests; vcan passes
  // it through, a real controller does not).
  virtual Status send(const Frame& frame) = 0;

  // Waits up to `timeout` for one frame (0 = do not wait). Returns kTimeout when nothing came.
  virtual Status receive(Frame& frame, std::chrono::nanoseconds timeout) = 0;

  // The name of the interface ("vcan0", or the virtual bus endpoint's name) for messages.
  virtual const std::string& name() const = 0;

  virtual BusStats stats() const = 0;
};

}  // namespace cdpr::can
