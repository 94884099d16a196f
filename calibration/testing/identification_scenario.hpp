// Scenarios shared by the identification tests and benchmarks (not installed): MINI with the
// frame anchors of Jin et al. 2018 Table 1 (nominal = SolidWorks column, truth = measured column)
// and a downward laser on a floor plane; the large test robot with perturbed anchors.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "testing/test_robots.hpp"

namespace cdpr::scenario {

// Table 1, "3D Equipment Measured Data", mm -> m. Cable 7 is taken at -x, +y (the table's sign
// typo, see the field notes).
inline Eigen::Matrix3Xd mini_measured_anchors() {
  Eigen::Matrix3Xd a(3, 8);
  a << 0.50640, -0.48887, -0.49189, 0.50363, 0.53936, -0.52095, -0.52415, 0.53657,  //
      -0.37300, -0.37426, 0.38146, 0.38276, -0.33962, -0.34169, 0.34790, 0.34886,   //
      -0.45320, -0.45320, -0.45320, -0.45320, 0.43026, 0.43064, 0.42968, 0.43048;
  return a;
}

// A laser at the platform centre pointing down at a floor plane.
inline void add_down_laser(RobotModel& robot, double floor_z) {
  LaserModel laser;
  laser.origin = Eigen::Vector3d(0.0, 0.0, 0.0);
  laser.direction = -Eigen::Vector3d::UnitZ();
  laser.plane_point = Eigen::Vector3d(0.0, 0.0, floor_z);
  laser.plane_normal = Eigen::Vector3d::UnitZ();
  laser.range_min = 0.0;
  laser.range_max = 50.0;
  robot.lasers = {laser};
}

struct Scenario {
  CalibratedModel nominal;
  CalibratedModel truth;
  testing::WorkspaceBox box;
};

// MINI: nominal = SolidWorks anchors, truth = measured anchors, encoder zeros from homing with
// the nominal model (so the true offsets are what homing really leaves).
inline Scenario mini_scenario() {
  Scenario s;
  RobotModel nominal = testing::mini_robot();
  add_down_laser(nominal, -0.40);
  RobotModel truth = nominal;
  truth.frame_anchors = mini_measured_anchors();
  // The true floor is slightly tilted and lower than believed.
  truth.lasers[0].plane_point = Eigen::Vector3d(0.0, 0.0, -0.4023);
  truth.lasers[0].plane_normal = Eigen::Vector3d(0.002, -0.001, 1.0).normalized();
  s.nominal = CalibratedModel::from_robot(nominal);
  s.truth = CalibratedModel::from_robot(truth);
  auto off = homing_offsets(truth, nominal, default_reference_tension(nominal));
  if (off) s.truth.readings.length_offsets = *off;
  s.box = testing::mini_workspace();
  return s;
}

// The laser of the shipped MINI configs: at the centre of the platform's bottom face, pointing
// down at the floor plane z = -0.6 m, range 0.1..1.0 m.
inline LaserModel mini_config_laser() {
  LaserModel laser;
  laser.origin = Eigen::Vector3d(0.0, 0.0, -0.03);
  laser.direction = -Eigen::Vector3d::UnitZ();
  laser.plane_point = Eigen::Vector3d(0.0, 0.0, -0.6);
  laser.plane_normal = Eigen::Vector3d::UnitZ();
  laser.range_min = 0.1;
  laser.range_max = 1.0;
  return laser;
}

// MINI exactly as shipped: nominal = config/mini.yaml, truth = config/mini-measured.yaml (the
// measured frame anchors with pulley frames pointing from them to the centre line, the same
// laser and floor plane in both), encoders homed with the nominal model (homed_truth), as
// `cdpr-fit simulate --nominal config/mini.yaml` does. tests/fit checks that these models equal
// the configs loaded by cdpr_config, so the benchmark figures are those of the shipped robot.
inline Scenario mini_config_scenario() {
  Scenario s;
  RobotModel nominal = testing::mini_robot();
  nominal.platform.inertia = Eigen::Vector3d(0.00435, 0.003, 0.00615).asDiagonal();
  nominal.lasers = {mini_config_laser()};
  RobotModel truth = nominal;
  truth.name = "MINI (measured)";
  truth.frame_anchors = mini_measured_anchors();
  for (int i = 0; i < truth.num_cables(); ++i) {
    truth.pulleys[static_cast<std::size_t>(i)].frame =
        testing::vertical_swivel_frame(truth.frame_anchors.col(i), /*cable_goes_up=*/i < 4);
  }
  s.nominal = CalibratedModel::from_robot(nominal);
  auto homed = homed_truth(truth, nominal);
  s.truth = homed ? *homed : CalibratedModel::from_robot(truth);
  s.box = testing::mini_workspace();
  return s;
}

// The issue 18 sensors with hidden mounting errors in the truth: swivel encoder zeros of up to
// 0.05 rad (encoders 3 and 6 count the other way), an inclinometer tilted by about a degree on
// its mount (rotated 0.3 rad about its z, which the nominal model knows) and an IMU heading zero
// of 0.4 rad. The nominal model knows the encoder directions and the mounting's rotation about
// the sensor z, not the zeros and the tilt.
inline void add_sensor_mounting_errors(Scenario& s) {
  RobotModel& truth = s.truth.robot;
  RobotModel& nominal = s.nominal.robot;
  const int m = truth.num_cables();
  truth.swivel_encoders.resize(static_cast<std::size_t>(m));
  nominal.swivel_encoders.resize(static_cast<std::size_t>(m));
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    truth.swivel_encoders[k].zero = 0.05 * std::sin(1.7 * i + 0.3);
    truth.swivel_encoders[k].direction = (i == 2 || i == 5) ? -1 : 1;
    nominal.swivel_encoders[k].direction = truth.swivel_encoders[k].direction;
  }
  truth.inclinometer.mounting_rpy = Eigen::Vector3d(0.012, -0.017, 0.3);
  truth.inclinometer.yaw_zero = 0.4;
  nominal.inclinometer.mounting_rpy = Eigen::Vector3d(0.0, 0.0, 0.3);
}

