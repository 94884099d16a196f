// The real-time thread of cdprd: scheduling and memory set-up, and the periodic loop.
//
//   class Cycle final : public cdpr::controller::CycleHandler {
//     void cycle(const Wake& w) noexcept override { ... one SYNC, PDOs, kinematics ... }
//   };
//   Cycle c;
//   cdpr::controller::RtLoop loop(options, c);       // options: RtOptions from the daemon YAML
//   if (auto st = loop.start(); !st) { ... }          // starts the thread, waits for its set-up
//   for (const auto& w : loop.setup().warnings) log_warning(w);
//   ... loop.stats() (lock-free), loop.cycles() (for the watchdog) ...
//   loop.stop();
//
// prepare_realtime() asks for SCHED_FIFO, CPU affinity, locked memory and pre-faulted stack and
// heap; whatever the system refuses becomes a warning in RtSetup (never an error or a crash):
// the loop still runs, only its timing is not guaranteed.
//
// PeriodicTimer wakes at absolute times on a fixed grid (clock_nanosleep, CLOCK_MONOTONIC,
// TIMER_ABSTIME), so lateness does not accumulate. A cycle whose compute ends after the next
// wake time is an overrun: it is counted and the grid is re-aligned to the first wake time after
// the end of that compute (the missed periods are skipped, not caught up in a burst; the phase of
// the grid is kept). The time source and the sleep are a LoopClock, so tests can step time
// (ManualLoopClock).
//
// The per-cycle path (PeriodicTimer::wait_next/end_cycle, CycleStats, the snapshot publication,
// RtLoop's loop body) allocates, locks, logs and throws nothing.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/controller/cycle_stats.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

// A point in time of CLOCK_MONOTONIC (the base of std::chrono::steady_clock on Linux and of
// SocketCAN and cdpr::can timestamps), as the time since its origin.
using MonoTime = std::chrono::nanoseconds;

struct RtOptions {
  int priority = 80;  // SCHED_FIFO priority (1..99); 0 keeps the normal scheduler
  int cpu = -1;       // CPU the thread is pinned to; -1: none
  std::chrono::nanoseconds period{std::chrono::milliseconds{4}};  // one SYNC per period
  bool lock_memory = true;                             // mlockall(MCL_CURRENT | MCL_FUTURE)
  std::size_t prefault_stack_bytes = 256 * 1024;       // touched on the RT thread's stack
  std::size_t prefault_heap_bytes = 32 * 1024 * 1024;  // malloc'ed, touched and kept by malloc
};

// What prepare_realtime() obtained. Each item not obtained has a warning saying why (errno
// named), what it means for the loop and how to fix it.
struct RtSetup {
  bool fifo = false;  // SCHED_FIFO obtained
  int priority = 0;   // its priority (0 when not FIFO)
  int cpu = -1;       // pinned to this CPU; -1: not pinned
  bool memory_locked = false;
  long timer_slack_ns = -1;          // the thread's timer slack after the set-up (-1: unknown)
  std::size_t stack_prefaulted = 0;  // bytes
  std::size_t heap_prefaulted = 0;   // bytes
  bool user_mode_linux = false;      // running inside user-mode-linux (timing is the host's)
  std::vector<std::string> warnings;

  // True when everything asked for was obtained (no warnings).
  bool complete() const { return warnings.empty(); }
  // "SCHED_FIFO 80, CPU 1, memory locked, 256 KiB stack and 32 MiB heap pre-faulted" or
  // "normal scheduler, not pinned, memory not locked, ..."
  std::string describe() const;
};

// Sets up the calling thread (scheduling, affinity, timer slack of 1 ns instead of the default
// 50 us that delays every wake-up under the normal scheduler, pre-faulted stack) and the process
// (memory lock, heap). Call it on the RT thread before its loop. Never fails; see
// RtSetup::warnings. Memory is locked only where the lock cannot make later allocations fail:
// RLIMIT_MEMLOCK unlimited or CAP_IPC_LOCK (with a finite limit, MCL_FUTURE would turn every
// allocation past the limit into an out-of-memory error).
RtSetup prepare_realtime(const RtOptions& options);

// Checks the options a daemon reads from its configuration (period > 0, priority 0..99,
// cpu -1 or a valid CPU number, sizes within reason).
Status validate(const RtOptions& options);

// The time source and sleep of a periodic loop.
class LoopClock {
 public:
  virtual ~LoopClock() = default;
  virtual MonoTime now() noexcept = 0;
  // Returns at or after `deadline` (absolute).
  virtual void sleep_until(MonoTime deadline) noexcept = 0;
};

// CLOCK_MONOTONIC with clock_nanosleep(TIMER_ABSTIME); signals do not cut a sleep short.
class MonotonicLoopClock final : public LoopClock {
 public:
  MonoTime now() noexcept override;
  void sleep_until(MonoTime deadline) noexcept override;
};
// One shared instance (stateless).
MonotonicLoopClock& monotonic_loop_clock();

