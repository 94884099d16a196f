// The equilibrium rows' Jacobian cable by cable (identification_costs.hpp).
//
// The residual is L^-1 v with v = w + correction and L L^T = cov, where w, the correction and cov
// are sums of one term per cable (and the weight's wrench in w). Each cable's terms depend on the
// pose, its anchor and attachment point and its five scalars (g, c, o, s, e): 17 coordinates. They
// are differentiated with 17-wide jets and their derivatives added into the sums' derivatives over
// all coordinates, in the functor's order; the whitening then runs on jets over all coordinates
// (in passes of 32). A jet's derivative components are computed independently of each other by
// the same operations whatever the jet's width, so values and derivatives are those of the
// automatic differentiation of the functor over all blocks, bit for bit (up to the sign of zeros).
#include <algorithm>
#include <memory>
#include <vector>

#include "identification_costs.hpp"

namespace cdpr::ident_detail {
namespace {

constexpr int kLocal = 17;        // pose 6, a 3, b 3, g, c, o, s, e
constexpr int kWeightLocal = 10;  // pose 6, mass 1, centre of mass 3
constexpr int kPass = 32;         // derivative components per pass of the whitening
constexpr int kLower = 21;        // cov's lower triangle (all the factorisation reads)
using JetCable = ceres::Jet<double, kLocal>;
using JetWeight = ceres::Jet<double, kWeightLocal>;
using JetPass = ceres::Jet<double, kPass>;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

// Index of cov(r, c), r >= c, in the lower triangle.
int lower_index(int r, int c) {
  return c * 6 - c * (c - 1) / 2 + (r - c);
}

// Jets of `n` values of `x`, seeded at `first`, `first` + 1, ...
template <typename J>
void seed(const double* x, int n, int first, J* out) {
  for (int q = 0; q < n; ++q) out[q] = J(x[q], first + q);
}

// Values and derivatives over all coordinates of w, the correction and cov's lower triangle.
struct Sums {
  explicit Sums(int coords)
      : n(coords),
        dw(static_cast<std::size_t>(6 * coords), 0.0),
        dcorr(static_cast<std::size_t>(6 * coords), 0.0),
        dcov(static_cast<std::size_t>(kLower * coords), 0.0) {}
  int n;
  Vec6 w = Vec6::Zero(), corr = Vec6::Zero();
  Mat6 cov = Mat6::Zero();
  std::vector<double> dw, dcorr, dcov;  // row-major: output x coordinate
  template <typename J>
  static void add(std::vector<double>& d, int stride, int row, const J& x, const int* coord) {
    for (int k = 0; k < J::DIMENSION; ++k)
      d[static_cast<std::size_t>(row * stride + coord[k])] += x.v[k];
  }
};

class EquilibriumCostFunction final : public ceres::CostFunction {
 public:
  EquilibriumCostFunction(EquilibriumCost* f, const std::vector<int>& block_sizes) : f_(f) {
    set_num_residuals(6);
    *mutable_parameter_block_sizes() = block_sizes;
    int offset = 0;
    for (int size : block_sizes) {
      offsets_.push_back(offset);
      offset += size;
    }
    num_coords_ = offset;
  }

  bool Evaluate(double const* const* p, double* residuals, double** jacobians) const override {
    if (jacobians == nullptr) return (*f_)(p, residuals);
    Sums s(num_coords_);
    add_weight(p, s);
    if (!add_cables(p, s)) return false;
    return whiten(s, residuals, jacobians);
  }

 private:
  // The weight's wrench and the external wrench start w.
  void add_weight(double const* const* p, Sums& s) const {
    const int mb = f_->mass_block;
    JetWeight x[kWeightLocal];
    seed(p[0], 6, 0, x);
    seed(p[mb], 1, 6, x + 6);
    seed(p[mb + 1], 3, 7, x + 7);
    Vec3<JetWeight> r;
    Mat3<JetWeight> R;
    pose_from_block(x, r, R);
    Eigen::Matrix<JetWeight, 6, 1> w;
    f_->weight_wrench<JetWeight>(R, x + 6, x + 7, w);
    int coord[kWeightLocal];
    for (int k = 0; k < 6; ++k) coord[k] = offsets_[0] + k;
    coord[6] = offsets_[static_cast<std::size_t>(mb)];
    for (int k = 0; k < 3; ++k) coord[7 + k] = offsets_[static_cast<std::size_t>(mb + 1)] + k;
    for (int q = 0; q < 6; ++q) {
      s.w(q) = w(q).a;
      Sums::add(s.dw, s.n, q, w(q), coord);
    }
  }

