#include "cdpr/calibration/force_sensor.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string_view>
#include <vector>

namespace cdpr {
namespace {

bool mentions(const Status& s, std::string_view text) {
  return s.message().find(text) != std::string_view::npos;
}

TEST(ForceSensor, RawAndTensionAreInverse) {
  const ForceSensorModel sensor{2.0, 3.5};
  for (const double f : {0.0, 1.0, 57.3, 480.0}) {
    EXPECT_DOUBLE_EQ(force_sensor_raw(sensor, f), 2.0 * f + 3.5);
    EXPECT_NEAR(force_sensor_tension(sensor, force_sensor_raw(sensor, f)), f, 1e-13);
  }
}

TEST(ForceSensor, ExactDataGiveExactParameters) {
  const ForceSensorModel truth{2.0, -1.25};
  std::vector<ForceCalibrationSample> samples;
  for (const double m : {0.0, 1.0, 2.0, 5.0, 10.0}) {
    samples.push_back({m, force_sensor_raw(truth, m * 9.81)});
  }
  const Result<ForceSensorFit> fit = fit_force_sensor(samples, 9.81);
  ASSERT_TRUE(fit.ok()) << fit.status().to_string();
  EXPECT_NEAR(fit->sensor.gain, truth.gain, 1e-13);
  EXPECT_NEAR(fit->sensor.offset, truth.offset, 1e-11);
  EXPECT_LT(fit->gain_stderr, 1e-12);
  EXPECT_LT(fit->residual_rms, 1e-11);
}

TEST(ForceSensor, StandardErrorsMatchTheScatter) {
  // Monte Carlo: the reported standard error is the spread of the estimate over repeats.
  const ForceSensorModel truth{2.0, 4.0};
  const double sigma = 0.5;
  std::mt19937_64 rng(3);
  std::normal_distribution<double> noise(0.0, sigma);
  std::vector<double> gains;
  double mean_reported = 0.0;
  double mean_offset_reported = 0.0;
  std::vector<double> offsets;
  const int repeats = 400;
  for (int r = 0; r < repeats; ++r) {
    std::vector<ForceCalibrationSample> samples;
    for (int k = 0; k < 12; ++k) {
      const double m = 0.5 * k;
      samples.push_back({m, force_sensor_raw(truth, m * 9.81) + noise(rng)});
    }
    const Result<ForceSensorFit> fit = fit_force_sensor(samples);
    ASSERT_TRUE(fit.ok());
    gains.push_back(fit->sensor.gain);
    offsets.push_back(fit->sensor.offset);
    mean_reported += fit->gain_stderr / repeats;
    mean_offset_reported += fit->offset_stderr / repeats;
  }
  auto spread = [](const std::vector<double>& v, double* mean) {
    double m = 0.0;
    for (double x : v) m += x / static_cast<double>(v.size());
    double s = 0.0;
    for (double x : v) s += (x - m) * (x - m);
    *mean = m;
    return std::sqrt(s / static_cast<double>(v.size() - 1));
  };
  double gain_mean = 0.0;
  double offset_mean = 0.0;
  const double gain_spread = spread(gains, &gain_mean);
  const double offset_spread = spread(offsets, &offset_mean);
  EXPECT_NEAR(gain_mean, truth.gain, 4.0 * gain_spread / std::sqrt(repeats));
  EXPECT_NEAR(offset_mean, truth.offset, 4.0 * offset_spread / std::sqrt(repeats));
  EXPECT_NEAR(mean_reported / gain_spread, 1.0, 0.15);
  EXPECT_NEAR(mean_offset_reported / offset_spread, 1.0, 0.15);
}

TEST(ForceSensor, RefusesDegenerateData) {
  const std::vector<ForceCalibrationSample> two{{1.0, 20.0}, {2.0, 40.0}};
  Result<ForceSensorFit> r = fit_force_sensor(two);
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(mentions(r.status(), "at least 3"));

  const std::vector<ForceCalibrationSample> same{{2.0, 40.0}, {2.0, 40.1}, {2.0, 39.9}};
  r = fit_force_sensor(same);
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(mentions(r.status(), "same mass")) << r.status().to_string();

  const std::vector<ForceCalibrationSample> negative{{1.0, 20.0}, {-2.0, 40.0}, {3.0, 60.0}};
  r = fit_force_sensor(negative);
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(mentions(r.status(), "sample 1"));

  const std::vector<ForceCalibrationSample> nan{
      {1.0, 20.0}, {2.0, std::numeric_limits<double>::quiet_NaN()}, {3.0, 60.0}};
  EXPECT_EQ(fit_force_sensor(nan).status().code(), ErrorCode::kInvalidArgument);

  const std::vector<ForceCalibrationSample> ok{{1.0, 20.0}, {2.0, 40.0}, {3.0, 60.0}};
  EXPECT_EQ(fit_force_sensor(ok, 0.0).status().code(), ErrorCode::kInvalidArgument);

  // Readings that ignore the load: noise only.
  const std::vector<ForceCalibrationSample> flat{{0.0, 5.0}, {1.0, 5.3}, {2.0, 4.8},
                                                 {3.0, 5.1}, {4.0, 4.9}, {5.0, 5.05}};
  r = fit_force_sensor(flat);
  EXPECT_EQ(r.status().code(), ErrorCode::kFailedPrecondition);
  EXPECT_TRUE(mentions(r.status(), "do not depend on the load"));
}

}  // namespace
}  // namespace cdpr
