// Supervision of the CAN controller seen through error frames (CAN_ERR_* classes, see
// linux/can/error.h and cdpr::can::error_class), the receive-overflow counter of the transport and
// the bus load of the configured traffic.
#pragma once

#include <chrono>
#include <cstdint>
#include <span>

#include "cdpr/can/can_bus.hpp"
#include "cdpr/canopen/events.hpp"

namespace cdpr::canopen {

enum class BusState : std::uint8_t { kErrorActive, kWarning, kErrorPassive, kBusOff };
std::string_view to_string(BusState s);

struct BusRecoveryPolicy {
  // After bus-off, the master stays silent this long and then transmits again (the controller
  // restarts by itself with the kernel's restart-ms, or through the restart hook below). A short
  // wait would flood a bus that has a real fault; a long one lets the drives' heartbeat consumers
  // stop them, which is the safe outcome.
  std::chrono::nanoseconds wait{std::chrono::milliseconds(500)};
};

class BusSupervisor {
 public:
  BusSupervisor() = default;
  explicit BusSupervisor(BusRecoveryPolicy policy) : policy_(policy) {}

  // Optional action run when the wait after bus-off is over (e.g. a netlink restart of the
  // interface). A function pointer and context, so calling it never allocates.
  void set_restart_hook(void (*fn)(void*), void* context) {
    restart_fn_ = fn;
    restart_ctx_ = context;
  }

  void on_error_frame(const can::Frame& frame, Timestamp now, Events& events);
  // The transport's counters: a growing rx_dropped is reported once per change.
  void on_stats(const can::BusStats& stats, Timestamp now, Events& events);
  // False while the bus is off and the recovery wait is not over; then re-enables (event).
  bool may_transmit(Timestamp now, Events& events);

  BusState state() const { return state_; }
  std::uint64_t bus_off_count() const { return bus_off_; }
  std::uint64_t error_passive_count() const { return passive_; }
  std::uint64_t warning_count() const { return warning_; }
  std::uint64_t recoveries() const { return recoveries_; }
  std::uint64_t rx_dropped() const { return rx_dropped_; }
  std::uint8_t tx_error_counter() const { return tec_; }
  std::uint8_t rx_error_counter() const { return rec_; }

 private:
  void enter(BusState s, Timestamp now, Events& events);

  BusRecoveryPolicy policy_{};
  BusState state_ = BusState::kErrorActive;
  Timestamp bus_off_since_{0};
  std::uint64_t bus_off_ = 0, passive_ = 0, warning_ = 0, recoveries_ = 0, rx_dropped_ = 0;
  std::uint8_t tec_ = 0, rec_ = 0;
  void (*restart_fn_)(void*) = nullptr;
  void* restart_ctx_ = nullptr;
};

// Bus load of a periodic traffic pattern.
struct BusLoad {
  double bits_per_cycle = 0;  // worst-case bits (stuffing and interframe space included)
  double cycle_s = 0;         // SYNC period
  double busy_s = 0;          // bits_per_cycle / bitrate
  double load = 0;            // busy_s / cycle_s
  bool warning = false;       // load above the warning threshold
};

// Frames sent once every `every_n_cycles` cycles (fractional for slower traffic such as
// heartbeats: 0.04 for a 100 ms heartbeat on a 4 ms cycle).
struct PeriodicFrame {
  std::uint8_t dlc = 0;
  double per_cycle = 1.0;
};

// Sums can::frame_bits (standard 11-bit frames: 47 fixed bits incl. 3-bit interframe space,
// 8 per data byte, worst-case stuff bits floor((34 + 8 n - 1) / 4)) over the frames of one cycle.
BusLoad compute_bus_load(std::span<const PeriodicFrame> frames, std::chrono::nanoseconds cycle,
                         double bitrate = 1e6, double warning_threshold = 0.7);

}  // namespace cdpr::canopen
