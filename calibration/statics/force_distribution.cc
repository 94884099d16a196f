#include "cdpr/calibration/force_distribution.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <limits>

namespace cdpr {
namespace {

constexpr int kMaxNull = kMaxCables - 6;  // largest null-space dimension
constexpr int kMaxConstraints = 2 * kMaxCables;

using Matrix6d = Eigen::Matrix<double, 6, 6>;
using NullVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxNull, 1>;
using NullMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxNull, kMaxNull>;

void finish(ForceDistributionResult& out,
            const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& At, const Wrench6& w,
            const Eigen::Ref<const Eigen::VectorXd>& f_min,
            const Eigen::Ref<const Eigen::VectorXd>& f_max, double tol) {
  out.balance_residual = (At * out.tensions + w).cwiseAbs().maxCoeff();
  out.cables_at_limits = 0;
  for (int i = 0; i < static_cast<int>(out.tensions.size()); ++i) {
    if (std::abs(out.tensions(i) - f_min(i)) <= tol ||
        std::abs(out.tensions(i) - f_max(i)) <= tol) {
      ++out.cables_at_limits;
    }
  }
}

// Largest violation of the limits and the cable that has it (-1 if none beyond tol).
int worst_violation(const CableVector& f, const Eigen::Ref<const Eigen::VectorXd>& f_min,
                    const Eigen::Ref<const Eigen::VectorXd>& f_max, const bool* fixed, double tol,
                    double* amount) {
  int worst = -1;
  double largest = tol;
  for (int i = 0; i < static_cast<int>(f.size()); ++i) {
    if (fixed != nullptr && fixed[i]) continue;
    const double v = std::max(f_min(i) - f(i), f(i) - f_max(i));
    if (v > largest) {
      largest = v;
      worst = i;
    }
  }
  if (amount != nullptr) *amount = largest;
  return worst;
}

ForceDistributionResult closed_form(
    const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& At, const Wrench6& w,
    const Eigen::Ref<const Eigen::VectorXd>& f_min, const Eigen::Ref<const Eigen::VectorXd>& f_max,
    const CableVector& f_ref, const ForceDistributionOptions& options) {
  ForceDistributionResult out;
  const int m = static_cast<int>(At.cols());
  bool fixed[kMaxCables] = {};
  out.tensions = f_ref;
  for (out.iterations = 1; out.iterations <= std::min(options.max_iterations, m + 1);
       ++out.iterations) {
    // Wrench left for the free cables, and their least-norm correction from f_ref.
    Wrench6 rest = w;
    Matrix6d AAt = Matrix6d::Zero();
    Wrench6 rhs = Wrench6::Zero();
    int free_count = 0;
    for (int i = 0; i < m; ++i) {
      const Wrench6 a = At.col(i);
      if (fixed[i]) {
        rest += a * out.tensions(i);
      } else {
        AAt.noalias() += a * a.transpose();
        rhs += a * f_ref(i);
        ++free_count;
      }
    }
    rhs += rest;
    const Eigen::LDLT<Matrix6d> ldlt(AAt);
    const double dmax = ldlt.vectorD().cwiseAbs().maxCoeff();
    if (free_count < 6 || ldlt.info() != Eigen::Success ||
        !(ldlt.vectorD().minCoeff() > options.rank_tolerance * dmax)) {
      out.outcome = out.iterations == 1 ? ForceDistributionOutcome::kDegenerate
                                        : ForceDistributionOutcome::kNotFound;
      out.status = Status::error(
          out.iterations == 1 ? ErrorCode::kNumericalFailure : ErrorCode::kOutOfRange,
          out.iterations == 1
              ? "force distribution: the structure matrix has rank < 6 at this pose"
              : "force distribution (closed form): gave up after fixing %d cables at their limits",
          out.iterations - 1);
      return out;
    }
    const Wrench6 mult = ldlt.solve(rhs);
    for (int i = 0; i < m; ++i) {
      if (!fixed[i]) out.tensions(i) = f_ref(i) - At.col(i).dot(mult);
    }
    const int worst =
        worst_violation(out.tensions, f_min, f_max, fixed, options.feasibility_tolerance, nullptr);
    if (worst < 0) {
      out.outcome = ForceDistributionOutcome::kFeasible;
      out.status = Status::success();
      return out;
    }
    // Fix the worst offender at the limit it violates and recompute the others.
    out.tensions(worst) = out.tensions(worst) < f_min(worst) ? f_min(worst) : f_max(worst);
    fixed[worst] = true;
  }
  out.outcome = ForceDistributionOutcome::kNotFound;
  out.status =
      Status(ErrorCode::kOutOfRange, "force distribution (closed form): no iterations left");
  return out;
}

// min 1/2 |x|^2 subject to C x >= d (rows of C are the constraint normals), dual active set
// (Goldfarb & Idnani 1983) with the identity Hessian. Returns false when infeasible.
bool project_origin_onto_polytope(
    const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxConstraints, kMaxNull>& C,
    const Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxConstraints, 1>& d, double tol,
    int max_iterations, NullVector& x, int* iterations) {
  const int n = static_cast<int>(C.cols());
  const int nc = static_cast<int>(C.rows());
  x.setZero(n);
  int active[kMaxNull];
  double u[kMaxNull + 1];
  int q = 0;
  *iterations = 0;
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxNull, kMaxNull> N(n, 0);
  while (*iterations < max_iterations) {
    ++*iterations;
    // Most violated constraint.
    int p = -1;
    double worst = -tol;
    for (int j = 0; j < nc; ++j) {
      const double s = C.row(j).dot(x) - d(j);
      if (s < worst) {
        worst = s;
        p = j;
      }
    }
    if (p < 0) return true;  // optimal
    const NullVector np = C.row(p).transpose();
    u[q] = 0.0;  // multiplier of p
    for (;;) {
      // Dual direction r = (N^T N)^-1 N^T np, primal direction z = np - N r.
      NullVector z = np;
      Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxNull, 1> r(q);
      if (q > 0) {
        N.resize(n, q);
        for (int k = 0; k < q; ++k) N.col(k) = C.row(active[k]).transpose();
        const NullMatrix G = N.transpose() * N;
        r = G.ldlt().solve(N.transpose() * np);
        z.noalias() -= N * r;
      }
      // Partial step: the largest step keeping the active multipliers >= 0.
      double t1 = std::numeric_limits<double>::infinity();
      int drop = -1;
      for (int k = 0; k < q; ++k) {
        if (r(k) > 0.0 && u[k] / r(k) < t1) {
          t1 = u[k] / r(k);
          drop = k;
        }
      }
      // Full step: makes constraint p active.
      const double zz = z.dot(np);
      const double s_p = np.dot(x) - d(p);
      const double t2 =
          zz > 1e-14 * np.squaredNorm() ? -s_p / zz : std::numeric_limits<double>::infinity();
      const double t = std::min(t1, t2);
      if (!std::isfinite(t)) return false;  // constraint p cannot be satisfied: infeasible
      x += t * z;
      for (int k = 0; k < q; ++k) u[k] -= t * r(k);
      u[q] += t;
      if (t2 <= t1) {
        active[q] = p;
        ++q;
        break;
      }
      // Drop constraint `drop` and try again with p.
      for (int k = drop; k + 1 <= q; ++k) {
        if (k + 1 < q) active[k] = active[k + 1];
        u[k] = u[k + 1];
      }
      --q;
      if (++*iterations >= max_iterations) return false;
    }
    if (q > n) return false;  // cannot happen for independent constraints
  }
  return false;
}

ForceDistributionResult quadratic_program(const StructureFactor& factor, const Wrench6& w,
                                          const Eigen::Ref<const Eigen::VectorXd>& f_min,
                                          const Eigen::Ref<const Eigen::VectorXd>& f_max,
                                          const CableVector& f_ref,
                                          const ForceDistributionOptions& options) {
  ForceDistributionResult out;
  const int m = factor.num_cables();
  if (!factor.valid()) {
    out.outcome = ForceDistributionOutcome::kDegenerate;
    out.status = Status::error(ErrorCode::kNumericalFailure,
                               "force distribution: the structure matrix has rank %d < 6 at this "
                               "pose",
                               factor.rank);
    out.tensions = f_ref;
    return out;
  }
  // Particular solution closest to f_ref: f_p = f_ref - Q1 (Q1^T f_ref + R^-T P^T w).
  const StructureFactor::CableMatrix& Q = factor.q;
  const Wrench6 pw = factor.permutation.transpose() * w;
  const Wrench6 y = factor.r.transpose().triangularView<Eigen::Lower>().solve(pw);
  const Wrench6 q1f = Q.leftCols<6>().transpose() * f_ref;
  const CableVector f_p = f_ref - Q.leftCols<6>() * (q1f + y);
  const int r = m - 6;
  if (r == 0) {
    out.tensions = f_p;
    const int worst =
        worst_violation(f_p, f_min, f_max, nullptr, options.feasibility_tolerance, nullptr);
    out.iterations = 1;
    out.outcome =
        worst < 0 ? ForceDistributionOutcome::kFeasible : ForceDistributionOutcome::kInfeasible;
    out.status = worst < 0 ? Status::success()
                           : Status::error(ErrorCode::kOutOfRange,
                                           "force distribution: the only balancing tensions put "
                                           "cable %d outside its limits",
                                           worst);
    return out;
  }
  // Constraints on lambda: N_i lambda >= f_min_i - f_p_i and -N_i lambda >= f_p_i - f_max_i.
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxConstraints, kMaxNull> C(2 * m, r);
  Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxConstraints, 1> d(2 * m);
  for (int i = 0; i < m; ++i) {
    C.row(2 * i) = Q.row(i).tail(r);
    d(2 * i) = f_min(i) - f_p(i);
    C.row(2 * i + 1) = -Q.row(i).tail(r);
    d(2 * i + 1) = f_p(i) - f_max(i);
  }
  NullVector lambda(r);
  const bool ok = project_origin_onto_polytope(C, d, options.feasibility_tolerance,
                                               options.max_iterations, lambda, &out.iterations);
  out.tensions = f_p + Q.rightCols(r) * lambda;
  const int worst =
      worst_violation(out.tensions, f_min, f_max, nullptr, options.feasibility_tolerance, nullptr);
  if (ok && worst < 0) {
    out.outcome = ForceDistributionOutcome::kFeasible;
    out.status = Status::success();
  } else if (!ok && out.iterations >= options.max_iterations) {
    out.outcome = ForceDistributionOutcome::kNotFound;
    out.status = Status::error(ErrorCode::kNumericalFailure,
                               "force distribution (QP): no solution in %d active-set steps",
                               out.iterations);
  } else {
    out.outcome = ForceDistributionOutcome::kInfeasible;
    out.status = Status(ErrorCode::kOutOfRange,
                        "force distribution: no tensions within the cable limits balance the "
                        "wrench (the pose is outside the wrench-feasible workspace)");
  }
  return out;
}

// The checks every distribute_forces overload makes; false: `out` says why. Else the reference
// tensions and the total wrench.
bool valid_input(const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& structure_matrix,
                 const Wrench6& wrench, const Eigen::Ref<const Eigen::VectorXd>& f_min,
                 const Eigen::Ref<const Eigen::VectorXd>& f_max,
                 const ForceDistributionOptions& options, ForceDistributionResult& out,
                 CableVector& f_ref, Wrench6& w) {
  const int m = static_cast<int>(structure_matrix.cols());
  if (m < 1 || m > kMaxCables || f_min.size() != m || f_max.size() != m) {
    out.status =
        Status::error(ErrorCode::kInvalidArgument,
                      "force distribution: %d cables (at most %d) with %d and %d limits", m,
                      kMaxCables, static_cast<int>(f_min.size()), static_cast<int>(f_max.size()));
    return false;
  }
  w = wrench + options.external_wrench;
  if (!structure_matrix.allFinite() || !w.allFinite() || !f_min.allFinite() || !f_max.allFinite() ||
      (f_min.array() > f_max.array()).any() ||
      (options.reference_tension.has_value() && !std::isfinite(*options.reference_tension)) ||
      options.max_iterations < 1) {
    out.status = Status(ErrorCode::kInvalidArgument,
                        "force distribution: non-finite input, f_min > f_max or bad options");
    return false;
  }
  f_ref.resize(m);
  for (int i = 0; i < m; ++i) {
    f_ref(i) = options.reference_tension.has_value() ? *options.reference_tension
                                                     : 0.5 * (f_min(i) + f_max(i));
  }
  return true;
}

// Rank, Q, R and the column permutation of a column-pivoted QR of A (m x 6) into `f`.
template <typename QMatrix, typename Qr>
bool take_factors(const Qr& qr, int m, double rank_tolerance, StructureFactor& f) {
  const double r00 = std::abs(qr.matrixQR()(0, 0));
  f.rank = 0;
  for (int k = 0; k < std::min(6, m); ++k) {
    f.rank += std::abs(qr.matrixQR()(k, k)) > rank_tolerance * r00;
  }
  if (f.rank < 6 || !(r00 > 0.0)) {
    f.status = StructureFactor::Factored::kRankDeficient;
    return false;
  }
  QMatrix q = QMatrix::Identity(m, m);  // formed at the QR's own (fixed or capped) size
  q.applyOnTheLeft(qr.householderQ());
  f.q = q;
  f.r = qr.matrixQR().template topRows<6>().template triangularView<Eigen::Upper>();
  f.permutation = qr.colsPermutation();
  f.status = StructureFactor::Factored::kFullRank;
  return true;
}

}  // namespace

const char* to_string(ForceDistributionOutcome outcome) {
  switch (outcome) {
    case ForceDistributionOutcome::kFeasible:
      return "feasible";
    case ForceDistributionOutcome::kInfeasible:
      return "infeasible";
    case ForceDistributionOutcome::kNotFound:
      return "not found";
    case ForceDistributionOutcome::kDegenerate:
      return "degenerate";
    case ForceDistributionOutcome::kInvalidInput:
      return "invalid input";
  }
  return "unknown";
}

Wrench6 gravity_wrench(const RobotModel& model, const Eigen::Matrix3d& rotation) {
  const Eigen::Vector3d G(0.0, 0.0, -model.platform.mass * model.gravity);
  Wrench6 w;
  w << G, (rotation * model.platform.center_of_mass).cross(G);
  return w;
}

bool StructureFactor::compute(
    const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& structure_matrix,
    double rank_tolerance) {
  rank = 0;
  const int m = static_cast<int>(structure_matrix.cols());
  if (m < 1 || m > kMaxCables) {
    status = Factored::kBadInput;
    structure.resize(6, 0);
    return false;
  }
  structure = structure_matrix;
  if (!structure.allFinite()) {
    status = Factored::kBadInput;
    return false;
  }
  // Eight cables (the common over-constrained robot) through Eigen's fixed-size QR: the same
  // algorithm, several times faster than the dynamic-size one at this size.
  if (m == 8) {
    using Fixed = Eigen::Matrix<double, 8, 6>;
    const Eigen::ColPivHouseholderQR<Fixed> qr(Fixed(structure.transpose()));
    return take_factors<Eigen::Matrix<double, 8, 8>>(qr, m, rank_tolerance, *this);
  }
  using Capped = Eigen::Matrix<double, Eigen::Dynamic, 6, 0, kMaxCables, 6>;
  const Eigen::ColPivHouseholderQR<Capped> qr(Capped(structure.transpose()));
  return take_factors<StructureFactor::CableMatrix>(qr, m, rank_tolerance, *this);
}

ForceDistributionResult distribute_forces(const StructureFactor& factor, const Wrench6& wrench,
                                          const Eigen::Ref<const Eigen::VectorXd>& f_min,
                                          const Eigen::Ref<const Eigen::VectorXd>& f_max,
                                          const ForceDistributionOptions& options) {
  CableVector f_ref;
  Wrench6 w;
  ForceDistributionResult out;
  if (!valid_input(factor.structure, wrench, f_min, f_max, options, out, f_ref, w)) return out;
  if (factor.status == StructureFactor::Factored::kNone ||
      factor.status == StructureFactor::Factored::kBadInput) {
    out.status = Status(ErrorCode::kInvalidArgument,
                        "force distribution: the structure matrix was not factored");
    return out;
  }
  out = quadratic_program(factor, w, f_min, f_max, f_ref, options);
  if (out.tensions.size() == factor.num_cables()) {
    finish(out, factor.structure, w, f_min, f_max, options.feasibility_tolerance);
  }
  return out;
}

ForceDistributionResult distribute_forces(
    const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& structure_matrix,
    const Wrench6& wrench, const Eigen::Ref<const Eigen::VectorXd>& f_min,
    const Eigen::Ref<const Eigen::VectorXd>& f_max, const ForceDistributionOptions& options) {
  CableVector f_ref;
  Wrench6 w;
  ForceDistributionResult out;
  if (!valid_input(structure_matrix, wrench, f_min, f_max, options, out, f_ref, w)) return out;
  if (options.method == ForceDistributionMethod::kClosedForm) {
    out = closed_form(structure_matrix, w, f_min, f_max, f_ref, options);
  } else {
    StructureFactor factor;
    factor.compute(structure_matrix, options.rank_tolerance);
    out = quadratic_program(factor, w, f_min, f_max, f_ref, options);
  }
  if (out.tensions.size() == structure_matrix.cols()) {
    finish(out, structure_matrix, w, f_min, f_max, options.feasibility_tolerance);
  }
  return out;
}

ForceDistributionResult distribute_forces(const RobotModel& model, const Pose& pose,
                                          const ForceDistributionOptions& options,
                                          ForceDistributionData& data) {
  const int m = model.num_cables();
  if (m > kMaxCables || static_cast<int>(model.cables.size()) != m ||
      data.kinematics.lengths.size() != m) {
    ForceDistributionResult out;
    out.status = Status::error(ErrorCode::kInvalidArgument,
                               "force distribution: model with %d cables (at most %d) or scratch "
                               "data of another size",
                               m, kMaxCables);
    return out;
  }
  if (!inverse_kinematics(model, pose, data.kinematics)) {
    ForceDistributionResult out;
    out.outcome = ForceDistributionOutcome::kDegenerate;
    out.status = Status::error(ErrorCode::kInvalidArgument,
                               "force distribution: cable %d is degenerate at this pose",
                               data.kinematics.invalid_cable);
    return out;
  }
  CableVector f_min(m), f_max(m);
  for (int i = 0; i < m; ++i) {
    f_min(i) = model.cables[static_cast<std::size_t>(i)].f_min;
    f_max(i) = model.cables[static_cast<std::size_t>(i)].f_max;
  }
  return distribute_forces(data.kinematics.structure_matrix,
                           gravity_wrench(model, data.kinematics.rotation), f_min, f_max, options);
}

double default_reference_tension(const RobotModel& model) {
  double lo = 0.0, hi = std::numeric_limits<double>::infinity();
  for (const CableModel& c : model.cables) {
    lo = std::max(lo, c.f_min);
    hi = std::min(hi, c.f_max);
  }
  return std::min(0.5 * (lo + hi), 4.0 * std::max(lo, 1.0));
}

}  // namespace cdpr