// MINI as shipped (mini_config_scenario) with the issue 18 sensors and hidden mounting errors
// (add_sensor_mounting_errors).
inline Scenario mini_sensor_scenario() {
  Scenario s = mini_config_scenario();
  add_sensor_mounting_errors(s);
  return s;
}

// LARGE: anchors perturbed by up to `perturbation` m per coordinate (seeded).
inline Scenario large_scenario(double perturbation = 0.03, unsigned seed = 7) {
  Scenario s;
  RobotModel nominal = testing::large_robot();
  add_down_laser(nominal, -2.0);
  RobotModel truth = nominal;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-perturbation, perturbation);
  for (int i = 0; i < truth.num_cables(); ++i) {
    for (int q = 0; q < 3; ++q) truth.frame_anchors(q, i) += u(rng);
  }
  truth.lasers[0].plane_point = Eigen::Vector3d(0.0, 0.0, -2.01);
  s.nominal = CalibratedModel::from_robot(nominal);
  s.truth = CalibratedModel::from_robot(truth);
  auto off = homing_offsets(truth, nominal, default_reference_tension(nominal));
  if (off) s.truth.readings.length_offsets = *off;
  s.box = testing::large_workspace();
  return s;
}

// The large robot (large_scenario) with the same issue 18 sensors and hidden mounting errors as
// mini_sensor_scenario (add_sensor_mounting_errors); its swivel pulleys are those of
// testing::large_robot, the same in the nominal model and the truth.
inline Scenario large_sensor_scenario() {
  Scenario s = large_scenario();
  add_sensor_mounting_errors(s);
  return s;
}

