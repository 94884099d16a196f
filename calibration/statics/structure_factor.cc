// StructureFactor: the column-pivoted Householder QR of A (m x 6) written out for these sizes.
// The pivot is the remaining column of largest norm, as in Eigen's ColPivHouseholderQR (the
// same R up to rounding, hence the same rank verdicts); Q stays as its six reflections and only
// its last m - 6 columns (the null-space basis) are formed. For eight cables this is a fraction
// of the instructions of Eigen's QR followed by forming the 8 x 8 Q.
#include <algorithm>
#include <cmath>

#include "cdpr/calibration/force_distribution.hpp"

namespace cdpr {
namespace {

// Factors the m x 6 column-major `a` (leading dimension m) in place: R on and above the
// diagonal, the reflections' vectors below it, their factors in tau, the pivots in `pivot`
// (step k swapped columns k and pivot[k]). kRows: m when known at compile time (else 0).
template <int kRows>
void householder_qr(double* a, int m_runtime, double* tau, int* pivot) {
  const int m = kRows > 0 ? kRows : m_runtime;
  const int steps = std::min(6, m);
  for (int k = 0; k < steps; ++k) {
    // Pivot: the remaining column with the largest norm of rows k..m-1 (the first on a tie).
    int p = k;
    double best = -1.0;
    for (int j = k; j < 6; ++j) {
      double s = 0.0;
      for (int i = k; i < m; ++i) s += a[j * m + i] * a[j * m + i];
      if (s > best) {
        best = s;
        p = j;
      }
    }
    pivot[k] = p;
    if (p != k) {
      for (int i = 0; i < m; ++i) std::swap(a[k * m + i], a[p * m + i]);
    }
    double* col = a + k * m;
    const double x0 = col[k];
    double tail = 0.0;
    for (int i = k + 1; i < m; ++i) tail += col[i] * col[i];
    if (!(tail > 0.0)) {  // already upper triangular in this column: H_k = I
      tau[k] = 0.0;
      continue;
    }
    const double norm = std::sqrt(x0 * x0 + tail);
    const double beta = x0 >= 0.0 ? -norm : norm;
    const double scale = 1.0 / (x0 - beta);
    for (int i = k + 1; i < m; ++i) col[i] *= scale;
    tau[k] = (beta - x0) / beta;
    col[k] = beta;
    // H_k on the remaining columns.
    for (int j = k + 1; j < 6; ++j) {
      double* c = a + j * m;
      double s = c[k];
      for (int i = k + 1; i < m; ++i) s += col[i] * c[i];
      s *= tau[k];
      c[k] -= s;
      for (int i = k + 1; i < m; ++i) c[i] -= s * col[i];
    }
  }
  for (int k = steps; k < 6; ++k) {
    tau[k] = 0.0;
    pivot[k] = k;
  }
}

// x <- H_k x (kRows as in householder_qr).
template <int kRows>
inline void reflect(const StructureFactor& f, int k, int m_runtime, double* x) {
  const int m = kRows > 0 ? kRows : m_runtime;
  const double* v = f.reflectors.data() + k * m;
  double s = x[k];
  for (int i = k + 1; i < m; ++i) s += v[i] * x[i];
  s *= f.tau(k);
  x[k] -= s;
  for (int i = k + 1; i < m; ++i) x[i] -= s * v[i];
}

// x <- Q x, or Q^T x when `transposed`.
template <int kRows>
void apply(const StructureFactor& f, bool transposed, double* x) {
  const int m = f.num_cables();
  // Unrolled: with the row count known, every reflection's loops have constant bounds.
  if (transposed) {
#pragma GCC unroll 6
    for (int k = 0; k < 6; ++k) reflect<kRows>(f, k, m, x);
  } else {
#pragma GCC unroll 6
    for (int k = 5; k >= 0; --k) reflect<kRows>(f, k, m, x);
  }
}

void apply_either(const StructureFactor& f, bool transposed, double* x) {
  if (f.num_cables() == 8) {
    apply<8>(f, transposed, x);
  } else {
    apply<0>(f, transposed, x);
  }
}

}  // namespace

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
  reflectors = structure.transpose();
  int pivot[6];
  // Eight cables (the common over-constrained robot) with the row count known at compile time.
  if (m == 8) {
    householder_qr<8>(reflectors.data(), m, tau.data(), pivot);
  } else {
    householder_qr<0>(reflectors.data(), m, tau.data(), pivot);
  }
  const double r00 = std::abs(reflectors(0, 0));
  for (int k = 0; k < std::min(6, m); ++k) {
    rank += std::abs(reflectors(k, k)) > rank_tolerance * r00;
  }
  if (rank < 6 || !(r00 > 0.0)) {
    status = Factored::kRankDeficient;
    return false;
  }
  r = reflectors.topRows<6>().triangularView<Eigen::Upper>();
  permutation.setIdentity();
  for (int k = 0; k < 6; ++k) permutation.applyTranspositionOnTheRight(k, pivot[k]);
  null.setZero(m, m - 6);
  for (int j = 0; j < m - 6; ++j) {
    double* x = null.data() + j * m;
    x[6 + j] = 1.0;
    apply_either(*this, false, x);
  }
  status = Factored::kFullRank;
  return true;
}

void StructureFactor::apply_q(CableVector& x) const {
  apply_either(*this, false, x.data());
}

void StructureFactor::apply_qt(CableVector& x) const {
  apply_either(*this, true, x.data());
}

CableVector StructureFactor::particular(const CableVector& f_ref, const Wrench6& w) const {
  // A = Q1 R P^T: f = f_ref - Q1 (Q1^T f_ref + y), y = R^-T P^T w, i.e. N N^T f_ref - Q1 y.
  const int m = num_cables();
  CableVector g = CableVector::Zero(m);
  const Wrench6 pw = permutation.transpose() * w;
  for (int k = 0; k < 6; ++k) {  // forward substitution with R^T
    double s = pw(k);
    for (int j = 0; j < k; ++j) s -= r(j, k) * g(j);
    g(k) = s / r(k, k);
  }
  apply_q(g);  // Q [y; 0] = Q1 y
  for (int j = 0; j < m - 6; ++j) {
    const double c = null.col(j).dot(f_ref);
    for (int i = 0; i < m; ++i) g(i) -= c * null(i, j);
  }
  return -g;
}

}  // namespace cdpr
