#include "cdpr/calibration/simulate.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
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

double default_reference_tension(const RobotModel& model) {
  double lo = 0.0, hi = std::numeric_limits<double>::infinity();
  for (const CableModel& c : model.cables) {
    lo = std::max(lo, c.f_min);
    hi = std::min(hi, c.f_max);
  }
  return std::min(0.5 * (lo + hi), 4.0 * std::max(lo, 1.0));
}

Result<Eigen::VectorXd> simple_tension_distribution(const RobotModel& model, const Pose& pose,
                                                    double reference_tension) {
  KinematicsData data(model);
  if (!inverse_kinematics(model, pose, data)) {
    return Status::Error(ErrorCode::kNumericalFailure,
                         "tension distribution: cable %d is degenerate at the pose",
                         data.invalid_cable + 1);
  }
  const int m = model.num_cables();
  const Eigen::MatrixXd At = data.structure_matrix;
  const Eigen::VectorXd f0 = Eigen::VectorXd::Constant(m, reference_tension);
  const Eigen::Matrix<double, 6, 1> w = platform_weight_wrench(model, pose);
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(At, Eigen::ComputeThinU | Eigen::ComputeThinV);
  if (svd.singularValues()(5) < 1e-9 * svd.singularValues()(0)) {
    return Status(ErrorCode::kNumericalFailure,
                  "tension distribution: the structure matrix is singular at the pose");
  }
  // Retry with 2x and 4x the reference pretension before giving up (more internal force often
  // lifts the slackest cable above f_min).
  int bad = -1;
  double bad_f = 0.0;
  for (double scale : {1.0, 2.0, 4.0}) {
    const Eigen::VectorXd fs = scale * f0;
    const Eigen::VectorXd f = fs - svd.solve(At * fs + w);
    bad = -1;
    for (int i = 0; i < m && bad < 0; ++i) {
      const CableModel& c = model.cables[static_cast<std::size_t>(i)];
      if (f(i) < c.f_min || f(i) > c.f_max) {
        bad = i;
        bad_f = f(i);
      }
    }
    if (bad < 0) return f;
  }
  const CableModel& c = model.cables[static_cast<std::size_t>(bad)];
  return Status::Error(ErrorCode::kOutOfRange,
                       "tension distribution: cable %d needs %.1f N, outside [%.1f, %.1f] N",
                       bad + 1, bad_f, c.f_min, c.f_max);
}

Result<Eigen::VectorXd> unstretched_lengths(const RobotModel& model, const Pose& pose,
                                            const Eigen::VectorXd& tensions) {
  KinematicsData data(model);
  if (!inverse_kinematics(model, pose, data)) {
    return Status::Error(ErrorCode::kNumericalFailure, "cable %d is degenerate at the pose",
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

// Hooke tensions at a pose for given unstretched lengths, and the net wrench on the platform.
bool net_wrench(const RobotModel& model, const Eigen::VectorXd& unstretched, const Pose& pose,
                KinematicsData& data, Eigen::VectorXd& f, Eigen::Matrix<double, 6, 1>& g) {
  if (!inverse_kinematics(model, pose, data)) return false;
  for (int i = 0; i < model.num_cables(); ++i) {
    // Hooke over the loaded length (routing part included, see elongation.hpp):
    // L_k - F (L_k + route) / (EA + F) = U  <=>  F = EA (L_k - U) / (U + route).
    const CableModel& c = model.cables[static_cast<std::size_t>(i)];
    const double route = ident_detail::loaded_length<double>(c, 0.0);
    const double stretch = data.lengths(i) - unstretched(i);
    f(i) = stretch > 0.0 ? c.ea * stretch / (unstretched(i) + route) : 0.0;
  }
  g = data.structure_matrix * f + platform_weight_wrench(model, pose);
  return true;
}

Status at_pose(const Status& s, std::size_t j) {
  return Status(s.code(), "simulate: pose " + std::to_string(j) + ": " + std::string(s.message()));
}

}  // namespace

Result<Pose> settle_platform(const RobotModel& model, const Eigen::VectorXd& unstretched,
                             const Pose& start, Eigen::VectorXd* tensions) {
  const int m = model.num_cables();
  KinematicsData data(model);
  Eigen::VectorXd f(m);
  Eigen::Matrix<double, 6, 1> g, gt;
  Pose x = start;
  if (!net_wrench(model, unstretched, x, data, f, g)) {
    return Status(ErrorCode::kNumericalFailure, "settle: degenerate cable at the start pose");
  }
  const double force_scale = std::max(1.0, model.platform.mass * model.gravity);
  for (int it = 0; it < 100; ++it) {
    if (g.norm() < 1e-10 * force_scale) break;
    Eigen::Matrix<double, 6, 6> J;
    const double h = 1e-7;
    for (int k = 0; k < 6; ++k) {
      Eigen::Matrix<double, 6, 1> v = x.vector();
      v(k) += h;
      if (!net_wrench(model, unstretched, Pose::from_vector(v), data, f, gt)) {
        return Status(ErrorCode::kNumericalFailure, "settle: degenerate cable");
      }
      J.col(k) = (gt - g) / h;
    }
    Eigen::Matrix<double, 6, 1> step = -J.colPivHouseholderQr().solve(g);
    if (!step.allFinite()) return Status(ErrorCode::kNumericalFailure, "settle: singular");
    const double cap = 0.01;  // m or rad per step
    const double big = step.cwiseAbs().maxCoeff();
    if (big > cap) step *= cap / big;
    // Backtracking on |g|.
    double alpha = 1.0;
    bool accepted = false;
    for (int ls = 0; ls < 30; ++ls) {
      const Pose trial = Pose::from_vector(x.vector() + alpha * step);
      if (net_wrench(model, unstretched, trial, data, f, gt) && gt.norm() < g.norm()) {
        x = trial;
        g = gt;
        accepted = true;
        break;
      }
      alpha *= 0.5;
    }
    if (!accepted) break;
  }
  net_wrench(model, unstretched, x, data, f, g);
  if (g.norm() > 1e-6 * force_scale) {
    return Status::Error(ErrorCode::kNumericalFailure,
                         "settle: no equilibrium found (net wrench %.3g N)", g.norm());
  }
  if (tensions) *tensions = f;
  return x;
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
    return Status::Error(ErrorCode::kInvalidArgument,
                         "homing: the true robot has %d cables, the nominal one %d",
                         truth.num_cables(), nominal.num_cables());
  }
  const double f_ref =
      std::isnan(reference_tension) ? default_reference_tension(nominal) : reference_tension;
  CalibratedModel out = CalibratedModel::FromRobot(truth);
  auto off = homing_offsets(truth, nominal, f_ref);
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
    pm.laser_distances.resize(k);
    for (int l = 0; l < k; ++l) {
      const double d = laser_distance(robot, l, true_pose);
      pm.laser_distances(l) = std::isnan(d) ? d : d + noisy(noise.sigma_laser);
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
