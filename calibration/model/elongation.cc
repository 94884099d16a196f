#include "cdpr/calibration/elongation.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>

namespace cdpr {

namespace {

// Value and partial derivatives of the polynomial in the scaled variables.
struct PolyEval {
  double value = 0.0;
  double d_s = 0.0;
  double d_t = 0.0;
};

PolyEval evaluate_scaled(const PolynomialSurface& surface, double s, double t) {
  const int n = surface.order;
  std::array<double, kMaxPolynomialOrder + 1> sp{};
  std::array<double, kMaxPolynomialOrder + 1> tp{};
  sp[0] = 1.0;
  tp[0] = 1.0;
  for (int k = 1; k <= n; ++k) {
    sp[static_cast<std::size_t>(k)] = sp[static_cast<std::size_t>(k - 1)] * s;
    tp[static_cast<std::size_t>(k)] = tp[static_cast<std::size_t>(k - 1)] * t;
  }
  PolyEval e;
  std::size_t c = 0;
  for (int degree = 0; degree <= n; ++degree) {
    for (int j = 0; j <= degree; ++j, ++c) {
      const int i = degree - j;
      const double coef = surface.coefficients[c];
      const double si = sp[static_cast<std::size_t>(i)];
      const double tj = tp[static_cast<std::size_t>(j)];
      e.value += coef * si * tj;
      if (i > 0) e.d_s += coef * i * sp[static_cast<std::size_t>(i - 1)] * tj;
      if (j > 0) e.d_t += coef * j * si * tp[static_cast<std::size_t>(j - 1)];
    }
  }
  return e;
}

// Row `row` of the graded monomial basis at (s, t), all columns of `order`.
void fill_basis_row(int order, double s, double t, Eigen::MatrixXd& design, Eigen::Index row) {
  Eigen::Index c = 0;
  for (int degree = 0; degree <= order; ++degree) {
    for (int j = 0; j <= degree; ++j, ++c) {
      design(row, c) = std::pow(s, degree - j) * std::pow(t, j);
    }
  }
}

struct LstsqResult {
  bool identifiable = false;
  double condition_number = std::numeric_limits<double>::infinity();
  Eigen::VectorXd coefficients;
};

LstsqResult solve_least_squares(const Eigen::MatrixXd& a, const Eigen::VectorXd& b,
                                double rank_tolerance) {
  LstsqResult r;
  if (a.rows() < a.cols()) return r;
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Eigen::VectorXd& sv = svd.singularValues();
  const double smax = sv(0);
  const double smin = sv(sv.size() - 1);
  if (!(smax > 0.0) || smin < rank_tolerance * smax) return r;
  r.identifiable = true;
  r.condition_number = smax / smin;
  r.coefficients = svd.solve(b);
  return r;
}

}  // namespace

ElongationDerivatives cable_elongation_derivatives(const CableModel& cable, double loaded_length,
                                                   double tension) {
  ElongationDerivatives d;
  switch (cable.elongation) {
    case ElongationKind::kRigid:
      return d;
    case ElongationKind::kHooke: {
      const double den = cable.ea + tension;
      d.elongation = tension * loaded_length / den;
      d.d_length = tension / den;
      d.d_tension = loaded_length * cable.ea / (den * den);
      return d;
    }
    case ElongationKind::kPolynomial: {
      const PolynomialSurface& p = cable.polynomial;
      const double s = (loaded_length - p.length_center) / p.length_scale;
      const double t = (tension - p.tension_center) / p.tension_scale;
      const PolyEval e = evaluate_scaled(p, s, t);
      d.elongation = e.value;
      d.d_length = e.d_s / p.length_scale;
      d.d_tension = e.d_t / p.tension_scale;
      return d;
    }
  }
  return d;
}

Result<double> loaded_length_from_unstretched(const CableModel& cable, double unstretched_length,
                                              double tension) {
  switch (cable.elongation) {
    case ElongationKind::kRigid:
      return unstretched_length;
    case ElongationKind::kHooke:
      if (!(cable.ea + tension > 0.0)) {
        return Status::error(ErrorCode::kNumericalFailure,
                             "Hooke elongation: tension %.6g N <= -EA (EA %.6g N)", tension,
                             cable.ea);
      }
      return unstretched_length * (1.0 + tension / cable.ea);
    case ElongationKind::kPolynomial:
      break;
  }
  // Newton on g(L) = L - dL(L, F) - L0, started at L0 + dL(L0, F).
  double length = unstretched_length + cable_elongation<double>(cable, unstretched_length, tension);
  for (int it = 0; it < 50; ++it) {
    const ElongationDerivatives d = cable_elongation_derivatives(cable, length, tension);
    const double slope = 1.0 - d.d_length;
    if (!(slope > 0.0)) {
      return Status::error(ErrorCode::kNumericalFailure,
                           "polynomial elongation: d(L - dL)/dL = %.3g <= 0 at L = %.6g m, "
                           "F = %.6g N (outside the fitted range?)",
                           slope, length, tension);
    }
    const double g = length - d.elongation - unstretched_length;
    const double step = g / slope;
    length -= step;
    if (std::abs(step) <= 1e-13 + 4.0 * std::numeric_limits<double>::epsilon() * std::abs(length)) {
      return length;
    }
  }
  return Status::error(ErrorCode::kNumericalFailure,
                       "polynomial elongation: no loaded length found for unstretched %.6g m, "
                       "F = %.6g N in 50 Newton steps",
                       unstretched_length, tension);
}

Status validate_polynomial_surface(const PolynomialSurface& surface) {
  if (surface.order < 0 || surface.order > kMaxPolynomialOrder) {
    return Status::error(ErrorCode::kOutOfRange, "polynomial order %d outside [0, %d]",
                         surface.order, kMaxPolynomialOrder);
  }
  const int need = polynomial_surface_size(surface.order);
  if (static_cast<int>(surface.coefficients.size()) != need) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial of order %d needs %d coefficients, got %zu", surface.order,
                         need, surface.coefficients.size());
  }
  for (std::size_t c = 0; c < surface.coefficients.size(); ++c) {
    if (!std::isfinite(surface.coefficients[c])) {
      return Status::error(ErrorCode::kInvalidArgument, "polynomial coefficient %zu is not finite",
                           c);
    }
  }
  if (!(surface.length_scale > 0.0) || !std::isfinite(surface.length_scale) ||
      !(surface.tension_scale > 0.0) || !std::isfinite(surface.tension_scale) ||
      !std::isfinite(surface.length_center) || !std::isfinite(surface.tension_center)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial scaling must be finite with positive scales (length_scale "
                         "%.6g, tension_scale %.6g)",
                         surface.length_scale, surface.tension_scale);
  }
  return Status::success();
}

