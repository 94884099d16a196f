// The equilibrium rows' Jacobian cable by cable (identification_costs.hpp).
//
// The residual is L^-1 v with v = w + correction and L L^T = cov, where w, the correction and cov
// are sums of one term per cable (and the weight's wrench in w). Each cable's terms depend on the
// pose, its anchor and attachment point and its five scalars (g, c, o, s, e): 17 coordinates. They
// are differentiated with 17-wide jets, added in the functor's order (so every value is the
// functor's, bit for bit), and chained through the whitening, itself differentiated with respect
// to v and the 21 entries of cov's lower triangle (the only ones the factorisation reads).
#include <memory>
#include <vector>

#include "identification_costs.hpp"

namespace cdpr::ident_detail {
namespace {

constexpr int kLocal = 17;        // pose 6, a 3, b 3, g, c, o, s, e
constexpr int kWeightLocal = 10;  // pose 6, mass 1, centre of mass 3
constexpr int kOutputs = 27;      // v 6, cov's lower triangle 21
using JetCable = ceres::Jet<double, kLocal>;
using JetWeight = ceres::Jet<double, kWeightLocal>;
using JetOut = ceres::Jet<double, kOutputs>;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

// Index of cov(r, c), r >= c, among the outputs.
int lower_index(int r, int c) {
  return 6 + c * 6 - c * (c - 1) / 2 + (r - c);
}

// Jets of `n` values of `x`, seeded at `first`, `first` + 1, ...
template <typename J>
void seed(const double* x, int n, int first, J* out) {
  for (int q = 0; q < n; ++q) out[q] = J(x[q], first + q);
}

class EquilibriumCostFunction final : public ceres::CostFunction {
 public:
  EquilibriumCostFunction(EquilibriumCost* f, const std::vector<int>& block_sizes) : f_(f) {
    set_num_residuals(6);
    *mutable_parameter_block_sizes() = block_sizes;
  }

  bool Evaluate(double const* const* p, double* residuals, double** jacobians) const override {
    if (jacobians == nullptr) return (*f_)(p, residuals);
    const int m = static_cast<int>(f_->k.size());
    // The weight's wrench starts w (derivatives over pose, mass and centre of mass).
    JetWeight xw[kWeightLocal];
    seed(p[0], 6, 0, xw);
    seed(p[f_->mass_block], 1, 6, xw + 6);
    seed(p[f_->mass_block + 1], 3, 7, xw + 7);
    Vec3<JetWeight> rw;
    Mat3<JetWeight> Rw;
    pose_from_block(xw, rw, Rw);
    Eigen::Matrix<JetWeight, 6, 1> ww;
    f_->weight_wrench<JetWeight>(Rw, xw + 6, xw + 7, ww);
    Vec6 w, correction = Vec6::Zero();
    Mat6 cov = Mat6::Zero();
    Eigen::Matrix<double, 6, kWeightLocal> dweight;
    for (int q = 0; q < 6; ++q) {
      w(q) = ww(q).a;
      dweight.row(q) = ww(q).v.transpose();
    }
    // Each cable's terms, added to the running sums as the functor adds them: the same products
    // in the same order (cov's entry (r, c) is (s a_r) a_c), so the values are the functor's.
    std::vector<Eigen::Matrix<double, kOutputs, kLocal>> dterms(static_cast<std::size_t>(m));
    JetCable x[kLocal];
    seed(p[0], 6, 0, x);
    Vec3<JetCable> r;
    Mat3<JetCable> R;
    pose_from_block(x, r, R);
    const JetCable sf2(f_->sigma_force * f_->sigma_force);
    for (int i = 0; i < m; ++i) {
      const EquilibriumCost::CableBlocks<double> blocks = f_->cable_blocks(p, i);
      seed(blocks.a, 3, 6, x + 6);
      seed(blocks.b, 3, 9, x + 9);
      const double* scalars[5] = {blocks.g, blocks.c, blocks.o, blocks.s, blocks.e};
      for (int q = 0; q < 5; ++q) x[12 + q] = JetCable(*scalars[q], 12 + q);
      const EquilibriumCost::CableBlocks<JetCable> jb{x + 6,  x + 9,  x + 12, x + 13,
                                                      x + 14, x + 15, x + 16};
      EquilibriumCost::CableTerms<JetCable> t;
      if (!f_->cable_terms<JetCable>(i, r, R, jb, t)) return false;
      Eigen::Matrix<double, kOutputs, kLocal>& d = dterms[static_cast<std::size_t>(i)];
      for (int q = 0; q < 6; ++q) {
        const JetCable wq = t.col(q) * t.force;
        w(q) += wq.a;
        d.row(q) = wq.v.transpose();
        if (t.has_length) {
          const JetCable cq = t.col(q) * t.correction;
          correction(q) += cq.a;
          d.row(q) += cq.v.transpose();
        }
      }
      const JetCable s = sf2 * t.weight;
      for (int r2 = 0; r2 < 6; ++r2) {
        const JetCable sr = s * t.col(r2);
        for (int c = 0; c <= r2; ++c) {
          const JetCable e = sr * t.col(c);
          cov(r2, c) += e.a;
          d.row(lower_index(r2, c)) = e.v.transpose();
        }
      }
    }
    // The whitening, differentiated with respect to v and cov's lower triangle.
    Eigen::Matrix<JetOut, 6, 1> v;
    Eigen::Matrix<JetOut, 6, 6> jcov;
    for (int q = 0; q < 6; ++q) v(q) = JetOut(w(q) + correction(q), q);
    for (int c = 0; c < 6; ++c) {
      for (int r2 = c; r2 < 6; ++r2) {
        jcov(r2, c) = JetOut(cov(r2, c), lower_index(r2, c));
        jcov(c, r2) = jcov(r2, c);
      }
    }
    Eigen::Matrix<JetOut, 6, 1> out;
    if (!EquilibriumCost::whiten<JetOut>(jcov, v, out)) return false;
    Eigen::Matrix<double, 6, kOutputs> D;
    for (int q = 0; q < 6; ++q) {
      residuals[q] = out(q).a;
      D.row(q) = out(q).v.transpose();
    }
    write_jacobians(m, D, dweight, dterms, jacobians);
    return true;
  }

