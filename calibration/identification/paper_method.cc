#include "cdpr/calibration/paper_method.hpp"

#include <Eigen/Dense>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "identification_internal.hpp"

namespace cdpr {

namespace {

// Kinematic length whose unstretched length under tension F is U (fixed point, dL small).
double kinematic_from_unstretched(const CableModel& c, double U, double F) {
  if (std::isnan(F)) return U;
  double L = U;
  for (int it = 0; it < 10; ++it) {
    L = U + cable_elongation<double>(c, ident_detail::loaded_length<double>(c, L), F);
  }
  return L;
}

class PaperProblem {
 public:
  PaperProblem(const CalibratedModel& initial, const MeasurementSet& set,
               const PaperMethodOptions& options)
      : set_(set), opt_(options), robot_(initial.robot), kin_(initial.robot) {
    m_ = robot_.num_cables();
    fk_poses_.resize(set.poses.size());
  }

  RobotModel& robot() { return robot_; }
  long fk_solves() const { return fk_solves_; }
  const std::vector<Pose>& fk_poses() const { return fk_poses_; }

  // Unstretched home lengths from the current anchors (the encoder zero of the paper).
  Eigen::VectorXd home_unstretched() {
    const PoseMeasurement& h = set_.poses[static_cast<std::size_t>(opt_.home_pose_index)];
    inverse_kinematics(robot_, robot_.home, kin_);
    Eigen::VectorXd U = kin_.lengths;
    for (int i = 0; i < m_; ++i) {
      const double F = h.tensions.size() == m_ ? h.tensions(i) : std::nan("");
      if (std::isnan(F)) continue;
      const CableModel& c = robot_.cables[static_cast<std::size_t>(i)];
      U(i) -=
          cable_elongation<double>(c, ident_detail::loaded_length<double>(c, kin_.lengths(i)), F);
    }
    return U;
  }

  // Gauss-Newton forward kinematics with a finite-difference Jacobian.
  Pose forward_kinematics(const Eigen::VectorXd& lengths, const Pose& start) {
    ++fk_solves_;
    Eigen::Matrix<double, 6, 1> x = start.vector();
    Eigen::MatrixXd J(m_, 6);
    for (int it = 0; it < opt_.fk_max_iterations; ++it) {
      inverse_kinematics(robot_, Pose::from_vector(x), kin_);
      const Eigen::VectorXd r = kin_.lengths - lengths;
      const double h = 1e-7;
      for (int k = 0; k < 6; ++k) {
        Eigen::Matrix<double, 6, 1> xp = x;
        xp(k) += h;
        inverse_kinematics(robot_, Pose::from_vector(xp), kin_);
        J.col(k) = (kin_.lengths - lengths - r) / h;
      }
      const Eigen::Matrix<double, 6, 1> dx = J.colPivHouseholderQr().solve(-r);
      x += dx;
      if (!dx.allFinite() || dx.norm() < opt_.fk_tolerance) break;
    }
    return Pose::from_vector(x);
  }

  // The stacked error vector of Eq. 10 at the current anchors.
  Eigen::VectorXd error() {
    const Eigen::VectorXd U_home = home_unstretched();
    const PoseMeasurement& h = set_.poses[static_cast<std::size_t>(opt_.home_pose_index)];
    const int n = set_.num_poses();
    const int per = m_ + (opt_.use_laser && !robot_.lasers.empty() ? 1 : 0);
    Eigen::VectorXd E = Eigen::VectorXd::Zero(per * n);
    Eigen::VectorXd Lm(m_);
    for (int j = 0; j < n; ++j) {
      const PoseMeasurement& pm = set_.poses[static_cast<std::size_t>(j)];
      for (int i = 0; i < m_; ++i) {
        const double U = pm.cable_lengths(i) - h.cable_lengths(i) + U_home(i);
        const double F = pm.tensions.size() == m_ ? pm.tensions(i) : std::nan("");
        Lm(i) = kinematic_from_unstretched(robot_.cables[static_cast<std::size_t>(i)], U, F);
      }
      const Pose x = forward_kinematics(Lm, pm.commanded);
      fk_poses_[static_cast<std::size_t>(j)] = x;
      inverse_kinematics(robot_, x, kin_);
      E.segment(per * j, m_) = kin_.lengths - Lm;
      if (per > m_ && pm.laser_distances.size() > 0 && !std::isnan(pm.laser_distances(0))) {
        const double d = laser_distance(robot_, 0, x);
        E(per * j + m_) = std::isnan(d) ? 0.0 : d - pm.laser_distances(0);
      }
    }
    return E;
  }

