// Test data of issue 41's concealed platform weight (platform_weight_test.cc in the
// identification, platform_weight_effect_test.cc in the locator): a platform 12 % heavier than
// configured whose centre of mass is off by (15, -10, 20) mm in the platform frame. Not installed.
#pragma once

#include <gtest/gtest.h>

#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "testing/identification_scenario.hpp"
#include "testing/residual_derivatives.hpp"

namespace cdpr::testing {

inline void conceal_weight(RobotModel& truth) {
  truth.platform.mass *= 1.12;
  truth.platform.center_of_mass += Eigen::Vector3d(0.015, -0.010, 0.020);
}

// The suspended crane with the concealed weight: the true platform hangs at home where its statics
// put it, the encoders are homed there with the nominal model, and 14 poses (seed 21) are
// commanded through the nominal model; noise-free elastic recording. `options` are the crane's
// usual items (swivel zeros, inclinometer mounting, no laser).
struct HeavyCrane {
  scenario::Scenario s;
  SimulatedMeasurements sim;
  IdentificationOptions options;
};

inline HeavyCrane heavy_crane() {
  HeavyCrane c;
  c.s = scenario::crane_scenario();
  scenario::Scenario& s = c.s;
  conceal_weight(s.truth.robot);
  const Result<SuspendedState> home =
      suspended_equilibrium_pose(s.truth.robot, s.nominal.robot.home);
  EXPECT_TRUE(home.ok());
  if (home.ok()) s.truth.robot.home = home->pose;
  auto off =
      homing_offsets(s.truth.robot, s.nominal.robot, default_reference_tension(s.nominal.robot));
  EXPECT_TRUE(off.ok());
  if (off.ok()) s.truth.readings.length_offsets = *off;
  const std::vector<Pose> commands = scenario::random_hanging_poses(s.nominal.robot, s.box, 14, 21);
  c.sim = simulated(s.truth, commands, scenario::crane_simulation(s, false), 4);
  c.options.estimate_laser_plane = false;
  c.options.estimate_swivel_zeros = true;
  c.options.estimate_inclinometer_mounting = true;
  return c;
}

}  // namespace cdpr::testing