// CRANE4 (issue 18, config/crane4.yaml): the 4-cable suspended crane with swivel encoders, an
// inclinometer and load cells. Truth: frame anchors off by up to 10 mm per coordinate (seeded),
// hidden swivel encoder zeros of up to 0.05 rad and an inclinometer tilted by about a degree on
// its mount; pulley frames, platform and cables as nominal. The true home pose is where the true
// crane hangs at the nominal home position and heading (its roll and pitch follow from the
// statics: the gauge of a suspended robot holds only the home position and yaw), and the encoders
// are homed there with the nominal model.
inline Scenario crane_scenario(unsigned seed = 5) {
  Scenario s;
  const RobotModel nominal = testing::crane_robot();
  RobotModel truth = nominal;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-0.01, 0.01);
  for (int i = 0; i < truth.num_cables(); ++i) {
    for (int q = 0; q < 3; ++q) truth.frame_anchors(q, i) += u(rng);
  }
  truth.swivel_encoders.resize(4);
  for (int i = 0; i < 4; ++i) {
    truth.swivel_encoders[static_cast<std::size_t>(i)].zero = 0.05 * std::sin(1.3 * i + 0.4);
  }
  truth.inclinometer.mounting_rpy = Eigen::Vector3d(-0.015, 0.011, 0.0);
  const Result<SuspendedState> home = suspended_equilibrium_pose(truth, nominal.home);
  if (home) truth.home = home->pose;
  s.nominal = CalibratedModel::from_robot(nominal);
  s.truth = CalibratedModel::from_robot(truth);
  auto off = homing_offsets(truth, nominal, default_reference_tension(nominal));
  if (off) s.truth.readings.length_offsets = *off;
  // Where the crane is used: 0.9 x 1.1 x 0.6 m around home, yaw as the statics allow.
  s.box = {nominal.home.position, Eigen::Vector3d(0.45, 0.55, 0.3), 0.0};
  return s;
}

// How the crane's recordings are simulated: elastic physics, commanded through `s`'s nominal
// model (which must outlive the options), swivel angles and inclinometer, no laser.
inline SimulationOptions crane_simulation(const Scenario& s, bool noise) {
  SimulationOptions so;
  so.physics = SimulationOptions::Physics::kElastic;
  so.controller = &s.nominal;
  so.add_noise = noise;
  so.laser = false;
  so.swivel = true;
  so.inclinometer = true;
  return so;
}

// `n` equilibrium poses of the suspended `model`: its home pose first, then random targets in
// `box` (position; the yaw within +-0.03 rad) made equilibria (suspended_equilibrium_pose) with
// every tension within [f_min, f_max]. These are the poses the controller commands.
inline std::vector<Pose> random_hanging_poses(const RobotModel& model,
                                              const testing::WorkspaceBox& box, int n,
                                              unsigned seed) {
  std::vector<Pose> poses{model.home};
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  int guard = 0;
  while (static_cast<int>(poses.size()) < n && guard++ < 100000) {
    Pose target;
    for (int k = 0; k < 3; ++k) target.position(k) = box.center(k) + box.half_extent(k) * u(rng);
    target.rpy = Eigen::Vector3d(0.0, 0.0, 0.03 * u(rng));
    SuspendedOptions so;
    const Result<SuspendedState> eq = suspended_equilibrium_pose(model, target, so);
    if (!eq) continue;
    if (!simple_tension_distribution(model, eq->pose, 0.0)) continue;
    poses.push_back(eq->pose);
  }
  return poses;
}

// `n` poses: the home pose first, then random poses in `box` whose tensions are feasible in
// `model` (simple_tension_distribution).
// `also` (optional) must be feasible too (e.g. the truth as well as the nominal model).
inline std::vector<Pose> random_feasible_poses(const RobotModel& model,
                                               const testing::WorkspaceBox& box, int n,
                                               unsigned seed, const RobotModel* also = nullptr) {
  std::vector<Pose> poses{model.home};
  std::mt19937 rng(seed);
  const double f_ref = default_reference_tension(model);
  int guard = 0;
  while (static_cast<int>(poses.size()) < n && guard++ < 100000) {
    const Pose p = testing::random_pose(box, rng);
    if (!simple_tension_distribution(model, p, f_ref)) continue;
    if (also && !simple_tension_distribution(*also, p, f_ref)) continue;
    poses.push_back(p);
  }
  return poses;
}

// The recording of `s`'s truth at `n` random feasible poses (random_feasible_poses with seed
// `pose_seed`, feasible in the nominal model and the truth), commanded by the nominal model, with
// `noise` drawn from seed `noise_seed`.
inline Result<SimulatedMeasurements> simulate_random_poses(const Scenario& s, int n,
                                                           unsigned pose_seed,
                                                           std::uint64_t noise_seed,
                                                           const SensorNoise& noise = {}) {
  const std::vector<Pose> poses =
      random_feasible_poses(s.nominal.robot, s.box, n, pose_seed, &s.truth.robot);
  SimulationOptions so;
  so.controller = &s.nominal;
  return simulate_measurements(s.truth, poses, noise, noise_seed, so);
}

}  // namespace cdpr::scenario
