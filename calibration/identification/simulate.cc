#include "cdpr/calibration/simulate.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>

#include "cdpr/calibration/elastostatics.hpp"
#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/force_distribution.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "identification_internal.hpp"

namespace cdpr {

Eigen::Vector3d rpy_from_rotation_matrix(const Eigen::Matrix3d& R) {
  const double pitch = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));
  const double roll = std::atan2(R(2, 1), R(2, 2));
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  return {roll, pitch, yaw};
}

Eigen::Matrix<double, 6, 1> platform_weight_wrench(const RobotModel& model, const Pose& pose) {
  const Eigen::Vector3d force(0.0, 0.0, -model.platform.mass * model.gravity);
  const Eigen::Matrix3d R = rotation_from_rpy<double>(pose.rpy);
  Eigen::Matrix<double, 6, 1> w;
  w << force, (R * model.platform.center_of_mass).cross(force);
  return w;
}

Result<Eigen::VectorXd> simple_tension_distribution(const RobotModel& model, const Pose& pose,
                                                    double reference_tension) {
  if (model.suspended && model.num_cables() < 6) {
    // Under-actuated: the tensions are unique, and exist only at an equilibrium pose.
    auto s = suspended_tensions(model, pose);
    if (!s) return Status(ErrorCode::kNumericalFailure, "tensions: " + s.status().to_string());
    if (s->wrench_residual > 1e-6 * model.platform.mass * model.gravity) {
      return Status::error(ErrorCode::kOutOfRange,
                           "tensions: the suspended platform cannot stay at this pose (%.3g N of "
                           "its weight unbalanced: not an equilibrium)",
                           s->wrench_residual);
    }
    for (int i = 0; i < model.num_cables(); ++i) {
      const CableModel& c = model.cables[static_cast<std::size_t>(i)];
      if (!(s->tensions(i) >= c.f_min && s->tensions(i) <= c.f_max)) {
        return Status::error(ErrorCode::kOutOfRange,
                             "tensions: cable %d would carry %.4g N at this pose, outside [%g, %g]",
                             i + 1, s->tensions(i), c.f_min, c.f_max);
      }
    }
    return Eigen::VectorXd(s->tensions);
  }
  ForceDistributionData data(model);
  // Retry with 2x and 4x the reference pretension before giving up (more internal force often
  // lifts the slackest cable above f_min while the nearest feasible point at the lower
  // reference would sit on a limit).
  ForceDistributionResult last;
  for (double scale : {1.0, 2.0, 4.0}) {
    ForceDistributionOptions options;
    options.reference_tension = scale * reference_tension;
    last = distribute_forces(model, pose, options, data);
    if (last.feasible() && last.cables_at_limits == 0) return Eigen::VectorXd(last.tensions);
    if (last.outcome == ForceDistributionOutcome::kDegenerate ||
        last.outcome == ForceDistributionOutcome::kInvalidInput) {
      return Status(ErrorCode::kNumericalFailure,
                    "tension distribution: " + std::string(last.status.message()));
    }
  }
  if (last.feasible()) return Eigen::VectorXd(last.tensions);
  return Status(ErrorCode::kOutOfRange,
                "tension distribution: " + std::string(last.status.message()));
}

Result<Eigen::VectorXd> unstretched_lengths(const RobotModel& model, const Pose& pose,
                                            const Eigen::VectorXd& tensions) {
  KinematicsData data(model);
  if (!inverse_kinematics(model, pose, data)) {
    return Status::error(ErrorCode::kNumericalFailure, "cable %d is degenerate at the pose",
                         data.invalid_cable + 1);
  }
  Eigen::VectorXd u(model.num_cables());
  for (int i = 0; i < model.num_cables(); ++i) {
    const CableModel& c = model.cables[static_cast<std::size_t>(i)];
    const double loaded = ident_detail::loaded_length<double>(c, data.lengths(i));
    u(i) = data.lengths(i) - cable_elongation<double>(c, loaded, tensions(i));
  }
  return u;
}

