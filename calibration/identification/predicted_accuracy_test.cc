#include "cdpr/calibration/predicted_accuracy.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>

#include "cdpr/calibration/identifiability.hpp"
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

// Issue 18: the prediction is the Cramer-Rao bound of the channels the robot records, the same
// bound the identifiability analysis works from for those channels and poses.
TEST(PredictedAccuracy, EqualsTheBoundOfTheChannelsRecorded) {
  const scenario::Scenario s = scenario::mini_sensor_scenario();
  const std::vector<Pose> poses = scenario::random_feasible_poses(s.nominal.robot, s.box, 15, 5);
  const SensorNoise noise;
  PredictedAccuracyOptions o;
  o.box.points_per_axis = 3;
  o.channels.laser = false;
  o.channels.swivel = true;
  o.channels.inclinometer = true;
  fit_estimates_to_channels(o.channels, &o.identification);
  auto a = predict_accuracy(s.nominal, poses, noise, o);
  ASSERT_TRUE(a.ok()) << a.status().to_string();

  // The same poses and channels through the simulator and the identifiability analysis.
  SimulationOptions so;
  so.add_noise = false;
  so.use_channels(o.channels);
  auto sim = simulate_measurements(s.nominal, poses, noise, 0, so);
  ASSERT_TRUE(sim.ok()) << sim.status().to_string();
  auto gi = geometry_information(s.nominal, sim->set, poses, o.identification);
  ASSERT_TRUE(gi.ok()) << gi.status().to_string();
  auto ir = analyze_identifiability(s.nominal, sim->set, o.identification);
  ASSERT_TRUE(ir.ok()) << ir.status().to_string();
  ASSERT_EQ(a->names, gi->names);
  ASSERT_EQ(a->names, ir->parameter_names);
  EXPECT_EQ(a->rank, ir->rank);
  ASSERT_TRUE(ir->identifiable());
  // The channels' mounting parameters are among the estimated, the laser's are not.
  const auto has = [&](const std::string& n) {
    return std::find(a->names.begin(), a->names.end(), n) != a->names.end();
  };
  EXPECT_TRUE(has("swivel_zero_1"));
  EXPECT_TRUE(has("inclinometer.mount.roll"));
  EXPECT_FALSE(has("laser_1.plane.c"));
  // Full rank: the bound is the square root of the diagonal of the inverse information.
  const Eigen::VectorXd crb = gi->information.inverse().diagonal().cwiseSqrt();
  ASSERT_EQ(crb.size(), a->crb_std.size());
  for (Eigen::Index q = 0; q < crb.size(); ++q) {
    EXPECT_NEAR(a->crb_std(q) / crb(q), 1.0, 1e-6) << a->names[static_cast<std::size_t>(q)];
  }

  // The channels matter: with lengths and forces only the anchors' bound is larger.
  PredictedAccuracyOptions none = o;
  none.channels = SensorChannels{};
  none.channels.laser = false;
  fit_estimates_to_channels(none.channels, &none.identification);
  auto b = predict_accuracy(s.nominal, poses, noise, none);
  ASSERT_TRUE(b.ok()) << b.status().to_string();
  EXPECT_GT(b->anchor_rms_std_m, 1.5 * a->anchor_rms_std_m);
  EXPECT_GT(b->position_rms_m, a->position_rms_m);
}

TEST(PredictedAccuracy, RefusesLaserParametersWithoutTheLaser) {
  const scenario::Scenario s = scenario::mini_sensor_scenario();
  const std::vector<Pose> poses = scenario::random_feasible_poses(s.nominal.robot, s.box, 10, 5);
  PredictedAccuracyOptions o;
  o.channels.laser = false;  // the default options still estimate the laser plane
  auto a = predict_accuracy(s.nominal, poses, SensorNoise{}, o);
  ASSERT_FALSE(a.ok());
  EXPECT_EQ(a.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(a.status().message().find("laser"), std::string_view::npos);
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
