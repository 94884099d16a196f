// Elasto-static forward model: where the platform of a robot with elastic, unilateral cables
// settles for given cable length commands, and with which tensions. The physics of the virtual
// robot (cdpr-sim) and of the identification's simulator.
//
// Per cable (lengths as in ik_compensation.hpp and elongation.hpp):
//   L_k(x)  kinematic length D_i -> platform anchor at pose x (pulley arc included)
//   l       length command: the unstretched length referenced to D_i (what the winch pays out)
//   L       = routing_length + L_k, the whole loaded cable
//   F       solves cable_elongation(cable, L, F) = L_k - l   (elongation.hpp), F >= 0;
//           a cable with L_k - l <= cable_elongation(cable, L, 0) is slack: F = 0.
// For Hooke cables this is F = EA max(0, L_k - l) / (routing_length + l).
//
// Equilibrium: the net wrench on the platform (about its origin, world frame)
//   W(x) = sum_i F_i(x) a_i(x) + W_gravity(x) + W_external = 0,   a_i = [u_i; (R b_i) x u_i]
// (A^T f + w = 0 in the structure-matrix notation of kinematics.hpp), solved for the pose by
// Newton / Levenberg-Marquardt with the analytic stiffness
//   K = dW/d(dr, dtheta) = -sum k_i a_i a_i^T + sum F_i da_i/dx + K_gravity,
// k_i = dF_i/dL_k,i (elastic part) plus the geometric stiffness of the tensions (exact for point
// anchors; for swivel pulleys the exit point's motion is neglected in the Newton matrix, and the
// reported stiffness is then taken by central differences of W). Rotations are updated
// multiplicatively, R <- exp([dtheta]x) R.
//
// When Levenberg-Marquardt stalls off an equilibrium (a local minimum of |W| that is not a zero,
// typically with most cables slack at the start: the platform hangs in cables that cannot hold
// it and K is singular), the solver descends the potential energy V from the start instead
// (dV = -W . dx: modified Newton with -sym(K) made positive definite, each step to the minimum of
// V along its direction, found from the sign of W . step alone) and polishes the result with
// Newton. That is what the platform itself does: it moves where the net wrench pushes it until
// the cables catch it, so it settles commands whose cables are all slack at the start pose (a
// true frame a few millimetres smaller than the commanding model's).
//
// Stability: the equilibrium is stable when the symmetric part of K is negative definite (the
// potential energy has a strict local minimum). Uniqueness cannot be proven cheaply; on request
// (ElastostaticOptions::uniqueness_starts) the solver restarts from poses spread around the
// solution and reports whether any of them converges to a different equilibrium.
//
// Not modelled: cable mass and sag (catenary.hpp), pulley friction, dynamics.
//
// Usage (constant model, scratch data sized once; repeated calls allocate nothing):
//   cdpr::ElastostaticData data(model);
//   cdpr::ElastostaticOptions options;              // start: rigid FK of the commands
//   cdpr::ElastostaticSummary s = cdpr::solve_elastostatics(model, commands, options, data);
//   if (s.success()) use(s.pose, data.tensions);
#pragma once

#include <Eigen/Core>
#include <optional>

#include "cdpr/calibration/forward_kinematics.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

using Wrench = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// The tension law of one cable (unilateral).
struct CableTension {
  double tension = 0.0;    // F, N (0 when slack)
  double stiffness = 0.0;  // dF/dL_k, N/m (0 when slack)
  bool taut = false;
  bool ok = true;  // false: no tension solves the elongation model (kRigid, or a polynomial
                   // surface that is not increasing in F at this length)
};

// F of one cable with kinematic length `kinematic_length` and length command `length_command`.
CableTension cable_tension(const CableModel& cable, double kinematic_length, double length_command);