namespace {

Status at_pose(const Status& s, std::size_t j) {
  return Status(s.code(), "simulate: pose " + std::to_string(j) + ": " + std::string(s.message()));
}

}  // namespace

Result<Pose> settle_platform(const RobotModel& model, const Eigen::VectorXd& unstretched,
                             const Pose& start, Eigen::VectorXd* tensions) {
  // Rigid cables have no elasto-static solution: they settle as Hooke cables with their EA.
  const bool any_rigid =
      std::any_of(model.cables.begin(), model.cables.end(),
                  [](const CableModel& c) { return c.elongation == ElongationKind::kRigid; });
  RobotModel hooke;
  if (any_rigid) {
    hooke = model;
    for (CableModel& c : hooke.cables) {
      if (c.elongation == ElongationKind::kRigid) c.elongation = ElongationKind::kHooke;
    }
  }
  const RobotModel& physics = any_rigid ? hooke : model;
  ElastostaticData data(physics);
  ElastostaticOptions options;
  options.initial_pose = start;
  ElastostaticSummary s = solve_elastostatics(physics, unstretched, options, data);
  if (!s.success()) {
    // From `start` every cable may be slack (stiff cables, a start a few mm off): start again
    // from the rigid forward kinematics of the commands, where the cables just reach.
    options.initial_pose.reset();
    s = solve_elastostatics(physics, unstretched, options, data);
  }
  if (!s.success()) {
    return Status(s.status.ok() ? ErrorCode::kNumericalFailure : s.status.code(),
                  "settle: " + std::string(s.status.message()));
  }
  if (tensions) *tensions = data.tensions;
  return s.pose;
}

double laser_distance(const RobotModel& model, int laser, const Pose& pose) {
  const LaserModel& l = model.lasers[static_cast<std::size_t>(laser)];
  const Eigen::Matrix3d R = rotation_from_rpy<double>(pose.rpy);
  const Eigen::Vector3d p = pose.position + R * l.origin;
  const Eigen::Vector3d d = R * l.direction.normalized();
  const Eigen::Vector3d n = l.plane_normal.normalized();
  const double den = n.dot(d);
  if (std::abs(den) < 1e-9) return std::numeric_limits<double>::quiet_NaN();
  const double t = n.dot(l.plane_point - p) / den;
  if (t < l.range_min || t > l.range_max) return std::numeric_limits<double>::quiet_NaN();
  return t;
}

double swivel_reading(const RobotModel& model, int cable, const Pose& pose) {
  const auto k = static_cast<std::size_t>(cable);
  const Eigen::Vector3d p =
      pose.position + rotation_from_rpy<double>(pose.rpy) * model.platform_anchors.col(cable);
  const Eigen::Vector3d v =
      model.pulleys[k].frame.transpose() * (p - model.frame_anchors.col(cable));
  if (!(v.x() * v.x() + v.y() * v.y() > 1e-18)) return std::numeric_limits<double>::quiet_NaN();
  const SwivelEncoderModel e = model.swivel_encoder(cable);
  const double x = e.direction * (std::atan2(v.y(), v.x()) - e.zero);
  return std::atan2(std::sin(x), std::cos(x));
}

namespace {
Eigen::Matrix3d sensor_rotation(const RobotModel& model, const Pose& pose) {
  return rotation_from_rpy<double>(pose.rpy) *
         rotation_from_rpy<double>(model.inclinometer.mounting_rpy);
}
}  // namespace

Eigen::Vector2d inclinometer_reading(const RobotModel& model, const Pose& pose) {
  const Eigen::Matrix3d Rs = sensor_rotation(model, pose);
  return {std::atan2(Rs(2, 1), Rs(2, 2)), std::atan2(-Rs(2, 0), std::hypot(Rs(2, 1), Rs(2, 2)))};
}

