// Forward kinematics of an over-constrained cable robot: the platform pose whose kinematic cable
// lengths best match m given lengths (m >= 6), by Levenberg-Marquardt on the m length equations
//
//   r_i(x) = L_i(x) - l_i,   i = 1..m,        J = dr/d(dp, dtheta) = -A  (A^T = structure matrix)
//
// with the analytic Jacobian from kinematics.hpp (point anchors or swivel pulleys). The pose is
// updated multiplicatively, R <- exp([dtheta]x) R (dtheta a small rotation in the world frame), so
// there is no Euler-angle singularity inside the solver; the result is returned as a Pose.
//
// Elastic cables: forward_kinematics_elastic takes the unstretched length commands (the winch's
// view, ik_compensation.hpp) and the measured tensions, converts each to the kinematic length
// L_k = l_u + dL(routing_length + L_k, F) (elongation.hpp, exact for a given tension), then
// solves the geometric problem.
//
// Usage (Pinocchio-style: constant model, scratch data sized once; repeated calls allocate
// nothing):
//
//   cdpr::ForwardKinematicsData data(model);
//   cdpr::ForwardKinematicsOptions options;             // initial pose: model.home
//   cdpr::ForwardKinematicsSummary s = cdpr::forward_kinematics(model, lengths, options, data);
//   if (!s.success()) log(s.status.to_string());        // says why
//   use(s.pose, data.residuals);
#pragma once

#include <Eigen/Core>
#include <limits>
#include <optional>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct ForwardKinematicsOptions {
  int max_iterations = 100;
  // Stop when every |r_i| is below this (consistent lengths), m.
  double residual_tolerance = 1e-12;
  // Stop when the step is below this, m; rotations count as dtheta * characteristic length (the
  // largest platform anchor radius), so both parts are in metres.
  double step_tolerance = 1e-13;
  // Stop when the relative cost decrease of an accepted step is below this (inconsistent lengths:
  // a least-squares pose with non-zero residuals).
  double function_tolerance = 1e-20;
  double initial_lambda = 1e-4;  // LM damping, relative to diag(J^T J)
  // A converged pose whose worst cable misses by more than this (m) is reported as
  // kInconsistentLengths: a local minimum, or lengths that do not fit the model. Infinity
  // accepts any least-squares pose.
  double max_residual = 1e-3;
  // First solve for the position with the orientation of the starting pose held fixed, then for
  // the full pose. Makes cold starts from home converge across large workspaces; costs a few
  // cheap iterations (counted in Summary::iterations).
  bool position_first = true;
  // When the solve ends in a local minimum (max |r_i| > max_residual) or does not converge,
  // restart from the position found with the orientations start rpy + {-a, 0, a}^3 (single axes
  // first, up to 26 restarts, each with max_iterations) and keep the best. Large robots with
  // small platforms have such minima (orientation off by ~25 degrees, residuals of mm). Genuinely
  // inconsistent lengths pay all 26 restarts before kInconsistentLengths is reported.
  bool orientation_restarts = true;
  double restart_angle = 0.3;  // a, rad
  // Starting pose; default (nullopt): model.home.
  std::optional<Pose> initial_pose;
};

enum class ForwardKinematicsTermination {
  kConverged,            // a residual, step or function tolerance was met, max |r_i| acceptable
  kInconsistentLengths,  // converged, but max |r_i| > options.max_residual
  kMaxIterations,        // no tolerance met in options.max_iterations
  kInvalidInput,         // wrong sizes, non-finite lengths or tensions, bad options
  kDegenerateGeometry,   // a cable is degenerate at the initial pose, or no step could be taken
  kNumericalFailure,     // non-finite values, singular normal equations
};

const char* to_string(ForwardKinematicsTermination termination);

// Ceres-style report. The residuals are in ForwardKinematicsData::residuals.
struct ForwardKinematicsSummary {
  Pose pose;                                               // best pose found (also on failure)
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // its rotation matrix
  ForwardKinematicsTermination termination = ForwardKinematicsTermination::kInvalidInput;
  Status status;       // ok on kConverged, else the reason in words
  int iterations = 0;  // LM iterations (accepted or rejected steps)
  int accepted_steps = 0;
  int restarts = 0;           // orientation restarts used (options.orientation_restarts)
  double initial_cost = 0.0;  // 0.5 sum r_i^2, m^2
  double final_cost = 0.0;
  double max_abs_residual = 0.0;  // m
  int worst_cable = -1;           // index of max |r_i|
  double rms_residual = 0.0;      // m

  bool success() const { return termination == ForwardKinematicsTermination::kConverged; }
};

// Scratch for forward_kinematics (sized for one model; reusing it makes calls allocation-free).
struct ForwardKinematicsData {
  explicit ForwardKinematicsData(int num_cables);
  explicit ForwardKinematicsData(const RobotModel& model)
      : ForwardKinematicsData(model.num_cables()) {}

  KinematicsData current;           // IK at the current iterate
  KinematicsData trial;             // IK at the trial step
  Eigen::VectorXd target_lengths;   // kinematic lengths being matched, m
  Eigen::VectorXd residuals;        // L_i(x) - l_i at the returned pose, m
  Eigen::VectorXd trial_residuals;  // m
  Eigen::VectorXd elongations;      // dL_i used by forward_kinematics_elastic, m
};

// Geometric FK: `kinematic_lengths` are the lengths L_i from D_i to the platform anchor (as
// inverse_kinematics returns them, pulley arc included). Allocates nothing when `data` was built
// for this model and kinematic_lengths is a plain Eigen::VectorXd (or a block of one).
ForwardKinematicsSummary forward_kinematics(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& kinematic_lengths,
    const ForwardKinematicsOptions& options, ForwardKinematicsData& data);

// FK with elastic cables: `unstretched_lengths` are the length commands l_u,i = L_i - dL_i (the
// winch's view: length_offset + counts converted, see winch.hpp), `tensions` the measured cable
// tensions, N. data.elongations receives dL_i, data.target_lengths the kinematic lengths.
ForwardKinematicsSummary forward_kinematics_elastic(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& unstretched_lengths,
    const Eigen::Ref<const Eigen::VectorXd>& tensions, const ForwardKinematicsOptions& options,
    ForwardKinematicsData& data);

}  // namespace cdpr
