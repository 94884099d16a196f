// The source of time for anything that waits or time-stamps: the real monotonic clock in
// production, a manual clock in tests so that timing logic runs deterministically.
//
//   cdpr::SteadyClock clock;                  // CLOCK_MONOTONIC
//   cdpr::ManualClock test_clock;             // starts at 0, moved by the test
//   test_clock.advance(std::chrono::milliseconds(5));
//
// Times are nanoseconds since an arbitrary epoch (the same base as SocketCAN timestamps for the
// steady clock). now() never allocates, locks or throws, so the RT loop may call it.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>

namespace cdpr {

class Clock {
 public:
  virtual ~Clock() = default;
  virtual std::chrono::nanoseconds now() const = 0;
  // True when time passes on its own, so that waiting for something makes sense. A manual clock
  // returns false: a receive() with a timeout then returns kTimeout at once when nothing is queued,
  // because no other thread is expected to send while the test drives the time.
  virtual bool real_time() const = 0;
};

// std::chrono::steady_clock (CLOCK_MONOTONIC, the same base as SocketCAN timestamps).
class SteadyClock final : public Clock {
 public:
  std::chrono::nanoseconds now() const override {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::steady_clock::now().time_since_epoch());
  }
  bool real_time() const override { return true; }
};

// Time set by the test. Thread-safe.
class ManualClock final : public Clock {
 public:
  explicit ManualClock(std::chrono::nanoseconds start = std::chrono::nanoseconds{0})
      : now_(start.count()) {}
  std::chrono::nanoseconds now() const override {
    return std::chrono::nanoseconds{now_.load(std::memory_order_acquire)};
  }
  bool real_time() const override { return false; }
  void set(std::chrono::nanoseconds t) { now_.store(t.count(), std::memory_order_release); }
  void advance(std::chrono::nanoseconds dt) {
    now_.fetch_add(dt.count(), std::memory_order_acq_rel);
  }

 private:
  std::atomic<std::int64_t> now_;
};

}  // namespace cdpr
