#include "cdpr/calibration/force_distribution.hpp"

#include <Eigen/Cholesky>
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

// Solves G r = b for the q x q Gram matrix G of the active normals (independent, so G is
// positive definite): Cholesky in place, Eigen's LDLT should rounding make it fail.
void solve_gram(double (&g)[kMaxNull][kMaxNull], const double* b, int q, double* r) {
  double l[kMaxNull][kMaxNull];
  bool ok = true;
  for (int a = 0; a < q && ok; ++a) {
    for (int c = 0; c <= a; ++c) {
      double sum = g[a][c];
      for (int e = 0; e < c; ++e) sum -= l[a][e] * l[c][e];
      if (a == c) {
        ok = sum > 0.0;
        l[a][a] = ok ? std::sqrt(sum) : 0.0;
      } else {
        l[a][c] = sum / l[c][c];
      }
    }
  }
  if (!ok) {
    NullMatrix G(q, q);
    NullVector rhs(q);
    for (int a = 0; a < q; ++a) {
      rhs(a) = b[a];
      for (int c = 0; c < q; ++c) G(a, c) = g[a][c];
    }
    const NullVector x = G.ldlt().solve(rhs);
    for (int a = 0; a < q; ++a) r[a] = x(a);
    return;
  }
  for (int a = 0; a < q; ++a) {
    double sum = b[a];
    for (int c = 0; c < a; ++c) sum -= l[a][c] * r[c];
    r[a] = sum / l[a][a];
  }
  for (int a = q - 1; a >= 0; --a) {
    double sum = r[a];
    for (int c = a + 1; c < q; ++c) sum -= l[c][a] * r[c];
    r[a] = sum / l[a][a];
  }
}

// min 1/2 |x|^2 subject to C x >= d, dual active set (Goldfarb & Idnani 1983) with the identity
// Hessian. The 2m rows of C are the null basis' rows N_i (lower limit of cable i, row 2i) and
// -N_i (upper limit, row 2i + 1). Returns false when infeasible. Fixed-capacity arrays: the
// active set has at most n = m - 6 normals.
bool project_origin_onto_polytope(const StructureFactor::NullMatrix& N, const double* d, double tol,
                                  int max_iterations, double* x, int* iterations) {
  const int n = static_cast<int>(N.cols());
  const int nc = 2 * static_cast<int>(N.rows());
  const auto normal = [&](int j, double* out) {
    const double sign = (j & 1) != 0 ? -1.0 : 1.0;
    for (int a = 0; a < n; ++a) out[a] = sign * N(j >> 1, a);
  };
  const auto dot = [n](const double* p, const double* q) {
    double s = 0.0;
    for (int a = 0; a < n; ++a) s += p[a] * q[a];
    return s;
  };
  for (int a = 0; a < n; ++a) x[a] = 0.0;
  double act[kMaxNull][kMaxNull];  // the active constraints' normals
  double u[kMaxNull + 1];
  int q = 0;
  *iterations = 0;
  while (*iterations < max_iterations) {
    ++*iterations;
    // Most violated constraint.
    int p = -1;
    double worst = -tol;
    for (int j = 0; j < nc; j += 2) {
      double nx = 0.0;
      for (int a = 0; a < n; ++a) nx += N(j >> 1, a) * x[a];
      if (nx - d[j] < worst) {
        worst = nx - d[j];
        p = j;
      }
      if (-nx - d[j + 1] < worst) {
        worst = -nx - d[j + 1];
        p = j + 1;
      }
    }
    if (p < 0) return true;  // optimal
    double np[kMaxNull];
    normal(p, np);
    u[q] = 0.0;  // multiplier of p
    for (;;) {
      // Dual direction r = (N^T N)^-1 N^T np, primal direction z = np - N r (N: active normals).
      double z[kMaxNull], r[kMaxNull];
      for (int a = 0; a < n; ++a) z[a] = np[a];
      if (q > 0) {
        double g[kMaxNull][kMaxNull], b[kMaxNull];
        for (int k = 0; k < q; ++k) {
          b[k] = dot(act[k], np);
          for (int c = 0; c <= k; ++c) g[k][c] = g[c][k] = dot(act[k], act[c]);
        }
        solve_gram(g, b, q, r);
        for (int k = 0; k < q; ++k) {
          for (int a = 0; a < n; ++a) z[a] -= act[k][a] * r[k];
        }
      }
      // Partial step: the largest step keeping the active multipliers >= 0.
      double t1 = std::numeric_limits<double>::infinity();
      int drop = -1;
      for (int k = 0; k < q; ++k) {
        if (r[k] > 0.0 && u[k] / r[k] < t1) {
          t1 = u[k] / r[k];
          drop = k;
        }
      }
      // Full step: makes constraint p active.
      const double zz = dot(z, np);
      const double s_p = dot(np, x) - d[p];
      const double t2 =
          zz > 1e-14 * dot(np, np) ? -s_p / zz : std::numeric_limits<double>::infinity();
      const double t = std::min(t1, t2);
      if (!std::isfinite(t)) return false;  // constraint p cannot be satisfied: infeasible
      for (int a = 0; a < n; ++a) x[a] += t * z[a];
      for (int k = 0; k < q; ++k) u[k] -= t * r[k];
      u[q] += t;
      if (t2 <= t1) {
        for (int a = 0; a < n; ++a) act[q][a] = np[a];
        ++q;
        break;
      }
      // Drop constraint `drop` and try again with p.
      for (int k = drop; k + 1 <= q; ++k) {
        if (k + 1 < q) {
          for (int a = 0; a < n; ++a) act[k][a] = act[k + 1][a];
        }
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
  // Particular solution closest to f_ref (the least-norm correction).
  const CableVector f_p = factor.particular(f_ref, w);
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
  const StructureFactor::NullMatrix& N = factor.null_basis();
  double d[kMaxConstraints];
  for (int i = 0; i < m; ++i) {
    d[2 * i] = f_min(i) - f_p(i);
    d[2 * i + 1] = f_p(i) - f_max(i);
  }
  double lambda[kMaxNull];
  const bool ok = project_origin_onto_polytope(N, d, options.feasibility_tolerance,
                                               options.max_iterations, lambda, &out.iterations);
  out.tensions = f_p;
  for (int j = 0; j < r; ++j) out.tensions += lambda[j] * N.col(j);
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
