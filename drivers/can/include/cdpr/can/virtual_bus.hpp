// An in-process CAN bus for tests and simulations.
//
//   cdpr::SteadyClock clock;                 // or cdpr::ManualClock for deterministic tests
//   cdpr::can::VirtualCanBus bus(clock);
//   auto master = bus.endpoint("master");    // std::unique_ptr<VirtualCanEndpoint>, a CanBus
//   auto drive3 = bus.endpoint("drive3");
//   master->send(frame);                     // drive3 receives it, master does not
//
// Every endpoint has a bounded receive queue allocated when the endpoint is created; a full queue
// drops the frame and counts it in that endpoint's stats().rx_dropped, like a kernel socket buffer.
// send() and receive() never allocate and may be called from different threads. Frames carry the
// bus clock's time at send as timestamp. The bus's shared state outlives the VirtualCanBus object
// while endpoints exist, so destruction order does not matter; the clock must outlive both.
//
// Optional bit-time model: each frame adds its worst-case duration on a classic CAN bus (bit
// stuffing included, see frame_bits()) to the bus busy time, so a caller can read the bus load
// over a window with load_sample() / bus_load(). The frames are still delivered at once: the model
// measures, it does not delay.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "cdpr/can/can_bus.hpp"
#include "cdpr/core/clock.hpp"

namespace cdpr::can {

struct VirtualBusOptions {
  std::size_t queue_capacity = 1024;  // frames per endpoint receive queue
  bool bit_timing = false;            // accumulate bus busy time with the bit-time model
  std::uint32_t bitrate = 1'000'000;  // bit/s of the modelled bus
};

// Bus busy time at a moment, for load over a window: bus_load(sample_before, sample_after).
struct LoadSample {
  Timestamp time{0};  // bus clock
  Timestamp busy{0};  // accumulated bus busy time
};

// Fraction of the window [a.time, b.time] the bus was busy (0 for an empty window). A value above
// 1 means the offered traffic would not fit on a real bus of that bitrate.
double bus_load(const LoadSample& a, const LoadSample& b);

// Worst-case number of bits a frame occupies on a classic CAN bus, interframe space included:
// fixed fields (standard 47, extended 67 bits incl. 3-bit IFS) + 8 per data byte (none for RTR)
// + worst-case stuff bits floor((stuffed - 1) / 4) over SOF..CRC (stuffed = 34 or 54 + 8 * bytes).
// An 8-byte standard frame gives 135 bits, an 8-byte extended one 160. An error frame counts as
// 6-bit flag + 6-bit echo + 8-bit delimiter + 3-bit IFS = 23 bits.
std::uint32_t frame_bits(const Frame& frame);

class VirtualCanEndpoint;

class VirtualCanBus {
 public:
  explicit VirtualCanBus(const Clock& clock, VirtualBusOptions options = {});
  ~VirtualCanBus();
  VirtualCanBus(const VirtualCanBus&) = delete;
  VirtualCanBus& operator=(const VirtualCanBus&) = delete;

  // Attaches a new endpoint (allocates its queue). Thread-safe.
  std::unique_ptr<VirtualCanEndpoint> endpoint(std::string name);

  // Delivers an error frame (error = true, dlc 8, `error_class` and `data`) to every endpoint, as a
  // controller reports bus-off or error-passive. Counts in the bus busy time like any frame.
  void inject_error(std::uint32_t error_class, const std::array<std::uint8_t, 8>& data = {});

  LoadSample load_sample() const;
  const Clock& clock() const;

  struct State;

 private:
  std::shared_ptr<State> state_;
};

class VirtualCanEndpoint final : public CanBus {
 public:
  ~VirtualCanEndpoint() override;
  VirtualCanEndpoint(const VirtualCanEndpoint&) = delete;
  VirtualCanEndpoint& operator=(const VirtualCanEndpoint&) = delete;

  Status send(const Frame& frame) override;
  Status receive(Frame& frame, std::chrono::nanoseconds timeout) override;
  const std::string& name() const override { return name_; }
  BusStats stats() const override;
  // While set, send() fails (kUnavailable) and nothing goes on the bus: a controller that lost
  // the bus, for tests of what the sender does then. Thread-safe.
  void set_transmit_failing(bool on) { tx_failing_.store(on, std::memory_order_relaxed); }

  struct Queue;

 private:
  friend class VirtualCanBus;
  VirtualCanEndpoint(std::shared_ptr<VirtualCanBus::State> state, std::string name,
                     std::size_t capacity);

  std::shared_ptr<VirtualCanBus::State> state_;
  std::string name_;
  Status empty_poll_;  // what a poll (timeout 0) that finds no frame returns, made once
  std::unique_ptr<Queue> queue_;
  std::atomic<bool> tx_failing_{false};
};

}  // namespace cdpr::can
