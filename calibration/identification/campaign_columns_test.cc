// What a real campaign records besides the readings (measurement.hpp: scatter, supported, start)
// and how the identification uses it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "cdpr/calibration/identification.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

constexpr int kPoses = 25;
constexpr int kMarked = 7;  // the pose each test marks

// MINI's recording at 25 random feasible poses, noise-free (its sigmas the default ones);
// `platform_share`: the share of the platform's weight the cables carry at pose kMarked (the
// support carries the rest; the elastic robot settles under that load).
SimulatedMeasurements recording(double platform_share = 1.0) {
  const scenario::Scenario s = scenario::mini_scenario();
  const std::vector<Pose> poses =
      scenario::random_feasible_poses(s.nominal.robot, s.box, kPoses, 11, &s.truth.robot);
  SensorNoise none;
  none.sigma_length = none.sigma_force = none.sigma_laser = 0.0;
  SimulationOptions so;
  so.controller = &s.nominal;
  auto sim = simulate_measurements(s.truth, poses, none, 5, so);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  if (platform_share != 1.0) {
    CalibratedModel resting = s.truth;
    resting.robot.platform.mass *= platform_share;
    auto supported = simulate_measurements(resting, {poses[kMarked]}, none, 5, so);
    EXPECT_TRUE(supported.ok()) << supported.status().to_string();
    sim->set.poses[kMarked] = supported->set.poses[0];
  }
  sim->set.noise = SensorNoise{};
  return *sim;
}

double anchor_error(const IdentificationReport& r) {
  return (r.estimate.robot.frame_anchors - scenario::mini_scenario().truth.robot.frame_anchors)
      .cwiseAbs()
      .maxCoeff();
}

Result<IdentificationReport> fit(const MeasurementSet& set) {
  return identify(scenario::mini_scenario().nominal, set, IdentificationOptions{});
}

TEST(CampaignColumns, ASupportedPoseKeepsItsLengthsButLeavesItsEquilibriumOut) {
  // The platform rested on something at one pose: the cables carried 80 % of its weight.
  SimulatedMeasurements sim = recording(0.8);
  auto blind = fit(sim.set);
  ASSERT_TRUE(blind.ok()) << blind.status().to_string();
  sim.set.poses[kMarked].supported = true;
  auto told = fit(sim.set);
  ASSERT_TRUE(told.ok()) << told.status().to_string();
  // Its equilibrium row is gone; its lengths are still fitted.
  EXPECT_TRUE(told->residuals[kMarked].wrench_normalized.array().isNaN().all());
  EXPECT_FALSE(told->residuals[kMarked].length_normalized.array().isNaN().all());
  EXPECT_FALSE(blind->residuals[kMarked].wrench_normalized.array().isNaN().any());
  // Told, everything left is consistent: the truth again (noise-free); blind, it is not.
  EXPECT_LT(told->chi2, 1e-6) << told->brief_report();
  EXPECT_LT(anchor_error(*told), 1e-6) << told->full_report();
  EXPECT_GT(blind->chi2, 1.0) << blind->brief_report();
  EXPECT_GT(anchor_error(*blind), 1e-5) << blind->full_report();
}

TEST(CampaignColumns, APoseScatterWeighsItsReadingsLess) {
  SimulatedMeasurements sim = recording();
  PoseMeasurement& pm = sim.set.poses[kMarked];
  // The readings averaged at this pose scattered by 2 mm (the platform swung): one of them is
  // 2 mm off.
  const double scatter = 2e-3;
  pm.cable_lengths(2) += scatter;
  auto blind = fit(sim.set);
  ASSERT_TRUE(blind.ok()) << blind.status().to_string();
  pm.scatter_length = scatter;
  auto told = fit(sim.set);
  ASSERT_TRUE(told.ok()) << told.status().to_string();
  EXPECT_LT(told->chi2, 0.1 * blind->chi2) << told->brief_report() << blind->brief_report();
  EXPECT_LT(anchor_error(*told), 0.2 * anchor_error(*blind));
  // noise_at is the recording's sigma widened in quadrature.
  const SensorNoise n = noise_at(sim.set.noise, pm);
  EXPECT_DOUBLE_EQ(n.sigma_length, std::hypot(sim.set.noise.sigma_length, scatter));
  EXPECT_DOUBLE_EQ(n.sigma_force, sim.set.noise.sigma_force);
}

TEST(CampaignColumns, AStartPoseIsWhereThePoseSolveStarts) {
  SimulatedMeasurements sim = recording();
  // The commanded poses are a plan 5 cm off where the platform went (as on a suspended robot).
  for (std::size_t j = 1; j < sim.set.poses.size(); ++j) {
    sim.set.poses[j].commanded.position += Eigen::Vector3d(0.05, -0.03, 0.02);
  }
  auto plain = fit(sim.set);
  ASSERT_TRUE(plain.ok()) << plain.status().to_string();
  // Told where the platform was: the solve starts there, the commanded pose stays as planned.
  for (std::size_t j = 1; j < sim.set.poses.size(); ++j) {
    sim.set.poses[j].start = sim.true_poses[j];
    EXPECT_EQ(start_of(sim.set.poses[j]).vector(), sim.true_poses[j].vector());
  }
  auto started = fit(sim.set);
  ASSERT_TRUE(started.ok()) << started.status().to_string();
  EXPECT_LT(started->initial_cost, 0.5 * plain->initial_cost);
  EXPECT_LT(anchor_error(*started), 1e-6) << started->full_report();
  // A reference pose still wins over a start pose.
  sim.set.poses[1].reference = sim.set.poses[1].commanded;
  EXPECT_EQ(start_of(sim.set.poses[1]).vector(), sim.set.poses[1].commanded.vector());
}

}  // namespace
}  // namespace cdpr
