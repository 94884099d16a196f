#include "cdpr/modbus/robust_stats.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <vector>

namespace cdpr::modbus {
namespace {

TEST(RobustMean, CleanDataGivesPlainMeanAndSampleStddev) {
  const std::vector<double> x = {1.0, 2.0, 3.0, 4.0, 5.0};
  const RobustMean r = robust_mean(x);
  EXPECT_EQ(r.used, 5);
  EXPECT_EQ(r.rejected, 0);
  EXPECT_DOUBLE_EQ(r.mean, 3.0);
  EXPECT_DOUBLE_EQ(r.median, 3.0);
  EXPECT_NEAR(r.stddev, std::sqrt(2.5), 1e-12);
}

TEST(RobustMean, RejectsGrossOutliers) {
  std::mt19937 rng(42);
  std::normal_distribution<double> noise(0.0, 1e-4);
  std::vector<double> x;
  for (int i = 0; i < 50; ++i) x.push_back(1.2345 + noise(rng));
  x[7] = 1.5;      // multipath
  x[23] = 0.2;     // beam hits the cable
  x[31] = 1.2360;  // 15 sigma
  const RobustMean r = robust_mean(x, 3.5, 0.0);
  EXPECT_EQ(r.rejected, 3);
  EXPECT_EQ(r.used, 47);
  EXPECT_NEAR(r.mean, 1.2345, 1e-4);
  EXPECT_LT(r.stddev, 2e-4);
  // Without rejection the mean would be off by millimetres.
  const double plain = std::accumulate(x.begin(), x.end(), 0.0) / static_cast<double>(x.size());
  EXPECT_GT(std::fabs(plain - 1.2345), 1e-3);
}

TEST(RobustMean, QuantisedDataKeepsNeighboursWithResolutionFloor) {
  // 0.1 mm steps: most readings equal, MAD = 0.
  std::vector<double> x(20, 0.5000);
  x[3] = 0.5001;
  x[9] = 0.4999;
  x[15] = 0.5100;  // a real outlier, 100 steps away
  const RobustMean with_floor = robust_mean(x, 3.5, 1e-4);
  EXPECT_EQ(with_floor.used, 19);
  EXPECT_EQ(with_floor.rejected, 1);
  EXPECT_NEAR(with_floor.mean, 0.5, 1e-12);
  // Without the floor every reading that is not exactly the median is thrown away.
  const RobustMean no_floor = robust_mean(x, 3.5, 0.0);
  EXPECT_EQ(no_floor.used, 17);
}

TEST(RobustMean, NonFiniteValuesAreRejectedAndEmptyInputIsSafe) {
  const std::vector<double> x = {1.0, std::numeric_limits<double>::quiet_NaN(), 1.0,
                                 std::numeric_limits<double>::infinity()};
  const RobustMean r = robust_mean(x);
  EXPECT_EQ(r.used, 2);
  EXPECT_EQ(r.rejected, 2);
  EXPECT_DOUBLE_EQ(r.mean, 1.0);
  EXPECT_EQ(r.stddev, 0.0);
  const RobustMean e = robust_mean(std::vector<double>{});
  EXPECT_EQ(e.used, 0);
  EXPECT_EQ(e.rejected, 0);
}

TEST(RobustMean, EvenCountUsesMiddlePairAndZeroWidthKeepsNothingSafely) {
  const std::vector<double> x = {1.0, 2.0, 3.0, 10.0};
  EXPECT_DOUBLE_EQ(robust_mean(x).median, 2.5);
  const RobustMean z = robust_mean(std::vector<double>{0.0, 10.0}, 0.0, 0.0);
  EXPECT_EQ(z.used, 0);
  EXPECT_EQ(z.rejected, 2);
  EXPECT_DOUBLE_EQ(z.mean, 5.0);
}

}  // namespace
}  // namespace cdpr::modbus