struct ElastostaticOptions {
  int max_iterations = 100;  // each of Newton and the energy descent (above)
  // Converged when every component of the net wrench is below this: forces in N, moments
  // divided by the platform radius rho (largest |b_i|), so also in N. Very stiff cables raise it
  // to the rounding floor, 64 eps sum_i (F_i + k_i L_k,i).
  double wrench_tolerance = 1e-8;
  // Stops (not converged) when the step is below this, m (rotations times rho).
  double step_tolerance = 1e-15;
  double initial_lambda = 1e-8;  // LM damping, relative to diag(K^T K); small = Newton
  // External wrench on the platform: force (N) through the platform origin and moment (N m),
  // world frame, constant.
  Wrench external_wrench = Wrench::Zero();
  // Starting pose; nullopt: the rigid forward kinematics of the commands (the pose where the
  // cables are at their command lengths), or model.home when that fails.
  std::optional<Pose> initial_pose;
  // Uniqueness check: number of extra starts (0 = no check). Start k is the solution displaced
  // by +-uniqueness_spread along one of the six pose directions (rotations by spread / rho).
  int uniqueness_starts = 0;
  double uniqueness_spread = 0.05;  // m
  // Two equilibria closer than this (m, rotations times rho) count as the same.
  double same_pose_tolerance = 1e-7;
};

enum class ElastostaticTermination {
  kConverged,           // |W| below the tolerance
  kNoConvergence,       // max_iterations, or no step reduced |W| (e.g. platform not held)
  kInvalidInput,        // sizes, non-finite commands, bad options, kRigid cables
  kDegenerateGeometry,  // a cable is degenerate at the start pose
  kNumericalFailure,    // non-finite values
};

const char* to_string(ElastostaticTermination termination);

enum class Uniqueness {
  kNotChecked,
  kUniqueAmongStarts,  // every extra start converged to this equilibrium (or failed)
  kMultiple,           // another start converged elsewhere: see alternative_pose
};

struct ElastostaticSummary {
  Pose pose;  // equilibrium (best pose found on failure)
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  ElastostaticTermination termination = ElastostaticTermination::kInvalidInput;
  Status status;  // ok on kConverged, else why
  int iterations = 0;
  double max_wrench_residual = 0.0;  // N (moments / rho), at the returned pose
  int taut_cables = 0;
  // Stability: smallest eigenvalue of -sym(K) with moments and rotations scaled by rho, N/m;
  // > 0 means stable.
  bool stable = false;
  double stability_margin = 0.0;
  Uniqueness uniqueness = Uniqueness::kNotChecked;
  int starts_converged = 0;              // extra starts that converged
  std::optional<Pose> alternative_pose;  // a different equilibrium, when kMultiple

  bool success() const { return termination == ElastostaticTermination::kConverged; }
};

// Scratch and results (sized once for a model).
struct ElastostaticData {
  explicit ElastostaticData(int num_cables);
  explicit ElastostaticData(const RobotModel& model) : ElastostaticData(model.num_cables()) {}

  KinematicsData kinematics;    // IK at the returned pose
  KinematicsData trial;         // IK at a trial step
  Eigen::VectorXd tensions;     // F_i at the returned pose, N
  Eigen::VectorXd stiffnesses;  // dF_i/dL_k,i, N/m
  Eigen::VectorXd trial_tensions;
  Eigen::VectorXd trial_stiffnesses;
  Wrench wrench = Wrench::Zero();         // net wrench at the returned pose
  Matrix6d stiffness = Matrix6d::Zero();  // K = dW/d(dr, dtheta) at the returned pose
  ForwardKinematicsData fk;               // for the default start
};

// Net wrench W on the platform at (position, rotation), and in data.kinematics, data.tensions,
// data.stiffnesses the cable state; with `stiffness` non-null also the analytic K (see the file
// comment). Returns false when a cable is degenerate (data.kinematics.invalid_cable) or its
// tension law fails. Allocates nothing.
bool elastostatic_wrench(const RobotModel& model, const Eigen::Vector3d& position,
                         const Eigen::Matrix3d& rotation,
                         const Eigen::Ref<const Eigen::VectorXd>& length_commands,
                         const Wrench& external_wrench, ElastostaticData& data, Wrench& wrench,
                         Matrix6d* stiffness);

// The equilibrium for `length_commands` (one per cable, m). Allocates nothing when `data` was
// built for this model.
ElastostaticSummary solve_elastostatics(const RobotModel& model,
                                        const Eigen::Ref<const Eigen::VectorXd>& length_commands,
                                        const ElastostaticOptions& options, ElastostaticData& data);

}  // namespace cdpr
