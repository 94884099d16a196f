// Identification of the geometry and sensor parameters of a cable robot from a MeasurementSet:
// joint nonlinear least squares over the chosen parameters and the N unknown platform poses
// (bundle-adjustment style), solved with Ceres (automatic derivatives through cable_geometry<Jet>,
// DENSE_SCHUR with the poses in elimination group 0).
//
// Residuals (each divided by its stated sigma, so a correct model gives chi^2 ~ dof):
// - Cable length, per cable and pose (SensorNoise::sigma_length, plus the force noise propagated
//   through the elongation):
//     r = U(pose) - ((1 + s_i) * reading_i + o_i),
//     U = L_k(pose; a_i, b_i) - dL(L_k, F_i)          (unstretched length, elongation.hpp)
//   with F_i the true tension from the reading through the force sensor model being estimated,
//   and, when the stiffness is estimated, dL = F L / (EA_i + F) (Hooke) with EA_i estimated.
//   A missing tension (NaN) gives dL = 0 for that cable (and a warning).
// - Laser k (sigma_laser): distance along the beam from its origin to the target plane n.x = c at
//   the pose, minus the reading.
// - Static equilibrium (6 per pose with all tensions measured): A^T(pose) F + w(pose), whitened by
//   the covariance sigma_force^2 A^T A computed at the initial pose (the force noise propagated).
// - Reference pose (sigma_reference_position / _angle), when a PoseMeasurement has one.
// - Swivel angle of cable i (sigma_swivel, issue 18): wrap(direction_i (gamma_i(pose; a_i, b_i) -
//   zero_i) - reading), gamma from the pulley frame of the model (robot_model.hpp).
// - Inclinometer (sigma_inclination, 2 per pose): roll and pitch of R(pose) R_m minus the
//   readings (wrapped), R_m the mounting rotation, whose roll and pitch corrections can be
//   estimated; the rotation about the sensor's own z stays at the config's value (an
//   inclinometer sees it only through tilt x angle, second order).
// - IMU heading (sigma_imu_yaw): wrap(yaw(R(pose) R_m) - yaw_zero - reading).
// All residuals have exact derivatives (automatic differentiation); the angle residuals are
// wrapped with atan2(sin, cos), whose derivative is exactly 1.
//
// Gauge. A cable robot's measurements are invariant under a rigid motion of the world frame, so
// something must fix it (IdentificationOptions::gauge):
// - kHomePose (default): the pose `home_pose_index` is the home pose (reference platform, the
//   paper's "same EE position"), held constant at its reference reading if it has one, else at
//   RobotModel::home. This fixes all six freedoms.
// - kLaserPlane: the laser target planes are held at their model values (3 freedoms fixed: z,
//   roll, pitch); the remaining ones must be fixed by the parameter choice (e.g. the paper's
//   16-parameter subset of the frame anchors).
// - kHomePoseAndLaserPlane: both.
// - kNone: the parameter choice alone must fix it.
// Whatever the choice, the geometry information (poses profiled out) is checked for rank before
// solving; a rank-deficient choice is refused with the unidentifiable directions in words.
//
// Every estimated coordinate is bounded to a physical range (ParameterBounds, Ceres box
// constraints); an estimate on its bound is flagged (ParameterEstimate::at_bound) and warned about.
//
// Parameterisation (tangent coordinates, each named in IdentificationReport::parameters):
// a_i.x/y/z (m), b_i.x/y/z (m), o_i (m), s_i (-), EA scale e_i (EA = EA_nominal (1 + e)),
// force sensor gain error g_i (gain = nominal (1 + g)) and offset c_i (raw units), laser origin
// (m, platform frame), laser direction (two small angles about the nominal direction, rad), plane
// normal (two small angles, rad) and plane offset c (m, n.x = c), swivel encoder zero zero_i
// (rad), inclinometer mounting correction (roll, pitch, rad, applied as R_m = R_m,config
// rotation_from_rpy(roll, pitch, 0)), IMU yaw zero (rad), platform mass (kg) and centre of mass
// (m, platform frame; both enter the weight's force and moment in the equilibrium residuals).
#pragma once

#include <Eigen/Core>
#include <functional>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Progress of long offline work, for a display: `what` ("solver iteration", "poses designed",
// "bootstrap resamples"), `done` of `total` (for the solver: the iteration and the iteration
// limit). Called on the calling thread between steps; it must not throw. The mathematics does no
// I/O: printing is the caller's.
using ProgressCallback = std::function<void(std::string_view what, int done, int total)>;