  void offsets_into(CalibratedModel& out) {
    const Eigen::VectorXd U_home = home_unstretched();
    const PoseMeasurement& h = set_.poses[static_cast<std::size_t>(opt_.home_pose_index)];
    for (int i = 0; i < m_; ++i) {
      out.readings.length_offsets(i) = U_home(i) - h.cable_lengths(i);
      out.readings.length_scales(i) = 0.0;
    }
  }

 private:
  const MeasurementSet& set_;
  PaperMethodOptions opt_;
  RobotModel robot_;
  KinematicsData kin_;
  int m_ = 0;
  long fk_solves_ = 0;
  std::vector<Pose> fk_poses_;
};

}  // namespace

Result<PaperMethodReport> paper_method(const CalibratedModel& initial, const MeasurementSet& set,
                                       const PaperMethodOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  CDPR_RETURN_IF_ERROR(validate(set, initial.robot));
  const int m = initial.robot.num_cables();
  const AnchorMask mask = options.parameters.size() == 0 ? paper_anchor_mask() : options.parameters;
  if (mask.cols() != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "paper method: the parameter mask has %d columns, the robot %d cables",
                         static_cast<int>(mask.cols()), m);
  }
  if (options.home_pose_index < 0 || options.home_pose_index >= set.num_poses()) {
    return Status(ErrorCode::kInvalidArgument, "paper method: home_pose_index is not a pose");
  }
  if (!(options.lambda > 0.0 && options.lambda <= 1.0)) {
    return Status(ErrorCode::kInvalidArgument, "paper method: lambda must be in (0, 1]");
  }
  std::vector<std::pair<int, int>> coords;  // (axis, cable)
  for (int i = 0; i < m; ++i) {
    for (int q = 0; q < 3; ++q) {
      if (mask(q, i)) coords.emplace_back(q, i);
    }
  }
  const int K = static_cast<int>(coords.size());
  const int per = m + (options.use_laser && !initial.robot.lasers.empty() ? 1 : 0);
  if (per * set.num_poses() < K) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "paper method: too few poses: %d errors for %d parameters",
                         per * set.num_poses(), K);
  }
  PaperProblem P(initial, set, options);
  auto get = [&](int k) -> double& {
    return P.robot().frame_anchors(coords[static_cast<std::size_t>(k)].first,
                                   coords[static_cast<std::size_t>(k)].second);
  };
  PaperMethodReport rep;
  Eigen::VectorXd E = P.error();
  rep.initial_error_norm = E.norm();
  rep.error_history.push_back(E.norm());
  Eigen::MatrixXd J(E.size(), K);
  rep.termination = "max iterations";
  for (int it = 0; it < options.max_iterations; ++it) {
    if (E.norm() <= options.e_stop) {
      rep.converged = true;
      rep.termination = "||Error|| <= E_stop";
      break;
    }
    for (int k = 0; k < K; ++k) {
      const double saved = get(k);
      get(k) = saved + options.fd_step;
      J.col(k) = (P.error() - E) / options.fd_step;
      get(k) = saved;
    }
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(J, Eigen::ComputeThinU | Eigen::ComputeThinV);
    svd.setThreshold(options.pinv_tolerance);
    const Eigen::VectorXd dV = svd.solve(E);
    for (int k = 0; k < K; ++k) get(k) -= options.lambda * dV(k);
    const double before = E.norm();
    E = P.error();
    rep.error_history.push_back(E.norm());
    rep.iterations = it + 1;
    if (!E.allFinite()) {
      return Status(ErrorCode::kNumericalFailure, "paper method: the error became non-finite");
    }
    if (before - E.norm() < options.min_relative_decrease * before) {
      rep.converged = true;
      rep.termination = "error stopped decreasing";
      break;
    }
  }
  if (!rep.converged && E.norm() <= options.e_stop) {
    rep.converged = true;
    rep.termination = "||Error|| <= E_stop";
  }
  rep.final_error_norm = E.norm();
  rep.fk_solves = P.fk_solves();
  rep.estimate = initial;
  rep.estimate.robot.frame_anchors = P.robot().frame_anchors;
  P.offsets_into(rep.estimate);
  for (int i = 0; i < m; ++i) {
    rep.estimate.robot.winches[static_cast<std::size_t>(i)].length_offset +=
        rep.estimate.readings.length_offsets(i) - initial.readings.length_offsets(i);
  }
  rep.poses = P.fk_poses();
  rep.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

std::string PaperMethodReport::summary() const {
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "Paper method: %s (%s), %d iterations, %ld FK solves, ||Error|| %.4g -> %.4g m, "
                "%.1f ms",
                converged ? "CONVERGED" : "NOT CONVERGED", termination.c_str(), iterations,
                fk_solves, initial_error_norm, final_error_norm, 1e3 * time_s);
  return buf;
}

}  // namespace cdpr