  // Each cable's terms added as EquilibriumCost::wrench adds them (the same jet operations).
  bool add_cables(double const* const* p, Sums& s) const {
    const int m = static_cast<int>(f_->k.size());
    JetCable x[kLocal];
    seed(p[0], 6, 0, x);
    Vec3<JetCable> r;
    Mat3<JetCable> R;
    pose_from_block(x, r, R);
    const JetCable sf2(f_->sigma_force * f_->sigma_force);
    int coord[kLocal];
    for (int k = 0; k < 6; ++k) coord[k] = offsets_[0] + k;
    for (int i = 0; i < m; ++i) {
      const EquilibriumCost::CableBlocks<double> blocks = f_->cable_blocks(p, i);
      seed(blocks.a, 3, 6, x + 6);
      seed(blocks.b, 3, 9, x + 9);
      const double* scalars[5] = {blocks.g, blocks.c, blocks.o, blocks.s, blocks.e};
      for (int q = 0; q < 5; ++q) x[12 + q] = JetCable(*scalars[q], 12 + q);
      const int block_of[kLocal - 6] = {1 + i,
                                        1 + i,
                                        1 + i,
                                        1 + m + i,
                                        1 + m + i,
                                        1 + m + i,
                                        1 + 2 * m + i,
                                        1 + 3 * m + i,
                                        1 + 4 * m + i,
                                        1 + 5 * m + i,
                                        1 + 6 * m + (f_->shared_stiffness ? 0 : i)};
      const int within[kLocal - 6] = {0, 1, 2, 0, 1, 2, 0, 0, 0, 0, 0};
      for (int k = 0; k < kLocal - 6; ++k) {
        coord[6 + k] = offsets_[static_cast<std::size_t>(block_of[k])] + within[k];
      }
      const EquilibriumCost::CableBlocks<JetCable> jb{x + 6,  x + 9,  x + 12, x + 13,
                                                      x + 14, x + 15, x + 16};
      EquilibriumCost::CableTerms<JetCable> t;
      if (!f_->cable_terms<JetCable>(i, r, R, jb, t)) return false;
      for (int q = 0; q < 6; ++q) {
        const JetCable wq = t.col(q) * t.force;
        s.w(q) += wq.a;
        Sums::add(s.dw, s.n, q, wq, coord);
        if (t.has_length) {
          const JetCable cq = t.col(q) * t.correction;
          s.corr(q) += cq.a;
          Sums::add(s.dcorr, s.n, q, cq, coord);
        }
      }
      const JetCable scale = sf2 * t.weight;
      for (int r2 = 0; r2 < 6; ++r2) {
        const JetCable sr = scale * t.col(r2);
        for (int c = 0; c <= r2; ++c) {
          const JetCable e = sr * t.col(c);
          s.cov(r2, c) += e.a;
          Sums::add(s.dcov, s.n, lower_index(r2, c), e, coord);
        }
      }
    }
    return true;
  }

  // L^-1 (w + correction) on jets over all coordinates, kPass at a time.
  bool whiten(const Sums& s, double* residuals, double** jac) const {
    const std::size_t n = static_cast<std::size_t>(s.n);
    for (int k0 = 0; k0 < s.n; k0 += kPass) {
      const int width = std::min(kPass, s.n - k0);
      Eigen::Matrix<JetPass, 6, 1> v;
      Eigen::Matrix<JetPass, 6, 6> cov;
      for (int q = 0; q < 6; ++q) {
        JetPass wq(s.w(q)), cq(s.corr(q));
        for (int l = 0; l < width; ++l) {
          wq.v[l] = s.dw[q * n + static_cast<std::size_t>(k0 + l)];
          cq.v[l] = s.dcorr[q * n + static_cast<std::size_t>(k0 + l)];
        }
        v(q) = wq + cq;
      }
      for (int c = 0; c < 6; ++c) {
        for (int r2 = c; r2 < 6; ++r2) {
          JetPass e(s.cov(r2, c));
          const auto row = static_cast<std::size_t>(lower_index(r2, c));
          for (int l = 0; l < width; ++l)
            e.v[l] = s.dcov[row * n + static_cast<std::size_t>(k0 + l)];
          cov(r2, c) = e;
          cov(c, r2) = e;
        }
      }
      Eigen::Matrix<JetPass, 6, 1> out;
      if (!EquilibriumCost::whiten<JetPass>(cov, v, out)) return false;
      for (int q = 0; q < 6; ++q) residuals[q] = out(q).a;
      write_pass(k0, width, out, jac);
    }
    return true;
  }

  // The derivative components k0 .. k0 + width - 1 into the blocks' Jacobians (row-major).
  void write_pass(int k0, int width, const Eigen::Matrix<JetPass, 6, 1>& out, double** jac) const {
    const std::vector<int>& sizes = parameter_block_sizes();
    for (std::size_t b = 0; b < sizes.size(); ++b) {
      if (jac[b] == nullptr) continue;
      const int size = sizes[b];
      for (int j = 0; j < size; ++j) {
        const int l = offsets_[b] + j - k0;
        if (l < 0 || l >= width) continue;
        for (int q = 0; q < 6; ++q) jac[b][q * size + j] = out(q).v[l];
      }
    }
  }

  std::unique_ptr<EquilibriumCost> f_;
  std::vector<int> offsets_;  // first coordinate of each block
  int num_coords_ = 0;
};

}  // namespace

ceres::CostFunction* equilibrium_cost_function(EquilibriumCost* f,
                                               const std::vector<int>& block_sizes) {
  if (f->null_basis.cols() > 0) {
    auto* cost = new ceres::DynamicAutoDiffCostFunction<EquilibriumCost, 40>(f);
    for (int size : block_sizes) cost->AddParameterBlock(size);
    cost->SetNumResiduals(6);
    return cost;
  }
  return new EquilibriumCostFunction(f, block_sizes);
}

}  // namespace cdpr::ident_detail
