// Issue 18: swivel-angle encoders, inclinometer and IMU heading as measurement channels, and
// self-calibration without external sensors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"
#include "testing/residual_derivatives.hpp"

namespace cdpr {
namespace {

struct SensorScenario {
  scenario::Scenario s;
  std::vector<Pose> poses;
};

// MINI with swivel encoders, inclinometer and IMU, hidden mounting errors in the truth.
SensorScenario sensor_scenario(int n) {
  SensorScenario d;
  d.s = scenario::mini_sensor_scenario();
  d.poses = scenario::random_feasible_poses(d.s.nominal.robot, d.s.box, n, 11, &d.s.truth.robot);
  return d;
}

SimulatedMeasurements simulate(const SensorScenario& d, bool laser, bool swivel, bool incl,
                               bool yaw, bool noise, std::uint64_t seed = 3) {
  SimulationOptions so;
  so.controller = &d.s.nominal;
  so.add_noise = noise;
  so.laser = laser;
  so.swivel = swivel;
  so.inclinometer = incl;
  so.imu_yaw = yaw;
  return testing::simulated(d.s.truth, d.poses, so, seed);
}

IdentificationOptions sensor_options(bool laser) {
  IdentificationOptions o;
  o.estimate_laser_plane = laser;
  o.estimate_swivel_zeros = true;
  o.estimate_inclinometer_mounting = true;
  o.estimate_imu_yaw_zero = true;
  return o;
}

TEST(SensorChannels, SimulatedReadingsFollowTheStatedModels) {
  const SensorScenario d = sensor_scenario(4);
  const SimulatedMeasurements sim = simulate(d, false, true, true, true, false);
  const RobotModel& truth = d.s.truth.robot;
  const Pose& p = sim.true_poses[2];
  const PoseMeasurement& pm = sim.set.poses[2];
  EXPECT_EQ(pm.laser_distances.size(), 0);
  // Swivel: the geometric angle of kinematics.hpp through the encoder's zero and direction.
  KinematicsData kin(truth);
  ASSERT_TRUE(inverse_kinematics(truth, p, kin));
  for (int i = 0; i < truth.num_cables(); ++i) {
    const SwivelEncoderModel e = truth.swivel_encoder(i);
    const double x = e.direction * (kin.swivel_angles(i) - e.zero);
    EXPECT_NEAR(pm.swivel_angles(i), std::atan2(std::sin(x), std::cos(x)), 1e-14) << i;
  }
  // Inclinometer: roll and pitch of R(pose) R_m; the IMU heading is its yaw minus the zero.
  const Eigen::Matrix3d Rs =
      rotation_from_rpy<double>(p.rpy) * rotation_from_rpy<double>(truth.inclinometer.mounting_rpy);
  const Eigen::Vector3d rpy = rpy_from_rotation(Rs);
  EXPECT_NEAR(pm.inclination(0), rpy(0), 1e-14);
  EXPECT_NEAR(pm.inclination(1), rpy(1), 1e-14);
  EXPECT_NEAR(pm.imu_yaw, rpy(2) - truth.inclinometer.yaw_zero, 1e-14);
}

TEST(SensorChannels, NewChannelsLeaveTheOtherReadingsOfASeedUnchanged) {
  const SensorScenario d = sensor_scenario(5);
  const SimulatedMeasurements a = simulate(d, true, false, false, false, true, 9);
  const SimulatedMeasurements b = simulate(d, false, true, true, true, true, 9);
  for (int j = 0; j < a.set.num_poses(); ++j) {
    const auto uj = static_cast<std::size_t>(j);
    EXPECT_EQ(a.set.poses[uj].cable_lengths, b.set.poses[uj].cable_lengths);
    EXPECT_EQ(a.set.poses[uj].tensions, b.set.poses[uj].tensions);
  }
}

// Before any statistics: on noise-free data every residual, the new ones included, is zero at
// the true parameters and poses.
TEST(SensorChannels, NoiseFreeResidualsAreZeroAtTheTruth) {
  const SensorScenario d = sensor_scenario(12);
  const SimulatedMeasurements sim = simulate(d, true, true, true, true, false);
  auto gi = geometry_information(d.s.truth, sim.set, sim.true_poses, sensor_options(true));
  ASSERT_TRUE(gi.ok()) << gi.status().to_string();
  EXPECT_EQ(gi->channel_rows.swivel, 12 * 8);
  EXPECT_EQ(gi->channel_rows.inclination, 12 * 2);
  EXPECT_EQ(gi->channel_rows.imu_yaw, 12);
  auto r = evaluate_residuals(d.s.truth, sim.set, sim.true_poses, sensor_options(true));
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  // Normalised residuals (sigma 0.5..10 mrad): 1e-9 is below 1e-11 rad.
  EXPECT_LT(testing::largest_residual(*r), 1e-9);
  // At the nominal mounting they are not zero: the test would see a wrong model.
  auto r0 = evaluate_residuals(d.s.nominal, sim.set, sim.true_poses, sensor_options(true));
  ASSERT_TRUE(r0.ok());
  EXPECT_GT(testing::largest_residual(*r0), 10.0);
}

// The exact (automatic) derivatives of every residual with respect to the pose and to the new
// parameters agree with central finite differences.
TEST(SensorChannels, ExactDerivativesMatchFiniteDifferences) {
  const SensorScenario d = sensor_scenario(6);
  const SimulatedMeasurements sim = simulate(d, true, true, true, true, true);
  IdentificationOptions o = sensor_options(true);
  o.gauge = Gauge::kNone;  // every pose free, so every pose has its Jacobian block
  o.estimate_laser_plane = false;
  // Evaluate away from the truth: nominal parameters, poses a little off.
  CalibratedModel at = d.s.nominal;
  at.robot.inclinometer.mounting_rpy = Eigen::Vector3d(0.01, 0.02, 0.3);
  at.robot.inclinometer.yaw_zero = 0.2;
  for (auto& e : at.robot.swivel_encoders) e.zero = 0.01;
  std::vector<Pose> poses = sim.true_poses;
  for (std::size_t j = 0; j < poses.size(); ++j) {
    poses[j].position += Eigen::Vector3d(1e-3, -2e-3, 1.5e-3) * static_cast<double>(j % 3);
    poses[j].rpy += Eigen::Vector3d(0.01, -0.02, 0.015);
  }
  const testing::ResidualDerivativeCheck check(at, sim.set, poses, o, /*step=*/1e-6,
                                               /*tolerance=*/2e-6);
  ASSERT_TRUE(check.ok());
  // Pose coordinates of pose 3.
  check.expect_pose_derivatives(3);
  // The new parameters, and one anchor coordinate (through the swivel rows too).
  using K = ParameterKind;
  check.expect_parameter_derivatives({K::kFrameAnchor, 1, 1}, [](CalibratedModel& c, double x) {
    c.robot.frame_anchors(1, 1) += x;
  });
  check.expect_parameter_derivatives({K::kSwivelZero, 2, -1}, [](CalibratedModel& c, double x) {
    c.robot.swivel_encoders[2].zero += x;
  });
  check.expect_parameter_derivatives(
      {K::kInclinometerMount, -1, 0}, [](CalibratedModel& c, double x) {
        c.robot.inclinometer.mounting_rpy =
            rpy_from_rotation(rotation_from_rpy<double>(c.robot.inclinometer.mounting_rpy) *
                              rotation_from_rpy<double>(x, 0.0, 0.0));
      });
  check.expect_parameter_derivatives(
      {K::kInclinometerMount, -1, 1}, [](CalibratedModel& c, double x) {
        c.robot.inclinometer.mounting_rpy =
            rpy_from_rotation(rotation_from_rpy<double>(c.robot.inclinometer.mounting_rpy) *
                              rotation_from_rpy<double>(0.0, x, 0.0));
      });
  check.expect_parameter_derivatives({K::kImuYawZero, -1, -1}, [](CalibratedModel& c, double x) {
    c.robot.inclinometer.yaw_zero += x;
  });
}

TEST(SensorChannels, NoiseFreeDataRecoversTheMountingErrors) {
  const SensorScenario d = sensor_scenario(25);
  const SimulatedMeasurements sim = simulate(d, false, true, true, true, false);
  auto rep = identify(d.s.nominal, sim.set, sensor_options(false));
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_TRUE(rep->converged) << rep->full_report();
  const RobotModel& est = rep->estimate.robot;
  const RobotModel& truth = d.s.truth.robot;
  EXPECT_LT((est.frame_anchors - truth.frame_anchors).cwiseAbs().maxCoeff(), 1e-6)
      << rep->full_report();
  ASSERT_EQ(est.swivel_encoders.size(), truth.swivel_encoders.size());
  // The nominal pulley frames' reference directions differ from the truth's (the measured
  // anchors' centre-line directions): the estimated zero absorbs that rotation about the axis.
  for (int i = 0; i < truth.num_cables(); ++i) {
    const Eigen::Matrix3d& fn = d.s.nominal.robot.pulleys[static_cast<std::size_t>(i)].frame;
    const Eigen::Matrix3d& ft = truth.pulleys[static_cast<std::size_t>(i)].frame;
    const double shift = std::atan2(ft.col(0).dot(fn.col(1)), ft.col(0).dot(fn.col(0)));
    const double expected = truth.swivel_encoder(i).zero + shift;
    EXPECT_NEAR(std::remainder(est.swivel_encoder(i).zero - expected, 2.0 * std::acos(-1.0)), 0.0,
                1e-8)
        << "cable " << i + 1;
  }
  const Eigen::Matrix3d Rm_est = rotation_from_rpy<double>(est.inclinometer.mounting_rpy);
  const Eigen::Matrix3d Rm_true = rotation_from_rpy<double>(truth.inclinometer.mounting_rpy);
  // The tilt is recovered exactly; the rotation about the sensor z was given (0.3 rad).
  EXPECT_LT((Rm_est - Rm_true).cwiseAbs().maxCoeff(), 1e-8);
  EXPECT_NEAR(est.inclinometer.yaw_zero, truth.inclinometer.yaw_zero, 1e-8);
  EXPECT_LT(rep->rms_swivel_rad, 1e-9);
  EXPECT_LT(rep->rms_inclination_rad, 1e-9);
}

// Self-calibration: encoders and force sensors only, on MINI (m = 8 > 6). Anchors and offsets
// are identifiable once the home pose fixes the world frame; the analysis says that nothing but
// the home pose and gravity fixes it.
TEST(SensorChannels, SelfCalibrationWithEncodersAndForceSensorsOnly) {
  const SensorScenario d = sensor_scenario(25);
  const SimulatedMeasurements sim = simulate(d, false, false, false, false, false);
  IdentificationOptions o;
  o.estimate_laser_plane = false;
  auto ir = analyze_identifiability(d.s.nominal, sim.set, o);
  ASSERT_TRUE(ir.ok()) << ir.status().to_string();
  EXPECT_TRUE(ir->identifiable()) << ir->summary();
  EXPECT_EQ(ir->num_parameters, 24 + 8);
  bool said = false;
  for (const std::string& n : ir->notes) {
    said = said || n.find("fixed by the home pose and gravity only") != std::string::npos;
  }
  EXPECT_TRUE(said) << ir->summary();
  auto rep = identify(d.s.nominal, sim.set, o);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_LT(
      (rep->estimate.robot.frame_anchors - d.s.truth.robot.frame_anchors).cwiseAbs().maxCoeff(),
      1e-6)
      << rep->full_report();
}

TEST(SensorChannels, AnalysisNamesWhatEachChannelMakesObservable) {
  const SensorScenario d = sensor_scenario(20);
  const SimulatedMeasurements sim = simulate(d, false, true, true, false, false);
  IdentificationOptions o = sensor_options(false);
  auto ir = analyze_identifiability(d.s.nominal, sim.set, o);
  ASSERT_TRUE(ir.ok()) << ir.status().to_string();
  EXPECT_TRUE(ir->identifiable()) << ir->summary();
  const ChannelContribution* swivel = nullptr;
  const ChannelContribution* incl = nullptr;
  for (const ChannelContribution& c : ir->channels) {
    if (c.channel == "swivel angles") swivel = &c;
    if (c.channel == "inclinometer") incl = &c;
  }
  ASSERT_NE(swivel, nullptr) << ir->summary();
  ASSERT_NE(incl, nullptr) << ir->summary();
  // Without the swivel angles their zeros are not observed at all; likewise the mounting.
  EXPECT_EQ(swivel->rank_without, ir->num_parameters - 8) << ir->summary();
  EXPECT_EQ(incl->rank_without, ir->num_parameters - 2) << ir->summary();
  ASSERT_FALSE(swivel->gains.empty());
  EXPECT_TRUE(std::isinf(swivel->gains.front().second));
  EXPECT_NE(ir->summary().find("channel swivel angles"), std::string::npos);
}

}  // namespace
}  // namespace cdpr
