// Design of the calibration poses: N poses (default 25, the home pose first) inside the
// wrench-feasible workspace, maximising the information about the chosen parameters
// (D-optimality on the Fisher information with the poses profiled out, GeometryInformation) that
// the channels the robot records give (PoseDesignOptions::channels: lengths and forces, and the
// laser, swivel encoders, inclinometer, IMU heading as chosen), then ordered for a short path.
//
// Algorithm: candidate grid (positions on a grid over the box x a set of orientations: zero and
// +-max_angle and the fractions angle_steps gives of it about each axis), filtered by the tension
// distribution (simulate.hpp simple_tension_distribution, i.e. force_distribution.hpp's QP, within
// the cable limits narrowed by tension_margin); greedy D-optimal selection (log det of the
// column-normalised information, with a small ridge until it is full rank, plus emphasis_weight x
// the log det of the emphasised parameters' own information), then Fedorov exchange passes (swap a
// selected pose for a candidate while the criterion increases), optionally followed by exchanges
// for position accuracy over a test box (DesignCriterion::kPositionAccuracy); finally a
// nearest-neighbour tour from home improved by 2-opt (distance = position distance + angle_weight *
// angle distance).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// What the design maximises.
enum class DesignCriterion {
  kDOptimal,  // log det of the (column-normalised) information about the parameters
  // D-optimal start, then exchanges that minimise the predicted mean squared platform position
  // error over `accuracy_box` (I-optimality: tr(W I^-1), W = sum over the box grid of G^T G,
  // G = d(position error)/d(parameters) through the controller's inverse kinematics). This is
  // what the robot's user sees; the anchors are then slightly less well determined.
  kPositionAccuracy,
};

struct PoseDesignOptions {
  int num_poses = 25;  // including the home pose
  DesignCriterion criterion = DesignCriterion::kDOptimal;
  AccuracyBox accuracy_box;  // for kPositionAccuracy (default: MINI's ISO 9283 cube)
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Vector3d half_extent = Eigen::Vector3d::Constant(0.156);  // m
  int points_per_axis = 5;
  double max_angle = 0.2618;  // rad (15 deg)
  // The candidates' tilts about each platform axis: max_angle x j / angle_steps, j
  // = 1..angle_steps, both signs. MINI cannot pitch 15 degrees anywhere in its box (0 of 250
  // candidates feasible; 158 at 8.6 degrees), so with the full angle alone no designed pose is
  // pitched and the component of the laser's beam direction that only a pitch shows is invisible.
  // 1 (the full angle only) is the default; 2 with the beam direction emphasised (below) names
  // more compound effects on both benchmark robots and is cdprd's design for MINI
  // (MeasuringSettings), but on LARGE it lets an absent laser mounting through beside named
  // effects and the gross-reading check fire on sag (docs/mismatch-benchmark.md, "Choices the
  // figures support"). Below 1: kInvalidArgument (as a negative or non-finite emphasis_weight).
  int angle_steps = 1;
  double reference_tension = std::numeric_limits<double>::quiet_NaN();  // N; NaN: default
  // N: a candidate needs a tension distribution within [f_min + margin, f_max - margin] of every
  // cable. A pose at the edge of the NOMINAL model's workspace can be outside the true robot's:
  // the true geometry's internal forces moved a cable of the virtual MINI 24 N past its f_max at
  // a 25-degree tilt (docs/mismatch-benchmark.md, "Choices the figures support"). 0: the limits
  // themselves.
  double tension_margin = 0.0;
  SensorNoise noise;
  // The channels the calibration will record (issue 18): the design maximises the information of
  // these (lengths and forces always) with `noise`. `identification` must not estimate the
  // laser's parameters without the laser (kInvalidArgument; fit_estimates_to_channels).
  SensorChannels channels;
  IdentificationOptions identification;
  // Parameters the design also asks to see well beside `identification`'s: the criterion adds
  // emphasis_weight x the log det of their information with every other parameter profiled out
  // (a compound D / Ds design); a kind `identification` does not estimate is added to the
  // information the design judges (not to log_det), and left out when the recorded channels do not
  // observe it (the laser's without the laser). The kind given is the laser's beam direction,
  // which the mismatch locator tests (a tilted mount) and the plain D-optimal set leaves to a few
  // poses: with weight 3 and angle_steps 2 the noncentrality of a 0.5 degree tilt left by the
  // standard identification rose on LARGE from 9.9 to 136, on MINI from 10.9 to 17.1, the
  // anchors' and the position's predicted accuracy as good or better. Weight 0 (the default, see
  // angle_steps): plain D-optimality on `identification`'s parameters. Each kind must be one
  // --estimate word's only kind (kInvalidArgument otherwise).
  std::vector<ParameterKind> emphasis{ParameterKind::kLaserDirection};
  double emphasis_weight = 0.0;
  int exchange_passes = 4;
  double angle_weight = 0.1;  // m per rad in the path length
  // "poses designed" k of num_poses during the greedy selection, then "exchange passes" p of
  // exchange_passes; empty: none.
  ProgressCallback progress;
};

