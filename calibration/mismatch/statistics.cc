// The distributions of the screen's tests (Numerical Recipes style: series and Lentz continued
// fractions) and the column-space basis its projections use.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "cdpr/calibration/mismatch.hpp"
#include "mismatch_internal.hpp"

namespace cdpr {
namespace {

double gamma_p_series(double a, double x) {
  double sum = 1.0 / a;
  double del = sum;
  double ap = a;
  for (int n = 0; n < 1000; ++n) {
    ap += 1.0;
    del *= x / ap;
    sum += del;
    if (std::abs(del) < std::abs(sum) * 1e-16) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

double gamma_q_fraction(double a, double x) {
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a;
  double c = 1.0 / kTiny;
  double d = 1.0 / b;
  double h = d;
  for (int i = 1; i < 1000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

// Regularised upper incomplete gamma Q(a, x).
double gamma_q(double a, double x) {
  if (!(x > 0.0)) return 1.0;
  if (x < a + 1.0) return std::max(0.0, 1.0 - gamma_p_series(a, x));
  return gamma_q_fraction(a, x);
}

double beta_fraction(double a, double b, double x) {
  constexpr double kTiny = 1e-300;
  const double qab = a + b, qap = a + 1.0, qam = a - 1.0;
  double c = 1.0;
  double d = 1.0 - qab * x / qap;
  if (std::abs(d) < kTiny) d = kTiny;
  d = 1.0 / d;
  double h = d;
  for (int m = 1; m < 1000; ++m) {
    const int m2 = 2 * m;
    double aa = m * (b - m) * x / ((qam + m2) * (a + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    h *= d * c;
    aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < 1e-16) break;
  }
  return h;
}

// Regularised incomplete beta I_x(a, b).
double beta_i(double a, double b, double x) {
  if (x <= 0.0) return 0.0;
  if (x >= 1.0) return 1.0;
  const double bt = std::exp(std::lgamma(a + b) - std::lgamma(a) - std::lgamma(b) +
                             a * std::log(x) + b * std::log1p(-x));
  if (x < (a + 1.0) / (a + b + 2.0)) return bt * beta_fraction(a, b, x) / a;
  return 1.0 - bt * beta_fraction(b, a, 1.0 - x) / b;
}

}  // namespace

Eigen::MatrixXd mismatch_detail::column_basis(const Eigen::MatrixXd& X, double tol) {
  if (X.cols() == 0 || X.norm() == 0) return Eigen::MatrixXd(X.rows(), 0);
  Eigen::MatrixXd Xs = X;
  for (Eigen::Index c = 0; c < Xs.cols(); ++c) {
    const double n = Xs.col(c).norm();
    if (n > 0) Xs.col(c) /= n;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(Xs, Eigen::ComputeThinU);
  int r = 0;
  const Eigen::VectorXd& s = svd.singularValues();
  for (Eigen::Index k = 0; k < s.size(); ++k) {
    if (s(k) > tol) ++r;
  }
  return svd.matrixU().leftCols(r);
}

double chi2_upper_tail(double x, double dof) {
  if (!(dof > 0)) return mismatch_detail::kNaN;
  if (!(x > 0)) return 1.0;
  return gamma_q(0.5 * dof, 0.5 * x);
}

double f_upper_tail(double x, double d1, double d2) {
  if (!(d1 > 0) || !(d2 > 0)) return mismatch_detail::kNaN;
  if (!(x > 0)) return 1.0;
  return beta_i(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * x));
}

}  // namespace cdpr
