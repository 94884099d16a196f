#include "cdpr/calibration/elastostatics.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>

#include "cdpr/calibration/elongation.hpp"

namespace cdpr {
namespace {

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d s;
  s << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return s;
}

Wrench scaled(const Wrench& w, double rho) {
  Wrench s = w;
  s.tail<3>() /= rho;
  return s;
}

// Tensions, net wrench and (optionally) the analytic stiffness at (r, R).
bool evaluate(const RobotModel& model, const Eigen::Vector3d& r, const Eigen::Matrix3d& R,
              const Eigen::Ref<const Eigen::VectorXd>& commands, const Wrench& external,
              KinematicsData& kin, Eigen::VectorXd& tensions, Eigen::VectorXd& stiffnesses,
              Wrench& w, Matrix6d* K, int* bad_cable) {
  if (!inverse_kinematics(model, r, R, kin)) {
    if (bad_cable != nullptr) *bad_cable = kin.invalid_cable;
    return false;
  }
  w.setZero();
  if (K != nullptr) K->setZero();
  const int m = model.num_cables();
  for (int i = 0; i < m; ++i) {
    const CableTension t =
        cable_tension(model.cables[static_cast<std::size_t>(i)], kin.lengths(i), commands(i));
    if (!t.ok) {
      if (bad_cable != nullptr) *bad_cable = i;
      return false;
    }
    tensions(i) = t.tension;
    stiffnesses(i) = t.stiffness;
    if (!t.taut) continue;
    const Wrench a = kin.structure_matrix.col(i);
    w += t.tension * a;
    if (K == nullptr) continue;
    // Elastic part: dF/dx = k dL/dx = -k a^T.
    K->noalias() -= t.stiffness * a * a.transpose();
    // Geometric part: F da/dx, with the cable leaving from a fixed point (the exit point).
    const Eigen::Vector3d u = kin.unit_vectors.col(i);
    const Eigen::Vector3d rho = R * model.platform_anchors.col(i);
    const Eigen::Matrix3d P =
        (Eigen::Matrix3d::Identity() - u * u.transpose()) / kin.free_lengths(i);
    const Eigen::Matrix3d S_rho = skew(rho);
    const Eigen::Matrix3d du_dr = -P;
    const Eigen::Matrix3d du_dth = P * S_rho;
    K->block<3, 3>(0, 0) += t.tension * du_dr;
    K->block<3, 3>(0, 3) += t.tension * du_dth;
    K->block<3, 3>(3, 0) += t.tension * (S_rho * du_dr);
    K->block<3, 3>(3, 3) += t.tension * (S_rho * du_dth + skew(u) * S_rho);
  }
  // Gravity at the centre of mass, moment about the platform origin.
  const Eigen::Vector3d G(0.0, 0.0, -model.platform.mass * model.gravity);
  const Eigen::Vector3d c = R * model.platform.center_of_mass;
  w.head<3>() += G;
  w.tail<3>() += c.cross(G);
  if (K != nullptr) K->block<3, 3>(3, 3) += skew(G) * skew(c);
  w += external;
  return w.allFinite();
}

// Residual wrench that rounding alone produces: a length error of a few ulps times each cable's
// stiffness (stiff cables cannot be balanced to better than this).
double wrench_noise_floor(const KinematicsData& kin, const Eigen::VectorXd& tensions,
                          const Eigen::VectorXd& stiffnesses) {
  const int m = static_cast<int>(tensions.size());
  double sum = 0.0;
  for (int i = 0; i < m; ++i) {
    sum += std::abs(tensions(i)) + std::abs(stiffnesses(i)) * std::abs(kin.lengths(i));
  }
  return 64.0 * std::numeric_limits<double>::epsilon() * sum;
}

struct CoreResult {
  ElastostaticTermination termination = ElastostaticTermination::kNoConvergence;
  int iterations = 0;
  double max_residual = std::numeric_limits<double>::infinity();
  int bad_cable = -1;
};

// Levenberg-Marquardt on the scaled wrench from (r, R); on return (r, R) is the best pose and
// data.kinematics / tensions / stiffnesses / wrench / stiffness hold its state.
CoreResult newton(const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& commands,
                  const ElastostaticOptions& options, double rho, Eigen::Vector3d& r,
                  Eigen::Matrix3d& R, ElastostaticData& data) {
  CoreResult out;
  Matrix6d K;
  Wrench w;
  if (!evaluate(model, r, R, commands, options.external_wrench, data.kinematics, data.tensions,
                data.stiffnesses, w, &K, &out.bad_cable)) {
    out.termination = out.bad_cable >= 0 && data.kinematics.invalid_cable >= 0
                          ? ElastostaticTermination::kDegenerateGeometry
                          : ElastostaticTermination::kNumericalFailure;
    return out;
  }
  Wrench ws = scaled(w, rho);
  double cost = ws.squaredNorm();
  double lambda = options.initial_lambda;
  // Scaling: wrench_s = D w and step = D step_s, D = diag(1, 1, 1, 1/rho, 1/rho, 1/rho).
  Eigen::Matrix<double, 6, 1> D;
  D << 1.0, 1.0, 1.0, 1.0 / rho, 1.0 / rho, 1.0 / rho;
  double tolerance = std::max(options.wrench_tolerance,
                              wrench_noise_floor(data.kinematics, data.tensions, data.stiffnesses));
  for (out.iterations = 0; out.iterations < options.max_iterations; ++out.iterations) {
    out.max_residual = ws.cwiseAbs().maxCoeff();
    if (out.max_residual <= tolerance) {
      out.termination = ElastostaticTermination::kConverged;
      break;
    }
    // Scaled Jacobian Ks = S_w K S_x^-1 with S_w = S_x^-1 = diag(1, 1, 1, 1/rho, 1/rho, 1/rho).
    const Matrix6d Ks = D.asDiagonal() * K * D.asDiagonal();
    const Matrix6d H = Ks.transpose() * Ks;
    const Wrench g = Ks.transpose() * ws;
    const double diag_floor = 1e-12 * std::max(H.diagonal().maxCoeff(), 1e-300);
    bool accepted = false;
    while (!accepted) {
      Matrix6d Ha = H;
      for (int k = 0; k < 6; ++k) Ha(k, k) += lambda * std::max(H(k, k), diag_floor);
      const Eigen::LDLT<Matrix6d> ldlt(Ha);
      const Wrench step_s = -ldlt.solve(g);
      if (!step_s.allFinite()) {
        lambda *= 10.0;
        if (lambda > 1e16) break;
        continue;
      }
      const Wrench step = D.asDiagonal() * step_s;                            // back to (m, rad)
      if (step_s.norm() <= options.step_tolerance * (1.0 + r.norm())) break;  // stalled
      const Eigen::Vector3d r_trial = r + step.head<3>();
      const Eigen::Matrix3d R_trial = rotation_exp(step.tail<3>()) * R;
      Matrix6d K_trial;
      Wrench w_trial;
      const bool ok =
          evaluate(model, r_trial, R_trial, commands, options.external_wrench, data.trial,
                   data.trial_tensions, data.trial_stiffnesses, w_trial, &K_trial, nullptr);
      const Wrench ws_trial = scaled(w_trial, rho);
      if (ok && ws_trial.squaredNorm() < cost) {
        r = r_trial;
        R = R_trial;
        K = K_trial;
        w = w_trial;
        ws = ws_trial;
        cost = ws.squaredNorm();
        data.kinematics = data.trial;
        data.tensions = data.trial_tensions;
        data.stiffnesses = data.trial_stiffnesses;
        tolerance = std::max(options.wrench_tolerance,
                             wrench_noise_floor(data.kinematics, data.tensions, data.stiffnesses));
        lambda = std::max(lambda * 0.1, 1e-15);
        accepted = true;
      } else {
        lambda *= 10.0;
        if (lambda > 1e16) break;
      }
    }
    if (!accepted) {
      out.max_residual = ws.cwiseAbs().maxCoeff();
      if (out.max_residual <= tolerance) {
        out.termination = ElastostaticTermination::kConverged;
      } else {
        out.termination = ElastostaticTermination::kNoConvergence;
      }
      break;
    }
  }
  out.max_residual = ws.cwiseAbs().maxCoeff();
  if (out.max_residual <= tolerance) out.termination = ElastostaticTermination::kConverged;
  data.wrench = w;
  data.stiffness = K;
  return out;
}

// Descent on the potential energy V (cables' elastic energy plus the platform's weight): the
// equilibria are the stationary points of V and the stable ones its minima, with dV = -W . dx.
// Levenberg-Marquardt on |W|^2 (newton above) can stall where |W| has a local minimum that is
// not an equilibrium, typically with most cables slack: the platform "hangs" in a position where
// the few taut cables cannot cancel gravity and K is nearly singular. Descent on V moves the
// platform the way the net wrench pushes it, as the physical platform would, until the cables
// catch it. Direction: modified Newton, H d = W (scaled), H = -sym(K) shifted to be positive
// definite (so d is a descent direction of V); step along d to the minimum of V on that line,
// located from the sign of the directional derivative phi'(a) = -W(x + a d) . d alone (V itself
// is not needed, so polynomial cables need no energy integral). On return (r, R) is the last
// pose and data holds its state; converged when every scaled wrench component is below the
// tolerance.
CoreResult energy_descent(const RobotModel& model,
                          const Eigen::Ref<const Eigen::VectorXd>& commands,
                          const ElastostaticOptions& options, double rho, Eigen::Vector3d& r,
                          Eigen::Matrix3d& R, ElastostaticData& data) {
  CoreResult out;
  Eigen::Matrix<double, 6, 1> D;
  D << 1.0, 1.0, 1.0, 1.0 / rho, 1.0 / rho, 1.0 / rho;
  Matrix6d K;
  Wrench w;
  if (!evaluate(model, r, R, commands, options.external_wrench, data.kinematics, data.tensions,
                data.stiffnesses, w, &K, &out.bad_cable)) {
    out.termination = ElastostaticTermination::kDegenerateGeometry;
    return out;
  }
  Wrench ws = scaled(w, rho);
  // Largest move per line search step (m, rotations times rho): keeps a step of a nearly
  // unsupported platform from jumping through the frame.
  const double max_step = 0.25 * std::max(rho, 0.1);
  for (out.iterations = 0; out.iterations < options.max_iterations; ++out.iterations) {
    const double tolerance =
        std::max(options.wrench_tolerance,
                 wrench_noise_floor(data.kinematics, data.tensions, data.stiffnesses));
    out.max_residual = ws.cwiseAbs().maxCoeff();
    if (out.max_residual <= tolerance) {
      out.termination = ElastostaticTermination::kConverged;
      return out;
    }
    const Matrix6d Ks = D.asDiagonal() * K * D.asDiagonal();
    const Matrix6d H = -0.5 * (Ks + Ks.transpose());
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(H);
    // H = Q diag(lambda) Q^T with every eigenvalue raised to at least `floor`: a small share of
    // the largest, and at least the stiffness that moves an unsupported direction (all cables
    // slack: H = 0) by max_step under the present wrench.
    const double floor =
        std::max(1e-6 * eig.eigenvalues().cwiseAbs().maxCoeff(), ws.norm() / max_step);
    Wrench d = Wrench::Zero();
    for (int k = 0; k < 6; ++k) {
      const double lambda = std::max(eig.eigenvalues()(k), floor);
      d += (eig.eigenvectors().col(k).dot(ws) / lambda) * eig.eigenvectors().col(k);
    }
    if (!d.allFinite() || !(d.norm() > 0.0)) break;
    if (d.norm() > max_step) d *= max_step / d.norm();
    const double slope0 = -ws.dot(d);  // phi'(0) < 0
    // phi'(a) at a trial step; false when the pose is degenerate there.
    auto slope_at = [&](double a, double& slope) {
      const Wrench step = D.asDiagonal() * (a * d);
      Wrench w_trial;
      if (!evaluate(model, r + step.head<3>(), rotation_exp(step.tail<3>()) * R, commands,
                    options.external_wrench, data.trial, data.trial_tensions,
                    data.trial_stiffnesses, w_trial, nullptr, nullptr)) {
        return false;
      }
      slope = -scaled(w_trial, rho).dot(d);
      return std::isfinite(slope);
    };
    // Bracket the minimum of V along d: lo descends, hi ascends (or is degenerate).
    double lo = 0.0;
    double hi = std::numeric_limits<double>::infinity();
    double a = 1.0;
    double slope = 0.0;
    for (int k = 0; k < 60; ++k) {
      if (!slope_at(a, slope) || slope > 0.0) {
        hi = a;
      } else {
        lo = a;
      }
      if (std::abs(slope) <= 0.5 * std::abs(slope0) && lo == a) break;  // curvature condition
      if (!std::isfinite(hi)) {
        if (a * d.norm() >= 4.0 * max_step) break;  // still descending: take the long step
        a *= 2.0;
      } else {
        if (hi - lo <= 1e-12 * hi) break;
        a = 0.5 * (lo + hi);
      }
    }
    if (!(lo > 0.0)) break;  // no descent possible along d
    const Wrench step = D.asDiagonal() * (lo * d);
    r += step.head<3>();
    R = rotation_exp(step.tail<3>()) * R;
    if (!evaluate(model, r, R, commands, options.external_wrench, data.kinematics, data.tensions,
                  data.stiffnesses, w, &K, &out.bad_cable)) {
      out.termination = ElastostaticTermination::kDegenerateGeometry;
      return out;
    }
    ws = scaled(w, rho);
  }
  out.max_residual = ws.cwiseAbs().maxCoeff();
  out.termination = ElastostaticTermination::kNoConvergence;
  return out;
}

double pose_distance(const Eigen::Vector3d& r1, const Eigen::Matrix3d& R1,
                     const Eigen::Vector3d& r2, const Eigen::Matrix3d& R2, double rho) {
  // Rotation angle of R1 R2^T by atan2(sin, cos): accurate for small angles (acos is not).
  const Eigen::Matrix3d dR = R1 * R2.transpose();
  const Eigen::Vector3d axis(dR(2, 1) - dR(1, 2), dR(0, 2) - dR(2, 0), dR(1, 0) - dR(0, 1));
  const double angle = std::atan2(0.5 * axis.norm(), 0.5 * (dR.trace() - 1.0));
  return std::max((r1 - r2).norm(), rho * angle);
}

}  // namespace