Result<PolynomialFitSummary> fit_polynomial_surface(std::span<const ElongationSample> samples,
                                                    const PolynomialFitOptions& options) {
  using Selection = PolynomialFitOptions::Selection;
  if (options.min_order < 0 || options.max_order > kMaxPolynomialOrder ||
      options.min_order > options.max_order) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial fit: orders %d..%d must satisfy 0 <= min <= max <= %d",
                         options.min_order, options.max_order, kMaxPolynomialOrder);
  }
  if (!(options.rank_tolerance > 0.0)) {
    return Status(ErrorCode::kInvalidArgument, "polynomial fit: rank_tolerance must be > 0");
  }
  const int n = static_cast<int>(samples.size());
  if (options.folds < 2 || options.folds > n) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial fit: %d folds for %d samples (need 2 <= folds <= samples)",
                         options.folds, n);
  }
  for (int k = 0; k < n; ++k) {
    const ElongationSample& s = samples[static_cast<std::size_t>(k)];
    if (!std::isfinite(s.length) || !std::isfinite(s.tension) || !std::isfinite(s.elongation)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "polynomial fit: sample %d is not finite (L %g, F %g, dL %g)", k,
                           s.length, s.tension, s.elongation);
    }
  }
  // Training sets have about n (K - 1) / K samples; the smallest candidate must fit in them.
  const int smallest_training = n - (n + options.folds - 1) / options.folds;
  const int min_size = polynomial_surface_size(options.min_order);
  if (smallest_training < min_size) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial fit: %d samples in %d folds leave %d per training set; order "
                         "%d needs at least %d",
                         n, options.folds, smallest_training, options.min_order, min_size);
  }
  const auto [lmin, lmax] = std::minmax_element(
      samples.begin(), samples.end(),
      [](const ElongationSample& a, const ElongationSample& b) { return a.length < b.length; });
  const auto [fmin, fmax] = std::minmax_element(
      samples.begin(), samples.end(),
      [](const ElongationSample& a, const ElongationSample& b) { return a.tension < b.tension; });
  const double l_span = lmax->length - lmin->length;
  const double f_span = fmax->tension - fmin->tension;
  if (options.max_order > 0 && !(l_span > 1e-12 * std::max(1.0, std::abs(lmax->length)))) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial fit: every sample has the same length (%.6g m); a surface "
                         "dL(L, F) needs at least two lengths",
                         lmax->length);
  }
  if (options.max_order > 0 && !(f_span > 1e-12 * std::max(1.0, std::abs(fmax->tension)))) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "polynomial fit: every sample has the same tension (%.6g N); a surface "
                         "dL(L, F) needs at least two tensions",
                         fmax->tension);
  }

  PolynomialSurface scaled;
  scaled.length_center = 0.5 * (lmax->length + lmin->length);
  scaled.length_scale = l_span > 0.0 ? 0.5 * l_span : 1.0;
  scaled.tension_center = 0.5 * (fmax->tension + fmin->tension);
  scaled.tension_scale = f_span > 0.0 ? 0.5 * f_span : 1.0;

  // Full design matrix at max_order; graded order nests, so order k uses the first columns.
  const int max_cols = polynomial_surface_size(options.max_order);
  Eigen::MatrixXd design(n, max_cols);
  Eigen::VectorXd target(n);
  for (int k = 0; k < n; ++k) {
    const ElongationSample& s = samples[static_cast<std::size_t>(k)];
    fill_basis_row(options.max_order, (s.length - scaled.length_center) / scaled.length_scale,
                   (s.tension - scaled.tension_center) / scaled.tension_scale, design, k);
    target(k) = s.elongation;
  }

  // Deterministic shuffle (Fisher-Yates on mt19937's standardised output) into folds.
  std::vector<int> fold(static_cast<std::size_t>(n));
  {
    std::vector<int> perm(static_cast<std::size_t>(n));
    std::iota(perm.begin(), perm.end(), 0);
    std::mt19937 rng(options.seed);
    for (int k = n - 1; k > 0; --k) {
      const int j = static_cast<int>(rng() % static_cast<std::uint32_t>(k + 1));
      std::swap(perm[static_cast<std::size_t>(k)], perm[static_cast<std::size_t>(j)]);
    }
    for (int k = 0; k < n; ++k) {
      fold[static_cast<std::size_t>(perm[static_cast<std::size_t>(k)])] = k % options.folds;
    }
  }

  PolynomialFitSummary summary;
  summary.num_samples = n;
  const double inf = std::numeric_limits<double>::infinity();
  for (int order = options.min_order; order <= options.max_order; ++order) {
    const int cols = polynomial_surface_size(order);
    std::vector<double> fold_rmse;
    bool identifiable = true;
    for (int f = 0; f < options.folds && identifiable; ++f) {
      const auto count_test = std::count(fold.begin(), fold.end(), f);
      const int n_test = static_cast<int>(count_test);
      const int n_train = n - n_test;
      Eigen::MatrixXd a(n_train, cols);
      Eigen::VectorXd b(n_train);
      int row = 0;
      for (int k = 0; k < n; ++k) {
        if (fold[static_cast<std::size_t>(k)] == f) continue;
        a.row(row) = design.row(k).head(cols);
        b(row) = target(k);
        ++row;
      }
      const LstsqResult fit = solve_least_squares(a, b, options.rank_tolerance);
      if (!fit.identifiable) {
        identifiable = false;
        break;
      }
      double sse = 0.0;
      for (int k = 0; k < n; ++k) {
        if (fold[static_cast<std::size_t>(k)] != f) continue;
        const double e = design.row(k).head(cols).dot(fit.coefficients) - target(k);
        sse += e * e;
      }
      fold_rmse.push_back(std::sqrt(sse / std::max(1, n_test)));
    }
    summary.orders.push_back(order);
    if (!identifiable) {
      summary.cv_rmse.push_back(inf);
      summary.cv_rmse_stderr.push_back(inf);
      continue;
    }
    const double k = static_cast<double>(fold_rmse.size());
    const double mean = std::accumulate(fold_rmse.begin(), fold_rmse.end(), 0.0) / k;
    double var = 0.0;
    for (const double r : fold_rmse) var += (r - mean) * (r - mean);
    var /= (k - 1.0);
    summary.cv_rmse.push_back(mean);
    summary.cv_rmse_stderr.push_back(std::sqrt(var / k));
  }

  std::size_t best = 0;
  for (std::size_t k = 1; k < summary.cv_rmse.size(); ++k) {
    if (summary.cv_rmse[k] < summary.cv_rmse[best]) best = k;
  }
  if (!std::isfinite(summary.cv_rmse[best])) {
    return Status::error(ErrorCode::kNumericalFailure,
                         "polynomial fit: no order in %d..%d is identifiable from the %d samples "
                         "(too few distinct lengths or tensions)",
                         options.min_order, options.max_order, n);
  }
  std::size_t chosen = best;
  if (options.selection == Selection::kOneStandardError) {
    const double threshold = summary.cv_rmse[best] + summary.cv_rmse_stderr[best];
    for (std::size_t k = 0; k < best; ++k) {
      if (summary.cv_rmse[k] <= threshold) {
        chosen = k;
        break;
      }
    }
  }
  summary.order = summary.orders[chosen];
  const int cols = polynomial_surface_size(summary.order);
  const LstsqResult fit =
      solve_least_squares(design.leftCols(cols), target, options.rank_tolerance);
  if (!fit.identifiable) {
    return Status::error(ErrorCode::kNumericalFailure,
                         "polynomial fit: order %d is not identifiable from all samples",
                         summary.order);
  }
  summary.surface = scaled;
  summary.surface.order = summary.order;
  summary.surface.coefficients.assign(fit.coefficients.data(),
                                      fit.coefficients.data() + fit.coefficients.size());
  summary.condition_number = fit.condition_number;
  summary.training_rmse =
      std::sqrt((design.leftCols(cols) * fit.coefficients - target).squaredNorm() / n);
  return summary;
}

}  // namespace cdpr
