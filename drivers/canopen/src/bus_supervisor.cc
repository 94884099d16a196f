#include "cdpr/canopen/bus_supervisor.hpp"

#include "cdpr/can/virtual_bus.hpp"  // can::frame_bits

namespace cdpr::canopen {

namespace ec = can::error_class;

std::string_view to_string(BusState s) {
  switch (s) {
    case BusState::kErrorActive:
      return "error active";
    case BusState::kWarning:
      return "error warning";
    case BusState::kErrorPassive:
      return "error passive";
    case BusState::kBusOff:
      return "bus-off";
  }
  return "invalid";
}

void BusSupervisor::enter(BusState s, Timestamp now, Events& events) {
  if (s == state_) return;
  Event e;
  e.time = now;
  switch (s) {
    case BusState::kBusOff:
      ++bus_off_;
      bus_off_since_ = now;
      e.type = EventType::kBusOff;
      events.push(e);
      break;
    case BusState::kErrorPassive:
      ++passive_;
      e.type = EventType::kBusErrorPassive;
      events.push(e);
      break;
    case BusState::kWarning:
      ++warning_;
      e.type = EventType::kBusErrorWarning;
      events.push(e);
      break;
    case BusState::kErrorActive:
      break;
  }
  state_ = s;
}

void BusSupervisor::on_error_frame(const can::Frame& frame, Timestamp now, Events& events) {
  if (!frame.error) return;
  const std::uint32_t cls = frame.error_class;
  if (cls & ec::kCounters) {
    tec_ = frame.data[6];
    rec_ = frame.data[7];
  }
  if (cls & ec::kBusOff) {
    enter(BusState::kBusOff, now, events);
    return;
  }
  if (cls & ec::kRestarted) {
    // The controller restarted by itself (kernel restart-ms): transmission works again.
    if (state_ == BusState::kBusOff) {
      ++recoveries_;
      Event e;
      e.type = EventType::kBusRecovered;
      e.time = now;
      events.push(e);
    }
    state_ = BusState::kErrorActive;
    return;
  }
  if (cls & ec::kController) {
    const std::uint8_t c = frame.data[1];
    constexpr std::uint8_t kBackToActive = 0x40;  // CAN_ERR_CRTL_ACTIVE
    if (c & (ec::kCtrlRxPassive | ec::kCtrlTxPassive)) {
      enter(BusState::kErrorPassive, now, events);
    } else if (c & (ec::kCtrlRxWarning | ec::kCtrlTxWarning)) {
      if (state_ != BusState::kBusOff) enter(BusState::kWarning, now, events);
    } else if (c & kBackToActive) {
      if (state_ != BusState::kBusOff) state_ = BusState::kErrorActive;
    }
  }
}

void BusSupervisor::on_stats(const can::BusStats& stats, Timestamp now, Events& events) {
  if (stats.rx_dropped > rx_dropped_) {
    Event e;
    e.type = EventType::kRxOverflow;
    e.value = static_cast<std::uint32_t>(stats.rx_dropped - rx_dropped_);
    e.time = now;
    events.push(e);
    rx_dropped_ = stats.rx_dropped;
  }
}

bool BusSupervisor::may_transmit(Timestamp now, Events& events) {
  if (state_ != BusState::kBusOff) return true;
  if (now - bus_off_since_ < policy_.wait) return false;
  if (restart_fn_ != nullptr) restart_fn_(restart_ctx_);
  ++recoveries_;
  state_ = BusState::kErrorActive;
  Event e;
  e.type = EventType::kBusRecovered;
  e.time = now;
  events.push(e);
  return true;
}

BusLoad compute_bus_load(std::span<const PeriodicFrame> frames, std::chrono::nanoseconds cycle,
                         double bitrate, double warning_threshold) {
  BusLoad l;
  for (const auto& f : frames) {
    can::Frame frame;
    frame.dlc = f.dlc;
    l.bits_per_cycle += f.per_cycle * can::frame_bits(frame);
  }
  l.cycle_s = std::chrono::duration<double>(cycle).count();
  l.busy_s = l.bits_per_cycle / bitrate;
  l.load = l.cycle_s > 0 ? l.busy_s / l.cycle_s : 0.0;
  l.warning = l.load > warning_threshold;
  return l;
}

}  // namespace cdpr::canopen