double imu_yaw_reading(const RobotModel& model, const Pose& pose) {
  const Eigen::Matrix3d Rs = sensor_rotation(model, pose);
  const double x = std::atan2(Rs(1, 0), Rs(0, 0)) - model.inclinometer.yaw_zero;
  return std::atan2(std::sin(x), std::cos(x));
}

Result<Eigen::VectorXd> homing_offsets(const RobotModel& truth, const RobotModel& nominal,
                                       double reference_tension) {
  auto ft = simple_tension_distribution(truth, truth.home, reference_tension);
  if (!ft) return ft.status();
  auto fn = simple_tension_distribution(nominal, nominal.home, reference_tension);
  if (!fn) return fn.status();
  auto ut = unstretched_lengths(truth, truth.home, *ft);
  if (!ut) return ut.status();
  auto un = unstretched_lengths(nominal, nominal.home, *fn);
  if (!un) return un.status();
  return Eigen::VectorXd(*ut - *un);
}

Result<CalibratedModel> homed_truth(const RobotModel& truth, const RobotModel& nominal,
                                    double reference_tension) {
  if (truth.num_cables() != nominal.num_cables()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "homing: the true robot has %d cables, the nominal one %d",
                         truth.num_cables(), nominal.num_cables());
  }
  const double f_ref =
      std::isnan(reference_tension) ? default_reference_tension(nominal) : reference_tension;
  CalibratedModel out = CalibratedModel::from_robot(truth);
  if (truth.suspended && truth.num_cables() < 6) {
    // A suspended crane is homed where it hangs: at the nominal home position and heading, its
    // roll and pitch those of the true robot's equilibrium there.
    auto home = suspended_equilibrium_pose(truth, nominal.home);
    if (!home) {
      return Status(home.status().code(),
                    "homing: the true suspended robot cannot hang at the home position: " +
                        std::string(home.status().message()));
    }
    out.robot.home = home->pose;
  }
  auto off = homing_offsets(out.robot, nominal, f_ref);
  if (!off) return Status(off.status().code(), "homing: " + std::string(off.status().message()));
  out.readings.length_offsets = *off;
  return out;
}

