// Plausibility checks of a RobotModel, before anything computes with it (Drake-style: clear user
// errors rather than NaNs three layers down).
//
// check_model looks at every field and returns the first problem found, with a message that
// starts with the field's name in the config-file notation, then ": " and what is wrong:
//   "cables[7].frame_anchor: the home pose puts the platform anchor on the frame anchor"
//   "cables[3].ea: expected a positive number (N), got -5"
// drivers/config maps that field name back to a file and line. Pure: no I/O, no allocation
// beyond the scratch of one inverse kinematics.
#pragma once

#include <Eigen/Core>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct ModelCheckOptions {
  // Spatial robots need six independent cable forces.
  int min_cables = 6;
  // Tolerance for unit vectors (laser beam, plane normal) and orthonormal pulley frames.
  double unit_tolerance = 1e-9;
  // Largest accepted condition number of the structure matrix at the home pose, with its moment
  // rows divided by the platform radius (largest |b_i|) so that both halves are in newtons.
  double max_condition_number = 1e3;
  // Singular values below rank_tolerance * sigma_max count as zero.
  double rank_tolerance = 1e-9;
  // Suspended robots with m < 6 cables (RobotModel::suspended): the home pose must be a static
  // equilibrium, the part of the weight the cables cannot balance below this fraction of m g
  // (moments divided by the platform radius).
  double equilibrium_tolerance = 1e-6;
};

// Conditioning of the structure matrix A^T (6 x m) at a pose, moment rows scaled by 1 / rho
// (rho = platform radius, the largest |b_i|).
struct StructureConditioning {
  bool valid = false;  // false when a cable is degenerate at the pose (see invalid_cable)
  int invalid_cable = -1;
  int rank = 0;
  double condition_number = 0.0;  // sigma_max / sigma_min (infinite when rank < 6)
  Eigen::Matrix<double, 6, 1> singular_values = Eigen::Matrix<double, 6, 1>::Zero();
};

StructureConditioning structure_conditioning(const RobotModel& model, const Pose& pose,
                                             double rank_tolerance = 1e-9);

// Ok, or kInvalidArgument naming the first wrong field. A robot with fewer than six cables is
// accepted when it is suspended (RobotModel::suspended, 3 to 5 cables): instead of rank 6 it must
// hang at home, i.e. the cable forces balance the platform's weight there (equilibrium_tolerance)
// with every tension within [f_min, f_max]; the message says which condition fails and why.
Status check_model(const RobotModel& model, const ModelCheckOptions& options = {});

}  // namespace cdpr
