// The benchmark's MINI scenario (calibration/testing/identification_scenario.hpp,
// mini_config_scenario) must be the shipped robot: its nominal model equal to config/mini.yaml and
// its truth equal to config/mini-measured.yaml as loaded by cdpr_config, so that the figures of
// bench/identification_bench are those of the configs `cdpr-fit` is run on.
#include <gtest/gtest.h>

#include <string>

#include "cdpr/config/robot_config.hpp"
#include "testing/identification_scenario.hpp"

namespace {

const std::string kSource = CDPR_SOURCE_DIR;

void expect_same_robot(const cdpr::RobotModel& a, const cdpr::RobotModel& b) {
  constexpr double kTol = 1e-12;
  ASSERT_EQ(a.num_cables(), b.num_cables());
  EXPECT_TRUE(a.frame_anchors.isApprox(b.frame_anchors, kTol)) << a.frame_anchors << "\n vs\n"
                                                               << b.frame_anchors;
  EXPECT_TRUE(a.platform_anchors.isApprox(b.platform_anchors, kTol));
  for (int i = 0; i < a.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    SCOPED_TRACE("cable " + std::to_string(i + 1));
    EXPECT_NEAR(a.pulleys[k].radius, b.pulleys[k].radius, kTol);
    EXPECT_TRUE(a.pulleys[k].frame.isApprox(b.pulleys[k].frame, 1e-9))
        << a.pulleys[k].frame << "\n vs\n"
        << b.pulleys[k].frame;
    EXPECT_EQ(a.winches[k].drum_diameter, b.winches[k].drum_diameter);
    EXPECT_EQ(a.winches[k].drum_pitch, b.winches[k].drum_pitch);
    EXPECT_EQ(a.winches[k].gear_ratio, b.winches[k].gear_ratio);
    EXPECT_EQ(a.winches[k].counts_per_rev, b.winches[k].counts_per_rev);
    EXPECT_EQ(a.winches[k].direction, b.winches[k].direction);
    EXPECT_EQ(a.winches[k].length_offset, b.winches[k].length_offset);
    EXPECT_EQ(a.cables[k].ea, b.cables[k].ea);
    EXPECT_EQ(a.cables[k].mass_per_length, b.cables[k].mass_per_length);
    EXPECT_EQ(a.cables[k].routing_length, b.cables[k].routing_length);
    EXPECT_EQ(a.cables[k].elongation, b.cables[k].elongation);
    EXPECT_EQ(a.cables[k].f_min, b.cables[k].f_min);
    EXPECT_EQ(a.cables[k].f_max, b.cables[k].f_max);
    EXPECT_EQ(a.force_sensors[k].gain, b.force_sensors[k].gain);
    EXPECT_EQ(a.force_sensors[k].offset, b.force_sensors[k].offset);
  }
  EXPECT_EQ(a.platform.mass, b.platform.mass);
  EXPECT_EQ(a.platform.center_of_mass, b.platform.center_of_mass);
  EXPECT_TRUE(a.platform.inertia.isApprox(b.platform.inertia, kTol));
  EXPECT_EQ(a.home.vector(), b.home.vector());
  EXPECT_EQ(a.gravity, b.gravity);
  ASSERT_EQ(a.lasers.size(), b.lasers.size());
  for (std::size_t l = 0; l < a.lasers.size(); ++l) {
    EXPECT_TRUE(a.lasers[l].origin.isApprox(b.lasers[l].origin, kTol));
    EXPECT_TRUE(a.lasers[l].direction.normalized().isApprox(b.lasers[l].direction.normalized()));
    EXPECT_TRUE(a.lasers[l].plane_point.isApprox(b.lasers[l].plane_point, kTol));
    EXPECT_TRUE(
        a.lasers[l].plane_normal.normalized().isApprox(b.lasers[l].plane_normal.normalized()));
    EXPECT_EQ(a.lasers[l].range_min, b.lasers[l].range_min);
    EXPECT_EQ(a.lasers[l].range_max, b.lasers[l].range_max);
  }
}

TEST(MiniConfigScenario, NominalIsConfigMini) {
  auto nominal = cdpr::config::load_robot_config(kSource + "/config/mini.yaml");
  ASSERT_TRUE(nominal.ok()) << nominal.status().to_string();
  expect_same_robot(cdpr::scenario::mini_config_scenario().nominal.robot, *nominal);
}

TEST(MiniConfigScenario, TruthIsConfigMiniMeasuredHomedWithTheNominal) {
  auto nominal = cdpr::config::load_robot_config(kSource + "/config/mini.yaml");
  auto truth = cdpr::config::load_robot_config(kSource + "/config/mini-measured.yaml");
  ASSERT_TRUE(nominal.ok() && truth.ok());
  const cdpr::scenario::Scenario s = cdpr::scenario::mini_config_scenario();
  expect_same_robot(s.truth.robot, *truth);
  // The encoder zeros are those of homing with the nominal model (as `cdpr-fit simulate`).
  auto homed = cdpr::homed_truth(*truth, *nominal);
  ASSERT_TRUE(homed.ok());
  EXPECT_TRUE(s.truth.readings.length_offsets.isApprox(homed->readings.length_offsets, 1e-12));
  EXPECT_GT(s.truth.readings.length_offsets.cwiseAbs().maxCoeff(), 1e-3);  // not trivially zero
  EXPECT_EQ(s.truth.readings.length_scales.cwiseAbs().maxCoeff(), 0.0);
}

// Homing is what puts an elastic platform commanded home at home: with the homed reading model
// the settled home pose is the home pose; with zero offsets (absolute encoder lengths) it is not.
TEST(MiniConfigScenario, HomedEncodersSettleTheElasticPlatformAtHome) {
  const cdpr::scenario::Scenario s = cdpr::scenario::mini_config_scenario();
  cdpr::SimulationOptions so;
  so.physics = cdpr::SimulationOptions::Physics::kElastic;
  so.controller = &s.nominal;
  so.add_noise = false;
  const std::vector<cdpr::Pose> home{s.nominal.robot.home};
  auto homed = cdpr::simulate_measurements(s.truth, home, cdpr::SensorNoise{}, 1, so);
  ASSERT_TRUE(homed.ok()) << homed.status().to_string();
  EXPECT_LT((homed->true_poses[0].vector() - s.nominal.robot.home.vector()).norm(), 1e-8);
  auto unhomed = cdpr::simulate_measurements(cdpr::CalibratedModel::from_robot(s.truth.robot), home,
                                             cdpr::SensorNoise{}, 1, so);
  ASSERT_TRUE(unhomed.ok());
  EXPECT_GT(unhomed->true_poses[0].position.norm(), 1e-3);
}

}  // namespace