enum class Gauge { kHomePose, kLaserPlane, kHomePoseAndLaserPlane, kNone };
enum class RobustLoss { kNone, kHuber, kCauchy };
enum class StiffnessEstimate { kFixed, kShared, kPerCable };

// Which coordinates of a 3 x m anchor set are estimated (true = estimated).
using AnchorMask = Eigen::Array<bool, 3, Eigen::Dynamic>;

// The paper's V = [x2..x7, y2..y7, z5..z8] for an 8-cable robot (1-based cable numbers).
AnchorMask paper_anchor_mask();

// The physical range of every estimated parameter kind, enforced in the solver as bounds (Ceres
// box constraints on the tangent coordinates). Ranges are relative to the starting model (the
// nominal config) unless stated. A parameter that ends on its bound is reported
// (ParameterEstimate::at_bound, a warning): the data pushed it outside what the robot can be,
// which is a sign of a missing effect or a bad recording, not a calibration.
struct ParameterBounds {
  double frame_anchor_m = 0.25;     // a_i: +- per coordinate around the nominal anchor
  double platform_anchor_m = 0.05;  // b_i: +- per coordinate
  double length_offset_m = 0.25;    // o_i: encoder zero correction, +-
  double length_scale = 0.05;       // s_i: transmission (drum) scale error, +- (5 %)
  double ea_factor_min = 0.1;       // EA within [min, max] x the config's EA
  double ea_factor_max = 10.0;
  double force_gain = 0.3;              // g_i: relative force sensor gain error, +- (30 %)
  double force_offset_fraction = 0.1;   // c_i: +- this fraction of f_max, in raw units (gain x N)
  double laser_origin_m = 0.1;          // laser origin on the platform, +- per coordinate
  double laser_direction_rad = 0.2;     // beam direction, +- per tangent angle (11.5 deg)
  double plane_normal_rad = 0.2;        // target plane normal, +- per tangent angle
  double plane_offset_m = 0.25;         // target plane offset c, +-
  double swivel_zero_rad = 0.5;         // swivel encoder zero, +- around the config's
  double inclinometer_mount_rad = 0.2;  // inclinometer mounting roll and pitch, +-
  double imu_yaw_zero_rad = 3.2;        // IMU heading zero, +- (about half a turn: any heading)
  double home_tilt_rad = 0.2;  // suspended robots: home roll and pitch, +- around the start
  // Platform mass within [min, max] x the config's mass (always > 0); each coordinate of the
  // centre of mass (platform frame) within +- RobotModel::platform_radius() of the config's: the
  // correction stays within the platform's extent (a config may place the centre of mass of a
  // hanging load below the plate, outside the anchors' radius).
  double mass_factor_min = 0.5;
  double mass_factor_max = 2.0;
};

struct IdentificationOptions {
  // --- What is estimated -------------------------------------------------------------------
  bool estimate_frame_anchors = true;
  AnchorMask frame_anchor_mask;  // 3 x m; empty = every coordinate
  bool estimate_platform_anchors = false;
  AnchorMask platform_anchor_mask;  // 3 x m; empty = every coordinate
  bool estimate_length_offsets = true;
  bool estimate_length_scales = false;
  StiffnessEstimate estimate_stiffness = StiffnessEstimate::kFixed;
  bool estimate_force_gains = false;
  bool estimate_force_offsets = false;
  bool estimate_laser_origin = false;
  bool estimate_laser_direction = false;
  bool estimate_laser_plane = true;
  // Issue 18 channels' mounting parameters.
  bool estimate_swivel_zeros = false;           // zero_i of every cable with swivel readings
  bool estimate_inclinometer_mounting = false;  // roll and pitch of the mounting rotation
  bool estimate_imu_yaw_zero = false;
  // Platform mass and centre of mass (the weight in the equilibrium residuals; they need measured
  // tensions). The mass is seen in the vertical force; the centre of mass in the moment of the
  // weight, its height only through tilted poses (the lever of the weight is horizontal).
  bool estimate_platform_mass = false;
  bool estimate_platform_com = false;