 private:
  // The chain rule into the blocks' Jacobians (row-major, 6 rows; null: a constant block).
  void write_jacobians(int m, const Eigen::Matrix<double, 6, kOutputs>& D,
                       const Eigen::Matrix<double, 6, kWeightLocal>& dweight,
                       const std::vector<Eigen::Matrix<double, kOutputs, kLocal>>& dterms,
                       double** jac) const {
    using RowMajor = Eigen::Matrix<double, 6, Eigen::Dynamic, Eigen::RowMajor>;
    const auto block = [&](int index, int size) {
      return Eigen::Map<RowMajor>(jac[index], 6, size);
    };
    const int e_blocks = f_->shared_stiffness ? 1 : m;
    const int mb = f_->mass_block;
    const Eigen::Matrix<double, 6, kWeightLocal> gw = D.leftCols<6>().lazyProduct(dweight);
    Eigen::Matrix<double, kOutputs, 6> dpose = Eigen::Matrix<double, kOutputs, 6>::Zero();
    if (jac[mb] != nullptr) block(mb, 1) = gw.col(6);
    if (jac[mb + 1] != nullptr) block(mb + 1, 3) = gw.rightCols<3>();
    for (int i = 0; i < e_blocks; ++i) {
      if (jac[1 + 6 * m + i] != nullptr) block(1 + 6 * m + i, 1).setZero();
    }
    for (int i = 0; i < m; ++i) {
      const Eigen::Matrix<double, kOutputs, kLocal>& d = dterms[static_cast<std::size_t>(i)];
      dpose += d.leftCols<6>();
      const Eigen::Matrix<double, 6, kLocal - 6> g = D.lazyProduct(d.rightCols<kLocal - 6>());
      if (jac[1 + i] != nullptr) block(1 + i, 3) = g.leftCols<3>();
      if (jac[1 + m + i] != nullptr) block(1 + m + i, 3) = g.middleCols<3>(3);
      for (int q = 0; q < 4; ++q) {  // g, c, o, s
        if (jac[1 + (2 + q) * m + i] != nullptr) block(1 + (2 + q) * m + i, 1) = g.col(6 + q);
      }
      const int e = 1 + 6 * m + (f_->shared_stiffness ? 0 : i);
      if (jac[e] != nullptr) block(e, 1) += g.col(10);
    }
    if (jac[0] != nullptr) block(0, 6) = gw.leftCols<6>() + D.lazyProduct(dpose);
  }

  std::unique_ptr<EquilibriumCost> f_;
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
