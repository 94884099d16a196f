// Timing statistics of the real-time loop: wake-up latency and compute time per cycle.
//
//   CycleStats stats;                              // owned and written by the RT thread only
//   stats.record_cycle(latency, compute, overrun, skipped);   // no allocation, no lock
//   board.publish(stats);                          // CycleStatsBoard: seqlock, lock-free
//   CycleStatsSnapshot s = board.read();           // any other thread, any time
//
// Durations go into a fixed-size log-linear histogram (DurationHistogram): 32 linear buckets of
// 32 ns below 1.024 us, then every octave from 2^10 ns (1.024 us) to 2^30 ns (1.074 s) split into
// 32 equal buckets, and one overflow bucket above. A percentile is reported as the upper edge of
// the bucket that holds it (clamped to the largest value seen), so it is never below the true
// value and at most one bucket width above it: at most 3.125 % of the value above 1.024 us, at
// most 32 ns below. Count, min, max and mean are exact.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>

#include "cdpr/core/seqlock.hpp"

namespace cdpr::controller {

class DurationHistogram {
 public:
  static constexpr std::size_t kSubBuckets = 32;  // buckets per octave
  static constexpr int kSubBucketBits = 5;        // log2(kSubBuckets)
  static constexpr int kFirstOctave = 10;         // linear below 2^10 ns
  static constexpr int kEndOctave = 30;           // overflow at and above 2^30 ns
  static constexpr std::size_t kBuckets =
      kSubBuckets + static_cast<std::size_t>(kEndOctave - kFirstOctave) * kSubBuckets + 1;
  // Largest relative width of a bucket above 2^10 ns (the resolution of a percentile).
  static constexpr double kRelativeResolution = 1.0 / kSubBuckets;
  // Width of a bucket below 2^10 ns.
  static constexpr std::chrono::nanoseconds kLinearResolution{1 << (kFirstOctave - kSubBucketBits)};

  // Adds one duration; a negative one counts as zero. O(1), no allocation.
  void record(std::chrono::nanoseconds d) noexcept;
  void reset() noexcept;

  std::uint64_t count() const noexcept { return count_; }
  // Exact; zero when empty.
  std::chrono::nanoseconds min() const noexcept;
  std::chrono::nanoseconds max() const noexcept;
  std::chrono::nanoseconds mean() const noexcept;
  // The q-quantile (0 < q <= 1, in steps of 1e-6): the upper edge of the bucket holding the
  // ceil(q * count)-th smallest value, clamped to [min, max]. Zero when empty.
  std::chrono::nanoseconds quantile(double q) const noexcept;

  std::uint64_t bucket_count(std::size_t i) const noexcept { return buckets_[i]; }
  // Index of the bucket that holds the rank-th smallest value (1 <= rank <= count()). Scans the
  // per-octave totals, then one octave: at most 21 + 32 steps.
  std::size_t bucket_of_rank(std::uint64_t rank) const noexcept;
  // Bucket i holds values in [bucket_lower(i), bucket_upper(i)); the last one has no upper edge
  // (bucket_upper returns nanoseconds::max()).
  static std::chrono::nanoseconds bucket_lower(std::size_t i) noexcept;
  static std::chrono::nanoseconds bucket_upper(std::size_t i) noexcept;
  static std::size_t bucket_index(std::chrono::nanoseconds d) noexcept;

 private:
  // Buckets in groups of kSubBuckets (the linear range, then one group per octave); the last
  // group is the overflow bucket alone.
  static constexpr std::size_t kGroups = (kBuckets + kSubBuckets - 1) / kSubBuckets;
  std::array<std::uint64_t, kBuckets> buckets_{};
  std::array<std::uint64_t, kGroups> groups_{};
  std::uint64_t count_ = 0;
  std::uint64_t sum_ns_ = 0;
  std::uint64_t min_ns_ = 0;
  std::uint64_t max_ns_ = 0;
};

// A distribution reduced to the figures the daemon reports.
struct DurationSummary {
  std::uint64_t count = 0;
  std::chrono::nanoseconds min{0};
  std::chrono::nanoseconds max{0};
  std::chrono::nanoseconds mean{0};
  std::chrono::nanoseconds p50{0};
  std::chrono::nanoseconds p99{0};
  std::chrono::nanoseconds p999{0};  // p99.9
};

DurationSummary summarize(const DurationHistogram& h) noexcept;

// What another thread may read about the loop (trivially copyable, for the seqlock).
struct CycleStatsSnapshot {
  std::uint64_t cycles = 0;              // completed cycles
  std::uint64_t overruns = 0;            // cycles whose compute ended after the next wake time
  std::uint64_t skipped_periods = 0;     // periods left out to re-align after overruns
  std::uint64_t last_overrun_cycle = 0;  // index of the newest overrun cycle (valid if overruns)
  std::chrono::nanoseconds last_overrun_compute{0};  // its compute time
  DurationSummary wake_latency;                      // actual wake time minus nominal wake time
  DurationSummary compute;  // from the wake-up to the end of the cycle's work
};

// The statistics of one loop. Written by one thread (not thread-safe); publish through
// CycleStatsBoard for readers on other threads.
class CycleStats {
 public:
  // One completed cycle. No allocation, no lock, no exception.
  void record_cycle(std::chrono::nanoseconds wake_latency, std::chrono::nanoseconds compute,
                    bool overrun, std::uint64_t skipped_periods) noexcept;
  void reset() noexcept;

  std::uint64_t cycles() const noexcept { return cycles_; }
  std::uint64_t overruns() const noexcept { return overruns_; }
  std::uint64_t skipped_periods() const noexcept { return skipped_; }
  const DurationHistogram& wake_latency() const noexcept { return latency_; }
  const DurationHistogram& compute() const noexcept { return compute_; }

  // Reduces both histograms (a scan of their filled buckets; no allocation).
  CycleStatsSnapshot snapshot() const noexcept;

 private:
  DurationHistogram latency_;
  DurationHistogram compute_;
  std::uint64_t cycles_ = 0;
  std::uint64_t overruns_ = 0;
  std::uint64_t skipped_ = 0;
  std::uint64_t last_overrun_cycle_ = 0;
  std::chrono::nanoseconds last_overrun_compute_{0};
};

// The newest snapshot of a loop's statistics, readable from any thread without a lock.
// The seqlock is cdpr::SeqLock (header-only; it belongs in a core library).
class CycleStatsBoard {
 public:
  // Single writer (the loop's thread). No allocation, no lock.
  void publish(const CycleStats& stats) noexcept { board_.store(stats.snapshot()); }
  void publish(const CycleStatsSnapshot& snapshot) noexcept { board_.store(snapshot); }
  // Any thread.
  CycleStatsSnapshot read() const noexcept { return board_.load(); }
  // Number of publications so far.
  std::uint64_t version() const noexcept { return board_.version(); }

 private:
  cdpr::SeqLock<CycleStatsSnapshot> board_;
};

// One line for a log or `cdprctl status` (allocates; not for the RT thread):
// "1000 cycles, 0 overruns (0 periods skipped); wake-up latency p50 52 us, p99 80 us,
//  p99.9 120 us, max 130 us; compute p50 3.1 us, ... (percentiles within 3.1 % above)"
std::string describe(const CycleStatsSnapshot& s);
// "52 us", "3.1 us", "850 ns", "4.2 ms", "1.3 s"
std::string format_duration(std::chrono::nanoseconds d);

}  // namespace cdpr::controller
