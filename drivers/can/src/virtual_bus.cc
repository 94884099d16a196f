#include "cdpr/can/virtual_bus.hpp"

#include <algorithm>
#include <condition_variable>
#include <mutex>
#include <utility>
#include <vector>

namespace cdpr::can {

double bus_load(const LoadSample& a, const LoadSample& b) {
  const auto window = b.time - a.time;
  if (window.count() <= 0) return 0.0;
  return static_cast<double>((b.busy - a.busy).count()) / static_cast<double>(window.count());
}

std::uint32_t frame_bits(const Frame& frame) {
  if (frame.error) return 6 + 6 + 8 + 3;
  const std::uint32_t data_bits = frame.rtr ? 0U : 8U * std::min<std::uint32_t>(frame.dlc, 8);
  // Stuffed region SOF..CRC: standard 1+11+1+1+1+4+15 = 34, extended 1+11+1+1+18+1+2+4+15 = 54.
  const std::uint32_t stuffed = (frame.extended ? 54U : 34U) + data_bits;
  // Unstuffed tail: CRC delimiter 1, ACK 2, EOF 7, IFS 3 = 13.
  const std::uint32_t stuff_bits = (stuffed - 1U) / 4U;
  return stuffed + 13U + stuff_bits;
}

// One endpoint's receive queue: a ring preallocated at creation. Guarded by State::mutex.
struct VirtualCanEndpoint::Queue {
  explicit Queue(std::size_t capacity) : ring(capacity == 0 ? 1 : capacity) {}

  bool push(const Frame& f) {
    if (size == ring.size()) {
      ++stats.rx_dropped;
      return false;
    }
    ring[(head + size) % ring.size()] = f;
    ++size;
    return true;
  }
  Frame pop() {
    Frame f = ring[head];
    head = (head + 1) % ring.size();
    --size;
    return f;
  }

  std::vector<Frame> ring;
  std::size_t head = 0;
  std::size_t size = 0;
  BusStats stats;
  std::condition_variable ready;
};

// Shared by the bus object and its endpoints. One mutex for the whole bus keeps delivery atomic
// (every endpoint sees frames in the same order, as on a real bus); the critical sections are a
// few copies, so contention is not a concern at CAN frame rates.
struct VirtualCanBus::State {
  State(const Clock& c, VirtualBusOptions o) : clock(c), options(o) {}

  // Caller holds `mutex`. Delivers to every queue except `from` (nullptr = to all).
  void deliver(const Frame& frame, const VirtualCanEndpoint::Queue* from) {
    Frame f = frame;
    f.timestamp = clock.now();
    if (options.bit_timing && options.bitrate > 0) {
      busy += Timestamp{static_cast<std::int64_t>(frame_bits(f)) * 1'000'000'000LL /
                        static_cast<std::int64_t>(options.bitrate)};
    }
    for (VirtualCanEndpoint::Queue* q : queues) {
      if (q == from) continue;
      if (q->push(f)) q->ready.notify_one();
    }
  }

  const Clock& clock;
  const VirtualBusOptions options;
  mutable std::mutex mutex;
  std::vector<VirtualCanEndpoint::Queue*> queues;
  Timestamp busy{0};
};

VirtualCanBus::VirtualCanBus(const Clock& clock, VirtualBusOptions options)
    : state_(std::make_shared<State>(clock, options)) {}

VirtualCanBus::~VirtualCanBus() = default;

std::unique_ptr<VirtualCanEndpoint> VirtualCanBus::endpoint(std::string name) {
  std::unique_ptr<VirtualCanEndpoint> ep(
      new VirtualCanEndpoint(state_, std::move(name), state_->options.queue_capacity));
  std::lock_guard lock(state_->mutex);
  state_->queues.push_back(ep->queue_.get());
  return ep;
}

void VirtualCanBus::inject_error(std::uint32_t error_class,
                                 const std::array<std::uint8_t, 8>& data) {
  Frame f;
  f.error = true;
  f.error_class = error_class & error_class::kAll;
  f.dlc = 8;
  f.data = data;
  std::lock_guard lock(state_->mutex);
  state_->deliver(f, nullptr);
}

LoadSample VirtualCanBus::load_sample() const {
  std::lock_guard lock(state_->mutex);
  return LoadSample{state_->clock.now(), state_->busy};
}

const Clock& VirtualCanBus::clock() const {
  return state_->clock;
}

VirtualCanEndpoint::VirtualCanEndpoint(std::shared_ptr<VirtualCanBus::State> state,
                                       std::string name, std::size_t capacity)
    : state_(std::move(state)),
      name_(std::move(name)),
      empty_poll_(Status::error(ErrorCode::kTimeout, "%s: no CAN frame waiting", name_.c_str())),
      queue_(std::make_unique<Queue>(capacity)) {}

VirtualCanEndpoint::~VirtualCanEndpoint() {
  std::lock_guard lock(state_->mutex);
  auto& qs = state_->queues;
  qs.erase(std::remove(qs.begin(), qs.end(), queue_.get()), qs.end());
}

Status VirtualCanEndpoint::send(const Frame& frame) {
  CDPR_RETURN_IF_ERROR(check_frame(frame, name_));
  if (tx_failing_.load(std::memory_order_relaxed)) {
    return Status(ErrorCode::kUnavailable, "transmit failing (test)");
  }
  // Normalise what a wire would carry: no payload for RTR, nothing beyond dlc.
  Frame f = frame;
  if (f.error) {
    f.id = 0;
    f.extended = false;
    f.rtr = false;
    f.dlc = 8;  // an error frame always carries 8 bytes (CAN_ERR_DLC)
  } else {
    f.error_class = 0;
  }
  for (std::size_t i = (f.rtr ? 0U : f.dlc); i < f.data.size(); ++i) f.data[i] = 0;
  std::lock_guard lock(state_->mutex);
  state_->deliver(f, queue_.get());
  ++queue_->stats.frames_sent;
  return Status::success();
}

Status VirtualCanEndpoint::receive(Frame& frame, std::chrono::nanoseconds timeout) {
  std::unique_lock lock(state_->mutex);
  Queue& q = *queue_;
  if (q.size == 0) {
    if (timeout.count() <= 0 || !state_->clock.real_time() ||
        !q.ready.wait_for(lock, timeout, [&q] { return q.size > 0; })) {
      // A poll (timeout 0, the RT cycle's reads until empty) gets the message made at
      // construction: formatting one costs more than the rest of the read.
      if (timeout.count() <= 0) return empty_poll_;
      return Status::error(ErrorCode::kTimeout, "%s: no CAN frame within %lld us", name_.c_str(),
                           static_cast<long long>(timeout.count() / 1000));
    }
  }
  frame = q.pop();
  ++q.stats.frames_received;
  if (frame.error) ++q.stats.error_frames;
  return Status::success();
}

BusStats VirtualCanEndpoint::stats() const {
  std::lock_guard lock(state_->mutex);
  return queue_->stats;
}

}  // namespace cdpr::can
