// Inverse kinematics with cable elongation compensation, for the real-time loop.
//
// For a desired pose and the planned cable tensions F_i (from the force distribution):
//
//   L_k,i = inverse_kinematics(pose)              kinematic length D_i -> platform anchor
//   L_i   = routing_length_i + L_k,i               loaded length of the whole cable
//   dL_i  = cable_elongation(cable_i, L_i, F_i)    elongation.hpp
//   l_i   = L_k,i - dL_i                           length command (unstretched, D-referenced)
//   c_i   = winch_length_to_counts(winch_i, l_i)   encoder target, winch.hpp
//
// The winch pays out unstretched cable: the routing part's own unstretched length is constant
// and lives in WinchModel::length_offset, so l_i is referenced to D_i like L_k,i. With no load
// l_i = L_k,i. forward_kinematics_elastic inverts this map (with the measured tensions).
// inverse_kinematics_compensated allocates nothing.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/calibration/winch.hpp"

namespace cdpr {

// Length command of one cable (template: double or ceres::Jet for the identification).
template <typename T>
T cable_length_command(const CableModel& cable, const T& kinematic_length, const T& tension) {
  return kinematic_length -
         cable_elongation<T>(cable, loaded_length<T>(cable, kinematic_length), tension);
}

// Scratch and results, sized once for a model.
struct CableCommandData {
  explicit CableCommandData(int num_cables)
      : kinematics(num_cables),
        loaded_lengths(num_cables),
        elongations(num_cables),
        length_commands(num_cables),
        counts(num_cables),
        counts_rounded(num_cables) {}
  explicit CableCommandData(const RobotModel& model) : CableCommandData(model.num_cables()) {}

  KinematicsData kinematics;        // lengths L_k, structure matrix, ...
  Eigen::VectorXd loaded_lengths;   // routing + L_k, m
  Eigen::VectorXd elongations;      // dL, m
  Eigen::VectorXd length_commands;  // l = L_k - dL, m
  Eigen::VectorXd counts;           // encoder targets, fractional
  Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1> counts_rounded;  // nearest integers
};

// The commands of all cables from inverse kinematics already made at the pose (`kinematics`,
// valid); data.kinematics is not touched. `tensions` has one entry per cable, N.
inline void compensate_lengths(const RobotModel& model, const KinematicsData& kinematics,
                               const Eigen::Ref<const Eigen::VectorXd>& tensions,
                               CableCommandData& data) {
  const int m = model.num_cables();
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const CableModel& cable = model.cables[k];
    const double lk = kinematics.lengths(i);
    const double loaded = loaded_length(cable, lk);
    const double dl = cable_elongation<double>(cable, loaded, tensions(i));
    const double command = lk - dl;
    const double counts = winch_length_to_counts<double>(model.winches[k], command);
    data.loaded_lengths(i) = loaded;
    data.elongations(i) = dl;
    data.length_commands(i) = command;
    data.counts(i) = counts;
    data.counts_rounded(i) = std::llround(counts);
  }
}

// All cables. Returns false (data.kinematics.invalid_cable set) when a cable is degenerate; the
// other cables' commands are still computed. `tensions` has one entry per cable, N.
inline bool inverse_kinematics_compensated(const RobotModel& model, const Pose& pose,
                                           const Eigen::Ref<const Eigen::VectorXd>& tensions,
                                           CableCommandData& data) {
  const bool ok = inverse_kinematics(model, pose, data.kinematics);
  compensate_lengths(model, data.kinematics, tensions, data);
  return ok;
}

}  // namespace cdpr
