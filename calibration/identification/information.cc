// The identification problem's information: its Jacobian evaluated a chunk of poses at a time,
// the poses eliminated (Schur complement onto the geometry columns), and the public entry points
// that need no solve (geometry_information, evaluate_residuals).
#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <memory>
#include <utility>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "identification_internal.hpp"
#include "identification_problem.hpp"

namespace cdpr {
namespace ident_detail {

Result<Information> information(Built& B, bool apply_loss, bool keep, bool with_per_pose) {
  const int P = B.num_geometry;
  const int n = static_cast<int>(B.poses.size());
  Information info;
  if (with_per_pose) info.per_pose.assign(static_cast<std::size_t>(n), Eigen::MatrixXd::Zero(P, P));
  info.total = Eigen::MatrixXd::Zero(P, P);
  info.hpp_inv.assign(static_cast<std::size_t>(n), Eigen::Matrix<double, 6, 6>::Zero());
  info.hpg.assign(static_cast<std::size_t>(n), Eigen::MatrixXd::Zero(6, P));
  std::size_t total_rows = 0;
  for (const auto& rows : B.rows_per_pose) total_rows += rows.size();
  info.residuals.reserve(total_rows);
  // The Jacobian is evaluated a chunk of poses at a time: the whole one as a CRS matrix is about
  // 4 kB per MINI pose (400 MB for 100,000 poses). Each pose's rows and columns, and so every sum
  // below, are the same as in one evaluation.
  constexpr int kChunk = 1024;
  ceres::Problem::EvaluateOptions eo;
  eo.apply_loss_function = apply_loss;
  std::vector<double> chunk_residuals;
  for (int j0 = 0; j0 < n; j0 += kChunk) {
    const int j1 = std::min(n, j0 + kChunk);
    eo.parameter_blocks = B.geometry_blocks;
    eo.residual_blocks.clear();
    std::vector<int> pose_col(static_cast<std::size_t>(j1 - j0), -1);
    int col = P;
    for (int j = j0; j < j1; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      eo.residual_blocks.insert(eo.residual_blocks.end(), B.blocks_per_pose[uj].begin(),
                                B.blocks_per_pose[uj].end());
      if (!B.pose_free[uj]) continue;
      eo.parameter_blocks.push_back(B.poses[uj].data());
      pose_col[static_cast<std::size_t>(j - j0)] = col;
      col += 6;
    }
    if (eo.residual_blocks.empty()) continue;
    ceres::CRSMatrix J;
    double cost = 0.0;
    chunk_residuals.clear();
    if (!B.problem.Evaluate(eo, &cost, &chunk_residuals, nullptr, &J)) {
      return Status(
          ErrorCode::kNumericalFailure,
          "identification: the model cannot be evaluated (a cable is degenerate at a pose)");
    }
    if (J.num_cols != col) {
      return Status::error(ErrorCode::kInternal,
                           "identification: Jacobian has %d columns, expected %d", J.num_cols, col);
    }
    info.residuals.insert(info.residuals.end(), chunk_residuals.begin(), chunk_residuals.end());
    int row = 0;
    for (int j = j0; j < j1; ++j) {
      const int rows = static_cast<int>(B.rows_per_pose[static_cast<std::size_t>(j)].size());
      Eigen::MatrixXd Jg = Eigen::MatrixXd::Zero(rows, P);
      Eigen::MatrixXd Jp = Eigen::MatrixXd::Zero(rows, 6);
      const int pc = pose_col[static_cast<std::size_t>(j - j0)];
      for (int r = 0; r < rows; ++r) {
        const int R = row + r;
        for (int idx = J.rows[static_cast<std::size_t>(R)];
             idx < J.rows[static_cast<std::size_t>(R) + 1]; ++idx) {
          const int cidx = J.cols[static_cast<std::size_t>(idx)];
          const double v = J.values[static_cast<std::size_t>(idx)];
          if (cidx < P) {
            Jg(r, cidx) = v;
          } else if (pc >= 0 && cidx >= pc && cidx < pc + 6) {
            Jp(r, cidx - pc) = v;
          }
        }
      }
      row += rows;
      Eigen::MatrixXd S = Jg.transpose() * Jg;
      if (keep) {
        info.jg.push_back(Jg);
        info.jp.push_back(Jp);
      }
      if (pc >= 0) {
        const Eigen::Matrix<double, 6, 6> Hpp = Jp.transpose() * Jp;
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(Hpp);
        Eigen::Matrix<double, 6, 1> inv = Eigen::Matrix<double, 6, 1>::Zero();
        const double lmax = es.eigenvalues().maxCoeff();
        for (int q = 0; q < 6; ++q) {
          if (es.eigenvalues()(q) > 1e-12 * lmax && lmax > 0) inv(q) = 1.0 / es.eigenvalues()(q);
        }
        const Eigen::Matrix<double, 6, 6> Hinv =
            es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
        const Eigen::MatrixXd Hpg = Jp.transpose() * Jg;
        S -= Hpg.transpose() * Hinv * Hpg;
        info.hpp_inv[static_cast<std::size_t>(j)] = Hinv;
        info.hpg[static_cast<std::size_t>(j)] = Hpg;
      }
      S = 0.5 * (S + S.transpose());
      info.total += S;
      if (with_per_pose) info.per_pose[static_cast<std::size_t>(j)] = std::move(S);
    }
  }
  return info;
}

// Moves the per-pose information out of `info`.
GeometryInformation to_public(const Built& B, Information& info, const CalibratedModel& model) {
  GeometryInformation gi;
  gi.ids = B.ids;
  gi.names = B.names;
  gi.units = B.units;
  gi.values.resize(B.num_geometry);
  for (int q = 0; q < B.num_geometry; ++q) gi.values(q) = *B.value_ptr[static_cast<std::size_t>(q)];
  gi.per_pose = std::move(info.per_pose);
  gi.information = info.total;
  gi.anchor_columns = B.anchor_columns;
  KinematicsData kin(model.robot);
  inverse_kinematics(model.robot, model.robot.home, kin);
  gi.home_cable_directions = kin.unit_vectors;
  gi.frame_anchors = model.robot.frame_anchors;
  for (int i = 0; i < B.m; ++i) {
    for (int q = 0; q < 3; ++q)
      gi.frame_anchors(q, i) = B.a[static_cast<std::size_t>(i)][static_cast<std::size_t>(q)];
  }
  gi.num_residuals = B.num_residuals;
  for (const auto& rows : B.rows_per_pose) {
    for (const RowInfo& ri : rows) {
      switch (ri.channel) {
        case Channel::kLength:
          ++gi.channel_rows.length;
          break;
        case Channel::kLaser:
          ++gi.channel_rows.laser;
          break;
        case Channel::kWrench:
          ++gi.channel_rows.wrench;
          break;
        case Channel::kReference:
          ++gi.channel_rows.reference;
          break;
        case Channel::kSwivel:
          ++gi.channel_rows.swivel;
          break;
        case Channel::kInclination:
          ++gi.channel_rows.inclination;
          break;
        case Channel::kImuYaw:
          ++gi.channel_rows.imu_yaw;
          break;
      }
    }
  }
  for (bool f : B.pose_free) gi.home_pose_fixed = gi.home_pose_fixed || !f;
  gi.home_tilt_free = B.home_tilt_free;
  int free_poses = 0;
  for (bool f : B.pose_free) free_poses += f ? 1 : 0;
  gi.num_pose_parameters = 6 * free_poses;
  return gi;
}

}  // namespace ident_detail

namespace {

// geometry_information, with or without the per-pose matrices.
Result<GeometryInformation> geometry_information_impl(const CalibratedModel& model,
                                                      const MeasurementSet& set,
                                                      const std::vector<Pose>& poses,
                                                      const IdentificationOptions& options,
                                                      bool keep_jacobians, bool with_per_pose) {
  auto built = ident_detail::build_problem(model, set, poses, options);
  if (!built) return built.status();
  auto info = ident_detail::information(**built, false, keep_jacobians, with_per_pose);
  if (!info) return info.status();
  GeometryInformation gi = ident_detail::to_public(**built, *info, model);
  gi.jacobian_geometry = std::move(info->jg);
  gi.jacobian_pose = std::move(info->jp);
  return gi;
}

}  // namespace

Result<GeometryInformation> geometry_information(const CalibratedModel& model,
                                                 const MeasurementSet& set,
                                                 const std::vector<Pose>& poses,
                                                 const IdentificationOptions& options,
                                                 bool keep_jacobians) {
  return geometry_information_impl(model, set, poses, options, keep_jacobians, true);
}

Result<GeometryInformation> ident_detail::total_geometry_information(
    const CalibratedModel& model, const MeasurementSet& set, const std::vector<Pose>& poses,
    const IdentificationOptions& options) {
  return geometry_information_impl(model, set, poses, options, false, false);
}

Result<std::vector<Eigen::VectorXd>> evaluate_residuals(const CalibratedModel& model,
                                                        const MeasurementSet& set,
                                                        const std::vector<Pose>& poses,
                                                        const IdentificationOptions& options) {
  auto built = ident_detail::build_problem(model, set, poses, options);
  if (!built) return built.status();
  ident_detail::Built& B = **built;
  std::vector<ceres::ResidualBlockId> blocks;
  for (const auto& v : B.blocks_per_pose) blocks.insert(blocks.end(), v.begin(), v.end());
  std::vector<Eigen::VectorXd> out;
  std::vector<double> r;
  if (!blocks.empty()) {
    ceres::Problem::EvaluateOptions eo;
    eo.apply_loss_function = false;
    eo.residual_blocks = blocks;
    double cost = 0.0;
    if (!B.problem.Evaluate(eo, &cost, &r, nullptr, nullptr)) {
      return Status(ErrorCode::kNumericalFailure,
                    "evaluate_residuals: the model cannot be evaluated at these poses");
    }
  }
  std::size_t row = 0;
  for (const auto& rows : B.rows_per_pose) {
    Eigen::VectorXd v(static_cast<Eigen::Index>(rows.size()));
    for (Eigen::Index q = 0; q < v.size(); ++q) v(q) = r[row++];
    out.push_back(std::move(v));
  }
  return out;
}

}  // namespace cdpr