const char* to_string(ElastostaticTermination termination) {
  switch (termination) {
    case ElastostaticTermination::kConverged:
      return "converged";
    case ElastostaticTermination::kNoConvergence:
      return "no convergence";
    case ElastostaticTermination::kInvalidInput:
      return "invalid input";
    case ElastostaticTermination::kDegenerateGeometry:
      return "degenerate geometry";
    case ElastostaticTermination::kNumericalFailure:
      return "numerical failure";
  }
  return "unknown";
}

CableTension cable_tension(const CableModel& cable, double kinematic_length,
                           double length_command) {
  CableTension t;
  const double stretch = kinematic_length - length_command;
  switch (cable.elongation) {
    case ElongationKind::kRigid:
      t.ok = false;  // infinitely stiff: no elasto-static equilibrium to compute
      return t;
    case ElongationKind::kHooke: {
      // Same law as elongation.hpp's dL = F L / (EA + F) with L = routing + L_k, solved for F.
      const double rest = cable.routing_length + length_command;
      if (!(rest > 0.0) || !(cable.ea > 0.0)) {
        t.ok = false;
        return t;
      }
      if (!(stretch > 0.0)) return t;
      t.tension = cable.ea * stretch / rest;
      t.stiffness = cable.ea / rest;
      t.taut = true;
      return t;
    }
    case ElongationKind::kPolynomial: {
      const double L = loaded_length(cable, kinematic_length);
      const ElongationDerivatives d0 = cable_elongation_derivatives(cable, L, 0.0);
      if (!(stretch > d0.elongation)) return t;  // slack
      // g(F) = dL(L, F) - stretch is increasing in F where the surface is valid: Newton, kept
      // inside a bracket [lo, hi] and falling back to bisection.
      double lo = 0.0;
      double hi = std::numeric_limits<double>::infinity();
      double F = cable.ea > 0.0 ? cable.ea * (stretch - d0.elongation) / L : 1.0;
      if (!(F > 0.0) || !std::isfinite(F)) F = 1.0;
      ElongationDerivatives d;
      for (int it = 0; it < 200; ++it) {
        d = cable_elongation_derivatives(cable, L, F);
        const double g = d.elongation - stretch;
        if (g > 0.0) {
          hi = F;
        } else {
          lo = F;
        }
        double next = d.d_tension > 0.0 ? F - g / d.d_tension : -1.0;
        if (!(next > lo && next < hi)) next = std::isfinite(hi) ? 0.5 * (lo + hi) : 2.0 * F + 1.0;
        const bool done = std::abs(next - F) <= 1e-13 * (1.0 + F);
        F = next;
        if (done) break;
        if (F > 1e12) break;
      }
      d = cable_elongation_derivatives(cable, L, F);
      if (!(d.d_tension > 0.0) || !(std::abs(d.elongation - stretch) <= 1e-9 * (1.0 + stretch))) {
        t.ok = false;
        return t;
      }
      t.tension = F;
      t.stiffness = (1.0 - d.d_length) / d.d_tension;
      t.taut = true;
      return t;
    }
  }
  t.ok = false;
  return t;
}