  // --- Which residuals are used --------------------------------------------------------------
  bool use_lengths = true;
  bool use_laser = true;
  bool use_equilibrium = true;
  bool use_reference = true;
  bool use_swivel = true;
  bool use_inclinometer = true;
  bool use_imu_yaw = true;
  // Cables whose tension reading is below this (N), or below slack_tension_sigmas times the
  // force noise (SensorNoise::sigma_force), are slack: their length residual is skipped. A slack
  // cable reads 0 +- sigma_force, so at 3 sigma about one slack reading in 740 passes as taut, and
  // its length is then off by the slack (several sigma); at 4 sigma one in 30000.
  double slack_tension_threshold = 3.0;
  double slack_tension_sigmas = 4.0;
  // Suspended robots with m < 6 cables (RobotModel::suspended, issue 18): the 6 - m equilibrium
  // components that no tension can balance constrain the pose without sensor noise; this small
  // model sigma (N, or N m for moments) only keeps them soft. With kHomePose the home pose then
  // holds its position and heading only: its roll and pitch are estimated ("home.roll",
  // "home.pitch"), gravity fixing the world frame's tilt.
  double suspended_equilibrium_sigma = 1e-3;

  // --- Gauge and robustness ------------------------------------------------------------------
  Gauge gauge = Gauge::kHomePose;
  int home_pose_index = 0;
  // With a home gauge, hold the row home_pose_index at its commanded pose instead of
  // RobotModel::home (its reference reading still wins): for a recording that does not start at
  // the home pose (`cdpr-fit --gauge start`). An error of that pose moves every anchor with it.
  bool home_at_commanded = false;
  RobustLoss loss = RobustLoss::kNone;
  double loss_scale = 3.0;  // in units of sigma (residuals are normalised)

  // --- Solver ----------------------------------------------------------------------------------
  int max_iterations = 100;
  // Relative; 1e-10 stops when the cost changes by 1e-10 of chi^2 (~1e-8 on 25 poses), far below
  // what matters statistically (tighter costs iterations: 15 instead of 6 on MINI).
  double function_tolerance = 1e-10;
  double gradient_tolerance = 1e-14;
  double parameter_tolerance = 1e-10;
  int num_threads = 1;
  ProgressCallback progress;  // after each solver iteration; empty: none

  // --- Checks and report ---------------------------------------------------------------------
  // Refuse (kFailedPrecondition) a choice whose column-normalised geometry information has
  // sigma_min / sigma_max below this (unidentifiable, including open gauge freedoms).
  double rank_tolerance = 1e-7;
  bool refuse_unidentifiable = true;
  bool compute_covariance = true;
  double condition_warning = 1e4;  // warn above this condition number (column-normalised)
  // Warn when a length-like parameter's std exceeds the larger of huge_std_anchor (m) and
  // huge_std_fraction of the frame size (the diagonal of the box around the frame anchors): what
  // is huge depends on the robot (1 cm on a 1.6 m frame, 12 cm on a 25 m one).
  double huge_std_anchor = 0.01;
  double huge_std_fraction = 0.005;
  double chi2_warning_sigmas = 4.0;  // warn when |chi2 - dof| > this * sqrt(2 dof)

  // --- Physical ranges ---------------------------------------------------------------------------
  ParameterBounds bounds;
};

// The tension (N) below which a cable counts as slack: the larger of the two thresholds above.
double slack_threshold(const IdentificationOptions& options, const SensorNoise& noise);

// One estimated scalar (a tangent coordinate).
// What an estimated parameter is: its kind, the cable or laser it belongs to and its component.
// The name for people (ParameterEstimate::name, GeometryInformation::names) is derived from it
// (parameter_name); code reads the id, never the name.
enum class ParameterKind {
  kFrameAnchor,        // a_i.x/y/z, m
  kPlatformAnchor,     // b_i.x/y/z, m
  kLengthOffset,       // o_i, m
  kLengthScale,        // s_i, -
  kStiffness,          // ea_scale (shared) or ea_scale_i: EA = EA_config (1 + e), -
  kForceGain,          // force_gain_i, -
  kForceOffset,        // force_offset_i, N (raw)
  kLaserOrigin,        // laser_l.origin.x/y/z, m
  kLaserDirection,     // laser_l.direction.u/v, rad
  kLaserPlaneNormal,   // laser_l.plane.normal.u/v, rad
  kLaserPlaneOffset,   // laser_l.plane.c, m
  kSwivelZero,         // swivel_zero_i, rad
  kInclinometerMount,  // inclinometer.mount.roll/pitch, rad
  kImuYawZero,         // imu.yaw_zero, rad
  kHomePose,           // home.x/y/z/roll/pitch/yaw (component 0..5); a suspended robot's home
                       // roll and pitch are estimated (m < 6), m / rad
  kPlatformMass,       // platform.mass, kg
  kPlatformCom,        // platform.com.x/y/z (platform frame), m
};

struct ParameterId {
  ParameterKind kind = ParameterKind::kFrameAnchor;
  int index = -1;      // 0-based cable or laser; -1: one for all (shared stiffness, IMU, ...)
  int component = -1;  // 0..2 for x/y/z, 0..1 for u/v and roll/pitch; -1: a scalar
  bool operator==(const ParameterId&) const = default;
};

