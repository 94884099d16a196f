#include "cdpr/controller/cycle_stats.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <limits>

namespace cdpr::controller {

using std::chrono::nanoseconds;

namespace {

constexpr std::size_t kLinearBuckets = DurationHistogram::kSubBuckets;
constexpr int kLinearShift = DurationHistogram::kFirstOctave - DurationHistogram::kSubBucketBits;
constexpr std::uint64_t kOverflowAt = std::uint64_t{1} << DurationHistogram::kEndOctave;

std::uint64_t to_ns(nanoseconds d) {
  return d.count() < 0 ? 0 : static_cast<std::uint64_t>(d.count());
}

// 1-based rank of the quantile given in parts per million: ceil(ppm * count / 1e6), at least 1.
// In integers, so that the 0.99-quantile of 100 values is the 99th and not the 100th.
std::uint64_t rank_of(std::uint64_t ppm, std::uint64_t count) {
  const std::uint64_t r = (ppm * count + 999'999) / 1'000'000;
  return r == 0 ? 1 : r;
}

nanoseconds clamp_to_seen(nanoseconds upper_edge, nanoseconds lo, nanoseconds hi) {
  return upper_edge > hi ? hi : (upper_edge < lo ? lo : upper_edge);
}

}  // namespace

std::size_t DurationHistogram::bucket_index(nanoseconds d) noexcept {
  const std::uint64_t v = to_ns(d);
  if (v < (std::uint64_t{1} << kFirstOctave)) return static_cast<std::size_t>(v >> kLinearShift);
  if (v >= kOverflowAt) return kBuckets - 1;
  const int octave_bit = std::bit_width(v) - 1;  // kFirstOctave .. kEndOctave-1
  const int shift = octave_bit - kSubBucketBits;
  const std::size_t sub = static_cast<std::size_t>((v >> shift) & (kSubBuckets - 1));
  return kLinearBuckets + static_cast<std::size_t>(octave_bit - kFirstOctave) * kSubBuckets + sub;
}

nanoseconds DurationHistogram::bucket_lower(std::size_t i) noexcept {
  if (i < kLinearBuckets) return nanoseconds{static_cast<std::int64_t>(i) << kLinearShift};
  if (i >= kBuckets - 1) return nanoseconds{static_cast<std::int64_t>(kOverflowAt)};
  const std::size_t k = i - kLinearBuckets;
  const int octave_bit = kFirstOctave + static_cast<int>(k / kSubBuckets);
  const std::uint64_t sub = k % kSubBuckets;
  return nanoseconds{
      static_cast<std::int64_t>((kSubBuckets + sub) << (octave_bit - kSubBucketBits))};
}

nanoseconds DurationHistogram::bucket_upper(std::size_t i) noexcept {
  if (i >= kBuckets - 1) return nanoseconds::max();
  return bucket_lower(i + 1);
}

void DurationHistogram::record(nanoseconds d) noexcept {
  const std::uint64_t v = to_ns(d);
  const std::size_t i = bucket_index(d);
  ++buckets_[i];
  ++groups_[i / kSubBuckets];
  if (count_ == 0 || v < min_ns_) min_ns_ = v;
  if (count_ == 0 || v > max_ns_) max_ns_ = v;
  ++count_;
  sum_ns_ += v;
}

void DurationHistogram::reset() noexcept {
  *this = DurationHistogram{};
}

nanoseconds DurationHistogram::min() const noexcept {
  return nanoseconds{static_cast<std::int64_t>(min_ns_)};
}
nanoseconds DurationHistogram::max() const noexcept {
  return nanoseconds{static_cast<std::int64_t>(max_ns_)};
}
nanoseconds DurationHistogram::mean() const noexcept {
  return count_ == 0 ? nanoseconds{0} : nanoseconds{static_cast<std::int64_t>(sum_ns_ / count_)};
}

std::size_t DurationHistogram::bucket_of_rank(std::uint64_t rank) const noexcept {
  std::uint64_t seen = 0;
  std::size_t g = 0;
  while (g + 1 < kGroups && seen + groups_[g] < rank) seen += groups_[g++];
  std::size_t i = g * kSubBuckets;
  const std::size_t end = std::min(i + kSubBuckets, kBuckets);
  for (; i + 1 < end; ++i) {
    seen += buckets_[i];
    if (seen >= rank) return i;
  }
  return i;
}

nanoseconds DurationHistogram::quantile(double q) const noexcept {
  if (count_ == 0) return nanoseconds{0};
  if (!(q > 0.0)) return min();
  if (q >= 1.0) return max();
  const std::uint64_t rank = rank_of(static_cast<std::uint64_t>(std::llround(q * 1e6)), count_);
  return clamp_to_seen(bucket_upper(bucket_of_rank(rank)), min(), max());
}

DurationSummary summarize(const DurationHistogram& h) noexcept {
  DurationSummary s;
  s.count = h.count();
  s.min = h.min();
  s.max = h.max();
  s.mean = h.mean();
  if (s.count == 0) return s;
  s.p50 = clamp_to_seen(
      DurationHistogram::bucket_upper(h.bucket_of_rank(rank_of(500'000, s.count))), s.min, s.max);
  s.p99 = clamp_to_seen(
      DurationHistogram::bucket_upper(h.bucket_of_rank(rank_of(990'000, s.count))), s.min, s.max);
  s.p999 = clamp_to_seen(
      DurationHistogram::bucket_upper(h.bucket_of_rank(rank_of(999'000, s.count))), s.min, s.max);
  return s;
}

void CycleStats::record_cycle(nanoseconds wake_latency, nanoseconds compute, bool overrun,
                              std::uint64_t skipped_periods) noexcept {
  latency_.record(wake_latency);
  compute_.record(compute);
  if (overrun) {
    ++overruns_;
    last_overrun_cycle_ = cycles_;
    last_overrun_compute_ = compute;
  }
  skipped_ += skipped_periods;
  ++cycles_;
}

void CycleStats::reset() noexcept {
  latency_.reset();
  compute_.reset();
  cycles_ = overruns_ = skipped_ = last_overrun_cycle_ = 0;
  last_overrun_compute_ = nanoseconds{0};
}

CycleStatsSnapshot CycleStats::snapshot() const noexcept {
  CycleStatsSnapshot s;
  s.cycles = cycles_;
  s.overruns = overruns_;
  s.skipped_periods = skipped_;
  s.last_overrun_cycle = last_overrun_cycle_;
  s.last_overrun_compute = last_overrun_compute_;
  s.wake_latency = summarize(latency_);
  s.compute = summarize(compute_);
  return s;
}

std::string format_duration(nanoseconds d) {
  const double ns = static_cast<double>(d.count());
  const double a = std::fabs(ns);
  char buf[32];
  if (a < 1e3) {
    std::snprintf(buf, sizeof buf, "%.0f ns", ns);
  } else if (a < 1e6) {
    std::snprintf(buf, sizeof buf, a < 1e4 ? "%.2f us" : (a < 1e5 ? "%.1f us" : "%.0f us"),
                  ns / 1e3);
  } else if (a < 1e9) {
    std::snprintf(buf, sizeof buf, a < 1e7 ? "%.2f ms" : (a < 1e8 ? "%.1f ms" : "%.0f ms"),
                  ns / 1e6);
  } else {
    std::snprintf(buf, sizeof buf, "%.2f s", ns / 1e9);
  }
  return buf;
}

namespace {

std::string describe_one(const char* name, const DurationSummary& d) {
  return std::string(name) + " p50 " + format_duration(d.p50) + ", p99 " + format_duration(d.p99) +
         ", p99.9 " + format_duration(d.p999) + ", max " + format_duration(d.max) + ", mean " +
         format_duration(d.mean);
}

}  // namespace

std::string describe(const CycleStatsSnapshot& s) {
  char head[160];
  std::snprintf(head, sizeof head, "%llu cycles, %llu overruns (%llu periods skipped); ",
                static_cast<unsigned long long>(s.cycles),
                static_cast<unsigned long long>(s.overruns),
                static_cast<unsigned long long>(s.skipped_periods));
  char tail[64];
  std::snprintf(tail, sizeof tail, " (percentiles within %.1f %% above)",
                100.0 * DurationHistogram::kRelativeResolution);
  return std::string(head) + describe_one("wake-up latency", s.wake_latency) + "; " +
         describe_one("compute", s.compute) + tail;
}

}  // namespace cdpr::controller