struct PoseDesign {
  std::vector<Pose> poses;  // in path order, home first
  double log_det = 0.0;     // of the column-normalised information of the selection
                            // (the estimated parameters; the emphasised ones added are not)
  // The emphasised kinds the design judged (PoseDesignOptions::emphasis minus those the channels
  // do not observe) and the log det of their column-normalised information with the others
  // profiled out; 0 with none.
  std::vector<ParameterKind> emphasised;
  double emphasis_log_det = 0.0;
  double path_length = 0.0;  // m (+ angle_weight * rad)
  int candidates = 0;        // feasible candidates
  int exchanges = 0;         // accepted Fedorov swaps (both criteria)
  // kPositionAccuracy: predicted RMS position error over the box (m) of the D-optimal start and
  // of the final selection (the same figure as PredictedAccuracy::position_rms_m, up to the
  // ridge); 0 for kDOptimal.
  double position_rms_d_optimal_m = 0.0;
  double position_rms_m = 0.0;
};

// Scales the candidate cube to the robot: centred at the home position, half sides
// `fraction` times the half size of the frame anchors' bounding box per axis (the wrench
// feasibility filter then trims it to the workspace). MINI: about 0.20 x 0.15 x 0.18 m;
// IPAnema 3: about 3.4 x 2.2 x 0.8 m. A suspended robot (anchors all up high) gets at least
// `fraction` times half the drop from the anchors to home as vertical half side (CRANE4: 0.2 m).
// Used when the user gives no box.
void fit_design_box_to_robot(const RobotModel& robot, PoseDesignOptions& options,
                             double fraction = 0.4);

// The pose the design may use for a candidate, or nullopt when the robot cannot be there: a
// fully constrained robot needs a feasible tension distribution (simple_tension_distribution);
// a suspended robot with m < 6 cables (issue 18) is only put where it hangs: the candidate's
// position and yaw, roll and pitch from the static equilibrium (suspended_statics.hpp), every
// tension within [f_min, f_max]. design_poses takes its candidates through this filter.
std::optional<Pose> feasible_design_pose(const RobotModel& robot, const Pose& candidate,
                                         double reference_tension);

// `robot` with every cable's tension limits narrowed to [f_min + margin, f_max - margin] (what
// design_poses judges its candidates with). kInvalidArgument for a negative or non-finite margin
// and for one that leaves a cable no range (naming the cable, from 1).
Result<RobotModel> narrow_tension_limits(const RobotModel& robot, double margin);

Result<PoseDesign> design_poses(const CalibratedModel& model,
                                const PoseDesignOptions& options = {});

// The expected accuracy (PredictedAccuracy) of the designed set versus a random set and a
// box-corner set of the same size.
struct PoseSetComparison {
  std::string label;
  int num_poses = 0;
  double anchor_rms_std_m = 0.0;
  double position_rms_m = 0.0;
  double condition_number = 0.0;
};

Result<std::vector<PoseSetComparison>> compare_pose_sets(const CalibratedModel& model,
                                                         const PoseDesignOptions& options,
                                                         const AccuracyBox& box,
                                                         std::uint64_t seed = 1);

}  // namespace cdpr