ElastostaticData::ElastostaticData(int num_cables)
    : kinematics(num_cables),
      trial(num_cables),
      tensions(Eigen::VectorXd::Zero(num_cables)),
      stiffnesses(Eigen::VectorXd::Zero(num_cables)),
      trial_tensions(Eigen::VectorXd::Zero(num_cables)),
      trial_stiffnesses(Eigen::VectorXd::Zero(num_cables)),
      fk(num_cables) {}

bool elastostatic_wrench(const RobotModel& model, const Eigen::Vector3d& position,
                         const Eigen::Matrix3d& rotation,
                         const Eigen::Ref<const Eigen::VectorXd>& length_commands,
                         const Wrench& external_wrench, ElastostaticData& data, Wrench& wrench,
                         Matrix6d* stiffness) {
  return evaluate(model, position, rotation, length_commands, external_wrench, data.kinematics,
                  data.tensions, data.stiffnesses, wrench, stiffness, nullptr);
}

ElastostaticSummary solve_elastostatics(const RobotModel& model,
                                        const Eigen::Ref<const Eigen::VectorXd>& length_commands,
                                        const ElastostaticOptions& options,
                                        ElastostaticData& data) {
  ElastostaticSummary summary;
  const int m = model.num_cables();
  if (length_commands.size() != m || data.tensions.size() != m ||
      static_cast<int>(model.cables.size()) != m) {
    summary.status = Status::error(ErrorCode::kInvalidArgument,
                                   "elastostatics: %d length commands and data for %d cables, "
                                   "the model has %d cables",
                                   static_cast<int>(length_commands.size()),
                                   static_cast<int>(data.tensions.size()), m);
    return summary;
  }
  if (!length_commands.allFinite() || !options.external_wrench.allFinite()) {
    summary.status = Status(ErrorCode::kInvalidArgument,
                            "elastostatics: non-finite length command or external wrench");
    return summary;
  }
  if (options.max_iterations < 1 || !(options.wrench_tolerance > 0.0) ||
      !(options.initial_lambda > 0.0) || options.uniqueness_starts < 0) {
    summary.status = Status(ErrorCode::kInvalidArgument, "elastostatics: bad options");
    return summary;
  }
  for (int i = 0; i < m; ++i) {
    if (model.cables[static_cast<std::size_t>(i)].elongation == ElongationKind::kRigid) {
      summary.status = Status::error(ErrorCode::kInvalidArgument,
                                     "cables[%d].elongation: a rigid cable has no elasto-static "
                                     "equilibrium (use hooke or polynomial)",
                                     i);
      return summary;
    }
  }
  const double rho = model.platform_radius();

  // Start pose.
  Pose start = model.home;
  if (options.initial_pose.has_value()) {
    start = *options.initial_pose;
  } else if (m >= 6) {
    ForwardKinematicsOptions fk_options;
    fk_options.max_residual = std::numeric_limits<double>::infinity();
    const ForwardKinematicsSummary fk =
        forward_kinematics(model, length_commands, fk_options, data.fk);
    if (fk.pose.position.allFinite() && fk.pose.rpy.allFinite() &&
        fk.termination != ForwardKinematicsTermination::kInvalidInput &&
        fk.termination != ForwardKinematicsTermination::kDegenerateGeometry &&
        fk.termination != ForwardKinematicsTermination::kNumericalFailure) {
      start = fk.pose;
    }
  }
  Eigen::Vector3d r = start.position;
  Eigen::Matrix3d R = rotation_from_rpy<double>(start.rpy);
  CoreResult core = newton(model, length_commands, options, rho, r, R, data);
  if (core.termination == ElastostaticTermination::kNoConvergence) {
    // Stalled off an equilibrium: descend the potential energy from the start pose, then
    // polish with Newton from where the descent ended.
    Eigen::Vector3d r_d = start.position;
    Eigen::Matrix3d R_d = rotation_from_rpy<double>(start.rpy);
    const CoreResult descent = energy_descent(model, length_commands, options, rho, r_d, R_d, data);
    if (descent.termination == ElastostaticTermination::kConverged ||
        descent.termination == ElastostaticTermination::kNoConvergence) {
      Eigen::Vector3d r_n = r_d;
      Eigen::Matrix3d R_n = R_d;
      const CoreResult polished = newton(model, length_commands, options, rho, r_n, R_n, data);
      if (polished.termination == ElastostaticTermination::kConverged) {
        core = polished;
        core.iterations += descent.iterations;
        r = r_n;
        R = R_n;
      }
    }
    if (core.termination != ElastostaticTermination::kConverged) {
      // Leave the data describing the best pose of the first attempt.
      Wrench w_best;
      Matrix6d K_best;
      evaluate(model, r, R, length_commands, options.external_wrench, data.kinematics,
               data.tensions, data.stiffnesses, w_best, &K_best, nullptr);
      data.wrench = w_best;
      data.stiffness = K_best;
    }
  }
  summary.iterations = core.iterations;
  summary.termination = core.termination;
  summary.max_wrench_residual = core.max_residual;
  summary.rotation = R;
  summary.pose = Pose{r, rpy_from_rotation(R)};
  if (core.termination == ElastostaticTermination::kDegenerateGeometry) {
    summary.status =
        Status::error(ErrorCode::kInvalidArgument,
                      "elastostatics: cable %d is degenerate at the start pose", core.bad_cable);
    return summary;
  }
  if (core.termination == ElastostaticTermination::kNumericalFailure) {
    summary.status = Status::error(ErrorCode::kNumericalFailure,
                                   "elastostatics: the tension law of cable %d failed (polynomial "
                                   "surface not increasing in the tension?) or values are not "
                                   "finite",
                                   core.bad_cable);
    return summary;
  }
  for (int i = 0; i < m; ++i) summary.taut_cables += data.tensions(i) > 0.0 ? 1 : 0;
  if (core.termination != ElastostaticTermination::kConverged) {
    summary.status = Status::error(
        ErrorCode::kNumericalFailure,
        "elastostatics: no equilibrium found in %d iterations (largest wrench residual %.3g N, "
        "%d of %d cables taut): the commands may not hold the platform",
        core.iterations, core.max_residual, summary.taut_cables, m);
    return summary;
  }

  // Stiffness at the solution: analytic for point anchors, central differences with pulleys.
  const Eigen::Vector3d r_star = r;
  const Eigen::Matrix3d R_star = R;
  bool any_pulley = false;
  for (const PulleyModel& p : model.pulleys) any_pulley = any_pulley || p.enabled();
  Matrix6d K = data.stiffness;
  if (any_pulley) {
    for (int j = 0; j < 6; ++j) {
      const double h = j < 3 ? 1e-7 * std::max(1.0, rho) : 1e-7;
      Wrench plus, minus;
      Wrench dx = Wrench::Zero();
      dx(j) = h;
      bool ok = evaluate(model, r_star + dx.head<3>(), rotation_exp(dx.tail<3>()) * R_star,
                         length_commands, options.external_wrench, data.trial, data.trial_tensions,
                         data.trial_stiffnesses, plus, nullptr, nullptr);
      ok = ok && evaluate(model, r_star - dx.head<3>(), rotation_exp(-dx.tail<3>()) * R_star,
                          length_commands, options.external_wrench, data.trial, data.trial_tensions,
                          data.trial_stiffnesses, minus, nullptr, nullptr);
      if (ok) K.col(j) = (plus - minus) / (2.0 * h);
    }
  }
  Eigen::Matrix<double, 6, 1> D;
  D << 1.0, 1.0, 1.0, 1.0 / rho, 1.0 / rho, 1.0 / rho;
  const Matrix6d Ks = D.asDiagonal() * K * D.asDiagonal();
  const Matrix6d S = -0.5 * (Ks + Ks.transpose());
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(S, Eigen::EigenvaluesOnly);
  summary.stability_margin = eig.eigenvalues()(0);
  summary.stable = summary.stability_margin > 1e-12 * eig.eigenvalues().cwiseAbs().maxCoeff();

  // Uniqueness: restart from displaced poses.
  if (options.uniqueness_starts > 0) {
    summary.uniqueness = Uniqueness::kUniqueAmongStarts;
    for (int k = 0; k < options.uniqueness_starts; ++k) {
      const int axis = k % 6;
      const double sign = (k / 6) % 2 == 0 ? 1.0 : -1.0;
      const double size = options.uniqueness_spread * (1.0 + static_cast<double>(k / 12));
      Wrench dx = Wrench::Zero();
      dx(axis) = sign * (axis < 3 ? size : size / rho);
      Eigen::Vector3d r_k = r_star + dx.head<3>();
      Eigen::Matrix3d R_k = rotation_exp(dx.tail<3>()) * R_star;
      const CoreResult alt = newton(model, length_commands, options, rho, r_k, R_k, data);
      if (alt.termination != ElastostaticTermination::kConverged) continue;
      ++summary.starts_converged;
      if (pose_distance(r_k, R_k, r_star, R_star, rho) > options.same_pose_tolerance &&
          !summary.alternative_pose.has_value()) {
        summary.uniqueness = Uniqueness::kMultiple;
        summary.alternative_pose = Pose{r_k, rpy_from_rotation(R_k)};
      }
    }
  }
  // Leave the data describing the solution.
  Wrench w;
  Matrix6d K_analytic;
  evaluate(model, r_star, R_star, length_commands, options.external_wrench, data.kinematics,
           data.tensions, data.stiffnesses, w, &K_analytic, nullptr);
  data.wrench = w;
  data.stiffness = K;
  summary.status = Status::success();
  return summary;
}

}  // namespace cdpr
