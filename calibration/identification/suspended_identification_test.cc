// Issue 18, second part: the estimator for a suspended robot with fewer than six cables (the
// 4-cable crane): the equilibrium residual is the pose constraint, the gauge keeps only the home
// position and heading.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "testing/identification_scenario.hpp"
#include "testing/residual_derivatives.hpp"

namespace cdpr {
namespace {

struct Crane {
  scenario::Scenario s;
  std::vector<Pose> commands;  // equilibrium poses of the nominal crane (what is commanded)
};

Crane crane(int n) {
  Crane c;
  c.s = scenario::crane_scenario();
  c.commands = scenario::random_hanging_poses(c.s.nominal.robot, c.s.box, n, 21);
  return c;
}

SimulatedMeasurements simulate(const Crane& c, bool noise, std::uint64_t seed = 4) {
  return testing::simulated(c.s.truth, c.commands, scenario::crane_simulation(c.s, noise), seed);
}

IdentificationOptions crane_options() {
  IdentificationOptions o;
  o.estimate_laser_plane = false;
  o.estimate_swivel_zeros = true;
  o.estimate_inclinometer_mounting = true;
  return o;
}

TEST(SuspendedIdentification, ScenarioHangsWhereTheStaticsSay) {
  const Crane c = crane(12);
  ASSERT_EQ(c.commands.size(), 12u);
  const SimulatedMeasurements sim = simulate(c, false);
  ASSERT_EQ(sim.true_poses.size(), 12u);
  // Commanding home, the true crane hangs at its true home (the homing makes it so): the gauge's
  // position and heading hold; the tilt differs from the nominal one.
  EXPECT_LT((sim.true_poses[0].position - c.s.nominal.robot.home.position).norm(), 1e-7);
  EXPECT_NEAR(sim.true_poses[0].rpy.z(), c.s.nominal.robot.home.rpy.z(), 1e-7);
  EXPECT_GT(sim.true_poses[0].rpy.head<2>().norm(), 1e-4);
  for (std::size_t j = 0; j < sim.true_poses.size(); ++j) {
    EXPECT_GT(sim.true_tensions[j].minCoeff(), 0.0) << "pose " << j;
    auto t = suspended_tensions(c.s.truth.robot, sim.true_poses[j]);
    ASSERT_TRUE(t.ok());
    EXPECT_LT(t->wrench_residual, 1e-6) << "pose " << j;
  }
}

// Before any statistics: on noise-free data every residual is zero at the true parameters and
// poses (to the elastostatic solver's tolerance), and far from zero at the nominal ones.
TEST(SuspendedIdentification, NoiseFreeResidualsAreZeroAtTheTruth) {
  const Crane c = crane(12);
  const SimulatedMeasurements sim = simulate(c, false);
  const IdentificationOptions o = crane_options();
  auto gi = geometry_information(c.s.truth, sim.set, sim.true_poses, o);
  ASSERT_TRUE(gi.ok()) << gi.status().to_string();
  EXPECT_EQ(gi->channel_rows.length, 12 * 4);
  EXPECT_EQ(gi->channel_rows.wrench, 12 * 6);
  EXPECT_EQ(gi->channel_rows.swivel, 12 * 4);
  EXPECT_EQ(gi->channel_rows.inclination, 12 * 2);
  EXPECT_TRUE(gi->home_tilt_free);
  auto r = evaluate_residuals(c.s.truth, sim.set, sim.true_poses, o);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_LT(testing::largest_residual(*r), 1e-4);
  auto r0 = evaluate_residuals(c.s.nominal, sim.set, sim.true_poses, o);
  ASSERT_TRUE(r0.ok());
  EXPECT_GT(testing::largest_residual(*r0), 10.0);
}

// The exact derivatives of the suspended equilibrium rows (and the others) with respect to the
// pose, an anchor and the home tilt agree with central finite differences.
TEST(SuspendedIdentification, ExactDerivativesMatchFiniteDifferences) {
  const Crane c = crane(6);
  const SimulatedMeasurements sim = simulate(c, true);
  const IdentificationOptions o = crane_options();
  CalibratedModel at = c.s.nominal;
  at.robot.swivel_encoders.assign(4, SwivelEncoderModel{0.01, 1});
  std::vector<Pose> poses = sim.true_poses;
  for (std::size_t j = 1; j < poses.size(); ++j) {
    poses[j].position += Eigen::Vector3d(1e-3, -2e-3, 1.5e-3) * static_cast<double>(j % 3);
    poses[j].rpy += Eigen::Vector3d(0.01, -0.02, 0.015);
  }
  const testing::ResidualDerivativeCheck check(at, sim.set, poses, o, /*step=*/1e-7,
                                               /*tolerance=*/1e-5);
  ASSERT_TRUE(check.ok());
  check.expect_pose_derivatives(3);
  // An anchor coordinate (every pose's rows).
  check.expect_parameter_derivatives(
      {ParameterKind::kFrameAnchor, 1, 1},
      [](CalibratedModel& m, double x) { m.robot.frame_anchors(1, 1) += x; });
  // The home pose's roll (a geometry column for a suspended robot): only pose 0's rows move.
  const ParameterId home_roll{ParameterKind::kHomePose, -1, 3};
  check.expect_parameter_derivatives(
      home_roll, [](CalibratedModel& m, double x) { m.robot.home.rpy.x() += x; }, /*only_pose=*/0);
  const int col = check.column(home_roll);
  ASSERT_GE(col, 0);
  EXPECT_GT(check.information().jacobian_geometry[0].col(col).norm(), 1.0);
}

// Noise-free data: the estimator, started from the nominal crane, returns the truth: anchors,
// encoder offsets, swivel zeros, inclinometer mounting and the home tilt.
TEST(SuspendedIdentification, NoiseFreeDataReturnsTheTruth) {
  const Crane c = crane(25);
  const SimulatedMeasurements sim = simulate(c, false);
  auto rep = identify(c.s.nominal, sim.set, crane_options());
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_TRUE(rep->converged) << rep->full_report();
  const RobotModel& est = rep->estimate.robot;
  const RobotModel& truth = c.s.truth.robot;
  EXPECT_LT((est.frame_anchors - truth.frame_anchors).cwiseAbs().maxCoeff(), 1e-6)
      << rep->full_report();
  EXPECT_LT((rep->estimate.readings.length_offsets - c.s.truth.readings.length_offsets)
                .cwiseAbs()
                .maxCoeff(),
            1e-6);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(est.swivel_encoder(i).zero, truth.swivel_encoder(i).zero, 1e-6) << i;
  }
  EXPECT_LT((est.inclinometer.mounting_rpy - truth.inclinometer.mounting_rpy).cwiseAbs().maxCoeff(),
            1e-6);
  EXPECT_LT((rep->poses[0].rpy - truth.home.rpy).cwiseAbs().maxCoeff(), 1e-6);
  // The calibrated model's home is where it hangs: the true home.
  EXPECT_LT((est.home.vector() - truth.home.vector()).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(rep->chi2, 1e-6);
}

// The analysis names the gauge of a suspended robot: translation and heading, fixed by the home
// pose; the tilt is fixed by gravity.
TEST(SuspendedIdentification, IdentifiabilityNamesWhatStaysInTheGauge) {
  const Crane c = crane(20);
  const SimulatedMeasurements sim = simulate(c, false);
  auto ir = analyze_identifiability(c.s.nominal, sim.set, crane_options());
  ASSERT_TRUE(ir.ok()) << ir.status().to_string();
  EXPECT_TRUE(ir->identifiable()) << ir->summary();
  EXPECT_EQ(ir->num_parameters, 12 + 4 + 4 + 2 + 2);
  bool gauge = false;
  for (const std::string& n : ir->notes) {
    gauge = gauge || n.find("translation (x, y, z) and heading") != std::string::npos;
  }
  EXPECT_TRUE(gauge) << ir->summary();
  // Without the equilibrium rows the home tilt is not estimated (the whole home pose is held).
  IdentificationOptions no_eq = crane_options();
  no_eq.use_equilibrium = false;
  auto gi = geometry_information(c.s.nominal, sim.set, sim.true_poses, no_eq);
  ASSERT_TRUE(gi.ok());
  EXPECT_FALSE(gi->home_tilt_free);
}

// Pose design puts a suspended robot only where it hangs: every designed pose is an equilibrium
// of the model with its tensions within limits, and the design identifies the crane.
TEST(SuspendedIdentification, DesignedPosesAreEquilibriaWithTensionsWithinLimits) {
  const scenario::Scenario s = scenario::crane_scenario();
  PoseDesignOptions design;
  design.num_poses = 15;
  design.center = s.nominal.robot.home.position;
  design.half_extent = Eigen::Vector3d(0.4, 0.5, 0.25);
  design.max_angle = 0.02;
  design.identification = crane_options();
  auto d = design_poses(s.nominal, design);
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(d->poses.size(), 15u);
  const RobotModel& robot = s.nominal.robot;
  for (std::size_t j = 0; j < d->poses.size(); ++j) {
    auto t = suspended_tensions(robot, d->poses[j]);
    ASSERT_TRUE(t.ok());
    EXPECT_LT(t->wrench_residual, 1e-6 * robot.platform.mass * robot.gravity) << "pose " << j;
    for (int i = 0; i < 4; ++i) {
      EXPECT_GE(t->tensions(i), robot.cables[static_cast<std::size_t>(i)].f_min) << j;
      EXPECT_LE(t->tensions(i), robot.cables[static_cast<std::size_t>(i)].f_max) << j;
    }
  }
  // A tilted candidate of a fully constrained robot passes unchanged; the crane's is levelled
  // by the statics.
  Pose tilted = robot.home;
  tilted.rpy.x() = 0.1;
  const std::optional<Pose> p = feasible_design_pose(robot, tilted, 0.0);
  ASSERT_TRUE(p.has_value());
  EXPECT_LT(std::abs(p->rpy.x()), 1e-9);
  Pose outside = robot.home;
  outside.position.x() = 1.5;
  EXPECT_FALSE(feasible_design_pose(robot, outside, 0.0).has_value());
  // The designed poses calibrate the crane (noise-free: the truth).
  auto sim = simulate_measurements(s.truth, d->poses, SensorNoise{}, 1,
                                   scenario::crane_simulation(s, false));
  ASSERT_TRUE(sim.ok()) << sim.status().to_string();
  auto rep = identify(s.nominal, sim->set, crane_options());
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_LT((rep->estimate.robot.frame_anchors - s.truth.robot.frame_anchors).cwiseAbs().maxCoeff(),
            1e-6);
}

}  // namespace
}  // namespace cdpr
