// Simulated measurements for tests, benchmarks and `cdpr-fit simulate`: what the robot's sensors
// would read at a set of poses, given the TRUE robot and reading model. Deterministic by seed.
//
// Two physics levels (SimulationOptions::physics):
// - kRigid: the platform is exactly at each given pose. Readings: the unstretched length from the
//   true geometry and the true tensions (tension distribution below), through the true reading
//   model; force sensors and the laser at that pose.
// - kElastic: the given poses are COMMANDS. The controller model (the nominal one) computes the
//   unstretched length commands from its IK and its planned tensions; the true robot settles
//   where its elastic cables balance the platform weight (settle_platform, i.e.
//   solve_elastostatics). The encoder reads the
//   command (plus noise), the force sensors the true tensions, the laser the true pose. This is the
//   paper's measuring stage (Section 5.1).
//
// Gaussian noise from SensorNoise is added to every reading unless options.add_noise is false.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <vector>

#include "cdpr/calibration/force_distribution.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Roll-pitch-yaw of R = Rz(yaw) Ry(pitch) Rx(roll) (inverse of rotation_from_rpy).
Eigen::Vector3d rpy_from_rotation_matrix(const Eigen::Matrix3d& R);

// Gravity wrench on the platform at `pose` (force and moment about the platform origin), world.
Eigen::Matrix<double, 6, 1> platform_weight_wrench(const RobotModel& model, const Pose& pose);

// The tensions the controller plans at `pose`: distribute_forces (force_distribution.hpp, exact
// QP) nearest to the uniform `reference_tension`; when that solution has a cable on a limit, the
// reference is raised to 2 and 4 times (more pretension lifts the slackest cable off f_min) and
// the first distribution with no cable on a limit is taken, else the last feasible one.
// kOutOfRange when the pose is outside the wrench-feasible workspace, kNumericalFailure when the
// geometry is degenerate. A suspended robot with m < 6 cables (issue 18) has no choice: its
// tensions are the unique ones that balance the weight (suspended_statics.hpp), and a pose that
// is not an equilibrium, or needs a tension outside [f_min, f_max], is kOutOfRange (the reference
// tension is not used).
Result<Eigen::VectorXd> simple_tension_distribution(const RobotModel& model, const Pose& pose,
                                                    double reference_tension);

// Unstretched length of every cable at `pose` under `tensions` (kinematic length minus the
// elongation of elongation.hpp's model).
Result<Eigen::VectorXd> unstretched_lengths(const RobotModel& model, const Pose& pose,
                                            const Eigen::VectorXd& tensions);

// Where an elastic robot with unstretched cable lengths `unstretched` settles (solve_elastostatics
// of elastostatics.hpp from `start`, then from the rigid forward kinematics if that fails: the
// cable laws of the model, slack cables carry nothing; rigid cables are taken as Hooke cables with
// their EA). Returns the pose and, in *tensions, the cable tensions there; the solver's reason when
// no equilibrium is found.
Result<Pose> settle_platform(const RobotModel& model, const Eigen::VectorXd& unstretched,
                             const Pose& start, Eigen::VectorXd* tensions = nullptr);

// Ray-plane distance of laser k at `pose` (NaN when the beam misses the plane or is out of range).
double laser_distance(const RobotModel& model, int laser, const Pose& pose);

// Noise-free readings of the issue 18 channels at `pose` (robot_model.hpp states the models):
// the swivel encoder of cable i (NaN when the platform anchor is on the swivel axis), the
// inclinometer's (roll, pitch) and the IMU heading.
double swivel_reading(const RobotModel& model, int cable, const Pose& pose);
Eigen::Vector2d inclinometer_reading(const RobotModel& model, const Pose& pose);
double imu_yaw_reading(const RobotModel& model, const Pose& pose);

// Encoder-zero offsets produced by homing: the reading at the home pose is set to the nominal
// model's unstretched length there, so o_i = U_true,i(home) - U_nominal,i(home) with the
// tensions planned by each model at home.
Result<Eigen::VectorXd> homing_offsets(const RobotModel& truth, const RobotModel& nominal,
                                       double reference_tension);

// The true reading model a real robot has after homing with the controller's model `nominal`:
// zero scale errors and the encoder-zero offsets of homing_offsets(truth, nominal,
// reference_tension) (NaN: default_reference_tension(nominal)). Simulating with it gives
// readings with the meaning measurement.hpp states (the reading at the home pose is the nominal
// model's length there), and with elastic physics the platform settles exactly at the home pose
// when the home pose is commanded, which is what the home-pose gauge of the identification and
// the paper's method assume. With zero offsets instead the encoders would read absolute true
// lengths and the platform would settle away from home (by up to the anchor errors). A suspended
// robot with m < 6 cables is homed where it hangs: the returned robot's home is the true
// equilibrium at the nominal home position and heading (suspended_statics.hpp), the pose whose
// position and yaw the identification's gauge holds for such a robot.
Result<CalibratedModel> homed_truth(
    const RobotModel& truth, const RobotModel& nominal,
    double reference_tension = std::numeric_limits<double>::quiet_NaN());

struct SimulationOptions {
  enum class Physics { kRigid, kElastic };
  Physics physics = Physics::kRigid;
  // The model the controller believes (nominal), used by kElastic to compute the length commands
  // and by both to convert raw force readings with the nominal sensor calibration. nullptr: the
  // truth's force sensors are the nominal ones; kElastic requires it.
  const CalibratedModel* controller = nullptr;
  // Pretension planned by the controller (kElastic) or used for the tensions (kRigid), N. NaN:
  // default_reference_tension of the model.
  double reference_tension = std::numeric_limits<double>::quiet_NaN();
  bool add_noise = true;
  // Poses that also get a reference pose reading (e.g. {0} for a reference platform at home).
  std::vector<int> reference_pose_indices;
  // Which channels the robot has (issue 18). Without the laser the poses get no laser distances
  // (k = 0). The noise of the new channels comes from a second random stream seeded from `seed`,
  // so switching them on leaves the length, force and laser readings of a seed unchanged.
  bool laser = true;
  bool swivel = false;
  bool inclinometer = false;
  bool imu_yaw = false;

  // Sets the four channel switches above from `channels`.
  void use_channels(const SensorChannels& channels) {
    laser = channels.laser;
    swivel = channels.swivel;
    inclinometer = channels.inclinometer;
    imu_yaw = channels.imu_yaw;
  }
};

struct SimulatedMeasurements {
  MeasurementSet set;
  std::vector<Pose> true_poses;                // where the platform really was
  std::vector<Eigen::VectorXd> true_tensions;  // N
};

Result<SimulatedMeasurements> simulate_measurements(const CalibratedModel& truth,
                                                    const std::vector<Pose>& poses,
                                                    const SensorNoise& noise, std::uint64_t seed,
                                                    const SimulationOptions& options = {});

}  // namespace cdpr
