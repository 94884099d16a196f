// Feasibility of poses and moves (run before a move is accepted, not in the RT loop) and the
// per-cycle tension plan and encoder targets (in the RT loop).
//
// The tension planner is the one the virtual robot's lock-step mode uses
// (simple_tension_distribution in calibration/simulate.hpp), rewritten allocation-free: the
// exact QP of force_distribution.hpp nearest to a uniform reference tension; when that solution
// has a cable on a limit, the reference is raised to 2 and 4 times and the first solution with no
// cable on a limit is taken, else the last feasible one. Feasibility does not depend on the
// reference, so an infeasible first attempt ends the search. Here the limits are the band
// [f_min + margin, f_max - margin] of each cable (margin 0: exactly simple_tension_distribution).
//
// The check is quasi-static, like the planner: the platform's weight at each pose, no inertial
// forces (for MINI at 0.5 m/s^2 these are 1 N against 20 N of weight; use the margin for them).
//
// Cables are numbered from 1 in messages (cable 1 is column 0 of the model).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <limits>
#include <numbers>
#include <optional>
#include <span>
#include <vector>

#include "cdpr/calibration/force_distribution.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/path.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/calibration/trajectory.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Tensions planned at one pose.
struct TensionPlan {
  ForceDistributionOutcome outcome = ForceDistributionOutcome::kInvalidInput;
  CableVector tensions;      // N; the accepted plan when feasible, else the last attempt
  double reference = 0.0;    // N, the uniform reference of the accepted attempt (1x, 2x or 4x)
  int cables_at_limits = 0;  // tensions on the band's edges
};

// The planner at a pose whose inverse kinematics is already in `kinematics` (valid, i.e.
// inverse_kinematics returned true). `reference_tension` > 0, N (e.g.
// default_reference_tension(model)); margin >= 0, N. Returns kOutOfRange when no tensions in the
// band balance the platform's weight (outside the wrench-feasible workspace), kNumericalFailure
// when the structure matrix has rank < 6, kInvalidArgument for bad input (an empty band, more than
// kMaxCables cables, a non-positive reference). Allocates nothing.
Status plan_tensions(const RobotModel& model, const KinematicsData& kinematics,
                     double reference_tension, double margin, TensionPlan& plan);
// One attempt at exactly `reference_tension` (no retry at 2x and 4x): a feasible plan with
// cables on the band's edges is accepted. The QP's solution is continuous in the pose and in the
// reference, so a reference that changes continuously gives a plan that does too (plan_tensions'
// choice between 1x, 2x and 4x steps). The same errors; allocates nothing.
Status plan_tensions_at(const RobotModel& model, const KinematicsData& kinematics,
                        double reference_tension, double margin, TensionPlan& plan);

// The same two with the structure matrix of `kinematics` already factored
// (factor.compute(kinematics.structure_matrix)): several plans at one pose factor once.
Status plan_tensions(const RobotModel& model, const KinematicsData& kinematics,
                     const StructureFactor& factor, double reference_tension, double margin,
                     TensionPlan& plan);
Status plan_tensions_at(const RobotModel& model, const KinematicsData& kinematics,
                        const StructureFactor& factor, double reference_tension, double margin,
                        TensionPlan& plan);

struct PathCheckOptions {
  double max_linear_step = 0.005;                          // m between checked points
  double max_angular_step = 0.5 * std::numbers::pi / 180;  // rad between checked points
  double tension_margin = 0.0;  // N: tensions must fit in [f_min + margin, f_max - margin]
  // Uniform reference tension of the planner, N; NaN: default_reference_tension(model).
  double reference_tension = std::numeric_limits<double>::quiet_NaN();
  // Allowed positions of the platform origin (world, m); nullopt: no box.
  std::optional<Eigen::AlignedBox3d> workspace_box;
  // Allowed kinematic cable lengths L_i (frame anchor to platform anchor, with the pulley arc),
  // m: e.g. what the drum holds and the shortest length the cable may be reeled to.
  double min_cable_length = 0.0;
  double max_cable_length = std::numeric_limits<double>::infinity();
  // The same per cable (each winch's software limits, cdprd.yaml `safety.cable_length`): one
  // entry per cable of the model, or empty (the two above for every cable).
  std::vector<double> min_cable_lengths, max_cable_lengths;
  // Cable-cable interference: the straight spans frame anchor a_i -> platform anchor r + R b_i of
  // two cables must stay at least this far apart (the cable diameter, m; 0: not checked). A pair
  // whose spans meet at an end by design (anchors closer than the diameter) is not checked. The
  // span starts at a_i, not at its pulley's tangent point (an error of at most the pulley radius
  // near the frame). Cable-platform interference is not checked.
  double cable_diameter = 0.0;
};

