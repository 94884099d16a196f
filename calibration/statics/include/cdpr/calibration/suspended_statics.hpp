// Statics of a suspended cable robot with m <= 6 cables (issue 18: under-actuated cranes).
//
// The platform hangs from the cables; gravity keeps them taut. With m < 6 cables the lengths fix
// only m of the six pose coordinates; the other 6 - m follow from the static equilibrium
//   A^T(x) f + w(x) = 0,   f_i > 0                         (kinematics.hpp notation)
// w = gravity wrench of the platform (mass at the centre of mass, about the platform origin,
// world axes). For m < 6 the structure matrix A^T is 6 x m: the equilibrium holds only where w
// lies in the span of the m cable wrenches (6 - m conditions on the pose), and then the tensions
// are unique. Solved here, all by damped Newton (Levenberg-Marquardt) on the square system of the
// unknowns and the equations below, with central-difference Jacobians; rotations are updated
// multiplicatively (R <- exp([dtheta]x) R); wrench rows are divided by the weight m g, moment
// rows also by the platform radius rho (largest |b_i|):
// - suspended_tensions: the least-squares tensions at a pose and how far the pose is from
//   equilibrium (the part of w the cables cannot balance), no solve.
// - suspended_equilibrium_pose ("inverse"): given a target pose, keep its position and its last
//   m - 3 rpy angles (yaw for m = 4; pitch and yaw for m = 5; none for m = 3) and find the first
//   6 - m angles (roll and pitch for m = 4) and the tensions: unknowns (those angles, f),
//   equations the 6 wrench components. This is where a crane can be put.
// - forward_kinematics_suspended (rigid cables): given the kinematic lengths L_i (D_i to the
//   platform anchor, pulley arc included), the hanging pose: unknowns (pose, f), equations the m
//   length equations and the 6 wrench components (6 + m each).
// - forward_kinematics_suspended_elastic: given the unstretched length commands, the pose where
//   the elastic cables (elongation.hpp) balance gravity: the rigid solution of the commands
//   polished by solve_elastostatics (elastostatics.hpp).
// Every solver refuses (kOutOfRange, naming the cable) a solution in which a cable would have to
// push (tension below SuspendedOptions::min_tension): the platform cannot hang there on all its
// cables. Wrong sizes or non-finite input give kInvalidArgument; no convergence
// kNumericalFailure. Nothing throws.
//
// Not checked: stability (a platform balanced above its anchors would be an equilibrium too;
// starting from the home pose of a crane the solver finds the hanging one), cable mass and sag.
#pragma once

#include <Eigen/Core>
#include <optional>

#include "cdpr/calibration/force_distribution.hpp"  // gravity_wrench
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct SuspendedOptions {
  int max_iterations = 200;
  // Converged when every scaled equation (lengths in m, wrench / weight) is below this.
  double tolerance = 1e-12;
  // A solution with a tension below this (N) is refused: the cable would be slack or push.
  double min_tension = 0.0;
  // Starting pose; nullopt: model.home (the inverse solver takes only its angles).
  std::optional<Pose> initial_pose;
};

struct SuspendedState {
  Pose pose;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::VectorXd tensions;  // f_i, N
  Eigen::VectorXd lengths;   // kinematic lengths at the pose, m
  // Largest component of A^T f + w (forces N, moments / rho N) with the least-squares tensions:
  // 0 at an equilibrium.
  double wrench_residual = 0.0;
  int iterations = 0;
};

// Least-squares tensions at `pose` (no sign constraint) and the equilibrium residual. Errors:
// a degenerate cable (kInvalidArgument, naming it).
Result<SuspendedState> suspended_tensions(const RobotModel& model, const Pose& pose);

// The equilibrium pose nearest `target` in the sense of the file comment (3 <= m <= 6).
Result<SuspendedState> suspended_equilibrium_pose(const RobotModel& model, const Pose& target,
                                                  const SuspendedOptions& options = {});

// Rigid forward kinematics of a suspended robot (m <= 6).
Result<SuspendedState> forward_kinematics_suspended(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& kinematic_lengths,
    const SuspendedOptions& options = {});

// Elastic forward kinematics: `unstretched_lengths` are the length commands (elastostatics.hpp).
Result<SuspendedState> forward_kinematics_suspended_elastic(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& unstretched_lengths,
    const SuspendedOptions& options = {});

}  // namespace cdpr
