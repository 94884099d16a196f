// The identification problem (not installed): the Ceres problem with its parameter storage and
// layout, built from a model and a recording (problem_build.cc), and its Jacobian information
// with the poses eliminated (information.cc). identification.cc solves it and reports.
#pragma once

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "identification_costs.hpp"

namespace cdpr::ident_detail {

enum class Channel { kLength, kLaser, kWrench, kReference, kSwivel, kInclination, kImuYaw };

struct RowInfo {
  Channel channel;
  int index;  // cable, laser or wrench component
};

struct LaserBlocks {
  std::array<double, 3> origin{};
  std::array<double, 2> direction{};
  std::array<double, 2> normal{};
  double c = 0.0;
  Eigen::Vector3d d0, de1, de2, n0, ne1, ne2;
};

// The Ceres problem with its parameter storage and layout.
struct Built {
  ceres::Problem problem;
  int m = 0;
  std::vector<std::array<double, 3>> a, b;
  std::vector<double> o, s, e, g, c;
  std::vector<LaserBlocks> lasers;
  std::vector<double> swivel_zero;     // zero_i, rad (issue 18)
  bool swivel_zero_free = false;       // some zero_i is estimated
  std::array<double, 2> incl_mount{};  // mounting correction (roll, pitch), rad
  Eigen::Matrix3d incl_mount0 = Eigen::Matrix3d::Identity();
  bool incl_mount_free = false;
  double imu_yaw_zero = 0.0;  // rad
  bool imu_yaw_zero_free = false;
  double mass = 1.0;            // platform mass, kg
  std::array<double, 3> com{};  // platform centre of mass, platform frame, m
  bool mass_free = false, com_free = false;
  std::vector<std::array<double, 6>> poses;
  std::vector<bool> pose_free;
  std::vector<CableConstants> constants;

  std::vector<double*> geometry_blocks;  // free geometry blocks, column order
  std::vector<int> geometry_sizes;       // tangent size of each
  std::vector<ParameterId> ids;
  std::vector<std::string> names, units;  // names: parameter_name(ids[q])
  std::vector<double*> value_ptr;         // ambient value of each geometry column
  std::vector<double> lower, upper;  // physical range of each geometry column (ParameterBounds)
  Eigen::Matrix3Xi anchor_columns;
  int num_geometry = 0;

  std::vector<std::vector<ceres::ResidualBlockId>> blocks_per_pose;
  std::vector<std::vector<RowInfo>> rows_per_pose;
  // The equilibrium functor of each pose (owned by its cost function; nullptr when none).
  std::vector<const EquilibriumCost*> equilibrium;
  std::vector<std::vector<double*>> equilibrium_blocks;  // its parameter blocks
  std::vector<std::string> notes;                        // warnings found while building
  int num_residuals = 0;
  bool shared_stiffness = false;
  bool home_tilt_free = false;  // suspended gauge: home roll and pitch are geometry columns
  // Suspended gauge held at a commanded pose (IdentificationOptions::home_at_commanded): the
  // calibrated home hangs at the config's home position and heading, not at the held pose.
  std::optional<Pose> hang_home_at;
};

// Builds the problem with values from `model` and pose guesses `poses`.
Result<std::unique_ptr<Built>> build_problem(const CalibratedModel& model,
                                             const MeasurementSet& set,
                                             const std::vector<Pose>& poses,
                                             const IdentificationOptions& opt);

// Jacobian pieces per pose and the Schur complement onto the geometry columns.
struct Information {
  std::vector<Eigen::MatrixXd> per_pose;             // P x P (only when asked for: n P^2 doubles)
  Eigen::MatrixXd total;                             // P x P
  std::vector<Eigen::Matrix<double, 6, 6>> hpp_inv;  // per free pose
  std::vector<Eigen::MatrixXd> hpg;                  // 6 x P per free pose
  std::vector<double> residuals;                     // in row order, as evaluated
  std::vector<Eigen::MatrixXd> jg, jp;               // raw blocks (only when kept)
};

// The information of `B` at its current values (Jacobian evaluated with or without the loss).
// `keep`: keep the raw Jacobian blocks; `with_per_pose`: keep each pose's Schur-reduced P x P
// information (pose design needs them; the identification does not, and on 100,000 poses they
// are a gigabyte).
Result<Information> information(Built& B, bool apply_loss, bool keep = false,
                                bool with_per_pose = false);

// The public form of `info` for `B` (moves the per-pose information out of `info`).
GeometryInformation to_public(const Built& B, Information& info, const CalibratedModel& model);

}  // namespace cdpr::ident_detail