// What a check saw (optional output; reset at the start of each check).
struct PathCheckSummary {
  int points = 0;  // poses checked
  // Smallest distance of a planned tension to its cable's hard limits f_min, f_max (N), and where.
  double min_tension_slack = std::numeric_limits<double>::infinity();
  double min_slack_s = 0.0;  // path parameter of that point
  int min_slack_cable = -1;  // 1-based
};

// One pose: inverse kinematics valid (no degenerate cable), inside the workspace box, tensions
// feasible within the band. kOutOfRange (outside the box or the wrench-feasible workspace),
// kNumericalFailure (degenerate cable or singular structure matrix) or kInvalidArgument (options),
// with a message naming the pose and the cable, e.g. "pose (0.300, 0.000, 0.000) m, (0.0, 0.0,
// 0.0) deg is outside the wrench-feasible workspace: cable 3 would need 212 N > f_max 200 N".
Status check_pose(const RobotModel& model, const Pose& pose, const PathCheckOptions& options = {},
                  PathCheckSummary* summary = nullptr);

// Every point of the move's path with steps of at most max_linear_step and max_angular_step (both
// ends included). The first failing point is named, e.g. "move to (0.300, 0.000, 0.000) m, (0.0,
// 0.0, 0.0) deg leaves the wrench-feasible workspace at s = 0.620 (0.186, 0.000, 0.000) m: cable 3
// would need 212 N > f_max 200 N". Allocates nothing per point (a few scratch vectors per call).
Status check_path(const RobotModel& model, const PoseTrajectory& trajectory,
                  const PathCheckOptions& options = {}, PathCheckSummary* summary = nullptr);

// Every point of a multi-segment path (path.hpp), motion by motion, with sigma steps such that
// the position moves at most max_linear_step and the rotation at most max_angular_step between
// checked points (from each motion's bounds on |dp/dsigma| and the angular rate), both ends of
// every motion included. The first failing point is named with the path file's line, e.g.
// "path line 7 leaves the wrench-feasible workspace at sigma = 0.412 m (0.120, 0.000, 0.050) m:
// cable 3 would need 212 N > f_max 200 N". PathCheckSummary's min_slack_s is then sigma (m).
Status check_path(const RobotModel& model, const Path& path, const PathCheckOptions& options = {},
                  PathCheckSummary* summary = nullptr);

// Smallest distance between the segments [p0, p1] and [q0, q1] (m).
double segment_distance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1,
                        const Eigen::Vector3d& q0, const Eigen::Vector3d& q1);

// Scratch and results of command_counts, sized once for a model.
struct CommandData {
  explicit CommandData(int num_cables) : kinematics(num_cables), cable(num_cables) {}
  explicit CommandData(const RobotModel& model) : CommandData(model.num_cables()) {}

  KinematicsData kinematics;  // inverse kinematics at the commanded pose (for the plan)
  StructureFactor factor;     // of kinematics.structure_matrix
  TensionPlan plan;           // planned tensions, N
  CableCommandData cable;     // compensated length commands and encoder counts (from
                              // `kinematics`: cable.kinematics is not filled)
};

// The RT step: inverse kinematics at `pose`, planned tensions (plan_tensions with
// `reference_tension` and `margin`), then inverse_kinematics_compensated with those tensions into
// data.cable (counts, counts_rounded). On failure (a degenerate cable, the pose outside the
// wrench-feasible workspace, bad input) it returns the reason and leaves data.cable as it was, so
// the caller can hold the previous targets. Allocates, locks, logs and throws nothing.
Status command_counts(const RobotModel& model, const Pose& pose, double reference_tension,
                      CommandData& data, double margin = 0.0);
// The same trying the `margins` in order, inverse kinematics and the structure matrix's
// factorization made once: the first margin with a feasible plan is used and its index stored in
// *chosen; when none is, the last margin's reason is returned and *chosen is -1. The same
// guarantees.
Status command_counts(const RobotModel& model, const Pose& pose, double reference_tension,
                      CommandData& data, std::span<const double> margins, int* chosen);

}  // namespace cdpr
