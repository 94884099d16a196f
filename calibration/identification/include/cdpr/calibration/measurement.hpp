// What the identification consumes: a set of measured poses and the stated sensor noise.
//
// Pure data, no I/O. tools/cdpr-fit maps a recording (drivers/recording) onto these types; the
// simulator (simulate.hpp) produces them from a true robot.
//
// Meaning of every field (SI units):
// - `commanded`: the pose the controller was asked to reach (nominal model). It is the initial
//   guess of the pose; the true pose is an unknown of the identification.
// - `cable_lengths(i)`: the length of cable i as read from its encoder through the NOMINAL winch
//   model, with the encoder zero set at homing so that the reading equals the nominal model's
//   length at the home pose. It measures the UNSTRETCHED (paid-out) length between the frame
//   anchor and the platform anchor; the identification relates it to the geometry by
//     L_geom(pose) * EA / (EA + F)  =  (1 + s_i) * cable_lengths(i) + o_i
//   where s_i is the transmission scale error, o_i the encoder-zero offset (identification.hpp).
//   NaN = not measured.
// - `tensions(i)`: cable tension in N through the NOMINAL force-sensor calibration
//   (RobotModel::force_sensors). NaN = not measured. An empty vector = no force sensors.
// - `laser_distances(k)`: distance in m along the beam of laser k (RobotModel::lasers[k]) from
//   its origin to the target plane. NaN = not measured / out of range.
// - `swivel_angles(i)` (issue 18): the reading of cable i's swivel-angle encoder, rad, as
//   RobotModel::swivel_encoders states (wrap(direction * (gamma - zero))). Empty vector = no
//   swivel encoders; NaN = not measured.
// - `inclination` (issue 18): the inclinometer's (roll, pitch), rad, of its sensor frame
//   R(pose) R_m (RobotModel::inclinometer). NaN = not measured (both or none).
// - `imu_yaw` (issue 18): an IMU's heading, rad (RobotModel::inclinometer.yaw_zero). NaN = none.
// - `reference`: the pose given by an external reference (home-position reference platform,
//   tracker), if any; weighted by the reference sigmas.
// - `time` (s since the start of the recording) and `temperature` (degC): informative, NaN when
//   unknown.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// One standard deviation of each sensor channel (white Gaussian noise assumed).
struct SensorNoise {
  double sigma_length = 1.0e-4;              // m, encoder length reading
  double sigma_laser = 1.0e-3;               // m, laser distance
  double sigma_force = 1.0;                  // N, cable tension
  double sigma_reference_position = 1.0e-4;  // m, reference pose position (per axis)
  double sigma_reference_angle = 1.0e-3;     // rad, reference pose roll/pitch/yaw
  // Issue 18 channels. Defaults: a 12-bit magnetic swivel encoder (1.5 mrad steps plus play),
  // a MEMS inclinometer of about 0.03 degrees, an IMU heading of about 0.6 degrees.
  double sigma_swivel = 1.0e-3;       // rad, swivel angle
  double sigma_inclination = 5.0e-4;  // rad, inclinometer roll and pitch
  double sigma_imu_yaw = 1.0e-2;      // rad, IMU heading
};

// The measurement channels a robot carries besides its winch encoders and force sensors (issue
// 18), for planning: pose design and predicted accuracy simulate these channels (with the noise
// of SensorNoise) and nothing else. The laser is used only when the model has one.
struct SensorChannels {
  bool laser = true;
  bool swivel = false;        // swivel_1..m (every cable with a swivel pulley)
  bool inclinometer = false;  // incl_roll, incl_pitch
  bool imu_yaw = false;

  // "laser, swivel, inclinometer" (the words of cdpr-fit --channels; "none" when empty).
  std::string words() const {
    std::string out;
    auto add = [&out](bool on, const char* w) {
      if (!on) return;
      if (!out.empty()) out += ", ";
      out += w;
    };
    add(laser, "laser");
    add(swivel, "swivel");
    add(inclinometer, "inclinometer");
    add(imu_yaw, "imu-yaw");
    return out.empty() ? std::string("none") : out;
  }
};

// How readings relate to physics beyond RobotModel: per-cable encoder-zero offset o_i (m) and
// transmission scale error s_i (dimensionless), in
//   unstretched length = (1 + s_i) * reading + o_i.
// Force sensors are described by RobotModel::force_sensors (raw = gain * tension + offset).
struct ReadingModel {
  Eigen::VectorXd length_offsets;  // o_i, m
  Eigen::VectorXd length_scales;   // s_i, dimensionless (0 = the nominal winch model is right)

  static ReadingModel nominal(int num_cables) {
    return ReadingModel{Eigen::VectorXd::Zero(num_cables), Eigen::VectorXd::Zero(num_cables)};
  }
};

// Everything the identification estimates: the robot model plus the reading model.
struct CalibratedModel {
  RobotModel robot;
  ReadingModel readings;

  // A model with nominal readings (zero offsets and scale errors).
  static CalibratedModel from_robot(const RobotModel& robot) {
    return CalibratedModel{robot, ReadingModel::nominal(robot.num_cables())};
  }
};

