// Predicted accuracy of a calibration before it is run, and realised accuracy after.
//
// predict_accuracy: from a model, a pose set and the sensor noise, the Cramer-Rao bound of every
// parameter (the inverse Fisher information with the poses profiled out; pseudo-inverse with the
// null space removed) for the channels the calibration records (PredictedAccuracyOptions::channels:
// lengths and forces always; laser, swivel encoders, inclinometer, IMU heading as chosen), and the
// platform position error it causes over a test box (ISO 9283: MINI's 312 mm cube centred at the
// origin by default), by propagating the parameter covariance through the forward-kinematics
// sensitivity (the same for every channel: the controller uses lengths only): the controller
// commands the lengths of its calibrated model, the true robot reaches the pose whose lengths
// match them (least squares over the m cables),
//   dx = -pinv(dL/dx) (dL/dp) dp,   Cov(x) = G Cov(p) G^T.
//
// measure_position_accuracy: the realised error of a calibrated controller on a true robot: at a
// grid of box poses, the controller plans tensions and commands unstretched lengths with ITS model
// (through its reading model), the true elastic robot settles (simulate.hpp settle_platform), and
// the position error is measured.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// A grid of points_per_axis^3 positions (zero orientation) in a box.
struct AccuracyBox {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();                // m
  Eigen::Vector3d half_extent = Eigen::Vector3d::Constant(0.156);  // m (MINI's 312 mm cube)
  int points_per_axis = 5;

  std::vector<Pose> grid() const;
};

// ISO 9283's five test positions of `box` (its cube for a cube): P1 the centre, P2..P5 on the
// diagonal plane through the edges (x, z) = (-hx, -hz) and (+hx, +hz), each at 10 % of the plane's
// diagonals from a corner (0.8 of the way from the centre to the corner). The iso9283_bench's
// points and the calibration report's.
std::vector<Eigen::Vector3d> iso9283_points(const AccuracyBox& box);

struct PredictedAccuracyOptions {
  IdentificationOptions identification;
  // The channels the calibration will record (issue 18), with the noise given to
  // predict_accuracy. Its identification options must not estimate the laser's parameters
  // without the laser channel (kInvalidArgument): fit_estimates_to_channels sets them.
  SensorChannels channels;
  AccuracyBox box;
  double reference_tension = std::numeric_limits<double>::quiet_NaN();  // N; NaN: default
  double rank_tolerance = 1e-7;
};

struct PredictedAccuracy {
  std::vector<ParameterId> ids;    // the estimated parameters (code reads these)
  std::vector<std::string> names;  // parameter_name of each id, for people
  Eigen::VectorXd crb_std;         // Cramer-Rao bound (standard deviation) of each parameter
  Eigen::MatrixXd covariance;      // of the parameters
  int rank = 0;
  double anchor_rms_std_m = 0.0;  // sqrt(mean variance) over the estimated anchor coordinates
  double position_rms_m = 0.0;    // predicted RMS position error over the box grid
  double position_max_m = 0.0;    // largest per-point RMS
  int grid_points = 0;            // feasible grid points used
  int skipped_points = 0;         // box targets left out (infeasible, or cannot hang)
};

// Fits the estimated parameters to `channels`, as cdpr-fit calibrate does for a recording: the
// laser's parameters (origin, direction, plane) are not estimated without the laser; the
// mounting parameters of each issue 18 channel (swivel zeros, inclinometer mounting roll and
// pitch, IMU yaw zero) are estimated exactly when the channel is recorded (a new sensor's
// mounting is not known before it is calibrated). Everything else is left as it is.
void fit_estimates_to_channels(const SensorChannels& channels, IdentificationOptions* options);

// kInvalidArgument when `identification` estimates parameters of a channel that `channels` does
// not record on `robot` (they would stay unobserved): the laser's without the laser.
Status check_estimates_for_channels(const RobotModel& robot, const SensorChannels& channels,
                                    const IdentificationOptions& identification);

Result<PredictedAccuracy> predict_accuracy(const CalibratedModel& model,
                                           const std::vector<Pose>& poses, const SensorNoise& noise,
                                           const PredictedAccuracyOptions& options = {});

// The sensitivity of the pose the platform reaches to the geometry parameters, at each point of
// `box` where the tensions are feasible at f_ref: G = -pinv(dL/dx) (dL/dp) (rows: position m,
// then orientation rad; columns: `ids`, the parameters `identification` estimates with the
// channels recorded; kInternal when a parameter of the lengths is not among them). The mounting
// parameters of the laser, swivel encoders, inclinometer and IMU do not enter the commanded
// lengths: their columns are zero. Shared by predict_accuracy and the position-accuracy pose
// design. An under-actuated suspended robot (suspended, m < 6) cannot hold a level pose: each box
// target is replaced by suspended_equilibrium_pose of its position and yaw (targets that cannot
// hang are skipped), and G = -J^-1 (dr/dp) with r the m cable lengths and the 6 - m equilibrium
// conditions no tension can balance (the tensions follow the platform). `skipped_points`
// (optional): how many box targets were left out.
Result<std::vector<Eigen::MatrixXd>> pose_sensitivities(const CalibratedModel& model,
                                                        const AccuracyBox& box, double f_ref,
                                                        const SensorNoise& noise,
                                                        const IdentificationOptions& identification,
                                                        const std::vector<ParameterId>& ids,
                                                        int* skipped_points = nullptr);

// A position-accuracy (AP-like) figure PREDICTED at the ISO 9283 points of `options.box`
// (iso9283_points), not measured: the largest over the points of
//  - nominal_m: the distance from the commanded point to where commanding with `nominal` takes
//    the robot whose geometry is `calibrated` (measure_position_accuracy at each point: the
//    nominal model's error if the calibration is right);
//  - calibrated_m: the RMS position error the calibrated model keeps from its parameters'
//    uncertainty, `crb` (predict_accuracy's Cramer-Rao covariance with `nominal` and `noise`)
//    propagated at the point as predict_accuracy does.
// kNumericalFailure when no point is feasible for either figure.
struct PredictedIsoPosition {
  double nominal_m = std::numeric_limits<double>::quiet_NaN();
  double calibrated_m = std::numeric_limits<double>::quiet_NaN();
  int points = 0;  // of the five, where both figures were computed
};
Result<PredictedIsoPosition> predict_iso9283_position(const CalibratedModel& nominal,
                                                      const CalibratedModel& calibrated,
                                                      const PredictedAccuracy& crb,
                                                      const SensorNoise& noise,
                                                      const PredictedAccuracyOptions& options);

struct RealizedAccuracy {
  double position_rms_m = 0.0;
  double position_max_m = 0.0;
  double orientation_rms_rad = 0.0;
  int grid_points = 0;
  int failed_points = 0;  // infeasible or not settled
};

Result<RealizedAccuracy> measure_position_accuracy(
    const CalibratedModel& truth, const CalibratedModel& controller, const AccuracyBox& box,
    double reference_tension = std::numeric_limits<double>::quiet_NaN());

}  // namespace cdpr
