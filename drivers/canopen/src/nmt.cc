#include "cdpr/canopen/nmt.hpp"

namespace cdpr::canopen {

bool decode_emcy(const can::Frame& frame, Emcy& out) {
  if (frame.error || frame.rtr || frame.extended) return false;
  if (frame.id <= cob::kEmcy || frame.id > cob::kEmcy + kMaxNodeId) return false;
  if (frame.dlc == 0) return false;  // that would be a SYNC-like frame, not an EMCY
  std::array<std::uint8_t, 8> d{};
  for (std::size_t i = 0; i < frame.dlc && i < 8; ++i) d[i] = frame.data[i];
  out.node = static_cast<NodeId>(frame.id - cob::kEmcy);
  out.code = get_u16(d.data());
  out.error_register = d[2];
  for (std::size_t i = 0; i < 5; ++i) out.manufacturer[i] = d[3 + i];
  out.time = frame.timestamp;
  return true;
}

std::string_view to_string(EventType t) {
  switch (t) {
    case EventType::kBootUp:
      return "boot-up";
    case EventType::kNmtStateChanged:
      return "NMT state changed";
    case EventType::kHeartbeatLost:
      return "heartbeat lost";
    case EventType::kHeartbeatRegained:
      return "heartbeat regained";
    case EventType::kEmcy:
      return "emergency";
    case EventType::kBusErrorWarning:
      return "bus error warning";
    case EventType::kBusErrorPassive:
      return "bus error passive";
    case EventType::kBusOff:
      return "bus-off";
    case EventType::kBusRecovered:
      return "bus recovered";
    case EventType::kRxOverflow:
      return "receive overflow";
    case EventType::kDriveFault:
      return "drive fault";
    case EventType::kDriveStuck:
      return "drive does not follow";
    case EventType::kSyncOverrun:
      return "SYNC overrun";
    case EventType::kTxFailed:
      return "transmit failed";
    case EventType::kLinkRestarted:
      return "link restarted after bus-off";
    case EventType::kLinkRestartFailed:
      return "link restart after bus-off failed";
  }
  return "invalid";
}

void NodeMonitor::consume(NodeId node, std::chrono::nanoseconds timeout) {
  nodes_[node].timeout = timeout;
}

void NodeMonitor::forget(NodeId node) {
  Node& n = nodes_[node];
  n.state = NmtState::kUnknown;
  n.heard = false;
}

bool NodeMonitor::on_frame(const can::Frame& frame, Timestamp now, Events& events) {
  if (frame.error || frame.rtr || frame.extended || frame.dlc != 1) return false;
  if (frame.id <= cob::kHeartbeat || frame.id > cob::kHeartbeat + kMaxNodeId) return false;
  const auto id = static_cast<NodeId>(frame.id - cob::kHeartbeat);
  Node& n = nodes_[id];
  const auto reported = static_cast<NmtState>(frame.data[0] & 0x7F);
  const bool was_lost = n.state == NmtState::kLost;
  n.last_seen = now;
  n.heard = true;
  Event e;
  e.node = id;
  e.time = now;
  e.nmt = reported;
  if (was_lost) {
    e.type = EventType::kHeartbeatRegained;
    events.push(e);
  }
  if (reported == NmtState::kBootUp) {
    ++n.boot_count;
    e.type = EventType::kBootUp;
    events.push(e);
  } else if (reported != n.state) {
    e.type = EventType::kNmtStateChanged;
    events.push(e);
  }
  n.state = reported;
  n.last_reported = reported;
  return true;
}

void NodeMonitor::check(Timestamp now, Events& events) {
  for (std::size_t id = 1; id <= kMaxNodeId; ++id) {
    Node& n = nodes_[id];
    if (n.timeout.count() <= 0 || !n.heard || n.state == NmtState::kLost) continue;
    if (now - n.last_seen > n.timeout) {
      n.state = NmtState::kLost;
      ++n.lost_count;
      Event e;
      e.type = EventType::kHeartbeatLost;
      e.node = static_cast<NodeId>(id);
      e.nmt = n.last_reported;
      e.value = static_cast<std::uint32_t>(to_ms(now - n.last_seen));
      e.time = now;
      events.push(e);
    }
  }
}

bool SyncProducer::poll(Timestamp now, can::Frame& frame) {
  if (!running_ || now < next_) return false;
  const auto late = (now - next_) / period_;  // whole periods missed
  if (late > 0) overruns_ += static_cast<std::uint64_t>(late);
  next_ += period_ * (late + 1);
  frame = make_frame(cob::kSync, overflow_ >= 2 ? 1 : 0);
  if (overflow_ >= 2) {
    frame.data[0] = counter_;
    counter_ = counter_ >= overflow_ ? 1 : static_cast<std::uint8_t>(counter_ + 1);
  }
  ++sent_;
  return true;
}

bool HeartbeatProducer::poll(Timestamp now, NmtState state, can::Frame& frame) {
  if (!enabled()) return false;
  if (!started_) {
    started_ = true;
    next_ = now;
  }
  if (now < next_) return false;
  // The next one is due a period after this one was due, not after it was sent: polled once per
  // cycle, "now + period" made every heartbeat late by up to a cycle (60 ms for 50 ms at a 20 ms
  // cycle). A caller late by whole periods gets one heartbeat, not a burst.
  const auto late = (now - next_) / period_;
  next_ += period_ * (late + 1);
  frame = make_frame(cob_id_, 1);
  frame.data[0] = static_cast<std::uint8_t>(state);
  return true;
}

}  // namespace cdpr::canopen