struct PoseMeasurement {
  Pose commanded;
  Eigen::VectorXd cable_lengths;    // m, size m; NaN = missing
  Eigen::VectorXd tensions;         // N, size m or empty; NaN = missing
  Eigen::VectorXd laser_distances;  // m, size = number of lasers (may be 0); NaN = missing
  Eigen::VectorXd swivel_angles;    // rad, size m or empty; NaN = missing
  Eigen::Vector2d inclination = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
  double imu_yaw = std::numeric_limits<double>::quiet_NaN();      // rad
  std::optional<Pose> reference;                                  // known pose, if any
  double time = std::numeric_limits<double>::quiet_NaN();         // s
  double temperature = std::numeric_limits<double>::quiet_NaN();  // degC
  // What a real campaign knows besides the readings (optional recording columns):
  // the tensions the controller planned at this pose (N, size m or empty; not an observation);
  Eigen::VectorXd planned_tensions;
  // the scatter of this pose's averaged readings (standard deviations, m and N; NaN: none): the
  // identification weighs the pose's length and tension residuals with
  // sqrt(sigma^2 + scatter^2) instead of the recording's sigma;
  double scatter_length = std::numeric_limits<double>::quiet_NaN();
  double scatter_force = std::numeric_limits<double>::quiet_NaN();
  // the platform rested on something (a support at homing): the cables did not carry its whole
  // weight, so the pose's static equilibrium is not used (its lengths and other readings are);
  bool supported = false;
  // a better start than the commanded pose (the robot's own estimate, a camera): the pose's
  // solve starts here; the commanded pose stays what was commanded.
  std::optional<Pose> start;
  // A known wrench on the platform besides gravity and the cables (force N, moment N m about the
  // platform's reference point, world axes), added to the static equilibrium: a payload, or a
  // modelled effect such as the cable weight the platform carries (diagnosis.hpp). Zero in
  // recordings.
  Eigen::Matrix<double, 6, 1> external_wrench = Eigen::Matrix<double, 6, 1>::Zero();
  // A known extra dependence of each cable's length residual on its tension reading besides the
  // model's elongation (m/N, size m or empty = none): e.g. the arc of a sagging cable, which
  // shrinks as the tension grows (diagnosis.hpp, sag). The force noise reaches the length
  // residual through it as through the elongation: the residual's sigma is
  // sqrt(sigma_length^2 + ((compliance + extra) sigma_force)^2). Empty in recordings.
  Eigen::VectorXd extra_compliance;
};

// The sensor noise at pose `pm`: the set's, with the length and tension sigmas widened by the
// pose's scatter (sqrt(sigma^2 + scatter^2)) where the recording gives one.
inline SensorNoise noise_at(const SensorNoise& set_noise, const PoseMeasurement& pm) {
  SensorNoise n = set_noise;
  if (pm.scatter_length > 0.0) n.sigma_length = std::hypot(n.sigma_length, pm.scatter_length);
  if (pm.scatter_force > 0.0) n.sigma_force = std::hypot(n.sigma_force, pm.scatter_force);
  return n;
}

// Where the solve of pose `pm` starts: the reference pose, else the start pose, else the
// commanded one.
inline Pose start_of(const PoseMeasurement& pm) {
  return pm.reference ? *pm.reference : pm.start ? *pm.start : pm.commanded;
}

struct MeasurementSet {
  std::vector<PoseMeasurement> poses;
  SensorNoise noise;

  int num_poses() const { return static_cast<int>(poses.size()); }
};

// Checks that `set` fits `model`: sizes of every vector, positive sigmas, finite commanded poses.
// The message names the pose and the field.
inline Status validate(const MeasurementSet& set, const RobotModel& model) {
  const int m = model.num_cables();
  const int k = static_cast<int>(model.lasers.size());
  const SensorNoise& n = set.noise;
  if (!(n.sigma_length > 0) || !(n.sigma_laser > 0) || !(n.sigma_force > 0) ||
      !(n.sigma_reference_position > 0) || !(n.sigma_reference_angle > 0) ||
      !(n.sigma_swivel > 0) || !(n.sigma_inclination > 0) || !(n.sigma_imu_yaw > 0)) {
    return Status(ErrorCode::kInvalidArgument,
                  "measurement set: every sensor sigma must be positive and finite");
  }
  for (int j = 0; j < set.num_poses(); ++j) {
    const PoseMeasurement& p = set.poses[static_cast<std::size_t>(j)];
    if (!p.commanded.vector().allFinite()) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: commanded pose is not finite", j);
    }
    if (p.cable_lengths.size() != m) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: %d cable lengths, the model has %d cables", j,
                           static_cast<int>(p.cable_lengths.size()), m);
    }
    if (p.tensions.size() != 0 && p.tensions.size() != m) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: %d tensions, the model has %d cables", j,
                           static_cast<int>(p.tensions.size()), m);
    }
    if (p.laser_distances.size() != 0 && p.laser_distances.size() != k) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: %d laser distances, the model has %d lasers",
                           j, static_cast<int>(p.laser_distances.size()), k);
    }
    if (p.swivel_angles.size() != 0 && p.swivel_angles.size() != m) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: %d swivel angles, the model has %d cables", j,
                           static_cast<int>(p.swivel_angles.size()), m);
    }
    if (std::isnan(p.inclination(0)) != std::isnan(p.inclination(1))) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: inclinometer roll and pitch must be both "
                           "measured or both missing",
                           j);
    }
    if (p.reference && !p.reference->vector().allFinite()) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: reference pose is not finite", j);
    }
    if (p.start && !p.start->vector().allFinite()) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: start pose is not finite", j);
    }
    if (p.planned_tensions.size() != 0 && p.planned_tensions.size() != m) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: %d planned tensions, the model has %d cables",
                           j, static_cast<int>(p.planned_tensions.size()), m);
    }
    if (p.scatter_length < 0.0 || p.scatter_force < 0.0 || std::isinf(p.scatter_length) ||
        std::isinf(p.scatter_force)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %d: a scatter must be finite and >= 0", j);
    }
  }
  return Status::success();
}

}  // namespace cdpr