Result<SimulatedMeasurements> simulate_measurements(const CalibratedModel& truth,
                                                    const std::vector<Pose>& poses,
                                                    const SensorNoise& noise, std::uint64_t seed,
                                                    const SimulationOptions& options) {
  const RobotModel& robot = truth.robot;
  const int m = robot.num_cables();
  const int k = static_cast<int>(robot.lasers.size());
  if (truth.readings.length_offsets.size() != m || truth.readings.length_scales.size() != m) {
    return Status(ErrorCode::kInvalidArgument,
                  "simulate: the true reading model must have one offset and scale per cable");
  }
  if (options.physics == SimulationOptions::Physics::kElastic && options.controller == nullptr) {
    return Status(ErrorCode::kInvalidArgument,
                  "simulate: elastic physics needs the controller (nominal) model");
  }
  const RobotModel& nominal = options.controller ? options.controller->robot : robot;
  const double f_ref = std::isnan(options.reference_tension) ? default_reference_tension(nominal)
                                                             : options.reference_tension;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  auto noisy = [&](double sigma) { return options.add_noise ? sigma * normal(rng) : 0.0; };
  // The issue 18 channels draw from their own stream (see SimulationOptions).
  // (Its own distribution object too: std::normal_distribution caches a second variate.)
  std::mt19937_64 rng2(seed ^ 0x9e3779b97f4a7c15ULL);
  std::normal_distribution<double> normal2(0.0, 1.0);
  auto noisy2 = [&](double sigma) { return options.add_noise ? sigma * normal2(rng2) : 0.0; };
  auto wrap = [](double x) { return std::atan2(std::sin(x), std::cos(x)); };

  SimulatedMeasurements out;
  out.set.noise = noise;
  for (std::size_t j = 0; j < poses.size(); ++j) {
    const Pose& command = poses[j];
    Pose true_pose = command;
    Eigen::VectorXd f_true(m);
    Eigen::VectorXd reading(m);
    if (options.physics == SimulationOptions::Physics::kRigid) {
      auto f = simple_tension_distribution(robot, command, f_ref);
      if (!f) return at_pose(f.status(), j);
      f_true = *f;
      auto u = unstretched_lengths(robot, command, f_true);
      if (!u) return at_pose(u.status(), j);
      reading = ((u->array() - truth.readings.length_offsets.array()) /
                 (1.0 + truth.readings.length_scales.array()))
                    .matrix();
    } else {
      const CalibratedModel& ctrl = *options.controller;
      auto f = simple_tension_distribution(ctrl.robot, command, f_ref);
      if (!f) return at_pose(f.status(), j);
      auto u_cmd = unstretched_lengths(ctrl.robot, command, *f);
      if (!u_cmd) {
        return at_pose(u_cmd.status(), j);
      }
      // The controller converts its unstretched command into a reading with ITS reading model.
      reading = ((u_cmd->array() - ctrl.readings.length_offsets.array()) /
                 (1.0 + ctrl.readings.length_scales.array()))
                    .matrix();
      const Eigen::VectorXd u_true =
          ((1.0 + truth.readings.length_scales.array()) * reading.array() +
           truth.readings.length_offsets.array())
              .matrix();
      auto settled = settle_platform(robot, u_true, command, &f_true);
      if (!settled) {
        return at_pose(settled.status(), j);
      }
      true_pose = *settled;
    }
    PoseMeasurement pm;
    pm.commanded = command;
    pm.time = static_cast<double>(j);
    pm.cable_lengths.resize(m);
    pm.tensions.resize(m);
    for (int i = 0; i < m; ++i) {
      pm.cable_lengths(i) = reading(i) + noisy(noise.sigma_length);
      const ForceSensorModel& st = robot.force_sensors[static_cast<std::size_t>(i)];
      const ForceSensorModel& sn = nominal.force_sensors[static_cast<std::size_t>(i)];
      const double raw = st.gain * f_true(i) + st.offset;
      pm.tensions(i) = (raw - sn.offset) / sn.gain + noisy(noise.sigma_force);
    }
    // Without a laser the laser noise is still drawn (and dropped), so that the lengths and
    // forces of a seed are the same with and without the laser (paired comparisons).
    pm.laser_distances.resize(k);
    for (int l = 0; l < k; ++l) {
      const double d = laser_distance(robot, l, true_pose);
      pm.laser_distances(l) = std::isnan(d) ? d : d + noisy(noise.sigma_laser);
    }
    if (!options.laser) pm.laser_distances.resize(0);
    if (options.swivel) {
      pm.swivel_angles.resize(m);
      for (int i = 0; i < m; ++i) {
        const double g = swivel_reading(robot, i, true_pose);
        pm.swivel_angles(i) = std::isnan(g) ? g : wrap(g + noisy2(noise.sigma_swivel));
      }
    }
    if (options.inclinometer) {
      const Eigen::Vector2d rp = inclinometer_reading(robot, true_pose);
      pm.inclination = rp;
      for (int q = 0; q < 2; ++q) pm.inclination(q) = wrap(rp(q) + noisy2(noise.sigma_inclination));
    }
    if (options.imu_yaw) {
      pm.imu_yaw = wrap(imu_yaw_reading(robot, true_pose) + noisy2(noise.sigma_imu_yaw));
    }
    if (std::find(options.reference_pose_indices.begin(), options.reference_pose_indices.end(),
                  static_cast<int>(j)) != options.reference_pose_indices.end()) {
      Pose ref = true_pose;
      for (int a = 0; a < 3; ++a) ref.position(a) += noisy(noise.sigma_reference_position);
      for (int a = 0; a < 3; ++a) ref.rpy(a) += noisy(noise.sigma_reference_angle);
      pm.reference = ref;
    }
    out.set.poses.push_back(std::move(pm));
    out.true_poses.push_back(true_pose);
    out.true_tensions.push_back(f_true);
  }
  return out;
}

}  // namespace cdpr
