#include "cdpr/controller/cycle_stats.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <random>
#include <thread>
#include <vector>

#include "alloc_counter.hpp"

namespace cdpr::controller {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using std::chrono::nanoseconds;
using H = DurationHistogram;

// The value the histogram should report for the q-quantile of `values`: the upper edge of the
// bucket of the ceil(q n)-th smallest value, clamped to [min, max].
nanoseconds expected_quantile(std::vector<nanoseconds> values, double q) {
  std::sort(values.begin(), values.end());
  const auto n = static_cast<double>(values.size());
  auto rank = static_cast<std::size_t>(std::ceil(q * n - 1e-9));
  if (rank == 0) rank = 1;
  const nanoseconds v = values[rank - 1];
  return std::clamp(H::bucket_upper(H::bucket_index(v)), values.front(), values.back());
}

TEST(DurationHistogram, BucketsTileTheRangeWithoutGapsOrOverlap) {
  EXPECT_EQ(H::bucket_lower(0), nanoseconds{0});
  for (std::size_t i = 0; i + 1 < H::kBuckets; ++i) {
    ASSERT_LT(H::bucket_lower(i), H::bucket_upper(i)) << i;
    ASSERT_EQ(H::bucket_upper(i), H::bucket_lower(i + 1)) << i;
    // Every bucket maps its own edges back to itself.
    ASSERT_EQ(H::bucket_index(H::bucket_lower(i)), i);
    ASSERT_EQ(H::bucket_index(H::bucket_upper(i) - nanoseconds{1}), i);
  }
  EXPECT_EQ(H::bucket_upper(H::kBuckets - 1), nanoseconds::max());
  EXPECT_EQ(H::bucket_index(nanoseconds{std::int64_t{1} << 30}), H::kBuckets - 1);
}

TEST(DurationHistogram, BucketWidthIsTheStatedResolution) {
  for (std::size_t i = 0; i + 1 < H::kBuckets; ++i) {
    const auto lo = static_cast<double>(H::bucket_lower(i).count());
    const auto width = static_cast<double>((H::bucket_upper(i) - H::bucket_lower(i)).count());
    if (H::bucket_lower(i) < nanoseconds{1 << H::kFirstOctave}) {
      EXPECT_EQ(width, static_cast<double>(H::kLinearResolution.count())) << i;
    } else {
      EXPECT_LE(width / lo, H::kRelativeResolution + 1e-12) << i;
    }
  }
  // 1 us .. 1 s are inside the bucketed range.
  EXPECT_LT(H::bucket_index(microseconds{1}), H::kBuckets - 1);
  EXPECT_LT(H::bucket_index(std::chrono::seconds{1}), H::kBuckets - 1);
}

TEST(DurationHistogram, EmptyReportsZero) {
  H h;
  EXPECT_EQ(h.count(), 0u);
  EXPECT_EQ(h.min(), nanoseconds{0});
  EXPECT_EQ(h.max(), nanoseconds{0});
  EXPECT_EQ(h.mean(), nanoseconds{0});
  EXPECT_EQ(h.quantile(0.5), nanoseconds{0});
  const DurationSummary s = summarize(h);
  EXPECT_EQ(s.count, 0u);
  EXPECT_EQ(s.p999, nanoseconds{0});
}

TEST(DurationHistogram, CountMinMaxMeanAreExact) {
  H h;
  std::vector<nanoseconds> v{microseconds{7}, nanoseconds{333}, milliseconds{3}, microseconds{51}};
  std::int64_t sum = 0;
  for (auto d : v) {
    h.record(d);
    sum += d.count();
  }
  EXPECT_EQ(h.count(), v.size());
  EXPECT_EQ(h.min(), *std::min_element(v.begin(), v.end()));
  EXPECT_EQ(h.max(), *std::max_element(v.begin(), v.end()));
  EXPECT_EQ(h.mean(), nanoseconds{sum / static_cast<std::int64_t>(v.size())});
}

TEST(DurationHistogram, QuantileIsTheUpperEdgeOfTheBucketOfTheRankedValue) {
  std::mt19937_64 rng(12);
  std::lognormal_distribution<double> dist(std::log(50e3), 0.6);  // around 50 us, long tail
  std::vector<nanoseconds> v;
  H h;
  for (int i = 0; i < 20000; ++i) {
    const nanoseconds d{static_cast<std::int64_t>(dist(rng))};
    v.push_back(d);
    h.record(d);
  }
  std::vector<nanoseconds> sorted = v;
  std::sort(sorted.begin(), sorted.end());
  for (double q : {0.001, 0.1, 0.5, 0.9, 0.99, 0.999, 0.9999}) {
    const nanoseconds got = h.quantile(q);
    EXPECT_EQ(got, expected_quantile(v, q)) << q;
    // Never below the true quantile, at most the stated resolution above it.
    const nanoseconds truth = sorted[static_cast<std::size_t>(std::ceil(q * 20000 - 1e-9)) - 1];
    EXPECT_GE(got, truth) << q;
    EXPECT_LE(static_cast<double>(got.count()),
              static_cast<double>(truth.count()) * (1 + H::kRelativeResolution) +
                  static_cast<double>(H::kLinearResolution.count()))
        << q;
  }
  EXPECT_EQ(h.quantile(1.0), sorted.back());
}

TEST(DurationHistogram, RankIsComputedInIntegersSo99thOf100IsNotTheLargest) {
  H h;
  std::vector<nanoseconds> v;
  for (int i = 1; i <= 100; ++i) {
    v.push_back(microseconds{10 * i});
    h.record(v.back());
  }
  const nanoseconds p99 = h.quantile(0.99);
  EXPECT_EQ(p99, expected_quantile(v, 0.99));
  EXPECT_GE(p99, v[98]);     // the 99th smallest
  EXPECT_LT(p99, v.back());  // not the 100th
}

TEST(DurationHistogram, NegativeCountsAsZeroAndOverflowKeepsTheExactMaximum) {
  H h;
  h.record(nanoseconds{-5});
  h.record(std::chrono::seconds{2});
  EXPECT_EQ(h.min(), nanoseconds{0});
  EXPECT_EQ(h.bucket_count(0), 1u);
  EXPECT_EQ(h.bucket_count(H::kBuckets - 1), 1u);
  EXPECT_EQ(h.max(), std::chrono::seconds{2});
  EXPECT_EQ(h.quantile(0.99), std::chrono::seconds{2});
}

TEST(DurationHistogram, SummaryMatchesQuantiles) {
  H h;
  std::mt19937_64 rng(3);
  std::exponential_distribution<double> dist(1.0 / 20e3);
  for (int i = 0; i < 5000; ++i) h.record(nanoseconds{static_cast<std::int64_t>(dist(rng))});
  const DurationSummary s = summarize(h);
  EXPECT_EQ(s.count, h.count());
  EXPECT_EQ(s.min, h.min());
  EXPECT_EQ(s.max, h.max());
  EXPECT_EQ(s.mean, h.mean());
  EXPECT_EQ(s.p50, h.quantile(0.5));
  EXPECT_EQ(s.p99, h.quantile(0.99));
  EXPECT_EQ(s.p999, h.quantile(0.999));
}

TEST(CycleStats, CountsCyclesOverrunsAndSkippedPeriods) {
  CycleStats s;
  s.record_cycle(microseconds{40}, microseconds{900}, false, 0);
  s.record_cycle(microseconds{60}, milliseconds{5}, true, 1);
  s.record_cycle(microseconds{50}, microseconds{800}, false, 0);
  s.record_cycle(microseconds{30}, milliseconds{9}, true, 2);
  const CycleStatsSnapshot snap = s.snapshot();
  EXPECT_EQ(snap.cycles, 4u);
  EXPECT_EQ(snap.overruns, 2u);
  EXPECT_EQ(snap.skipped_periods, 3u);
  EXPECT_EQ(snap.last_overrun_cycle, 3u);
  EXPECT_EQ(snap.last_overrun_compute, milliseconds{9});
  EXPECT_EQ(snap.wake_latency.count, 4u);
  EXPECT_EQ(snap.wake_latency.max, microseconds{60});
  EXPECT_EQ(snap.compute.min, microseconds{800});
  s.reset();
  EXPECT_EQ(s.snapshot().cycles, 0u);
  EXPECT_EQ(s.compute().count(), 0u);
}

TEST(CycleStats, RecordAndPublishDoNotAllocate) {
  CycleStats s;
  CycleStatsBoard board;
  test::AllocationCounter count;
  for (int i = 0; i < 1000; ++i) {
    s.record_cycle(microseconds{i % 97}, microseconds{i % 13}, i % 100 == 0, i % 100 == 0);
    board.publish(s);
  }
  const CycleStatsSnapshot snap = board.read();
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(snap.cycles, 1000u);
}

TEST(CycleStatsBoard, ReaderOnAnotherThreadSeesOnlyConsistentSnapshots) {
  CycleStats s;
  CycleStatsBoard board;
  std::atomic<bool> done{false};
  std::atomic<long> inconsistent{0}, reads{0};
  std::thread reader([&] {
    std::uint64_t last = 0;
    while (!done.load(std::memory_order_relaxed)) {
      const CycleStatsSnapshot snap = board.read();
      // Written together: a torn copy would mix counts of different cycles.
      if (snap.wake_latency.count != snap.cycles || snap.compute.count != snap.cycles ||
          snap.overruns != snap.cycles / 10 || snap.cycles < last) {
        inconsistent.fetch_add(1);
      }
      last = snap.cycles;
      reads.fetch_add(1, std::memory_order_relaxed);
    }
  });
  const auto t0 = std::chrono::steady_clock::now();
  std::uint64_t i = 0;
  while (i < 50000 ||
         (reads.load() < 1000 && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5))) {
    ++i;
    s.record_cycle(microseconds{i % 200}, microseconds{i % 30}, i % 10 == 0, 0);
    board.publish(s);
  }
  done = true;
  reader.join();
  EXPECT_EQ(inconsistent.load(), 0);
  EXPECT_GT(reads.load(), 0);
  EXPECT_EQ(board.read().cycles, i);
}