// "a_3.x", "o_5", "ea_scale", "laser_1.plane.c", "inclinometer.mount.pitch", ...; a vector kind
// with component -1 names the whole vector: "a_3", "laser_1.origin", "home".
std::string parameter_name(const ParameterId& id);

// The words of `cdpr-fit ... --estimate` and the parameter kinds each switches on: one table
// (estimate_items(), in the order the tools list them).
struct EstimateItem {
  std::string_view word;             // "anchors", "stiffness-per-cable", "laser-plane", ...
  std::vector<ParameterKind> kinds;  // the kinds it estimates
  void (*set)(IdentificationOptions&, bool on) = nullptr;  // switches it on or off
  bool (*is_set)(const IdentificationOptions&) = nullptr;
  int required_cables = 0;  // > 0: only for a robot with that many cables (the paper's subset)
};
const std::vector<EstimateItem>& estimate_items();
const EstimateItem* find_estimate_item(std::string_view word);  // nullptr: not a word of the table
// The word that estimates `kind` and nothing else ("laser-direction" for kLaserDirection);
// nullptr when no word does.
const EstimateItem* estimate_item_of(ParameterKind kind);
// Switches on exactly the items `words` name and every other item off: the one vocabulary of
// cdpr-fit's --estimate and cdprd's identification.estimate. An empty list changes nothing (the
// caller's defaults); ["none"] alone switches every item off (a fixed model: only the poses). The
// error names the unknown word with the table's words, or the item a robot of `num_cables` cannot
// use (0: not known yet, that check left to identify()).
Status set_estimate(const std::vector<std::string>& words, int num_cables,
                    IdentificationOptions& options);
// The words of the items switched on in `options`, in the table's order.
std::vector<std::string> estimate_words(const IdentificationOptions& options);

struct ParameterEstimate {
  ParameterId id;
  std::string name;  // parameter_name(id): "a_3.x", "o_5", "laser_1.plane.c", ...
  std::string unit;  // "m", "-", "rad", "N"
  double initial = 0.0;
  double value = 0.0;
  double std_dev = 0.0;  // from the covariance; infinity if not computed / in the null space
  double lower = -std::numeric_limits<double>::infinity();  // physical range (ParameterBounds)
  double upper = std::numeric_limits<double>::infinity();
  bool at_bound = false;  // the estimate ended on lower or upper
};

// Residuals of one pose, in SI units and normalised by their sigma (NaN where not measured).
struct PoseResiduals {
  Eigen::VectorXd length_m, length_normalized;  // m entries
  Eigen::VectorXd laser_m, laser_normalized;    // k entries
  Eigen::Matrix<double, 6, 1> wrench_si = Eigen::Matrix<double, 6, 1>::Constant(
      std::numeric_limits<double>::quiet_NaN());  // N, N m (before whitening)
  Eigen::Matrix<double, 6, 1> wrench_normalized =
      Eigen::Matrix<double, 6, 1>::Constant(std::numeric_limits<double>::quiet_NaN());
  Eigen::Matrix<double, 6, 1> reference_normalized =
      Eigen::Matrix<double, 6, 1>::Constant(std::numeric_limits<double>::quiet_NaN());
  Eigen::VectorXd swivel_rad, swivel_normalized;  // m entries (issue 18)
  Eigen::Vector2d inclination_rad =
      Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
  Eigen::Vector2d inclination_normalized =
      Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
  double imu_yaw_rad = std::numeric_limits<double>::quiet_NaN();
  double imu_yaw_normalized = std::numeric_limits<double>::quiet_NaN();
};

struct IdentificationReport {
  // The calibrated model. robot.winches[i] carries the corrected encoder zero and transmission
  // (length_offset' = (1 + s_i) length_offset + o_i, drum diameter and pitch scaled by 1 + s_i);
  // readings holds o_i and s_i relative to the readings of the MeasurementSet.
  CalibratedModel estimate;
  std::vector<Pose> poses;                            // estimated poses
  std::vector<Eigen::Matrix<double, 6, 1>> pose_std;  // their std (m, rad)
  std::vector<ParameterEstimate> parameters;          // geometry/sensor tangent coordinates
  Eigen::MatrixXd covariance;                         // of `parameters`, same order
  std::vector<PoseResiduals> residuals;

