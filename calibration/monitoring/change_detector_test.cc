// The CUSUM and its threshold: the stated false-alarm rate holds on simulated N(0, 1) residuals,
// a shift is detected, bad input is refused.
#include "cdpr/calibration/change_detector.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace cdpr {
namespace {

// Alarms of `channels` CUSUMs fed `samples` N(mean, 1) samples each.
int alarms(double h, double k, int channels, long samples, double mean, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(mean, 1.0);
  int count = 0;
  for (int c = 0; c < channels; ++c) {
    Cusum cusum(k, h);
    for (long s = 0; s < samples; ++s) count += cusum.update(normal(rng)) ? 1 : 0;
  }
  return count;
}

TEST(Cusum, ThresholdGivesTheStatedFalseAlarmRateOnNoise) {
  // 4 channels at 3600 samples per hour, 2 false alarms per hour stated: simulate 250 hours.
  const double rate = 2.0, per_hour = 3600.0, k = 0.5;
  const int channels = 4;
  Result<double> h = cusum_threshold(rate, per_hour, channels, k);
  ASSERT_TRUE(h.ok()) << h.status().to_string();
  const double hours = 250.0;
  const int n = alarms(*h, k, channels, static_cast<long>(hours * per_hour), 0.0, 7);
  const double measured = n / hours;
  EXPECT_GT(measured, 0.8 * rate) << "h " << *h;
  EXPECT_LT(measured, 1.25 * rate) << "h " << *h;
}

TEST(Cusum, SiegmundArlGrowsWithTheThresholdAndMatchesTheTableValue) {
  // Two-sided, k = 0.5, h = 4: the classical in-control ARL is about 168 per side pair
  // (one side ~ 336); Siegmund's approximation gives 336.
  EXPECT_NEAR(cusum_arl0(4.0, 0.5), 336.0, 5.0);
  EXPECT_GT(cusum_arl0(5.0, 0.5), cusum_arl0(4.0, 0.5));
  Result<double> h = cusum_threshold(3600.0 / 168.0, 3600.0, 1, 0.5);
  ASSERT_TRUE(h.ok());
  EXPECT_NEAR(*h, 4.0, 0.05);
}

TEST(Cusum, DetectsAShiftOfTwiceTheAllowanceWithinTensSamples) {
  Result<double> h = cusum_threshold(0.1, 3600.0, 10, 0.5);
  ASSERT_TRUE(h.ok());
  std::mt19937_64 rng(3);
  std::normal_distribution<double> normal(1.0, 1.0);
  Cusum cusum(0.5, *h);
  int n = 0;
  while (!cusum.update(normal(rng)) && n < 1000) ++n;
  EXPECT_LT(n, 4.0 * (*h + 1.166) / 0.5);  // the mean run length is (h + 1.166) / (mu - k)
  EXPECT_EQ(cusum.last_alarm_sign(), 1);
  EXPECT_EQ(cusum.statistic(), 0.0);  // restarted after the alarm
}

TEST(Cusum, SkipsNonFiniteSamplesAndRefusesBadRates) {
  Cusum cusum(0.5, 1.0);
  EXPECT_FALSE(cusum.update(std::nan("")));
  EXPECT_FALSE(cusum.update(INFINITY));
  EXPECT_EQ(cusum.statistic(), 0.0);
  EXPECT_FALSE(cusum_threshold(0.0, 3600.0, 1, 0.5).ok());
  EXPECT_FALSE(cusum_threshold(1.0, 3600.0, 0, 0.5).ok());
  EXPECT_FALSE(cusum_threshold(1.0, 3600.0, 1, -0.5).ok());
}

}  // namespace
}  // namespace cdpr
