// Design of the calibration poses: N poses (default 25, the home pose first) inside the
// wrench-feasible workspace, maximising the information about the chosen parameters
// (D-optimality on the Fisher information with the poses profiled out, GeometryInformation),
// then ordered for a short path.
//
// Algorithm: candidate grid (positions on a grid over the box x a set of orientations: zero and
// +-max_angle about each axis), filtered by the tension distribution (simulate.hpp
// simple_tension_distribution; the force_distribution of statics replaces it when available);
// greedy D-optimal selection (log det of the column-normalised information, with a small ridge
// until it is full rank), then Fedorov exchange passes (swap a selected pose for a candidate while
// log det increases); finally a nearest-neighbour tour from home improved by 2-opt (distance =
// position distance + angle_weight * angle distance).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct PoseDesignOptions {
  int num_poses = 25;  // including the home pose
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Vector3d half_extent = Eigen::Vector3d::Constant(0.156);  // m
  int points_per_axis = 5;
  double max_angle = 0.2618;                                            // rad (15 deg)
  double reference_tension = std::numeric_limits<double>::quiet_NaN();  // N; NaN: default
  SensorNoise noise;
  IdentificationOptions identification;
  int exchange_passes = 4;
  double angle_weight = 0.1;  // m per rad in the path length
};

struct PoseDesign {
  std::vector<Pose> poses;   // in path order, home first
  double log_det = 0.0;      // of the column-normalised information of the selection
  double path_length = 0.0;  // m (+ angle_weight * rad)
  int candidates = 0;        // feasible candidates
  int exchanges = 0;         // accepted Fedorov swaps
};

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