  // Channel RMS (SI) after the fit.
  double rms_length_m = 0.0, rms_laser_m = 0.0, rms_wrench_n = 0.0;
  double rms_swivel_rad = 0.0, rms_inclination_rad = 0.0, rms_imu_yaw_rad = 0.0;

  double initial_cost = 0.0;  // 0.5 sum r^2 (normalised residuals, loss applied)
  double final_cost = 0.0;
  double chi2 = 0.0;  // sum of squared normalised residuals, no loss
  // log det of the residuals' covariance (SI units) over the length, laser and equilibrium rows:
  // the length sigmas and the equilibrium whitening depend on the cable compliance, so models
  // with different elongation laws are compared by the deviance chi2 + log_det_covariance
  // (-2 log likelihood up to a constant), not by chi2 alone (a softer cable inflates its sigmas).
  double log_det_covariance = 0.0;
  int num_residuals = 0;
  int num_parameters = 0;  // geometry + free pose coordinates
  int dof = 0;             // num_residuals - num_parameters
  int iterations = 0;
  bool converged = false;
  std::string termination;  // Ceres' message
  double solve_time_s = 0.0;
  double total_time_s = 0.0;
  int rank = 0;                   // of the column-normalised geometry information
  double condition_number = 0.0;  // sigma_max / sigma_min of the column-normalised Jacobian
  std::vector<std::string> warnings;

  // Names of the parameters that ended on a bound of their physical range.
  std::vector<std::string> parameters_at_bound() const;
  bool trustworthy() const { return converged && warnings.empty(); }
  std::string brief_report() const;
  std::string full_report() const;
};

// Identifies the parameters chosen in `options` from `set`, starting from `initial` (the nominal
// model). Errors: kInvalidArgument (sizes, options), kFailedPrecondition (too few poses or an
// unidentifiable choice; the message names the directions), kNumericalFailure (the solver failed).
Result<IdentificationReport> identify(const CalibratedModel& initial, const MeasurementSet& set,
                                      const IdentificationOptions& options = {});

// The Fisher information of the chosen parameters with the poses profiled out (Schur complement),
// per pose, evaluated at `model` and the poses `poses` (the measured readings enter only the
// elongation and force terms; residual values are not used). `information` = sum of per_pose.
struct GeometryInformation {
  std::vector<ParameterId> ids;
  std::vector<std::string> names;  // parameter_name of each id
  std::vector<std::string> units;
  Eigen::VectorXd values;                  // current tangent values (for naming)
  std::vector<Eigen::MatrixXd> per_pose;   // P x P each (already Schur-reduced)
  Eigen::MatrixXd information;             // P x P
  Eigen::Matrix3Xd home_cable_directions;  // unit u_i at home (for naming anchor directions)
  Eigen::Matrix3Xd frame_anchors;          // a_i at the evaluation point (gauge detection)
  Eigen::Matrix3Xi anchor_columns;  // 3 x m: column of a_i.x/y/z in `names`, -1 if not estimated
  int num_residuals = 0;
  int num_pose_parameters = 0;
  // Rows of each channel (what the identifiability analysis says about the gauge).
  struct ChannelRows {
    int length = 0, laser = 0, wrench = 0, reference = 0, swivel = 0, inclination = 0, imu_yaw = 0;
  } channel_rows;
  bool home_pose_fixed = false;  // the gauge holds a pose at the home pose
  bool home_tilt_free = false;   // suspended robot: only its position and heading are held
  // Whitened Jacobian blocks per pose (rows = that pose's residuals), filled only when
  // geometry_information is called with keep_jacobians = true.
  std::vector<Eigen::MatrixXd> jacobian_geometry;  // rows x P
  std::vector<Eigen::MatrixXd> jacobian_pose;      // rows x 6 (zero for a fixed pose)
};

Result<GeometryInformation> geometry_information(const CalibratedModel& model,
                                                 const MeasurementSet& set,
                                                 const std::vector<Pose>& poses,
                                                 const IdentificationOptions& options,
                                                 bool keep_jacobians = false);

// The whitened residuals of every pose at `model` and the poses `poses` (the rows of each pose
// in the order GeometryInformation's Jacobian blocks have them: lengths, lasers, equilibrium,
// reference, swivel angles, inclinometer, IMU yaw). With GeometryInformation's Jacobians this
// lets tests compare the exact derivatives with finite differences, and checks that noise-free
// data gives zero residuals at the true parameters.
Result<std::vector<Eigen::VectorXd>> evaluate_residuals(const CalibratedModel& model,
                                                        const MeasurementSet& set,
                                                        const std::vector<Pose>& poses,
                                                        const IdentificationOptions& options);

}  // namespace cdpr
