#include "cdpr/calibration/predicted_accuracy.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

TEST(PredictedAccuracy, ScalesWithTheNoiseAndIsPositive) {
  scenario::Scenario s = scenario::mini_scenario();
  const std::vector<Pose> poses = scenario::random_feasible_poses(s.nominal.robot, s.box, 25, 11);
  SensorNoise noise;
  PredictedAccuracyOptions o;
  o.box.points_per_axis = 3;
  // The same rows at both noise levels: the slack threshold would otherwise follow sigma_force.
  o.identification.slack_tension_sigmas = 0.0;
  auto a = predict_accuracy(s.nominal, poses, noise, o);
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  EXPECT_EQ(a->rank, static_cast<int>(a->names.size()));
  EXPECT_GT(a->position_rms_m, 0.0);
  EXPECT_GT(a->anchor_rms_std_m, 0.0);
  EXPECT_GT(a->grid_points, 0);
  // Every noise doubled: every bound doubles (the information is quadratic in 1/sigma).
  SensorNoise twice = noise;
  twice.sigma_length *= 2;
  twice.sigma_laser *= 2;
  twice.sigma_force *= 2;
  twice.sigma_reference_position *= 2;
  twice.sigma_reference_angle *= 2;
  auto b = predict_accuracy(s.nominal, poses, twice, o);
  ASSERT_TRUE(b.ok());
  EXPECT_NEAR(b->anchor_rms_std_m / a->anchor_rms_std_m, 2.0, 0.02);
  EXPECT_NEAR(b->position_rms_m / a->position_rms_m, 2.0, 0.02);
}

TEST(PredictedAccuracy, PerfectControllerReachesTheTargets) {
  scenario::Scenario s = scenario::mini_scenario();
  AccuracyBox box;
  box.points_per_axis = 3;
  auto perfect = measure_position_accuracy(s.truth, s.truth, box);
  ASSERT_TRUE(perfect.ok()) << perfect.status().to_string();
  EXPECT_LT(perfect->position_rms_m, 1e-7);
  auto nominal = measure_position_accuracy(s.truth, s.nominal, box);
  ASSERT_TRUE(nominal.ok());
  EXPECT_GT(nominal->position_rms_m, 1e-3);  // the SolidWorks anchors are off by ~10 mm
}

}  // namespace
}  // namespace cdpr
