#include "cdpr/calibration/suspended_statics.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include "cdpr/calibration/elastostatics.hpp"

namespace cdpr {
namespace {

Status check_input(const RobotModel& model, int min_cables, const char* what) {
  const int m = model.num_cables();
  if (m < min_cables || m > 6) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s: a suspended robot with %d cables is not supported (3 to 6 cables: "
                         "fewer leave the platform free to turn about a cable line)",
                         what, m);
  }
  if (!(model.platform.mass > 0.0) || !(model.gravity > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s: a suspended robot needs a positive platform.mass and gravity (only "
                         "gravity keeps its cables taut)",
                         what);
  }
  return Status::success();
}

// Scaled wrench residual (A^T f + w) / weight, moments also / rho, at (position, rotation) with
// tensions `f` (N). False when a cable is degenerate.
bool scaled_wrench(const RobotModel& model, const Eigen::Vector3d& position,
                   const Eigen::Matrix3d& rotation, const Eigen::VectorXd& f, double weight,
                   double rho, KinematicsData& kin, Eigen::Ref<Eigen::VectorXd> out) {
  if (!inverse_kinematics(model, position, rotation, kin)) return false;
  Eigen::Matrix<double, 6, 1> w = kin.structure_matrix * f + gravity_wrench(model, rotation);
  w /= weight;
  w.tail<3>() /= rho;
  out = w;
  return true;
}

// Damped Newton on the square system F(z) = 0, Jacobian by central differences with step h.
// `apply(z0, dz, z)` applies a step (rotations multiplicatively). Returns iterations used or -1.
struct NewtonResult {
  bool converged = false;
  bool evaluable = true;
  int iterations = 0;
  double max_residual = 0.0;
};

using Eval = std::function<bool(const Eigen::VectorXd& z, Eigen::VectorXd& F)>;
using Apply = std::function<Eigen::VectorXd(const Eigen::VectorXd& z, const Eigen::VectorXd& dz)>;

NewtonResult newton(Eigen::VectorXd& z, int rows, const Eval& eval, const Apply& apply,
                    const SuspendedOptions& options) {
  NewtonResult out;
  const int n = static_cast<int>(z.size());
  Eigen::VectorXd F(rows), Fp(rows), Fm(rows), Ft(rows);
  if (!eval(z, F)) {
    out.evaluable = false;
    return out;
  }
  double cost = F.squaredNorm();
  double lambda = 1e-6;
  const double h = 1e-7;
  Eigen::MatrixXd J(rows, n);
  for (int it = 0; it < options.max_iterations; ++it) {
    out.iterations = it;
    out.max_residual = F.cwiseAbs().maxCoeff();
    if (out.max_residual < options.tolerance) {
      out.converged = true;
      return out;
    }
    for (int q = 0; q < n; ++q) {
      Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
      e(q) = h;
      if (!eval(apply(z, e), Fp) || !eval(apply(z, -e), Fm)) {
        out.evaluable = false;
        return out;
      }
      J.col(q) = (Fp - Fm) / (2.0 * h);
    }
    const Eigen::MatrixXd H = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * F;
    bool accepted = false;
    for (int tries = 0; tries < 30 && !accepted; ++tries) {
      Eigen::MatrixXd A = H;
      A.diagonal() += lambda * (H.diagonal().array() + 1e-12).matrix();
      const Eigen::VectorXd dz = A.ldlt().solve(-g);
      if (!dz.allFinite()) {
        lambda *= 10.0;
        continue;
      }
      const Eigen::VectorXd zt = apply(z, dz);
      if (eval(zt, Ft) && Ft.allFinite() && Ft.squaredNorm() < cost) {
        z = zt;
        F = Ft;
        cost = Ft.squaredNorm();
        lambda = std::max(lambda / 10.0, 1e-12);
        accepted = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!accepted) break;  // no step reduces the residual: a local minimum
  }
  out.max_residual = F.cwiseAbs().maxCoeff();
  out.converged = out.max_residual < options.tolerance;
  return out;
}

Status refuse_slack(const SuspendedState& s, const SuspendedOptions& options, const char* what) {
  for (int i = 0; i < static_cast<int>(s.tensions.size()); ++i) {
    if (!(s.tensions(i) >= options.min_tension)) {
      return Status::error(ErrorCode::kOutOfRange,
                           "%s: cables[%d] would need a tension of %.4g N (below %.4g N): the "
                           "platform cannot hang there on all its cables (position [%.4g, %.4g, "
                           "%.4g] m)",
                           what, i, s.tensions(i), options.min_tension, s.pose.position.x(),
                           s.pose.position.y(), s.pose.position.z());
    }
  }
  return Status::success();
}

// Fills lengths, least-squares tensions and the residual of `s` from its pose.
Status finish_state(const RobotModel& model, SuspendedState& s) {
  KinematicsData kin(model);
  if (!inverse_kinematics(model, s.pose.position, s.rotation, kin)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables[%d]: degenerate at the pose (the platform anchor lies on the "
                         "frame anchor or inside its pulley)",
                         kin.invalid_cable);
  }
  const Eigen::Matrix<double, 6, 1> w = gravity_wrench(model, s.rotation);
  const Eigen::MatrixXd A = kin.structure_matrix;
  s.tensions = A.colPivHouseholderQr().solve(-w);
  Eigen::Matrix<double, 6, 1> r = A * s.tensions + w;
  r.tail<3>() /= model.platform_radius();
  s.wrench_residual = r.cwiseAbs().maxCoeff();
  s.lengths = kin.lengths;
  return Status::success();
}

}  // namespace

Result<SuspendedState> suspended_tensions(const RobotModel& model, const Pose& pose) {
  if (model.num_cables() < 1 || !pose.vector().allFinite()) {
    return Status(ErrorCode::kInvalidArgument,
                  "suspended_tensions: no cables or a non-finite pose");
  }
  SuspendedState s;
  s.pose = pose;
  s.rotation = rotation_from_rpy<double>(pose.rpy);
  CDPR_RETURN_IF_ERROR(finish_state(model, s));
  return s;
}

Result<SuspendedState> suspended_equilibrium_pose(const RobotModel& model, const Pose& target,
                                                  const SuspendedOptions& options) {
  CDPR_RETURN_IF_ERROR(check_input(model, 3, "suspended_equilibrium_pose"));
  if (!target.vector().allFinite()) {
    return Status(ErrorCode::kInvalidArgument, "suspended_equilibrium_pose: non-finite target");
  }
  const int m = model.num_cables();
  const int nfree = 6 - m;  // the first nfree rpy angles
  const double weight = model.platform.mass * model.gravity;
  const double rho = model.platform_radius();
  KinematicsData kin(model);
  Eigen::Vector3d rpy0 = target.rpy;
  if (options.initial_pose) {
    for (int q = 0; q < nfree; ++q) rpy0(q) = options.initial_pose->rpy(q);
  }
  auto rpy_of = [&](const Eigen::VectorXd& z) {
    Eigen::Vector3d rpy = target.rpy;
    for (int q = 0; q < nfree; ++q) rpy(q) = z(q);
    return rpy;
  };
  // z = the free angles; the tensions are eliminated (least squares at each trial), so the
  // residual is the part of the weight the cables cannot balance (variable projection).
  Eigen::VectorXd z(nfree);
  for (int q = 0; q < nfree; ++q) z(q) = rpy0(q);
  Eigen::VectorXd f_ls(m);
  const Eval eval = [&](const Eigen::VectorXd& zz, Eigen::VectorXd& F) {
    const Eigen::Matrix3d R = rotation_from_rpy<double>(rpy_of(zz));
    if (!inverse_kinematics(model, target.position, R, kin)) return false;
    const Eigen::Matrix<double, 6, 1> w = gravity_wrench(model, R);
    const Eigen::MatrixXd A = kin.structure_matrix;
    f_ls = A.colPivHouseholderQr().solve(-w);
    return scaled_wrench(model, target.position, R, f_ls, weight, rho, kin, F);
  };
  const Apply apply = [](const Eigen::VectorXd& zz, const Eigen::VectorXd& dz) {
    return Eigen::VectorXd(zz + dz);
  };
  const NewtonResult nr = newton(z, 6, eval, apply, options);
  SuspendedState s;
  s.pose = Pose{target.position, rpy_of(z)};
  s.rotation = rotation_from_rpy<double>(s.pose.rpy);
  s.iterations = nr.iterations;
  if (!nr.evaluable) {
    return Status(ErrorCode::kInvalidArgument,
                  "suspended_equilibrium_pose: a cable is degenerate near the target pose");
  }
  if (!nr.converged) {
    return Status::error(ErrorCode::kNumericalFailure,
                         "suspended_equilibrium_pose: no orientation balances gravity at position "
                         "[%.4g, %.4g, %.4g] m (residual %.3g of the weight after %d iterations)",
                         target.position.x(), target.position.y(), target.position.z(),
                         nr.max_residual, nr.iterations);
  }
  CDPR_RETURN_IF_ERROR(finish_state(model, s));
  CDPR_RETURN_IF_ERROR(refuse_slack(s, options, "suspended_equilibrium_pose"));
  return s;
}

Result<SuspendedState> forward_kinematics_suspended(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& kinematic_lengths,
    const SuspendedOptions& options) {
  CDPR_RETURN_IF_ERROR(check_input(model, 3, "forward_kinematics_suspended"));
  const int m = model.num_cables();
  if (kinematic_lengths.size() != m || !kinematic_lengths.allFinite() ||
      !(kinematic_lengths.array() > 0.0).all()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "forward_kinematics_suspended: expected %d positive finite lengths (m), "
                         "got %d",
                         m, static_cast<int>(kinematic_lengths.size()));
  }
  const double weight = model.platform.mass * model.gravity;
  const double rho = model.platform_radius();
  const Pose start = options.initial_pose.value_or(model.home);
  Eigen::Matrix3d R0 = rotation_from_rpy<double>(start.rpy);
  KinematicsData kin(model);
  Eigen::VectorXd target(m);
  // z = (position, rotation vector w with R = exp([w]x) R0, tensions / weight); R0 is re-based
  // after every continuation stage.
  auto rotation_of = [&](const Eigen::VectorXd& z) {
    return Eigen::Matrix3d(rotation_exp(z.segment<3>(3)) * R0);
  };
  Eigen::VectorXd z = Eigen::VectorXd::Zero(6 + m);
  z.head<3>() = start.position;
  Eigen::VectorXd start_lengths(m);
  {
    SuspendedState s0;
    s0.pose = start;
    s0.rotation = R0;
    CDPR_RETURN_IF_ERROR(finish_state(model, s0));
    z.tail(m) = s0.tensions.cwiseMax(0.0) / weight;
    start_lengths = s0.lengths;
  }
  const Eval eval = [&](const Eigen::VectorXd& zz, Eigen::VectorXd& F) {
    const Eigen::VectorXd f = zz.tail(m) * weight;
    const Eigen::Matrix3d R = rotation_of(zz);
    if (!scaled_wrench(model, zz.head<3>(), R, f, weight, rho, kin, F.tail(6))) return false;
    F.head(m) = kin.lengths - target;
    return F.allFinite();
  };
  const Apply apply = [](const Eigen::VectorXd& zz, const Eigen::VectorXd& dz) {
    return Eigen::VectorXd(zz + dz);
  };
  // Continuation from the start pose's own lengths (where the start is, or is next to, an
  // equilibrium) to the given ones: each stage is a short Newton solve from the previous
  // equilibrium, so the solver follows the hanging branch instead of jumping to another one.
  NewtonResult nr;
  double lambda = 0.0, step = 0.25;
  int total_iterations = 0;
  bool first = true;
  while (true) {
    const double next = first ? 0.0 : std::min(1.0, lambda + step);
    target = start_lengths + next * (kinematic_lengths - start_lengths);
    Eigen::VectorXd trial = z;
    nr = newton(trial, 6 + m, eval, apply, options);
    total_iterations += nr.iterations;
    if (nr.evaluable && nr.converged) {
      z = trial;
      R0 = rotation_of(z);
      z.segment<3>(3).setZero();
      lambda = next;
      first = false;
      step = std::min(2.0 * step, 1.0);
      if (lambda >= 1.0) break;
    } else if (first || step < 1.0 / 1024.0) {
      break;
    } else {
      step *= 0.5;
    }
  }
  nr.iterations = total_iterations;
  SuspendedState s;
  s.rotation = rotation_of(z);
  s.pose = Pose{z.head<3>(), rpy_from_rotation(s.rotation)};
  s.iterations = nr.iterations;
  if (!nr.evaluable) {
    return Status(ErrorCode::kInvalidArgument,
                  "forward_kinematics_suspended: a cable is degenerate on the way from the start "
                  "pose");
  }
  if (!nr.converged) {
    return Status::error(ErrorCode::kNumericalFailure,
                         "forward_kinematics_suspended: no pose has these cable lengths and "
                         "balances gravity with them (largest scaled residual %.3g after %d "
                         "iterations)",
                         nr.max_residual, nr.iterations);
  }
  CDPR_RETURN_IF_ERROR(finish_state(model, s));
  s.tensions = z.tail(m) * weight;
  CDPR_RETURN_IF_ERROR(refuse_slack(s, options, "forward_kinematics_suspended"));
  return s;
}

Result<SuspendedState> forward_kinematics_suspended_elastic(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& unstretched_lengths,
    const SuspendedOptions& options) {
  // The rigid pose of the commands is a close start (the cables stretch by F L / EA).
  // Its tensions are not checked: rigid cables are far more sensitive to the lengths than
  // elastic ones (a cable near slack may come out slightly negative).
  SuspendedOptions rigid_options = options;
  rigid_options.min_tension = -std::numeric_limits<double>::infinity();
  CDPR_ASSIGN_OR_RETURN(SuspendedState rigid,
                        forward_kinematics_suspended(model, unstretched_lengths, rigid_options));
  for (const CableModel& c : model.cables) {
    if (c.elongation == ElongationKind::kRigid) return rigid;
  }
  ElastostaticData data(model);
  ElastostaticOptions eo;
  eo.initial_pose = rigid.pose;
  const ElastostaticSummary es = solve_elastostatics(model, unstretched_lengths, eo, data);
  if (!es.success()) {
    return Status::error(ErrorCode::kNumericalFailure, "forward_kinematics_suspended_elastic: %s",
                         std::string(es.status.message()).c_str());
  }
  SuspendedState s;
  s.pose = es.pose;
  s.rotation = es.rotation;
  s.tensions = data.tensions;
  s.lengths = data.kinematics.lengths;
  s.wrench_residual = es.max_wrench_residual;
  s.iterations = rigid.iterations + es.iterations;
  CDPR_RETURN_IF_ERROR(refuse_slack(s, options, "forward_kinematics_suspended_elastic"));
  return s;
}

}  // namespace cdpr
