// Network management seen from the master: node state tracking from boot-up and heartbeat
// messages with a per-node consumer timeout, the SYNC producer and the master's own heartbeat.
// All per-cycle calls are allocation-free; time is always passed in by the caller so the same code
// runs on the monotonic clock and on a test's injected clock.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>

#include "cdpr/canopen/events.hpp"
#include "cdpr/canopen/types.hpp"

namespace cdpr::canopen {

// State of every node 1..127 as far as the master knows it.
class NodeMonitor {
 public:
  struct Node {
    NmtState state = NmtState::kUnknown;
    NmtState last_reported = NmtState::kUnknown;  // before kLost
    Timestamp last_seen{0};
    std::chrono::nanoseconds timeout{0};  // 0 = not consumed
    std::uint32_t boot_count = 0;
    std::uint32_t lost_count = 0;
    bool heard = false;
  };

  // Consume node's heartbeat: if nothing arrives within `timeout` after the last one, the node is
  // reported lost. The clock starts at the first heartbeat (CiA 301 behaviour), so a node that is
  // not there yet is "unknown", not "lost".
  void consume(NodeId node, std::chrono::nanoseconds timeout);

  // Feeds one frame; returns true if it was a heartbeat/boot-up (0x700 + node, 1 byte).
  bool on_frame(const can::Frame& frame, Timestamp now, Events& events);

  // Checks consumer timeouts; a node that times out becomes kLost once (one event).
  void check(Timestamp now, Events& events);

  // What the master expects after it has sent an NMT command (heartbeat confirms later).
  void forget(NodeId node);

  const Node& node(NodeId id) const { return nodes_[id]; }
  NmtState state(NodeId id) const { return nodes_[id].state; }

 private:
  std::array<Node, kMaxNodeId + 1> nodes_{};
};

// SYNC producer (CiA 301, 7.2.5). The period is the communication cycle period (0x1006).
class SyncProducer {
 public:
  SyncProducer() = default;
  // counter_overflow 0: SYNC without data; 2..240: one counter byte 1..overflow (0x1019).
  explicit SyncProducer(std::chrono::nanoseconds period, std::uint8_t counter_overflow = 0)
      : period_(period), overflow_(counter_overflow) {}

  void start(Timestamp now) {
    running_ = true;
    next_ = now;
    counter_ = 1;
  }
  void stop() { running_ = false; }
  bool running() const { return running_; }
  std::chrono::nanoseconds period() const { return period_; }

  // True (and `frame` filled) when a SYNC is due at `now`. A caller that was late by whole periods
  // gets one SYNC, not a burst: the schedule moves on and `overruns` counts the skipped periods.
  bool poll(Timestamp now, can::Frame& frame);

  std::uint64_t sent() const { return sent_; }
  std::uint64_t overruns() const { return overruns_; }
  Timestamp next_due() const { return next_; }

 private:
  std::chrono::nanoseconds period_{std::chrono::milliseconds(4)};
  std::uint8_t overflow_ = 0;
  std::uint8_t counter_ = 1;
  bool running_ = false;
  Timestamp next_{0};
  std::uint64_t sent_ = 0;
  std::uint64_t overruns_ = 0;
};

// The master's own heartbeat, watched by the drives through 0x1016 so that a dead master stops
// them (0x6007).
class HeartbeatProducer {
 public:
  HeartbeatProducer() = default;
  HeartbeatProducer(std::uint32_t cob_id, std::chrono::nanoseconds period)
      : cob_id_(cob_id), period_(period) {}
  bool enabled() const { return period_.count() > 0; }
  // True (and `frame` filled) when a heartbeat is due. Heartbeats are due every period from the
  // first poll on, whatever the polling cycle (no drift).
  bool poll(Timestamp now, NmtState state, can::Frame& frame);
  // The boot-up message (state 0x00) the master sends once before its first heartbeat.
  can::Frame boot_up() const {
    can::Frame f = make_frame(cob_id_, 1);
    f.data[0] = static_cast<std::uint8_t>(NmtState::kBootUp);
    return f;
  }

 private:
  std::uint32_t cob_id_ = 0x77F;
  std::chrono::nanoseconds period_{0};
  Timestamp next_{0};
  bool started_ = false;
};

}  // namespace cdpr::canopen