// Time that moves only when told, for deterministic tests: sleep_until(d) sets the time to
// max(now, d) + the wake-up latency set for the next wake-ups; the code under test calls
// advance() to model compute time. Thread-safe (the loop may run on another thread).
class ManualLoopClock final : public LoopClock {
 public:
  explicit ManualLoopClock(MonoTime start = MonoTime{0}) : now_(start.count()) {}
  MonoTime now() noexcept override { return MonoTime{now_.load(std::memory_order_acquire)}; }
  void sleep_until(MonoTime deadline) noexcept override;
  void advance(std::chrono::nanoseconds dt) noexcept {
    now_.fetch_add(dt.count(), std::memory_order_acq_rel);
  }
  void set_wake_latency(std::chrono::nanoseconds latency) noexcept {
    latency_.store(latency.count(), std::memory_order_release);
  }
  std::uint64_t sleeps() const noexcept { return sleeps_.load(std::memory_order_acquire); }

 private:
  std::atomic<std::int64_t> now_;
  std::atomic<std::int64_t> latency_{0};
  std::atomic<std::uint64_t> sleeps_{0};
};

// One wake-up of the loop, given to the cycle.
struct Wake {
  MonoTime nominal{0};                  // the scheduled wake time (on the grid)
  MonoTime now{0};                      // when the thread woke
  std::chrono::nanoseconds latency{0};  // now - nominal
  std::uint64_t cycle = 0;              // index of this cycle (0, 1, 2, ...)
  std::uint64_t tick = 0;               // index of its period on the grid (cycles + skipped)
  std::uint64_t skipped = 0;            // periods skipped right before this cycle (overrun)
};

// The end of a cycle, as PeriodicTimer::end_cycle() measured it.
struct CycleEnd {
  std::chrono::nanoseconds compute{0};  // end - wake
  bool overrun = false;                 // the compute ended after the next nominal wake time
  std::uint64_t skipped = 0;            // periods skipped to re-align
  MonoTime next_wake{0};                // nominal time of the next cycle
};

// A fixed-period wake-up on an absolute grid, with the statistics of its cycles. One thread.
//
//   PeriodicTimer timer(clock, 4ms);
//   timer.start();                       // optional: the first wake-up is now + period
//   while (running) {
//     const Wake w = timer.wait_next();  // ends the previous cycle, sleeps, wakes
//     work(w);
//   }
class PeriodicTimer {
 public:
  // period > 0 (validate() checks the configured value).
  PeriodicTimer(LoopClock& clock, std::chrono::nanoseconds period) noexcept;

  // Sets the grid: the first wake-up at clock.now() + period, or at first_wake.
  void start() noexcept;
  void start(MonoTime first_wake) noexcept;

  // Ends the running cycle (if end_cycle() was not called), sleeps until the next nominal time
  // and returns the wake-up. Starts the grid if start() was not called.
  Wake wait_next() noexcept;
  // Ends the running cycle now: records its latency and compute time, detects an overrun and
  // re-aligns the grid. Without a running cycle it returns {} and records nothing.
  CycleEnd end_cycle() noexcept;

  std::chrono::nanoseconds period() const noexcept { return period_; }
  MonoTime next_wake() const noexcept { return next_; }
  const CycleStats& stats() const noexcept { return stats_; }
  void reset_stats() noexcept { stats_.reset(); }

 private:
  LoopClock& clock_;
  std::chrono::nanoseconds period_;
  MonoTime next_{0};
  bool started_ = false;
  bool in_cycle_ = false;
  Wake current_{};
  std::uint64_t cycles_ = 0;
  std::uint64_t tick_ = 0;
  std::uint64_t pending_skipped_ = 0;
  CycleStats stats_;
};

// The work of one cycle, run on the RT thread. Must not allocate, lock, log or throw.
class CycleHandler {
 public:
  virtual ~CycleHandler() = default;
  virtual void cycle(const Wake& wake) noexcept = 0;
};

// A thread that runs prepare_realtime() and then handler.cycle() once per period until stop().
// Statistics are published after every cycle (lock-free; stats()).
class RtLoop {
 public:
  // The handler and the clock must outlive the loop.
  RtLoop(RtOptions options, CycleHandler& handler, LoopClock& clock = monotonic_loop_clock());
  ~RtLoop();  // stops
  RtLoop(const RtLoop&) = delete;
  RtLoop& operator=(const RtLoop&) = delete;

  // Starts the thread and returns when prepare_realtime() has run on it (setup() is then
  // valid). Errors: invalid options, already running, the thread could not be created.
  Status start();
  // Asks the loop to end after the running cycle; any thread, the cycle included. No allocation.
  void request_stop() noexcept { stop_.store(true, std::memory_order_release); }
  // request_stop() and waits for the thread (at most about one period). Idempotent.
  // Not from the cycle itself.
  void stop();

  bool running() const noexcept { return running_.load(std::memory_order_acquire); }
  const RtSetup& setup() const noexcept { return setup_; }
  const RtOptions& options() const noexcept { return options_; }
  // Lock-free, any thread. Statistics of the current run (since the last start()).
  CycleStatsSnapshot stats() const noexcept { return board_.read(); }
  // Completed cycles over every run of this object (for the watchdog: feed it only while this
  // advances). Any thread.
  std::uint64_t cycles() const noexcept { return cycles_.load(std::memory_order_acquire); }

 private:
  void run() noexcept;

  RtOptions options_;
  CycleHandler& handler_;
  LoopClock& clock_;
  RtSetup setup_;
  CycleStatsBoard board_;
  std::atomic<std::uint64_t> cycles_{0};
  std::atomic<bool> stop_{false};
  std::atomic<bool> running_{false};
  std::atomic<bool> set_up_{false};
  std::thread thread_;
};

}  // namespace cdpr::controller