TEST(CycleStats, DescribeNamesTheFigures) {
  CycleStats s;
  s.record_cycle(microseconds{52}, nanoseconds{3100}, false, 0);
  s.record_cycle(microseconds{80}, milliseconds{5}, true, 1);
  const std::string text = describe(s.snapshot());
  EXPECT_NE(text.find("2 cycles, 1 overruns (1 periods skipped)"), std::string::npos) << text;
  EXPECT_NE(text.find("max " + format_duration(microseconds{80})), std::string::npos) << text;
  EXPECT_NE(text.find("wake-up latency"), std::string::npos) << text;
  EXPECT_NE(text.find("compute"), std::string::npos) << text;
}

TEST(FormatDuration, PicksAReadableUnit) {
  EXPECT_EQ(format_duration(nanoseconds{850}), "850 ns");
  EXPECT_EQ(format_duration(nanoseconds{3100}), "3.10 us");
  EXPECT_EQ(format_duration(microseconds{52}), "52.0 us");
  EXPECT_EQ(format_duration(microseconds{120}), "120 us");
  EXPECT_EQ(format_duration(microseconds{4200}), "4.20 ms");
  EXPECT_EQ(format_duration(milliseconds{1300}), "1.30 s");
}

}  // namespace
}  // namespace cdpr::controller
