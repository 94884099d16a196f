// The setpoint stream (docs/motion.md "Setpoint stream"): an application sends one pose per
// cycle as a datagram on a UNIX datagram socket next to the control socket; a receiving thread
// decodes and checks each and hands it to the RT loop through a lock-free single-producer
// single-consumer ring (RtController::push_setpoint), which the cycle drains without a lock, an
// allocation or a system call.
//
// Record (72 bytes, little-endian):
//   offset 0   u32  magic 0x53504443 ("CDPS")
//          4   u16  version 1
//          6   u16  flags, 0
//          8   u64  sequence number (increasing by 1 per setpoint)
//         16   i64  sender's CLOCK_MONOTONIC time when sent, ns
//         24   f64  x, y, z (m), roll, pitch, yaw (rad): world pose of the platform
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <thread>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/controller/motion_command.hpp"
#include "cdpr/core/clock.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

inline constexpr std::uint32_t kSetpointMagic = 0x53504443;
inline constexpr std::uint16_t kSetpointVersion = 1;
inline constexpr std::size_t kSetpointBytes = 72;

std::array<std::byte, kSetpointBytes> encode_setpoint(std::uint64_t seq, std::int64_t sent_ns,
                                                      const Pose& pose);
// kInvalidArgument naming what is wrong (size, magic, version, flags, a value not finite).
Result<StreamSetpoint> decode_setpoint(std::span<const std::byte> bytes);

// What the receiver counted since it opened.
struct StreamCounters {
  std::uint64_t received = 0;   // datagrams
  std::uint64_t malformed = 0;  // not a setpoint record (dropped)
  std::uint64_t gaps = 0;       // setpoints missing between two received (sequence jumps)
  std::uint64_t reordered = 0;  // a sequence number not above the last one (dropped)
  std::uint64_t refused = 0;    // failed the check (handed over refused: the stream ends)
  std::uint64_t overflow = 0;   // the RT loop's ring was full (dropped)
};

class SetpointReceiver {
 public:
  // The check of one pose (box, tensions, cable lengths); a failure refuses the setpoint.
  using Check = std::function<Status(const Pose&)>;
  // Where checked setpoints go (RtController::push_setpoint); false: full.
  using Sink = std::function<bool(const StreamSetpoint&)>;

  // Binds `path` (an existing socket file is replaced), mode 0660, and starts the thread.
  // kIoError naming the path.
  static Result<std::unique_ptr<SetpointReceiver>> open(const std::string& path, Check check,
                                                        Sink sink, const cdpr::Clock& clock);
  ~SetpointReceiver();  // stops the thread, removes the socket file
  SetpointReceiver(const SetpointReceiver&) = delete;
  SetpointReceiver& operator=(const SetpointReceiver&) = delete;

  const std::string& path() const { return path_; }
  StreamCounters counters() const;
  // Handles one datagram (the thread's body; public for tests).
  void handle(std::span<const std::byte> bytes);

 private:
  SetpointReceiver(std::string path, int fd, Check check, Sink sink, const cdpr::Clock& clock);
  void run();

  std::string path_;
  int fd_ = -1;
  Check check_;
  Sink sink_;
  const cdpr::Clock& clock_;
  std::uint64_t last_seq_ = 0;
  bool have_seq_ = false;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> received_{0}, malformed_{0}, gaps_{0}, reordered_{0}, refused_{0},
      overflow_{0};
  std::thread thread_;
};

}  // namespace cdpr::controller
