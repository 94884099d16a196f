#include "cdpr/calibration/diagnosis.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <utility>

#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/model_validation.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "text_format.hpp"

namespace cdpr {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

using mismatch_detail::format;

// Symmetric pseudo-inverse with the eigenvalue threshold relative to the largest one (after a
// diagonal scaling, so that columns of very different units are treated alike).
Eigen::MatrixXd pinv_sym(const Eigen::MatrixXd& A, double tol = 1e-12) {
  const Eigen::Index n = A.rows();
  if (n == 0) return A;
  Eigen::VectorXd d(n);
  for (Eigen::Index i = 0; i < n; ++i) d(i) = A(i, i) > 0 ? 1.0 / std::sqrt(A(i, i)) : 0.0;
  const Eigen::MatrixXd As = d.asDiagonal() * A * d.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(As);
  const Eigen::VectorXd& ev = es.eigenvalues();
  const double top = std::max(ev.maxCoeff(), 0.0);
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    if (ev(i) > tol * top && ev(i) > 0) inv(i) = 1.0 / ev(i);
  }
  return d.asDiagonal() * es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose() *
         d.asDiagonal();
}

// Orthonormal basis of the column space of X (columns scaled to unit norm first).
Eigen::MatrixXd column_basis(const Eigen::MatrixXd& X, double tol) {
  if (X.cols() == 0 || X.norm() == 0) return Eigen::MatrixXd(X.rows(), 0);
  Eigen::MatrixXd Xs = X;
  for (Eigen::Index c = 0; c < Xs.cols(); ++c) {
    const double nrm = Xs.col(c).norm();
    if (nrm > 0) Xs.col(c) /= nrm;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(Xs, Eigen::ComputeThinU);
  int r = 0;
  for (Eigen::Index k = 0; k < svd.singularValues().size(); ++k) {
    if (svd.singularValues()(k) > tol) ++r;
  }
  return svd.matrixU().leftCols(r);
}

const CandidateColumns* find_columns(const MismatchDesign& d, const std::string& id) {
  for (const auto& c : d.candidates) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

// Per-pose cross products of [geometry | blocks... | residual] with the pose's own Jacobian
// projected out (Frisch-Waugh: projecting the block-diagonal pose columns pose by pose and then
// the geometry columns equals projecting the whole identification Jacobian). Weighted sums of
// these give the screen on any resample of the poses, the fold fits of the cross-validation and
// the canonical correlations of an augmented pose set without touching the residual vectors.
struct PoseGrams {
  int geometry = 0;                // leading columns
  std::vector<int> block_start;    // first column of each block
  std::vector<int> block_size;     // columns of each block
  int total = 0;                   // columns including the residual (last)
  std::vector<Eigen::MatrixXd> M;  // per pose, total x total
  std::vector<Eigen::MatrixXd> Z;  // per pose, projected rows (kept only on request)
};

PoseGrams pose_grams(const MismatchDesign& d, const std::vector<const Eigen::MatrixXd*>& blocks,
                     bool with_geometry, bool keep_rows) {
  PoseGrams g;
  const int np = d.num_poses();
  g.geometry = with_geometry && np > 0 ? static_cast<int>(d.jacobian_geometry[0].cols()) : 0;
  int col = g.geometry;
  for (const Eigen::MatrixXd* b : blocks) {
    g.block_start.push_back(col);
    g.block_size.push_back(static_cast<int>(b->cols()));
    col += static_cast<int>(b->cols());
  }
  g.total = col + 1;
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int r0 = d.pose_start[uj];
    const int nr = d.pose_start[uj + 1] - r0;
    Eigen::MatrixXd Z(nr, g.total);
    if (g.geometry > 0) Z.leftCols(g.geometry) = d.jacobian_geometry[uj];
    for (std::size_t b = 0; b < blocks.size(); ++b) {
      Z.middleCols(g.block_start[b], g.block_size[b]) = blocks[b]->middleRows(r0, nr);
    }
    Z.col(g.total - 1) = d.residuals.segment(r0, nr);
    const Eigen::MatrixXd Q = column_basis(d.jacobian_pose[uj], 1e-10);
    if (Q.cols() > 0) Z -= Q * (Q.transpose() * Z);
    g.M.push_back(Z.transpose() * Z);
    if (keep_rows) g.Z.push_back(std::move(Z));
  }
  return g;
}

// Gram of the non-geometry columns (blocks and residual) with the geometry projected out.
Eigen::MatrixXd reduce_geometry(const Eigen::MatrixXd& M, int geometry) {
  const Eigen::Index rest = M.rows() - geometry;
  if (geometry == 0) return M;
  const Eigen::MatrixXd Gi = pinv_sym(M.topLeftCorner(geometry, geometry));
  const Eigen::MatrixXd B = M.topRightCorner(geometry, rest);
  return M.bottomRightCorner(rest, rest) - B.transpose() * Gi * B;
}

// Greedy choice of extra poses: `M` is the information of the recorded poses (np of them in
// `g`), and the candidates are the poses after them. Each step adds the allowed candidate whose
// Gram raises `score` the most, and only while the score rises above `floor` (updated to the
// score reached). Returns the chosen candidates (0-based), in order; `M` includes them.
std::vector<int> greedy_extra_poses(const PoseGrams& g, int np, int count,
                                    const std::function<bool(int)>& allowed,
                                    const std::function<double(const Eigen::MatrixXd&)>& score,
                                    double floor, Eigen::MatrixXd& M) {
  std::vector<int> chosen;
  const int nc = static_cast<int>(g.M.size()) - np;
  std::vector<bool> used(static_cast<std::size_t>(std::max(nc, 0)), false);
  for (int step = 0; step < count; ++step) {
    int best = -1;
    double best_value = floor;
    for (int q = 0; q < nc; ++q) {
      if (used[static_cast<std::size_t>(q)] || !allowed(q)) continue;
      const double v = score(M + g.M[static_cast<std::size_t>(np + q)]);
      if (v > best_value) {
        best_value = v;
        best = q;
      }
    }
    if (best < 0) break;
    used[static_cast<std::size_t>(best)] = true;
    M += g.M[static_cast<std::size_t>(np + best)];
    chosen.push_back(best);
    floor = best_value;
  }
  return chosen;
}

// Rank of a candidate's projected columns relative to their unprojected norms.
int projected_rank(const Eigen::MatrixXd& S, const Eigen::VectorXd& raw_norm2, double tol) {
  const Eigen::Index k = S.rows();
  if (k == 0) return 0;
  Eigen::VectorXd d(k);
  for (Eigen::Index i = 0; i < k; ++i) d(i) = raw_norm2(i) > 0 ? 1.0 / std::sqrt(raw_norm2(i)) : 0;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(d.asDiagonal() * S * d.asDiagonal());
  int r = 0;
  for (Eigen::Index i = 0; i < k; ++i) {
    if (es.eigenvalues()(i) > tol) ++r;
  }
  return r;
}

// Largest canonical correlation of two column blocks from their (projected) Gram blocks.
double canonical_correlation(const Eigen::MatrixXd& Saa, const Eigen::MatrixXd& Sbb,
                             const Eigen::MatrixXd& Sab) {
  auto inv_sqrt = [](const Eigen::MatrixXd& A) {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(A);
    const double top = std::max(es.eigenvalues().maxCoeff(), 0.0);
    Eigen::VectorXd s = Eigen::VectorXd::Zero(A.rows());
    for (Eigen::Index i = 0; i < A.rows(); ++i) {
      if (es.eigenvalues()(i) > 1e-10 * top && es.eigenvalues()(i) > 0) {
        s(i) = 1.0 / std::sqrt(es.eigenvalues()(i));
      }
    }
    return Eigen::MatrixXd(es.eigenvectors() * s.asDiagonal() * es.eigenvectors().transpose());
  };
  const Eigen::MatrixXd C = inv_sqrt(Saa) * Sab * inv_sqrt(Sbb);
  if (C.size() == 0) return 0.0;
  return std::min(1.0, Eigen::JacobiSVD<Eigen::MatrixXd>(C).singularValues()(0));
}

// Forward selection on a reduced Gram (candidate blocks and residual, geometry projected out).
struct SelectionInput {
  std::vector<int> start, size, rank;
  std::vector<double> logn;  // per candidate: log of its BIC sample size
  std::vector<std::string> family;
  int n = 0, dof = 0;
  double alpha = 0.01;
  int max_effects = 3;
};

std::vector<int> forward_select(const Eigen::MatrixXd& S, const SelectionInput& in) {
  const Eigen::Index last = S.rows() - 1;
  const double rss0 = S(last, last);
  std::vector<int> sel_cols;
  std::vector<int> chosen;
  std::set<std::string> families;
  double rss = rss0;
  int k_sel = 0;
  auto rss_with = [&](const std::vector<int>& cols) {
    const auto q = static_cast<Eigen::Index>(cols.size());
    Eigen::MatrixXd A(q, q);
    Eigen::VectorXd b(q);
    for (Eigen::Index u = 0; u < q; ++u) {
      b(u) = S(cols[static_cast<std::size_t>(u)], last);
      for (Eigen::Index v = 0; v < q; ++v) {
        A(u, v) = S(cols[static_cast<std::size_t>(u)], cols[static_cast<std::size_t>(v)]);
      }
    }
    // Named, not inlined into the dot product: GCC 12 at -O2 reports a use-after-free in Eigen's
    // temporary there (-Werror=use-after-free, a false positive).
    const Eigen::VectorXd x = pinv_sym(A, 1e-9) * b;
    return rss0 - b.dot(x);
  };
  for (int step = 0; step < in.max_effects; ++step) {
    struct Option {
      int c;
      double p, bic, rss;
    };
    std::vector<Option> opts;
    for (std::size_t c = 0; c < in.start.size(); ++c) {
      if (in.rank[c] == 0 || families.count(in.family[c])) continue;
      const int k = in.rank[c];
      const int d2 = in.dof - k_sel - k;
      if (d2 <= 0) continue;
      std::vector<int> cols = sel_cols;
      for (int q = 0; q < in.size[c]; ++q) cols.push_back(in.start[c] + q);
      const double rc = std::max(rss_with(cols), 1e-300);
      const double drop = std::max(rss - rc, 0.0);
      const double f = (drop / k) / (rc / d2);
      opts.push_back({static_cast<int>(c), f_upper_tail(f, k, d2),
                      in.n * std::log(rc / rss) + k * in.logn[c], rc});
    }
    if (opts.empty()) break;
    // Holm over the contenders of this step: the adjusted p of each.
    std::vector<std::size_t> order(opts.size());
    for (std::size_t q = 0; q < order.size(); ++q) order[q] = q;
    std::sort(order.begin(), order.end(),
              [&](std::size_t a, std::size_t b) { return opts[a].p < opts[b].p; });
    std::vector<double> adj(opts.size());
    double running = 0.0;
    for (std::size_t q = 0; q < order.size(); ++q) {
      running = std::max(running,
                         std::min(1.0, static_cast<double>(order.size() - q) * opts[order[q]].p));
      adj[order[q]] = running;
    }
    int best = -1;
    for (std::size_t q = 0; q < opts.size(); ++q) {
      if (adj[q] >= in.alpha || opts[q].bic >= 0) continue;
      if (best < 0 || opts[q].bic < opts[static_cast<std::size_t>(best)].bic) {
        best = static_cast<int>(q);
      }
    }
    if (best < 0) break;
    // Within a family prefer the simplest eligible member (shared before per cable) unless the
    // richer one is significantly better than it.
    for (std::size_t q = 0; q < opts.size(); ++q) {
      const Option& rich = opts[static_cast<std::size_t>(best)];
      const auto rc = static_cast<std::size_t>(rich.c);
      const auto qc = static_cast<std::size_t>(opts[q].c);
      if (in.family[qc] != in.family[rc] || in.rank[qc] >= in.rank[rc]) continue;
      if (adj[q] >= in.alpha || opts[q].bic >= 0) continue;
      const int dk = in.rank[rc] - in.rank[qc];
      const int d2 = in.dof - k_sel - in.rank[rc];
      const double f = (std::max(opts[q].rss - rich.rss, 0.0) / dk) / (rich.rss / d2);
      if (f_upper_tail(f, dk, d2) >= in.alpha) best = static_cast<int>(q);
    }
    const Option& o = opts[static_cast<std::size_t>(best)];
    const auto c = static_cast<std::size_t>(o.c);
    chosen.push_back(o.c);
    families.insert(in.family[c]);
    for (int q = 0; q < in.size[c]; ++q) sel_cols.push_back(in.start[c] + q);
    k_sel += in.rank[c];
    rss = o.rss;
  }
  return chosen;
}

// Linearised K-fold cross-validation over poses: the geometry (and the effect columns `extra`)
// from a Gauss-Newton step on K-1 folds, the held-out poses re-located (their own pose columns
// projected out). `normalized`: RMS of all held-out residuals in sigmas (every channel: an
// effect of the laser or of the force sensors may leave the lengths alone); `length_m`: RMS of
// the held-out length residuals in m (what people read).
struct CvRms {
  double normalized = 0.0;
  double length_m = 0.0;
};

CvRms cv_rms(const MismatchDesign& d, const Eigen::MatrixXd* extra, const std::vector<int>& fold,
             int folds) {
  std::vector<const Eigen::MatrixXd*> blocks;
  if (extra != nullptr && extra->cols() > 0) blocks.push_back(extra);
  const PoseGrams g = pose_grams(d, blocks, true, true);
  const int np = d.num_poses();
  const int q = g.total - 1;
  double sum_len = 0.0, sum_all = 0.0;
  int count_len = 0, count_all = 0;
  for (int f = 0; f < folds; ++f) {
    Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
    for (int j = 0; j < np; ++j) {
      if (fold[static_cast<std::size_t>(j)] != f) M += g.M[static_cast<std::size_t>(j)];
    }
    const Eigen::VectorXd delta = -pinv_sym(M.topLeftCorner(q, q)) * M.topRightCorner(q, 1);
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      if (fold[uj] != f) continue;
      const Eigen::MatrixXd& Z = g.Z[uj];
      const Eigen::VectorXd e = Z.col(q) + Z.leftCols(q) * delta;
      for (Eigen::Index k = 0; k < e.size(); ++k) {
        const int row = d.pose_start[uj] + static_cast<int>(k);
        sum_all += e(k) * e(k);
        ++count_all;
        if (d.kind[static_cast<std::size_t>(row)] != ResidualKind::kLength) continue;
        const double em = e(k) * d.sigma_length(row);
        sum_len += em * em;
        ++count_len;
      }
    }
  }
  CvRms out;
  out.normalized = count_all > 0 ? std::sqrt(sum_all / count_all) : 0.0;
  out.length_m = count_len > 0 ? std::sqrt(sum_len / count_len) : 0.0;
  return out;
}

// Moves a fitted effect into the data: sigma * (X theta) added to the length and laser readings
// (both residuals are (model - reading) / sigma), and the effect on the equilibrium rows, in SI
// (CandidateColumns::si), taken off the pose's external wrench. With `force_noise`, an effect that
// follows the tension readings (CandidateColumns::dtension) adds its derivative by them to the
// lengths' extra compliance, so that the length sigmas carry the force noise the corrected
// readings now hold (DiagnosisOptions::gauss_newton_force_noise). False when the effect acts on
// rows that cannot take it (equilibrium rows without SI columns, reference-pose rows).
bool corrected_set(const MeasurementSet& set, const MismatchDesign& d, const CandidateColumns& c,
                   const Eigen::VectorXd& theta, bool force_noise, MeasurementSet& out) {
  out = set;
  if (c.tension_readings.cols() == theta.size() && c.tension_readings.rows() > 0) {
    // An error of the tension readings: each reading corrected (CandidateColumns::
    // tension_readings), the rows follow through the identification.
    const Eigen::VectorXd e = c.tension_readings * theta;
    const int np = set.num_poses();
    if (e.size() % std::max(np, 1) != 0) return false;
    const int m = np > 0 ? static_cast<int>(e.size() / np) : 0;
    for (int j = 0; j < np; ++j) {
      PoseMeasurement& pm = out.poses[static_cast<std::size_t>(j)];
      if (pm.tensions.size() != m) continue;
      for (int i = 0; i < m; ++i) pm.tensions(i) -= e(static_cast<Eigen::Index>(j) * m + i);
    }
    return true;
  }
  const Eigen::VectorXd v = c.X * theta;
  const bool have_si = c.si.rows() == c.X.rows() && c.si.cols() == c.X.cols();
  const Eigen::VectorXd v_si = have_si ? Eigen::VectorXd(c.si * theta) : Eigen::VectorXd();
  const bool have_slope =
      force_noise && c.dtension.rows() == c.X.rows() && c.dtension.cols() == c.X.cols();
  const Eigen::VectorXd slope =
      have_slope ? Eigen::VectorXd(c.dtension * theta) : Eigen::VectorXd();
  const double scale = v.cwiseAbs().maxCoeff();
  for (int k = 0; k < d.num_rows(); ++k) {
    const auto uk = static_cast<std::size_t>(k);
    PoseMeasurement& pm = out.poses[static_cast<std::size_t>(d.pose[uk])];
    switch (d.kind[uk]) {
      case ResidualKind::kLength:
        pm.cable_lengths(d.index[uk]) += d.sigma_length(k) * v(k);
        if (have_slope && slope(k) != 0.0) {
          if (pm.extra_compliance.size() != pm.cable_lengths.size()) {
            pm.extra_compliance = Eigen::VectorXd::Zero(pm.cable_lengths.size());
          }
          pm.extra_compliance(d.index[uk]) += d.sigma_length(k) * slope(k);
        }
        break;
      case ResidualKind::kLaser:
        pm.laser_distances(d.index[uk]) += set.noise.sigma_laser * v(k);
        break;
      case ResidualKind::kWrench:
        if (have_si) {
          pm.external_wrench(d.index[uk]) -= v_si(k);
        } else if (std::abs(v(k)) > 1e-9 * scale) {
          return false;
        }
        break;
      default:
        if (std::abs(v(k)) > 1e-9 * scale) return false;
        break;
    }
  }
  return true;
}

// An identification parameter as an effect parameter in engineer words.
EffectParameter describe_parameter(const ParameterEstimate& p, const CalibratedModel& initial) {
  EffectParameter e;
  e.name = p.name;
  e.unit = p.unit;
  e.value = p.value;
  e.std_dev = p.std_dev;
  // The 1-based cable number ("" for one shared by every cable).
  const std::string cable = p.id.index >= 0 ? std::to_string(p.id.index + 1) : std::string();
  if (p.id.kind == ParameterKind::kStiffness) {
    const int i = std::max(p.id.index, 0);
    const double ea0 = initial.robot.cables[static_cast<std::size_t>(i)].ea;
    e.name = cable.empty() ? "EA" : "EA_" + cable;
    e.unit = "N";
    e.value = ea0 * (1.0 + p.value);
    e.std_dev = ea0 * p.std_dev;
    const int dg = digits_for(e.std_dev / 1e3);
    e.text = (cable.empty() ? std::string("cable elasticity: EA = ")
                            : "cable elasticity of cable " + cable + ": EA = ") +
             format("%.*f +- %.*f kN", dg, e.value / 1e3, dg, e.std_dev / 1e3);
  } else if (p.id.kind == ParameterKind::kLengthScale) {
    const int dg = digits_for(100 * p.std_dev);
    e.text = "drum scale error of winch " + cable + ": " + signed_number(100 * p.value, dg) +
             format(" +- %.*f %%", dg, 100 * p.std_dev);
  } else if (p.id.kind == ParameterKind::kForceGain) {
    const int dg = digits_for(100 * p.std_dev);
    e.text = "force sensor gain error of cable " + cable + ": " + signed_number(100 * p.value, dg) +
             format(" +- %.*f %%", dg, 100 * p.std_dev);
  } else if (p.id.kind == ParameterKind::kForceOffset) {
    const int dg = digits_for(p.std_dev);
    e.text = "force sensor offset of cable " + cable + ": " + signed_number(p.value, dg) +
             format(" +- %.*f N", dg, p.std_dev);
  } else if (p.unit == "m") {
    const double dv = 1e3 * (p.value - p.initial);
    const int dg = digits_for(1e3 * p.std_dev);
    e.text =
        p.name + " moved by " + signed_number(dv, dg) + format(" +- %.*f mm", dg, 1e3 * p.std_dev);
  } else if (p.unit == "rad") {
    const int dg = digits_for(1e3 * p.std_dev);
    e.text = p.name + ": " + signed_number(1e3 * p.value, dg) +
             format(" +- %.*f mrad", dg, 1e3 * p.std_dev);
  } else {
    const int dg = digits_for(p.std_dev);
    e.text = p.name + " = " + format("%.*f +- %.*f %s", dg, p.value, dg, p.std_dev, p.unit.c_str());
  }
  return e;
}

// The log of each candidate's BIC sample size (DiagnosisOptions::bic_informing_rows): the number
// of readings its columns act on, or every reading.
std::map<std::string, double> bic_log_sizes(const MismatchDesign& D, bool informing_rows) {
  std::map<std::string, double> out;
  const double all = std::log(static_cast<double>(std::max(1, D.num_rows())));
  for (const auto& c : D.candidates) {
    double logn = all;
    if (informing_rows && c.X.size() > 0) {
      const double top = c.X.cwiseAbs().maxCoeff();
      int rows = 0;
      for (Eigen::Index r = 0; r < c.X.rows(); ++r) {
        if (c.X.row(r).cwiseAbs().maxCoeff() > 1e-12 * top) ++rows;
      }
      if (rows > 0) logn = std::log(static_cast<double>(rows));
    }
    out[c.id] = logn;
  }
  return out;
}

// ---- Stage 1, selection: the bootstrap over poses with forward selection on the projected
// columns (the inclusion probability of every candidate), and the candidates kept for the full
// refits.
struct Selection {
  std::vector<double> inclusion;                   // per candidate of the standard design
  std::map<std::string, double> family_inclusion;  // per selection group
  std::set<std::string> kept;                      // the kept candidates' ids
  std::vector<std::string> to_refit;               // the same, in the design's order

  double family_probability(const std::string& family) const {
    const auto it = family_inclusion.find(selection_group(family));
    return it == family_inclusion.end() ? 0.0 : it->second;
  }
};

Selection select_candidates(const MismatchDesign& D0, const MismatchSummary& screen, int np,
                            const DiagnosisOptions& options) {
  const int n = D0.num_rows();
  const double alpha = options.screen.alpha;
  std::vector<const Eigen::MatrixXd*> blocks;
  for (const auto& c : D0.candidates) blocks.push_back(&c.X);
  const PoseGrams G0 = pose_grams(D0, blocks, true, false);
  SelectionInput sel;
  sel.n = n;
  sel.dof = screen.dof;
  sel.alpha = alpha;
  sel.max_effects = options.max_effects;
  const std::map<std::string, double> log_sizes = bic_log_sizes(D0, options.bic_informing_rows);
  Eigen::MatrixXd Mfull = Eigen::MatrixXd::Zero(G0.total, G0.total);
  for (const auto& M : G0.M) Mfull += M;
  const Eigen::MatrixXd Sfull = reduce_geometry(Mfull, G0.geometry);
  for (std::size_t c = 0; c < D0.candidates.size(); ++c) {
    sel.start.push_back(G0.block_start[c] - G0.geometry);
    sel.size.push_back(G0.block_size[c]);
    sel.family.push_back(selection_group(D0.candidates[c].family));
    sel.logn.push_back(log_sizes.at(D0.candidates[c].id));
    const Eigen::VectorXd raw = Mfull.diagonal().segment(G0.block_start[c], G0.block_size[c]);
    sel.rank.push_back(projected_rank(
        Sfull.block(sel.start.back(), sel.start.back(), sel.size.back(), sel.size.back()), raw,
        options.screen.rank_tolerance));
  }
  std::vector<double> inclusion(D0.candidates.size(), 0.0);
  std::map<std::string, double> family_inclusion;
  std::vector<std::set<std::string>> selected_families;  // per resample
  const std::vector<int> full_selection = forward_select(Sfull, sel);
  std::mt19937 rng(options.seed);
  std::uniform_int_distribution<int> pick(0, np - 1);
  for (int b = 0; b < options.bootstrap_samples; ++b) {
    std::vector<double> w(static_cast<std::size_t>(np), 0.0);
    for (int q = 0; q < np; ++q) w[static_cast<std::size_t>(pick(rng))] += 1.0;
    // The poses that fix the gauge (held constant by the identification) are always kept.
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      if (D0.jacobian_pose[uj].norm() == 0) w[uj] = std::max(w[uj], 1.0);
    }
    Eigen::MatrixXd M = Eigen::MatrixXd::Zero(G0.total, G0.total);
    for (int j = 0; j < np; ++j) {
      if (w[static_cast<std::size_t>(j)] > 0)
        M += w[static_cast<std::size_t>(j)] * G0.M[static_cast<std::size_t>(j)];
    }
    std::set<std::string> fams;
    for (int c : forward_select(reduce_geometry(M, G0.geometry), sel)) {
      inclusion[static_cast<std::size_t>(c)] += 1.0 / options.bootstrap_samples;
      family_inclusion[sel.family[static_cast<std::size_t>(c)]] += 1.0 / options.bootstrap_samples;
      fams.insert(sel.family[static_cast<std::size_t>(c)]);
    }
    selected_families.push_back(std::move(fams));
    if (options.progress) options.progress("bootstrap resamples", b + 1, options.bootstrap_samples);
  }
  if (options.bootstrap_samples == 0) {
    for (int c : full_selection) {
      inclusion[static_cast<std::size_t>(c)] = 1.0;
      family_inclusion[sel.family[static_cast<std::size_t>(c)]] = 1.0;
    }
    std::set<std::string> fams;
    for (int c : full_selection) fams.insert(sel.family[static_cast<std::size_t>(c)]);
    selected_families.push_back(std::move(fams));
  }

  // Kept candidates and their confounded partners.
  // Kept: every member of a family selected (by any of its members) in at least the threshold
  // fraction of the resamples. A strong effect makes the first-order screen prefer the richer
  // member of a family by chance of its nonlinearity; the full refits decide within the family.
  // Two confounded families split the resamples between them, so the support of a family
  // counts the resamples that selected it or a family confounded with it on this pose set.
  std::map<std::string, std::set<std::string>> allied;
  for (const auto& c : D0.candidates) {
    allied[selection_group(c.family)].insert(selection_group(c.family));
  }
  for (const auto& p : screen.confounded) {
    const CandidateColumns* a = find_columns(D0, p.first);
    const CandidateColumns* b = find_columns(D0, p.second);
    if (a == nullptr || b == nullptr) continue;
    allied[selection_group(a->family)].insert(selection_group(b->family));
    allied[selection_group(b->family)].insert(selection_group(a->family));
  }
  std::vector<std::string> to_refit;
  std::set<std::string> kept;
  for (const auto& c : D0.candidates) {
    int support = 0;
    for (const auto& fams : selected_families) {
      bool any = false;
      for (const std::string& f : allied[selection_group(c.family)]) any = any || fams.count(f) > 0;
      support += any ? 1 : 0;
    }
    const double frac =
        selected_families.empty() ? 0.0 : support / static_cast<double>(selected_families.size());
    if (frac >= options.inclusion_threshold && frac > 0) {
      kept.insert(c.id);
      to_refit.push_back(c.id);
    }
  }
  return Selection{std::move(inclusion), std::move(family_inclusion), std::move(kept),
                   std::move(to_refit)};
}

// Fold assignment of the cross-validation (deterministic, balanced).
struct Folds {
  int K = 0;              // folds
  std::vector<int> fold;  // per pose; -1: always in the training folds
};

Folds assign_folds(const MismatchDesign& D0, int np, const DiagnosisOptions& options) {
  Folds out;
  std::vector<int>& fold = out.fold;
  fold.resize(static_cast<std::size_t>(np));
  {
    std::vector<int> perm(static_cast<std::size_t>(np));
    for (int j = 0; j < np; ++j) perm[static_cast<std::size_t>(j)] = j;
    std::mt19937 frng(options.seed + 7919u);
    std::shuffle(perm.begin(), perm.end(), frng);
    // A pose held fixed by the gauge (the home pose) always stays in the training folds.
    std::erase_if(perm,
                  [&](int j) { return D0.jacobian_pose[static_cast<std::size_t>(j)].norm() == 0; });
    for (int j = 0; j < np; ++j) fold[static_cast<std::size_t>(j)] = -1;
    out.K = options.cv_folds == 0 ? std::max(1, static_cast<int>(perm.size()))
                                  : std::min(options.cv_folds, np);
    for (std::size_t q = 0; q < perm.size(); ++q) {
      fold[static_cast<std::size_t>(perm[q])] = static_cast<int>(q) % out.K;
    }
  }
  return out;
}

// A state is a model (identification options, readings with the Gauss-Newton effects moved to
// them) and its fit; refit() adds one candidate to a state.
struct State {
  IdentificationOptions opt;
  MeasurementSet set;
  IdentificationReport report;
  MismatchDesign design;
  std::vector<std::string> gn_ids;  // Gauss-Newton effects (columns in `design`)
  std::vector<Eigen::VectorXd> gn_theta;
  CvRms cv;
  // The catenary's correction that `set` carries (empty without sag): what refit_catenary moved
  // into the lengths and the external wrench, so that it can be taken out and recomputed at a
  // later estimate (polish_gauss_newton).
  std::vector<Eigen::VectorXd> catenary_lengths;
  std::vector<Eigen::Matrix<double, 6, 1>> catenary_wrenches;
  // Its share of the lengths' extra compliance (per pose, size m), beside the Gauss-Newton
  // effects' (corrected_set).
  std::vector<Eigen::VectorXd> catenary_compliance;
};

// A state refitted from `cur`: its own options, readings and fit, `cur`'s Gauss-Newton effects and
// catenary correction (the cross-validation left to the caller).
State successor(const State& cur, IdentificationOptions opt, MeasurementSet set,
                IdentificationReport report, MismatchDesign design) {
  State next;
  next.opt = std::move(opt);
  next.set = std::move(set);
  next.report = std::move(report);
  next.design = std::move(design);
  next.gn_ids = cur.gn_ids;
  next.gn_theta = cur.gn_theta;
  next.catenary_lengths = cur.catenary_lengths;
  next.catenary_wrenches = cur.catenary_wrenches;
  next.catenary_compliance = cur.catenary_compliance;
  return next;
}

// `a` - `b` of two extra compliances (PoseMeasurement::extra_compliance; empty = zero).
Eigen::VectorXd compliance_difference(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  if (b.size() == 0) return a;
  if (a.size() == 0) return -b;
  return a - b;
}

// `set` with the catenary's correction of `st` taken out (the readings before refit_catenary,
// with the later Gauss-Newton effects' corrections kept).
MeasurementSet without_catenary(const State& st) {
  MeasurementSet out = st.set;
  for (std::size_t j = 0; j < out.poses.size() && j < st.catenary_lengths.size(); ++j) {
    PoseMeasurement& pm = out.poses[j];
    pm.cable_lengths -= st.catenary_lengths[j];
    pm.external_wrench -= st.catenary_wrenches[j];
    if (j < st.catenary_compliance.size()) {
      pm.extra_compliance = compliance_difference(pm.extra_compliance, st.catenary_compliance[j]);
    }
  }
  return out;
}

// The design of a state: its readings (made with the force sensors of `nominal`) with the tensions
// as its fit reads them (the columns of the effects that follow the tension, creep, compliance,
// nonlinear elasticity, then use the corrected tension once a force sensor gain or offset is
// estimated).
Result<MismatchDesign> state_design(const CalibratedModel& nominal, const IdentificationReport& rep,
                                    const MeasurementSet& set, const IdentificationOptions& opt,
                                    const MismatchOptions& mopt) {
  return mismatch_design(rep.estimate, tensions_read_with(set, nominal.robot, rep.estimate.robot),
                         rep.poses, &rep.residuals, opt, mopt);
}

// What the refits of one diagnosis share.
struct RefitContext {
  const DiagnosisOptions& options;
  const MismatchDesign& design0;  // the standard identification's design
  const Selection& selection;
  const Folds& folds;
  int dof = 0;            // of the screen
  int m = 0;              // cables
  double logn = 0.0;      // log of the number of residuals
  double log_det0 = 0.0;  // the standard fit's log det: deviances are relative to it
  std::map<std::string, double> log_sizes;  // per candidate: log of its BIC sample size
  // The model the recording's tension readings were made with (their force sensor calibration).
  const CalibratedModel& nominal;

  double log_size(const std::string& id) const {
    const auto it = log_sizes.find(id);
    return it == log_sizes.end() ? logn : it->second;
  }
};

// identify() of a refit, started from an earlier state's estimate `from`. The recording's tension
// readings were made with the nominal force sensor calibration, and identify() reads a tension as
// made with its initial model's calibration (true_tension in identification.cc): the initial model
// keeps the nominal's force sensors, so that an estimated gain or offset is relative to the
// readings and is not applied twice (started from an estimate with a 2 % gain, the next refit's
// model carried 4 %).
Result<IdentificationReport> identify_from(const CalibratedModel& nominal,
                                           const CalibratedModel& from, const MeasurementSet& set,
                                           const IdentificationOptions& opt) {
  CalibratedModel initial = from;
  initial.robot.force_sensors = nominal.robot.force_sensors;
  return identify(initial, set, opt);
}

CvRms state_cv(const RefitContext& ctx, const State& st) {
  Eigen::MatrixXd extra(st.design.num_rows(), 0);
  for (const std::string& id : st.gn_ids) {
    const CandidateColumns* cc = find_columns(st.design, id);
    if (cc == nullptr) continue;
    Eigen::MatrixXd e2(extra.rows(), extra.cols() + cc->X.cols());
    e2 << extra, cc->X;
    extra = std::move(e2);
  }
  return cv_rms(st.design, &extra, ctx.folds.fold, ctx.folds.K);
}

// The least-squares step of an effect's columns X on the residual of design `at`, the
// identification's Jacobian projected out; rank 0 when the data fix none of them (no step).
struct GaussNewtonStep {
  Eigen::VectorXd step;
  Eigen::MatrixXd Ai;  // pseudo-inverse of the projected information of the columns
  int rank = 0;
};
GaussNewtonStep gauss_newton_step(const MismatchDesign& at, const Eigen::MatrixXd& X,
                                  double rank_tolerance) {
  GaussNewtonStep out;
  const auto k = X.cols();
  std::vector<const Eigen::MatrixXd*> bl{&X};
  const PoseGrams g = pose_grams(at, bl, true, false);
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
  for (const auto& Mj : g.M) M += Mj;
  const Eigen::MatrixXd S = reduce_geometry(M, g.geometry);
  out.rank =
      projected_rank(S.topLeftCorner(k, k), M.diagonal().segment(g.geometry, k), rank_tolerance);
  if (out.rank == 0) return out;
  out.Ai = pinv_sym(S.topLeftCorner(k, k), 1e-9);
  out.step = out.Ai * S.block(0, k, k, 1);
  return out;
}

constexpr int kGaussNewtonIterations = 8;
constexpr double kDevianceSettled = 0.01;  // chi^2: a Gauss-Newton refit has converged

// A Gauss-Newton step's corrected readings, re-identified from the best state so far (or
// `cur`); kept as the best when the deviance fell. nullopt: the identification or the design
// failed; else whether the deviance has settled.
std::optional<bool> keep_gauss_newton_step(const RefitContext& ctx, const State& cur,
                                           const std::string& id, MeasurementSet&& corrected,
                                           const Eigen::VectorXd& theta, std::optional<State>& best,
                                           double& best_dev) {
  auto rep = identify_from(ctx.nominal, best ? best->report.estimate : cur.report.estimate,
                           corrected, cur.opt);
  if (!rep) return std::nullopt;
  auto des = state_design(ctx.nominal, *rep, corrected, cur.opt, ctx.options.screen);
  if (!des) return std::nullopt;
  const double dev = rep->chi2 + rep->log_det_covariance;
  // Deviances are chi^2 units with an offset (the log det of the covariance, in SI units) that
  // says nothing of the fit: settled is an absolute change. (Relative to the deviance, LARGE's
  // creep stopped ~100 chi^2 short of its optimum, and every later refit gained that back.)
  const bool settled = best && best_dev - dev < kDevianceSettled;
  if (dev < best_dev) {
    best = successor(cur, cur.opt, std::move(corrected), std::move(*rep), std::move(*des));
    best->gn_ids.push_back(id);
    best->gn_theta.push_back(theta);
    best_dev = dev;
  }
  return settled;
}

// The refit hooks of the descriptors' refit kinds (EffectRefit, effect_library.hpp).

// kIdentification: identify() with the effect's switch on (and its alternative, the lower BIC
// kept). nullopt when it does not converge (the caller falls back to Gauss-Newton).
std::optional<State> refit_by_identification(const RefitContext& ctx, const State& cur,
                                             const EffectDescriptor& effect, EffectFit& fit) {
  IdentificationOptions opt = cur.opt;
  effect.estimate(opt);
  auto rep = identify_from(ctx.nominal, cur.report.estimate, cur.set, opt);
  if (effect.alternative != nullptr) {
    // A reduced set of the effect's parameters (the laser mounting: the beam direction
    // alone), kept when it fits with the lower BIC or the full set cannot be fitted.
    IdentificationOptions dir = opt;
    effect.alternative(dir);
    auto rep_dir = identify_from(ctx.nominal, cur.report.estimate, cur.set, dir);
    auto bic = [&](const IdentificationReport& r) {
      return r.chi2 + r.log_det_covariance +
             static_cast<double>(r.parameters.size()) * ctx.log_size(std::string(effect.id));
    };
    if (rep_dir && rep_dir->converged && (!rep || !rep->converged || bic(*rep_dir) < bic(*rep))) {
      rep = std::move(rep_dir);
      opt = dir;
    }
  }
  if (rep && rep->converged) {
    auto des = state_design(ctx.nominal, *rep, cur.set, opt, ctx.options.screen);
    if (des) {
      State next = successor(cur, opt, cur.set, std::move(*rep), std::move(*des));
      fit.extra_parameters =
          static_cast<int>(next.report.parameters.size() - cur.report.parameters.size());
      std::set<std::string> old;
      for (const auto& p : cur.report.parameters) old.insert(p.name);
      for (const auto& p : next.report.parameters) {
        if (!old.count(p.name))
          fit.parameters.push_back(describe_parameter(p, cur.report.estimate));
      }
      fit.modelled_in_config = true;
      return next;
    }
  }
  return std::nullopt;
}

// kCatenary: sag. `cur.set` holds the readings without the catenary's correction; `mu0` > 0 when
// the residuals of `cur` have the effect at mu0 moved out (a refresh at a later estimate, from
// polish_gauss_newton).
std::optional<State> refit_catenary(const RefitContext& ctx, const State& cur,
                                    const std::string& id, EffectFit& fit, double mu0 = 0.0) {
  const int m = ctx.m;
  // Sag, one parameter: the cables' mass per length mu, fitted by Gauss-Newton on the exact
  // catenary effect (sag_effect, mismatch.hpp) rather than on the first-order columns: the
  // small-sag arc is wrong by its square for a heavy cable at low tension (100 g/m at 50 N
  // over 8 m: ~0.2 mm), and the linear columns left a structured remainder that other
  // candidates took. mu >= 0; the derivative by a forward difference. The catenary is evaluated
  // at the tensions the fit reads (tensions_read_with) and at its EA.
  double mu = std::max(0.0, mu0), info = 0.0;
  std::optional<State> best;
  double best_dev = std::numeric_limits<double>::infinity();
  const State* base = &cur;
  for (int it = 0; it < 6; ++it) {
    const double h = std::max(1e-4, 0.02 * mu);
    const MeasurementSet seen =
        tensions_read_with(cur.set, ctx.nominal.robot, base->report.estimate.robot);
    auto e0 =
        sag_effect(base->report.estimate, seen, base->report.poses, base->design, cur.opt, mu);
    auto e1 =
        sag_effect(base->report.estimate, seen, base->report.poses, base->design, cur.opt, mu + h);
    if (!e0 || !e1) break;
    // The residuals of `base` have the effect at mu (at the previous estimate) moved out:
    // the step fits what is left with the derivative of the effect.
    const Eigen::MatrixXd J = (e1->X - e0->X) / h;
    const PoseGrams g = pose_grams(base->design, {&J}, true, false);
    Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
    for (const auto& Mj : g.M) M += Mj;
    const Eigen::MatrixXd S = reduce_geometry(M, g.geometry);
    if (!(S(0, 0) > 0)) break;
    info = S(0, 0);
    const double next_mu = std::max(0.0, mu + S(0, 1) / S(0, 0));
    if (!(next_mu > 0.0)) break;
    Eigen::VectorXd comp;
    auto e = sag_effect(base->report.estimate, seen, base->report.poses, base->design, cur.opt,
                        next_mu, &comp);
    if (!e) break;
    CandidateColumns per_unit = *e;
    per_unit.X /= next_mu;
    per_unit.si /= next_mu;
    const Eigen::VectorXd theta = Eigen::VectorXd::Constant(1, next_mu);
    MeasurementSet corrected;
    if (!corrected_set(cur.set, base->design, per_unit, theta, false, corrected)) break;
    // The corrected lengths depend on the tension readings through the sag: their sigma
    // carries that part of the force noise too (else chi^2 grows with the sag's steepness
    // at low tension, ~0.5 mm per N at 40 N on LARGE).
    for (int k = 0; k < base->design.num_rows(); ++k) {
      const auto uk = static_cast<std::size_t>(k);
      if (base->design.kind[uk] != ResidualKind::kLength) continue;
      PoseMeasurement& pm = corrected.poses[static_cast<std::size_t>(base->design.pose[uk])];
      if (pm.extra_compliance.size() != m) pm.extra_compliance = Eigen::VectorXd::Zero(m);
      pm.extra_compliance(base->design.index[uk]) += comp(k);
    }
    const std::optional<bool> settled =
        keep_gauss_newton_step(ctx, cur, id, std::move(corrected), theta, best, best_dev);
    if (!settled) break;
    mu = next_mu;
    if (*settled) break;
    base = &*best;
  }
  if (!best) return std::nullopt;
  State next = std::move(*best);
  // The correction the readings now carry, for a later refresh.
  next.catenary_lengths.assign(next.set.poses.size(), Eigen::VectorXd());
  next.catenary_wrenches.assign(next.set.poses.size(), Eigen::Matrix<double, 6, 1>::Zero());
  next.catenary_compliance.assign(next.set.poses.size(), Eigen::VectorXd());
  for (std::size_t j = 0; j < next.set.poses.size(); ++j) {
    next.catenary_lengths[j] = next.set.poses[j].cable_lengths - cur.set.poses[j].cable_lengths;
    next.catenary_wrenches[j] =
        next.set.poses[j].external_wrench - cur.set.poses[j].external_wrench;
    next.catenary_compliance[j] = compliance_difference(next.set.poses[j].extra_compliance,
                                                        cur.set.poses[j].extra_compliance);
  }
  fit.extra_parameters = 1;
  const double scale = std::sqrt(std::max(1.0, next.report.chi2 / std::max(1, ctx.dof - 1)));
  const double mu_fit = next.gn_theta.back()(0);
  const double sd = info > 0 ? scale / std::sqrt(info) : kNaN;
  fit.parameters.push_back(describe_coefficient(id, 0, 1, mu_fit, sd));
  CalibratedModel probe = next.report.estimate;
  fit.modelled_in_config = write_effect(id, next.gn_theta.back(), probe);
  return next;
}

// kGaussNewton (and the fallback of a failed identification refit).
std::optional<State> refit_gauss_newton(const RefitContext& ctx, const State& cur,
                                        const std::string& id, const CandidateColumns* cc,
                                        EffectFit& fit) {
  // Gauss-Newton augmented fit: the coefficients from the columns with the identification's
  // Jacobian projected out, the effect moved to the readings, the identification redone
  // from its solution; repeated (the columns re-evaluated at the new estimate) until the
  // deviance settles, so that a strong effect is fitted to its optimum, not to first order.
  const int k = static_cast<int>(cc->X.cols());
  Eigen::VectorXd theta = Eigen::VectorXd::Zero(k);
  Eigen::MatrixXd Ai;
  int rank = 0;
  const MismatchDesign* at = &cur.design;
  const CandidateColumns* cols = cc;
  std::optional<State> best;
  double best_dev = std::numeric_limits<double>::infinity();
  for (int it = 0; it < kGaussNewtonIterations; ++it) {
    GaussNewtonStep gn = gauss_newton_step(*at, cols->X, ctx.options.screen.rank_tolerance);
    if (gn.rank == 0) break;
    if (it == 0) rank = gn.rank;
    Ai = std::move(gn.Ai);
    theta += gn.step;
    MeasurementSet corrected;
    if (!corrected_set(cur.set, *at, *cols, theta, ctx.options.gauss_newton_force_noise,
                       corrected)) {
      break;
    }
    const std::optional<bool> settled =
        keep_gauss_newton_step(ctx, cur, id, std::move(corrected), theta, best, best_dev);
    if (!settled) break;
    if (*settled) break;
    at = &best->design;
    cols = find_columns(*at, id);
    if (cols == nullptr || cols->X.cols() != k) break;
  }
  if (!best || rank == 0) return std::nullopt;
  State next = std::move(*best);
  theta = next.gn_theta.back();
  fit.extra_parameters = rank;
  const double scale = std::sqrt(std::max(1.0, next.report.chi2 / std::max(1, ctx.dof - rank)));
  for (int q = 0; q < k; ++q) {
    if (Ai(q, q) <= 0) continue;  // a column the data do not fix
    fit.parameters.push_back(describe_coefficient(id, q, k, theta(q), std::sqrt(Ai(q, q)) * scale));
  }
  CalibratedModel probe = next.report.estimate;
  fit.modelled_in_config = write_effect(id, theta, probe);
  return next;
}

// -2 log likelihood of a state up to the constant shared by all states of this recording.
double deviance(const RefitContext& ctx, const State& st) {
  return st.report.chi2 + st.report.log_det_covariance - ctx.log_det0;
}

// BIC of a state with effects whose extra parameters cost `penalty` together (up to the shared
// constant).
double joint_bic(const RefitContext& ctx, const State& st, double penalty) {
  return deviance(ctx, st) + penalty;
}

// The BIC penalty of the effects' extra parameters: k ln n of each.
double bic_penalty(const RefitContext& ctx, const std::vector<EffectFit>& effects) {
  double p = 0.0;
  for (const auto& f : effects) p += f.extra_parameters * ctx.log_size(f.id);
  return p;
}

// The catenary of a state recomputed at its estimate: the correction refit_catenary moved into the
// readings was computed at the tensions and EA of its own fit, and an effect added after it (force
// sensor gains, the cables' EA) changes both (LARGE sag + Hooke + force gain, noise-free: chi^2 94
// left over 188 dof with the stale correction). Its readings taken back, the mass per length is
// refitted from its value at the state's estimate; kept when the deviance falls (`dev` updated).
bool refresh_catenary(const RefitContext& ctx, State& st, double& dev) {
  std::size_t e = st.gn_ids.size();
  for (std::size_t q = 0; q < st.gn_ids.size(); ++q) {
    const EffectDescriptor* effect = find_effect(st.gn_ids[q]);
    if (effect != nullptr && effect->refit == EffectRefit::kCatenary) e = q;
  }
  if (e == st.gn_ids.size() || st.catenary_lengths.size() != st.set.poses.size() ||
      st.gn_theta[e].size() != 1) {
    return false;
  }
  const std::string id = st.gn_ids[e];
  const double mu = st.gn_theta[e](0);
  State pre = st;
  pre.set = without_catenary(st);
  pre.catenary_lengths.clear();
  pre.catenary_wrenches.clear();
  pre.catenary_compliance.clear();
  pre.gn_ids.erase(pre.gn_ids.begin() + static_cast<std::ptrdiff_t>(e));
  pre.gn_theta.erase(pre.gn_theta.begin() + static_cast<std::ptrdiff_t>(e));
  EffectFit unused;
  std::optional<State> next = refit_catenary(ctx, pre, id, unused, mu);
  if (!next) return false;
  const double d = deviance(ctx, *next);
  if (!(d < dev - kDevianceSettled)) return false;
  st = std::move(*next);
  dev = d;
  return true;
}

// The Gauss-Newton effects of a state refitted beside the effects that came after them: added
// in turn, an earlier effect keeps the coefficients it was fitted with alone, and the later ones
// (the drum scales beside creep, estimated by identify()) move the optimum. Each pass takes every
// Gauss-Newton effect's step from the residual the state leaves (its columns at the state's
// estimate, the identification projected out), moves it into the readings and redoes the
// identification, kept while the deviance falls. (LARGE creep + drum scale: creep fitted first
// left ~10^2 chi^2 along its own column; the second screen found creep at p 1e-27 beside itself,
// and every further candidate gained that back, rejected only by the cross-validation.) The
// catenary keeps its own fit (its correction also changes the length sigmas): each pass recomputes
// it at the state's estimate (refresh_catenary).
void polish_gauss_newton(const RefitContext& ctx, State& st) {
  if (st.gn_ids.empty()) return;
  double dev = deviance(ctx, st);
  bool moved = false;
  for (int pass = 0; pass < kGaussNewtonIterations; ++pass) {
    bool improved = false;
    for (std::size_t e = 0; e < st.gn_ids.size(); ++e) {
      const EffectDescriptor* effect = find_effect(st.gn_ids[e]);
      if (effect == nullptr || effect->refit == EffectRefit::kCatenary) continue;
      const CandidateColumns* cols = find_columns(st.design, st.gn_ids[e]);
      if (cols == nullptr || cols->X.cols() != st.gn_theta[e].size()) continue;
      const GaussNewtonStep gn =
          gauss_newton_step(st.design, cols->X, ctx.options.screen.rank_tolerance);
      if (gn.rank == 0) continue;
      MeasurementSet corrected;
      if (!corrected_set(st.set, st.design, *cols, gn.step, ctx.options.gauss_newton_force_noise,
                         corrected)) {
        continue;
      }
      auto rep = identify_from(ctx.nominal, st.report.estimate, corrected, st.opt);
      if (!rep) continue;
      auto des = state_design(ctx.nominal, *rep, corrected, st.opt, ctx.options.screen);
      if (!des) continue;
      const double d = rep->chi2 + rep->log_det_covariance - ctx.log_det0;
      if (!(d < dev - kDevianceSettled)) continue;
      st.set = std::move(corrected);
      st.report = std::move(*rep);
      st.design = std::move(*des);
      st.gn_theta[e] += gn.step;
      dev = d;
      improved = moved = true;
    }
    if (refresh_catenary(ctx, st, dev)) improved = moved = true;
    if (!improved) break;
  }
  if (moved) st.cv = state_cv(ctx, st);
}

// The accepted Gauss-Newton effects' parameters as `st` has them (after polish_gauss_newton the
// coefficients differ from those of the trial that accepted them; the standard deviations stay
// the trial's).
void refresh_gauss_newton_parameters(const State& st, std::vector<EffectFit>& fits) {
  for (std::size_t e = 0; e < st.gn_ids.size(); ++e) {
    const std::string& id = st.gn_ids[e];
    const Eigen::VectorXd& theta = st.gn_theta[e];
    const int k = static_cast<int>(theta.size());
    for (EffectFit& f : fits) {
      if (f.id != id) continue;
      for (int q = 0; q < k; ++q) {
        const std::string name = describe_coefficient(id, q, k, 0.0, 0.0).name;
        for (EffectParameter& p : f.parameters) {
          if (p.name == name) p = describe_coefficient(id, q, k, theta(q), p.std_dev);
        }
      }
    }
  }
}

// The accepted effects estimated by identify() (elasticity, drum scales, force sensor gains, ...)
// as the model of `st` has them: the values and deviations of its identification, refitted beside
// every effect accepted after them (the model written, d.model_after, is this one; the trial that
// accepted an effect had the value before the later ones were in).
void refresh_identified_parameters(const State& st, std::vector<EffectFit>& fits) {
  // The model the identification started from, as describe_parameter reads it: EA is reported as
  // EA0 (1 + e).
  CalibratedModel initial = st.report.estimate;
  for (const ParameterEstimate& p : st.report.parameters) {
    if (p.id.kind != ParameterKind::kStiffness) continue;
    for (std::size_t i = 0; i < initial.robot.cables.size(); ++i) {
      if (p.id.index < 0 || static_cast<std::size_t>(p.id.index) == i) {
        initial.robot.cables[i].ea /= 1.0 + p.value;
      }
    }
  }
  for (EffectFit& f : fits) {
    const EffectDescriptor* effect = find_effect(f.id);
    if (effect == nullptr || effect->refit != EffectRefit::kIdentification) continue;
    for (const ParameterEstimate& p : st.report.parameters) {
      const EffectParameter now = describe_parameter(p, initial);
      for (EffectParameter& e : f.parameters) {
        if (e.name == now.name) e = now;
      }
    }
  }
}

// Stage 2, refit: the model of `cur` with candidate `id` added, fitted in full by the refit hook
// of the candidate's descriptor (effect_library.hpp); `fit` says how much better it is. nullopt:
// the candidate cannot be fitted on this state.
std::optional<State> refit(const RefitContext& ctx, const State& cur, const std::string& id,
                           EffectFit& fit) {
  const CandidateColumns* cc = find_columns(cur.design, id);
  if (cc == nullptr) return std::nullopt;
  fit = EffectFit{};
  fit.id = id;
  fit.name = cc->name;
  fit.family = cc->family;
  for (std::size_t c = 0; c < ctx.design0.candidates.size(); ++c) {
    if (ctx.design0.candidates[c].id == id) {
      fit.inclusion_probability = ctx.selection.inclusion[c];
      fit.family_inclusion_probability =
          ctx.selection.family_probability(ctx.design0.candidates[c].family);
    }
  }
  fit.chi2_before = cur.report.chi2;
  fit.deviance_before = deviance(ctx, cur);
  fit.cv_rms_before = cur.cv.length_m;
  fit.cv_normalized_before = cur.cv.normalized;
  const EffectDescriptor* effect = find_effect(id);
  std::optional<State> next;
  if (effect != nullptr && effect->refit == EffectRefit::kIdentification) {
    next = refit_by_identification(ctx, cur, *effect, fit);
  }
  if (!next && effect != nullptr && effect->refit == EffectRefit::kCatenary) {
    next = refit_catenary(ctx, cur, id, fit);
    if (!next) return std::nullopt;
  }
  // An identification refit that fails falls back to the Gauss-Newton augmented fit.
  if (!next) next = refit_gauss_newton(ctx, cur, id, cc, fit);
  if (!next) return std::nullopt;
  next->cv = state_cv(ctx, *next);
  fit.chi2_after = next->report.chi2;
  fit.cv_rms_after = next->cv.length_m;
  fit.cv_normalized_after = next->cv.normalized;
  fit.deviance_after = deviance(ctx, *next);
  fit.lrt_statistic = fit.deviance_before - fit.deviance_after;
  fit.lrt_p_value =
      fit.extra_parameters > 0 ? chi2_upper_tail(fit.lrt_statistic, fit.extra_parameters) : 1.0;
  fit.bic_delta = -fit.lrt_statistic + fit.extra_parameters * ctx.log_size(id);
  return next;
}

struct Trial {
  EffectFit fit;
  State state;
};

const EffectFit* trial_fit(const std::vector<Trial>& trials, const std::string& id) {
  for (const auto& t : trials) {
    if (t.fit.id == id) return &t.fit;
  }
  return nullptr;
}

// Holm's step-down adjustment of p-values (same order as `p`).
std::vector<double> holm(const std::vector<double>& p) {
  std::vector<std::size_t> order(p.size());
  for (std::size_t q = 0; q < order.size(); ++q) order[q] = q;
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return p[a] < p[b]; });
  std::vector<double> adj(p.size(), 1.0);
  double running = 0.0;
  for (std::size_t q = 0; q < order.size(); ++q) {
    running = std::max(running, std::min(1.0, static_cast<double>(order.size() - q) * p[order[q]]));
    adj[order[q]] = running;
  }
  return adj;
}

// What an effect must show to be accepted: its likelihood-ratio test passes (after Holm over the
// tried ones) at `alpha`, it is worth its parameters (BIC below 0) and it improves the held-out
// fit; an effect of the selection group of the suspect being confirmed
// (DiagnosisOptions::confirm_suspect) also needs its BIC below -strong_bic.
struct Gate {
  double alpha = 0.05;
  std::string strong_group;  // empty: none
  double strong_bic = 0.0;
};

Gate gate_of(const DiagnosisOptions& options) {
  Gate g;
  g.alpha = options.screen.alpha;
  if (const EffectDescriptor* e =
          options.confirm_suspect.empty() ? nullptr : find_effect(options.confirm_suspect)) {
    g.strong_group = selection_group(std::string(e->family));
    g.strong_bic = options.weak_step_bic;
  }
  return g;
}

// A step that adds `f` beside accepted effects is held back as a suspect instead of taken
// (DiagnosisOptions::weak_step_bic): weak evidence, robot time available, not a confirmatory run.
bool held_back_step(const EffectFit& f, const DiagnosisOptions& options) {
  return options.weak_step_bic > 0.0 && options.follow_up_poses > 0 &&
         options.screen.only_groups.empty() && !(f.bic_delta < -options.weak_step_bic);
}

bool passes_tests(const EffectFit& f, double p_adj, const Gate& gate) {
  const double needed = !gate.strong_group.empty() && selection_group(f.family) == gate.strong_group
                            ? -gate.strong_bic
                            : 0.0;
  return p_adj < gate.alpha && f.bic_delta < std::min(0.0, needed) &&
         f.cv_normalized_after < f.cv_normalized_before;
}

// Among passing fits, one per family: the simplest, unless a richer member is significantly
// better than it (LRT of the difference) and has the lower BIC; of those, the lowest BIC.
const Trial* choose_trial(const std::vector<const Trial*>& pool, const std::vector<double>& adj,
                          const Gate& gate) {
  std::map<std::string, const Trial*> per_family;
  std::vector<std::size_t> order(pool.size());
  for (std::size_t q = 0; q < order.size(); ++q) order[q] = q;
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return pool[a]->fit.extra_parameters < pool[b]->fit.extra_parameters;
  });
  for (std::size_t q : order) {
    const Trial* t = pool[q];
    if (!passes_tests(t->fit, adj[q], gate)) continue;
    const std::string group = selection_group(t->fit.family);
    auto it = per_family.find(group);
    if (it == per_family.end()) {
      per_family[group] = t;
      continue;
    }
    const EffectFit& simple = it->second->fit;
    const int dk = t->fit.extra_parameters - simple.extra_parameters;
    const double gain = simple.deviance_after - t->fit.deviance_after;
    if (dk > 0 && chi2_upper_tail(gain, dk) < gate.alpha && t->fit.bic_delta < simple.bic_delta) {
      it->second = t;
    }
  }
  const Trial* best = nullptr;
  for (const auto& [fam, t] : per_family) {
    if (best == nullptr || t->fit.bic_delta < best->fit.bic_delta) best = t;
  }
  return best;
}

// The forward step's choice among the effects tried beside the accepted ones (Holm over their
// likelihood-ratio tests); nullptr when none passes. Only a trial whose BIC is more than
// `min_evidence` below the accepted set's can be chosen (every trial counts in Holm's family).
const Trial* best_step(const std::vector<Trial>& tried, const Gate& gate,
                       double min_evidence = 0.0) {
  std::vector<double> p;
  for (const auto& t : tried) p.push_back(t.fit.lrt_p_value);
  const std::vector<double> all = holm(p);
  std::vector<const Trial*> pool;
  std::vector<double> adj;
  for (std::size_t q = 0; q < tried.size(); ++q) {
    if (!(tried[q].fit.bic_delta < -min_evidence)) continue;
    pool.push_back(&tried[q]);
    adj.push_back(all[q]);
  }
  return choose_trial(pool, adj, gate);
}

// A candidate the screen sees only through a structure it does not explain: significant, but no
// longer once the unexplained structures (MismatchSummary::unexplained) are projected out. It
// would take part of physics outside the library under a wrong name (a force sensor gain for
// pulley friction on LARGE), so it is not named.
bool proxy_for_structure(const MismatchSummary& screen, const std::string& id, double gate) {
  const CandidateScreen* cs = screen.find(id);
  return cs != nullptr && cs->p_adjusted < gate && !(cs->p_beyond_structure < gate);
}

// Two candidates confounded on this pose set (canonical correlation of their projected columns
// above the threshold) are not accepted together unless the newcomer `id` keeps at least
// `own_directions` directions of its own (its rank minus the canonical correlations above the
// threshold): per-cable force gains beside creep or sag keep 7 of 8 and are tried, creep or
// elasticity beside the gains keep none. The second screening round (`second_round`) also tries
// every candidate beside an effect estimated by identify() (`conditional`): its parameters are then
// in the model the newcomer is screened and tested against, so the test is conditional on it.
// Letting every confounded pair into the first round's forward steps was measured worse (3 seeds:
// LARGE compound 17/27 instead of 19/27: elasticity beside creep, 0.97, was named); with the own
// directions rule LARGE's gains beside creep are named in 3 of 3 (docs/mismatch-benchmark.md).
bool confounded_clash(const std::vector<ConfoundedPair>& pairs, const std::string& accepted_id,
                      const std::string& id, bool conditional = false, int own_directions = 0) {
  const EffectDescriptor* e = find_effect(accepted_id);
  if (conditional && e != nullptr && e->refit == EffectRefit::kIdentification) return false;
  for (const auto& p : pairs) {
    const bool first = p.first == id && p.second == accepted_id;
    if (!first && !(p.first == accepted_id && p.second == id)) continue;
    const int own = (first ? p.first_rank : p.second_rank) - p.directions;
    if (own_directions > 0 && own >= own_directions) return false;
    return true;
  }
  return false;
}

// The effects `ids` refitted jointly from the standard model, in that order (each marked
// accepted); nullopt when one cannot be fitted.
struct JointFit {
  State state;
  std::vector<EffectFit> fits;
  double penalty = 0.0;  // the BIC penalty of the effects' extra parameters together
};
std::optional<JointFit> joint_refit(const RefitContext& ctx, const State& standard,
                                    const std::vector<std::string>& ids) {
  JointFit out{standard, {}, 0.0};
  for (const std::string& id : ids) {
    EffectFit f;
    auto nx = refit(ctx, out.state, id, f);
    if (!nx) return std::nullopt;
    out.state = std::move(*nx);
    if (ctx.options.polish_gauss_newton && !out.fits.empty()) polish_gauss_newton(ctx, out.state);
    out.penalty += f.extra_parameters * ctx.log_size(id);
    f.accepted = true;
    out.fits.push_back(std::move(f));
  }
  return out;
}

// The candidate list as reported: each accepted effect's entry is its accepted fit, the accepted
// ones first, then by BIC.
void order_candidates(std::vector<EffectFit>& candidates) {
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const EffectFit& a, const EffectFit& b) {
                     if (a.accepted != b.accepted) return a.accepted;
                     return a.bic_delta < b.bic_delta;
                   });
}

// ---- Stage 3, acceptance: every kept candidate refitted from the standard model (the trials),
// forward selection from each of the best passing first effects, then swaps.
struct Acceptance {
  std::vector<Trial> trials;          // the kept candidates, each added to the standard model
  std::vector<EffectFit> candidates;  // refitted candidates, accepted first, then by BIC
  std::vector<EffectFit> accepted;
  State current;                    // the model with the accepted effects
  std::set<std::string> ids_taken;  // the accepted effects' ids
  // Joint BIC of each set of effects refitted jointly from the standard model by the swaps, in
  // the order refitted (+inf: could not be fitted); stage 4 judges pairs in the set with them.
  std::map<std::vector<std::string>, double> joint_bics;
  // An effect held back for weak evidence (DiagnosisOptions::weak_step_bic: a forward step of the
  // winning path or the second round): a suspect for follow-up poses, not named.
  std::optional<EffectFit> held_back;
};

// A refinement (an accepted effect whose selection group holds a simpler family: nonlinear
// elasticity beside Hooke's) is named only when what it adds passes the gate of naming an effect:
// the set refitted jointly with the simpler member in its place, the likelihood ratio of the
// refinement's extra parameters, Bonferroni over the library, below
// DiagnosisOptions::refinement_gate_p; else the simpler member takes its place. (The paths' joint
// BIC charges one curvature parameter log n, ~6: LARGE's Hooke beside sag, seed 5, was named
// nonlinear elasticity at a deviance gain of 7.6.)
void keep_refinements_that_pass(const RefitContext& ctx, const State& standard,
                                const MismatchSummary& screen, Acceptance& acc) {
  if (!(ctx.options.refinement_gate_p > 0.0)) return;
  const double library = static_cast<double>(std::max<std::size_t>(1, screen.candidates.size()));
  for (std::size_t pos = 0; pos < acc.accepted.size(); ++pos) {
    const EffectFit& rich = acc.accepted[pos];
    const std::string group = selection_group(rich.family);
    const CandidateColumns* rc = find_columns(ctx.design0, rich.id);
    if (rc == nullptr || rich.family == group) continue;  // not a refinement
    // The simplest member of the group's own family (Hooke's shared EA for nonlinear elasticity;
    // not EA per cable, which nonlinear elasticity does not nest).
    const CandidateColumns* simple = nullptr;
    for (const CandidateColumns& c : ctx.design0.candidates) {
      if (c.family != group || c.X.cols() >= rc->X.cols() ||
          (simple != nullptr && c.X.cols() >= simple->X.cols())) {
        continue;
      }
      simple = &c;
    }
    if (simple == nullptr) continue;
    std::vector<std::string> ids;
    for (const EffectFit& f : acc.accepted) ids.push_back(f.id == rich.id ? simple->id : f.id);
    auto joint = joint_refit(ctx, standard, ids);
    if (!joint) continue;
    acc.joint_bics[ids] = joint_bic(ctx, joint->state, joint->penalty);
    const int dk = rich.extra_parameters - joint->fits[pos].extra_parameters;
    const double gain = deviance(ctx, joint->state) - deviance(ctx, acc.current);
    if (dk <= 0 ||
        chi2_upper_tail(std::max(0.0, gain), dk) * library < ctx.options.refinement_gate_p) {
      continue;
    }
    acc.current = std::move(joint->state);
    acc.accepted = std::move(joint->fits);
    acc.ids_taken.clear();
    for (const EffectFit& f : acc.accepted) acc.ids_taken.insert(f.id);
  }
}

Acceptance accept_effects(const RefitContext& ctx, const State& standard,
                          const MismatchSummary& screen) {
  const DiagnosisOptions& options = ctx.options;
  const std::vector<ConfoundedPair>& pairs = screen.confounded;
  Acceptance out;
  std::vector<Trial>& trials = out.trials;
  for (const std::string& id : ctx.selection.to_refit) {
    EffectFit fit;
    auto st = refit(ctx, standard, id, fit);
    if (st) trials.push_back({std::move(fit), std::move(*st)});
  }
  const Gate gate = gate_of(options);
  auto passes = [&](const EffectFit& f, double p_adj) { return passes_tests(f, p_adj, gate); };
  auto choose = [&](const std::vector<const Trial*>& pool, const std::vector<double>& adj) {
    return choose_trial(pool, adj, gate);
  };
  State current = standard;
  std::set<std::string> families_taken;
  std::set<std::string>& ids_taken = out.ids_taken;
  auto is_confounded = [&](const std::string& accepted_id, const std::string& id) {
    return confounded_clash(pairs, accepted_id, id, false, options.forward_own_directions);
  };
  // Forward selection, started from each of the (up to four) best first effects that pass: the
  // greedy path from the single best may begin with a per-cable effect that also absorbs part of
  // a second one (winch compliance per winch for elasticity + drum scale). Each path adds
  // further effects refitted jointly with the accepted ones and tested against them; the path
  // with the lowest joint BIC wins.
  std::vector<const Trial*> firsts;
  {
    std::vector<const Trial*> pool;
    std::vector<double> p;
    for (const auto& t : trials) {
      // The first effect must also be seen by the linear screen (Holm-adjusted over the library):
      // on noise, a nonlinear refit can reach a far minimum (a beam tilt of 8 degrees on MINI's
      // null data, LRT 20 on 2 parameters) whose likelihood ratio overstates its significance.
      // An effect the screen sees only before the correction is a suspect (follow-up poses).
      const CandidateScreen* cs = screen.find(t.fit.id);
      if (cs != nullptr && !(cs->p_adjusted < options.screen_gate_p)) continue;
      if (proxy_for_structure(screen, t.fit.id, options.screen_gate_p)) continue;
      pool.push_back(&t);
      p.push_back(t.fit.lrt_p_value);
    }
    const std::vector<double> adj = holm(p);
    if (const Trial* b = choose(pool, adj)) firsts.push_back(b);
    std::vector<std::size_t> order(pool.size());
    for (std::size_t q = 0; q < order.size(); ++q) order[q] = q;
    std::sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
      return pool[x]->fit.bic_delta < pool[y]->fit.bic_delta;
    });
    for (std::size_t q : order) {
      if (firsts.size() >= 4) break;
      if (!passes(pool[q]->fit, adj[q])) continue;
      if (std::find(firsts.begin(), firsts.end(), pool[q]) == firsts.end()) {
        firsts.push_back(pool[q]);
      }
    }
    for (const auto& t : trials) out.candidates.push_back(t.fit);
  }
  struct Path {
    std::vector<EffectFit> accepted;
    State state;
    double bic = 0.0;
    std::optional<EffectFit> held_back;  // the step it stopped at for weak evidence
  };
  auto forward_from = [&](const Trial& first) {
    Path path{{first.fit}, first.state, 0.0, std::nullopt};
    path.accepted.front().accepted = true;
    std::set<std::string> groups{selection_group(first.fit.family)};
    std::set<std::string> ids{first.fit.id};
    while (static_cast<int>(path.accepted.size()) < options.max_effects) {
      std::vector<Trial> more;
      for (const std::string& id : ctx.selection.to_refit) {
        const CandidateColumns* cc = find_columns(ctx.design0, id);
        if (cc == nullptr || !ctx.selection.kept.count(id) ||
            groups.count(selection_group(cc->family)) ||
            proxy_for_structure(screen, id, options.screen_gate_p))
          continue;
        bool clash = false;
        for (const std::string& t : ids) clash = clash || is_confounded(t, id);
        if (clash) continue;
        EffectFit fit;
        auto st = refit(ctx, path.state, id, fit);
        if (st) more.push_back({std::move(fit), std::move(*st)});
      }
      const Trial* best = best_step(more, gate);
      if (best == nullptr) break;
      if (held_back_step(best->fit, options)) {
        // The paths compete as if the step were taken: holding it back decides what is named,
        // not which path explains the recording best (a path ending at a weak step would lose to
        // one with a stand-in for its first effect: elasticity for creep beside force gains).
        path.held_back = best->fit;
        std::vector<EffectFit> with = path.accepted;
        with.push_back(best->fit);
        path.bic = joint_bic(ctx, best->state, bic_penalty(ctx, with));
        return path;
      }
      EffectFit f = best->fit;
      f.accepted = true;
      path.accepted.push_back(f);
      groups.insert(selection_group(f.family));
      ids.insert(f.id);
      path.state = best->state;
      if (options.polish_gauss_newton) polish_gauss_newton(ctx, path.state);
    }
    path.bic = joint_bic(ctx, path.state, bic_penalty(ctx, path.accepted));
    return path;
  };
  if (options.max_effects > 0 && !firsts.empty()) {
    std::optional<Path> best_path;
    for (const Trial* t : firsts) {
      Path path = forward_from(*t);
      if (!best_path || path.bic < best_path->bic) best_path = std::move(path);
    }
    out.accepted = std::move(best_path->accepted);
    current = std::move(best_path->state);
    out.held_back = std::move(best_path->held_back);
    for (const auto& f : out.accepted) {
      ids_taken.insert(f.id);
      families_taken.insert(selection_group(f.family));
    }
  }
  // Swaps. The forward steps are greedy: a per-cable effect may take the first place by also
  // absorbing part of a second effect (winch compliance per winch for elasticity + drum scale).
  // With two or more accepted effects, each one is replaced in turn by every other kept
  // candidate, the set refitted jointly from the standard model, and the best swap that lowers
  // the joint BIC is made (repeated while one helps). A swap never brings in a candidate
  // confounded with one of the others, whatever its own directions: each swap is a joint refit of
  // the whole set, and admitting those made a mutated 12-pose recording's diagnose spend 138
  // refits (100 s) on swaps, for no change in the benchmark's verdicts.
  for (int pass = 0; pass < 3 && out.accepted.size() >= 2; ++pass) {
    const double bic_now = joint_bic(ctx, current, bic_penalty(ctx, out.accepted));
    double best_bic = bic_now - 2.0;  // a swap must gain clearly
    std::optional<State> best_state;
    std::vector<EffectFit> best_set;
    for (std::size_t pos = 0; pos < out.accepted.size(); ++pos) {
      for (const std::string& id : ctx.selection.to_refit) {
        const CandidateColumns* cc = find_columns(ctx.design0, id);
        if (cc == nullptr || ids_taken.count(id) ||
            proxy_for_structure(screen, id, options.screen_gate_p))
          continue;
        // A member of the replaced effect's own selection group with no more columns (Hooke for
        // nonlinear elasticity) may come in beside an effect that the replaced one was as
        // confounded with: the set is no more confounded than before, and no richer. (A richer
        // member let in so named nonlinear elasticity for LARGE's Hooke beside sag, seed 5.)
        const std::string& replaced = out.accepted[pos].id;
        const CandidateColumns* rc = find_columns(ctx.design0, replaced);
        const bool same_group =
            rc != nullptr &&
            selection_group(out.accepted[pos].family) == selection_group(cc->family) &&
            cc->X.cols() <= rc->X.cols();
        bool clash = false;
        for (std::size_t q = 0; q < out.accepted.size(); ++q) {
          if (q == pos) continue;
          const std::string& other = out.accepted[q].id;
          clash = clash || selection_group(out.accepted[q].family) == selection_group(cc->family) ||
                  (confounded_clash(pairs, other, id) &&
                   !(same_group && confounded_clash(pairs, other, replaced)));
        }
        if (clash) continue;
        std::vector<std::string> ids;
        for (std::size_t q = 0; q < out.accepted.size(); ++q) {
          ids.push_back(q == pos ? id : out.accepted[q].id);
        }
        auto joint = joint_refit(ctx, standard, ids);
        const double b = joint ? joint_bic(ctx, joint->state, joint->penalty)
                               : std::numeric_limits<double>::infinity();
        out.joint_bics[ids] = b;
        if (!joint) continue;
        if (b < best_bic) {
          best_bic = b;
          best_state = std::move(joint->state);
          best_set = std::move(joint->fits);
        }
      }
    }
    if (!best_state) break;
    current = std::move(*best_state);
    out.accepted = std::move(best_set);
    ids_taken.clear();
    families_taken.clear();
    for (const auto& f : out.accepted) {
      ids_taken.insert(f.id);
      families_taken.insert(selection_group(f.family));
    }
  }
  out.current = std::move(current);
  keep_refinements_that_pass(ctx, standard, screen, out);
  for (auto& c : out.candidates) {
    c.accepted = false;
    for (const auto& f : out.accepted) {
      if (c.id == f.id) c = f;
    }
  }
  for (const auto& f : out.accepted) {
    const bool listed = std::any_of(out.candidates.begin(), out.candidates.end(),
                                    [&](const EffectFit& c) { return c.id == f.id; });
    if (!listed) out.candidates.push_back(f);
  }
  order_candidates(out.candidates);
  return out;
}

// ---- Stage 3b, the second screening round: the screen redone on the model with the accepted
// effects. An effect that a larger one hid at the first screen (the bootstrap selects the larger
// one first, so the smaller misses the inclusion threshold and is never refitted) shows on the
// residual that the accepted effects leave. Each candidate significant there (Holm over the
// library, the same gate as a first effect, and not a proxy for unexplained structure) is
// refitted jointly with the accepted effects and accepted by the tests of a forward step; the
// screen is then redone, until nothing passes or max_effects are accepted. The last screen's
// structure scan says what the model with the effects still leaves unexplained.
// A candidate confounded on this pose set with an accepted effect is tried only when that effect
// is estimated by the identification (its parameters are then in the Jacobian the screen
// projects out, so the screen's test is conditional on it); beside an effect moved into the
// readings at its fitted size, the screen's test would not be.
MismatchSummary second_round(const RefitContext& ctx, const MismatchSummary& screen0,
                             Acceptance& acc) {
  const DiagnosisOptions& options = ctx.options;
  const Gate gate = gate_of(options);
  MismatchSummary last;
  for (;;) {
    auto s2 = locate_mismatch(acc.current.report, acc.current.set, acc.current.opt, options.screen);
    if (!s2) {
      // The model with the effects cannot be screened (e.g. no degrees of freedom left): the
      // first screen's conclusions stand.
      last = screen0;
      break;
    }
    last = std::move(*s2);
    if (static_cast<int>(acc.accepted.size()) >= options.max_effects) break;
    std::set<std::string> groups;
    for (const auto& f : acc.accepted) groups.insert(selection_group(f.family));
    std::vector<Trial> more;
    for (const CandidateScreen& cs : last.candidates) {
      if (cs.rank == 0 || !(cs.p_adjusted < options.screen_gate_p) ||
          !(cs.p_beyond_structure < options.screen_gate_p) || acc.ids_taken.count(cs.id)) {
        continue;
      }
      const CandidateColumns* cc = find_columns(ctx.design0, cs.id);
      if (cc == nullptr || groups.count(selection_group(cc->family))) continue;
      bool clash = false;
      for (const auto& f : acc.accepted) {
        clash = clash || confounded_clash(screen0.confounded, f.id, cs.id, /*conditional=*/true,
                                          options.second_round_own_directions);
      }
      if (clash) continue;
      EffectFit fit;
      auto st = refit(ctx, acc.current, cs.id, fit);
      if (st) more.push_back({std::move(fit), std::move(*st)});
    }
    const Trial* best = best_step(more, gate, options.second_round_min_evidence);
    if (best == nullptr) break;
    if (held_back_step(best->fit, options)) {
      // Weak evidence: robot time decides it (stage 5 proposes its follow-up poses). One held
      // back by the first round's forward steps stays the suspect.
      if (!acc.held_back) {
        acc.held_back = best->fit;
        acc.held_back->round = 2;
      }
      break;
    }
    EffectFit f = best->fit;
    f.accepted = true;
    f.round = 2;
    // Its size beside the accepted effects; as a candidate, its fit from the standard model.
    acc.accepted.push_back(f);
    acc.ids_taken.insert(f.id);
    acc.current = best->state;
    if (options.polish_gauss_newton) polish_gauss_newton(ctx, acc.current);
    bool listed = false;
    for (auto& c : acc.candidates) {
      if (c.id == f.id) {
        c = f;
        listed = true;
      }
    }
    if (!listed) acc.candidates.push_back(f);
  }
  order_candidates(acc.candidates);
  return last;
}

// ---- Stage 3c, the backward check: once the second round accepted an effect, an earlier one may
// only have stood in for it (winch compliance per winch for per-cable force gains). Each accepted
// effect is tested for removal: the others refitted jointly from the standard model, the
// likelihood ratio of the full set against that (Holm over the accepted effects). The effect with
// the weakest evidence is dropped while its corrected p-value is not below alpha. Returns whether
// an effect was dropped.
bool backward_check(const RefitContext& ctx, const State& standard, Acceptance& acc) {
  const double alpha = ctx.options.screen.alpha;
  bool dropped = false;
  while (acc.accepted.size() >= 2) {
    const double dev_full = deviance(ctx, acc.current);
    std::vector<double> p;
    std::vector<std::optional<JointFit>> without;
    for (std::size_t pos = 0; pos < acc.accepted.size(); ++pos) {
      std::vector<std::string> ids;
      for (std::size_t q = 0; q < acc.accepted.size(); ++q) {
        if (q != pos) ids.push_back(acc.accepted[q].id);
      }
      auto joint = joint_refit(ctx, standard, ids);
      const int k = acc.accepted[pos].extra_parameters;
      if (!joint || k <= 0) {
        p.push_back(0.0);  // cannot be tested: kept
        without.emplace_back();
        continue;
      }
      p.push_back(chi2_upper_tail(std::max(0.0, deviance(ctx, joint->state) - dev_full), k));
      for (std::size_t q = 0, f = 0; q < acc.accepted.size(); ++q) {
        if (q != pos) joint->fits[f++].round = acc.accepted[q].round;
      }
      without.push_back(std::move(joint));
    }
    const std::vector<double> adj = holm(p);
    std::size_t weakest = 0;
    for (std::size_t q = 1; q < adj.size(); ++q) {
      if (p[q] > p[weakest]) weakest = q;
    }
    if (adj[weakest] < alpha || !without[weakest]) break;
    const std::string gone = acc.accepted[weakest].id;
    acc.current = std::move(without[weakest]->state);
    acc.accepted = std::move(without[weakest]->fits);
    acc.ids_taken.erase(gone);
    for (auto& c : acc.candidates) {
      if (c.id == gone) c.accepted = false;
    }
    dropped = true;
  }
  if (dropped) {
    for (auto& c : acc.candidates) {
      for (const auto& f : acc.accepted) {
        if (c.id == f.id) c = f;
      }
    }
    order_candidates(acc.candidates);
  }
  return dropped;
}

// ---- Stage 4, naming: the screen's confounded pairs that this recording cannot tell apart (both
// fitted from the standard model; the fits not yet tried are added to the trials and candidates).
std::vector<ConfoundedPair> confounded_pairs(const RefitContext& ctx, const State& standard,
                                             const MismatchSummary& screen, Acceptance& acc) {
  // A pair of the screen (canonical correlation above the threshold) is reported as confounded
  // only when this recording cannot tell its two fits apart: a BIC difference of more than
  // DiagnosisOptions::decisive_bic between them (both fitted from the standard model) is very
  // strong evidence for the better one (Kass and Raftery), and then it is named alone.
  // Beside other accepted effects, the alternative is also judged in the accepted set: the set
  // with the accepted effect swapped for it, refitted jointly from the standard model. Alone, an
  // alternative can lose decisively where beside the others it does not (MINI creep + drum scale
  // + laser tilt: a common drum scale takes creep's constant part, and the shared EA beside the
  // drum scales fits as well as creep, while alone the two differ by more than decisive_bic);
  // the pair is then reported, and its separating poses decide.
  const double bic_now = joint_bic(ctx, acc.current, bic_penalty(ctx, acc.accepted));
  auto close_in_the_set = [&](const std::string& taken_id, const std::string& other_id) {
    if (acc.accepted.size() < 2) return false;  // alone is the set
    std::vector<std::string> ids;
    for (const auto& f : acc.accepted) {
      if (f.id != taken_id && f.id == other_id) return false;
      ids.push_back(f.id == taken_id ? other_id : f.id);
    }
    auto known = acc.joint_bics.find(ids);  // the swaps' last pass tried most of these
    if (known == acc.joint_bics.end()) {
      auto joint = joint_refit(ctx, standard, ids);
      const double b = joint ? joint_bic(ctx, joint->state, joint->penalty)
                             : std::numeric_limits<double>::infinity();
      known = acc.joint_bics.emplace(ids, b).first;
    }
    return known->second - bic_now <= ctx.options.decisive_bic;
  };
  std::vector<ConfoundedPair> found;
  for (const auto& p : screen.confounded) {
    const bool taken_a = acc.ids_taken.count(p.first) > 0,
               taken_b = acc.ids_taken.count(p.second) > 0;
    if (!taken_a && !taken_b) continue;
    for (const std::string& id : {p.first, p.second}) {
      if (trial_fit(acc.trials, id) != nullptr) continue;
      EffectFit fit;
      auto st = refit(ctx, standard, id, fit);
      if (!st) continue;
      acc.trials.push_back({fit, std::move(*st)});
      acc.candidates.push_back(std::move(fit));
    }
    const EffectFit* fa = trial_fit(acc.trials, p.first);
    const EffectFit* fb = trial_fit(acc.trials, p.second);
    if (taken_a != taken_b) {
      const EffectFit* taken = taken_a ? fa : fb;
      const EffectFit* other = taken_a ? fb : fa;
      if (other == nullptr) continue;  // the other cannot be fitted at all: nothing to confuse
      if (taken != nullptr && other->bic_delta - taken->bic_delta > ctx.options.decisive_bic &&
          !close_in_the_set(taken_a ? p.first : p.second, taken_a ? p.second : p.first))
        continue;
    }
    found.push_back(p);
  }
  return found;
}

// ---- Stage 5, extra-pose design. Extra poses (separating and follow-up) come from a feasible
// candidate grid: 4 x 4 x 4 positions over the region the recording visited x {level, +-tilt roll,
// +-tilt pitch}, each at the planned pretension and at twice it (equal tensions at different free
// lengths tell a ~F*L effect from a ~F one), simulated noise-free with the standard estimate and
// appended to the recording as one augmented design.
struct ExtraPoseGrid {
  std::vector<Pose> poses;
  std::vector<double> pretensions;       // N, per pose
  std::optional<MismatchDesign> design;  // the recording with the grid appended
};

// When an extra pose measured right after the recording would be read: time and temperature
// (NaN where the recording has none).
PoseMeasurement next_reading_slot(const MeasurementSet& set) {
  PoseMeasurement next;
  double first = kNaN, last = kNaN;
  int timed = 0;
  for (const PoseMeasurement& pm : set.poses) {
    if (std::isfinite(pm.time)) {
      if (!std::isfinite(first)) first = pm.time;
      last = pm.time;
      ++timed;
    }
    if (std::isfinite(pm.temperature)) next.temperature = pm.temperature;
  }
  if (timed >= 2) next.time = last + (last - first) / static_cast<double>(timed - 1);
  // One time stamp, or times so large that the next one overflows: the last one.
  if (timed >= 1 && !std::isfinite(next.time)) next.time = last;
  return next;
}

ExtraPoseGrid extra_pose_grid(const RobotModel& robot, const IdentificationReport& before,
                              const MeasurementSet& set,
                              const IdentificationOptions& identification,
                              const DiagnosisOptions& options) {
  ExtraPoseGrid out;
  std::vector<Pose>& cand = out.poses;
  std::vector<double>& cand_pretension = out.pretensions;
  std::optional<MismatchDesign>& aug = out.design;
  {
    // The region the recording has already visited (the robot held the platform there with
    // this model's commands), capped by the pose-design box of the robot: near the edge of the
    // model's wrench-feasible workspace the real robot may not hold the platform (cables go
    // slack where the anchors differ from the model).
    PoseDesignOptions box;
    fit_design_box_to_robot(robot, box);
    Eigen::Vector3d he = Eigen::Vector3d::Zero();
    double tilt = 0.0;
    for (const Pose& p : before.poses) {
      he = he.cwiseMax((p.position - robot.home.position).cwiseAbs());
      tilt = std::max(
          {tilt, std::abs(p.rpy(0) - robot.home.rpy(0)), std::abs(p.rpy(1) - robot.home.rpy(1))});
    }
    he = options.separating_half_extent_scale * he.cwiseMin(box.half_extent);
    tilt = std::min(tilt, 0.2);
    const double f_ref = default_reference_tension(before.estimate.robot);
    std::vector<Pose> grid;
    const int ppa = 4;
    const std::vector<Eigen::Vector3d> rpys = {
        Eigen::Vector3d::Zero(), Eigen::Vector3d(tilt, 0, 0), Eigen::Vector3d(-tilt, 0, 0),
        Eigen::Vector3d(0, tilt, 0), Eigen::Vector3d(0, -tilt, 0)};
    for (int ix = 0; ix < ppa; ++ix) {
      for (int iy = 0; iy < ppa; ++iy) {
        for (int iz = 0; iz < ppa; ++iz) {
          for (const auto& rpy : rpys) {
            Pose p;
            p.position =
                robot.home.position + he.cwiseProduct(Eigen::Vector3d(-1.0 + 2.0 * ix / (ppa - 1),
                                                                      -1.0 + 2.0 * iy / (ppa - 1),
                                                                      -1.0 + 2.0 * iz / (ppa - 1)));
            p.rpy = robot.home.rpy + rpy;
            // Feasible for the estimate and for the model the recording was commanded with.
            if (simple_tension_distribution(before.estimate.robot, p, f_ref) &&
                simple_tension_distribution(robot, p, f_ref)) {
              grid.push_back(p);
            }
          }
        }
      }
    }
    // The extra poses are measured after the recording: their time is the next pose's (the
    // recording's mean spacing after its last pose), their temperature the last one read. The
    // time-dependent candidates (creep, drifts) are evaluated there, not where the simulation
    // below would put them (pose g at g seconds, as if at the start: a creep column near zero
    // on those made 6 extra poses seem to separate creep from elasticity, canonical correlation
    // 0.95 -> 0.11, which the poses measured after the recording did not).
    const PoseMeasurement next = next_reading_slot(set);
    MeasurementSet all = set;
    std::vector<Pose> all_poses = before.poses;
    for (const double level : {f_ref, 2.0 * f_ref}) {
      std::vector<Pose> ok;
      for (const Pose& p : grid) {
        if (level == f_ref || (simple_tension_distribution(before.estimate.robot, p, level) &&
                               simple_tension_distribution(robot, p, level))) {
          ok.push_back(p);
        }
      }
      SimulationOptions so;
      so.add_noise = false;
      so.reference_tension = level;
      auto sim = simulate_measurements(before.estimate, ok, set.noise, 1, so);
      if (!sim) continue;
      for (std::size_t g = 0; g < ok.size(); ++g) {
        all.poses.push_back(sim->set.poses[g]);
        all.poses.back().time = next.time;
        all.poses.back().temperature = next.temperature;
        all_poses.push_back(ok[g]);
        cand.push_back(ok[g]);
        cand_pretension.push_back(level);
      }
    }
    if (!cand.empty()) {
      auto des =
          mismatch_design(before.estimate, all, all_poses, nullptr, identification, options.screen);
      if (des) aug = std::move(*des);
    }
  }
  return out;
}

// The separating poses of each confounded pair: greedy over the grid, lowest canonical
// correlation of the pair.
std::vector<ConfoundedFinding> separate(const std::vector<ConfoundedPair>& found,
                                        const std::vector<Trial>& trials, const ExtraPoseGrid& grid,
                                        int np, const DiagnosisOptions& options) {
  std::vector<ConfoundedFinding> out;
  {
    for (const auto& p : found) {
      ConfoundedFinding cf;
      cf.first = p.first;
      cf.second = p.second;
      cf.correlation = p.correlation;
      cf.correlation_with_extra = p.correlation;
      cf.description = p.description;
      if (const EffectFit* f = trial_fit(trials, p.first)) cf.first_fit = *f;
      if (const EffectFit* f = trial_fit(trials, p.second)) cf.second_fit = *f;
      const CandidateColumns* ca = grid.design ? find_columns(*grid.design, p.first) : nullptr;
      const CandidateColumns* cb = grid.design ? find_columns(*grid.design, p.second) : nullptr;
      if (ca != nullptr && cb != nullptr) {
        const PoseGrams g = pose_grams(*grid.design, {&ca->X, &cb->X}, true, false);
        const int ka = g.block_size[0], kb = g.block_size[1];
        auto corr = [&](const Eigen::MatrixXd& M) {
          const Eigen::MatrixXd S = reduce_geometry(M, g.geometry);
          return canonical_correlation(S.topLeftCorner(ka, ka), S.block(ka, ka, kb, kb),
                                       S.block(0, ka, ka, kb));
        };
        Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
        for (int j = 0; j < np; ++j) M += g.M[static_cast<std::size_t>(j)];
        // Lowest canonical correlation: maximise its negative, only while it falls.
        const std::vector<int> chosen = greedy_extra_poses(
            g, np, options.separating_poses, [](int) { return true; },
            [&](const Eigen::MatrixXd& Mq) { return -corr(Mq); }, -corr(M), M);
        for (int q : chosen) {
          cf.separating_poses.push_back(grid.poses[static_cast<std::size_t>(q)]);
          cf.separating_pretensions.push_back(grid.pretensions[static_cast<std::size_t>(q)]);
        }
        const double rho = corr(M);
        cf.correlation_with_extra = rho;
      }
      out.push_back(std::move(cf));
    }
  }
  return out;
}

// The follow_up_poses poses that add the most information on `suspect`'s parameters (log det of
// its projected information, the identification profiled out; greedy over the grid at the planned
// pretension); nullopt when the grid has none for it.
std::optional<FollowUp> follow_up_for(const CandidateScreen& suspect, const RobotModel& estimate,
                                      const ExtraPoseGrid& grid, int np,
                                      const DiagnosisOptions& options) {
  const CandidateColumns* cs = grid.design ? find_columns(*grid.design, suspect.id) : nullptr;
  if (cs == nullptr) return std::nullopt;
  const PoseGrams g = pose_grams(*grid.design, {&cs->X}, true, false);
  const int k = g.block_size[0];
  auto logdet = [&](const Eigen::MatrixXd& M) {
    const Eigen::MatrixXd S = reduce_geometry(M, g.geometry).topLeftCorner(k, k);
    const double ridge = 1e-9 * std::max(S.trace(), 1e-300);
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(S + ridge * Eigen::MatrixXd::Identity(k, k));
    return ldlt.vectorD().array().max(ridge).log().sum();
  };
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
  for (int j = 0; j < np; ++j) M += g.M[static_cast<std::size_t>(j)];
  const double f_ref = default_reference_tension(estimate);
  FollowUp fu;
  fu.suspect = suspect.id;
  fu.name = suspect.name;
  fu.p_value = suspect.p_value;
  fu.p_adjusted = suspect.p_adjusted;
  fu.parameters = k;
  fu.information_before = logdet(M);
  const std::vector<int> chosen = greedy_extra_poses(
      g, np, options.follow_up_poses,
      [&](int q) { return grid.pretensions[static_cast<std::size_t>(q)] == f_ref; }, logdet,
      -std::numeric_limits<double>::infinity(), M);
  for (int q : chosen) {
    fu.poses.push_back(grid.poses[static_cast<std::size_t>(q)]);
    fu.pretensions.push_back(grid.pretensions[static_cast<std::size_t>(q)]);
  }
  fu.information_after = logdet(M);
  if (fu.poses.empty()) return std::nullopt;
  return fu;
}

// Follow-up poses for a suspect. With no effect named, the candidate with the lowest
// screen p-value is a suspect when that p-value after Holm's correction is below
// options.suspect_p: an effect near the noise (a laser tilt of half a degree leaves 0.6 sigma
// on 25 laser rows) is often visible there but not named. (Before Holm's correction the
// smallest of the library's p-values was below 0.2 on 17 of 20 null recordings.) Its
// poses (follow_up_for) are proposed; measured and appended, they decide it.
// When the screen's overall test already fails (the verdict will be "mismatch unexplained"),
// more poses are the next step anyway: the candidate with the lowest p-value is then the suspect
// whatever its corrected p-value.
std::optional<FollowUp> follow_up(const MismatchSummary& screen, const RobotModel& estimate,
                                  const std::function<const ExtraPoseGrid&()>& grid_of, int np,
                                  const DiagnosisOptions& options, bool misfit_clause = true,
                                  const std::vector<std::string>& not_suspects = {}) {
  const bool unexplained_misfit = misfit_clause && screen.p_value < options.screen.alpha;
  const CandidateScreen* suspect = nullptr;
  for (const auto& cs : screen.candidates) {
    if (cs.modelled || cs.rank == 0) continue;
    if (std::find(not_suspects.begin(), not_suspects.end(), cs.id) != not_suspects.end()) continue;
    if (proxy_for_structure(screen, cs.id, options.screen_gate_p)) continue;
    if (!(cs.p_adjusted < options.suspect_p) && !unexplained_misfit) continue;
    if (suspect == nullptr || cs.p_value < suspect->p_value) suspect = &cs;
  }
  if (suspect == nullptr) return std::nullopt;
  return follow_up_for(*suspect, estimate, grid_of(), np, options);
}

void state_gross_readings(Diagnosis& d) {
  d.verdict = Diagnosis::Verdict::kInconclusive;
  d.headline = "Inconclusive: " + describe(d.gross_readings) + ", not missing physics. Check " +
               (d.gross_readings.size() == 1 ? "that reading" : "those readings") +
               ", measure the pose again or leave it out, and diagnose again.";
  d.findings.push_back(d.headline);
  for (const auto& g : d.gross_readings) {
    d.findings.push_back("Gross reading: " + describe(g) +
                         " from the standard model refitted with a robust (Cauchy) loss.");
  }
}

// ---- Stage 6, the model with the accepted effects: `after`, model_after (the Gauss-Newton effects
// written where the config can hold them), the held-out RMS (cross-validation or the validation
// recording) and the per-channel RMS.
Status model_the_effects(Diagnosis& d, const State& current, const CvRms& cv_before, int K,
                         bool leave_one_out, const MeasurementSet* validation,
                         const CalibratedModel& nominal,
                         const IdentificationOptions& identification, int nl) {
  d.held_out_source = validation != nullptr ? "validation recording"
                      : leave_one_out       ? "leave-one-pose-out cross-validation"
                                            : format("%d-fold cross-validation", K);
  d.held_out_rms_before = cv_before.length_m;
  d.held_out_rms_after = cv_before.length_m;
  if (!d.accepted.empty()) {
    d.after = current.report;
    d.model_after = current.report.estimate;
    for (std::size_t q = 0; q < current.gn_ids.size(); ++q) {
      write_effect(current.gn_ids[q], current.gn_theta[q], d.model_after);
    }
    RobotModel& after = d.model_after.robot;
    if (after.suspended && after.num_cables() < 6 && !current.gn_ids.empty()) {
      // The effects written may move where the platform hangs: the config's home must stay an
      // equilibrium (the model check of the config loader), at the same position and heading.
      if (const auto hang = suspended_equilibrium_pose(after, after.home); hang.ok()) {
        after.home = hang->pose;
      }
    }
    d.held_out_rms_after = current.cv.length_m;
  }
  if (validation != nullptr) {
    // Held-out = the validation recording: its poses re-located with the geometry fixed.
    IdentificationOptions fixed = identification;
    fixed.estimate_frame_anchors = false;
    fixed.estimate_platform_anchors = false;
    // identify() needs at least one estimated parameter: the encoder zeros are re-estimated on
    // the validation recording (a new recording is homed again), everything else is fixed.
    fixed.estimate_length_offsets = true;
    fixed.estimate_length_scales = false;
    fixed.estimate_stiffness = StiffnessEstimate::kFixed;
    fixed.estimate_force_gains = false;
    fixed.estimate_force_offsets = false;
    fixed.estimate_laser_origin = false;
    fixed.estimate_laser_direction = false;
    fixed.estimate_laser_plane = false;
    fixed.gauge = Gauge::kNone;
    fixed.compute_covariance = false;
    // The validation's tensions were read with the nominal's force sensors; identify() reads them
    // with its initial model's (which carries the gains and offsets estimated, if any).
    auto vb =
        identify(d.before.estimate,
                 tensions_read_with(*validation, nominal.robot, d.before.estimate.robot), fixed);
    if (!vb) {
      Status st = vb.status();
      st.prepend("diagnose: re-locating the validation poses: ");
      return st;
    }
    d.held_out_rms_before = vb->rms_length_m;
    d.held_out_rms_after = vb->rms_length_m;
    if (d.after) {
      auto va =
          identify(d.model_after,
                   tensions_read_with(*validation, nominal.robot, d.model_after.robot), fixed);
      if (va) d.held_out_rms_after = va->rms_length_m;
    }
  }
  const IdentificationReport& aft = d.after ? *d.after : d.before;
  d.channels.push_back({"cable lengths", "m", d.before.rms_length_m, aft.rms_length_m});
  // A channel is listed when the recording has it (a laser in the config need not be measured).
  auto measured = [&](auto rows_of) {
    for (const PoseResiduals& pr : d.before.residuals) {
      if (rows_of(pr)) return true;
    }
    return false;
  };
  if (nl > 0 && identification.use_laser && measured([](const PoseResiduals& pr) {
        return pr.laser_normalized.size() > 0 && !pr.laser_normalized.array().isNaN().all();
      })) {
    d.channels.push_back({"laser", "m", d.before.rms_laser_m, aft.rms_laser_m});
  }
  if (identification.use_equilibrium && d.before.rms_wrench_n > 0) {
    d.channels.push_back({"equilibrium (force)", "N", d.before.rms_wrench_n, aft.rms_wrench_n});
  }
  if (identification.use_swivel && measured([](const PoseResiduals& pr) {
        return pr.swivel_normalized.size() > 0 && !pr.swivel_normalized.array().isNaN().all();
      })) {
    d.channels.push_back({"swivel angles", "rad", d.before.rms_swivel_rad, aft.rms_swivel_rad});
  }
  if (identification.use_inclinometer &&
      measured([](const PoseResiduals& pr) { return !std::isnan(pr.inclination_normalized(0)); })) {
    d.channels.push_back(
        {"inclinometer", "rad", d.before.rms_inclination_rad, aft.rms_inclination_rad});
  }
  if (identification.use_imu_yaw &&
      measured([](const PoseResiduals& pr) { return !std::isnan(pr.imu_yaw_normalized); })) {
    d.channels.push_back({"IMU yaw", "rad", d.before.rms_imu_yaw_rad, aft.rms_imu_yaw_rad});
  }
  return Status::success();
}

// "the direction of the last move of cables 2 and 5 (cable tensions); ...": what the structures
// follow, for a headline.
std::string unexplained_words(const std::vector<UnexplainedStructure>& structures) {
  std::vector<std::string> variables;
  for (const auto& u : structures) {
    if (std::find(variables.begin(), variables.end(), u.variable) == variables.end()) {
      variables.push_back(u.variable);
    }
  }
  std::string what;
  for (const std::string& v : variables) {
    std::vector<int> cables;
    std::string where;
    for (const auto& u : structures) {
      if (u.variable != v) continue;
      for (int c : u.cables) {
        if (std::find(cables.begin(), cables.end(), c) == cables.end()) cables.push_back(c);
      }
      where += (where.empty() ? "" : ", ") + u.channel;
    }
    std::sort(cables.begin(), cables.end());
    std::string list;
    for (std::size_t q = 0; q < cables.size(); ++q) {
      if (q > 0) list += q + 1 == cables.size() ? " and " : ", ";
      list += std::to_string(cables[q] + 1);
    }
    if (!what.empty()) what += "; ";
    what += "the " + v + " of cable" + (cables.size() > 1 ? "s " : " ") + list + " (" + where + ")";
  }
  return what;
}

// ---- Stage 7, verdict and findings.
void state_verdict(Diagnosis& d, double alpha) {
  const bool misfit = d.screen.p_value < alpha;
  if (!d.accepted.empty()) {
    d.verdict = Diagnosis::Verdict::kMismatchNamed;
    std::string names;
    for (const auto& f : d.accepted) {
      if (!names.empty()) names += "; ";
      names += f.name;
    }
    d.headline = "Missing physics found: " + names + ".";
    if (d.screen_after && !d.screen_after->unexplained.empty()) {
      d.headline += " Unexplained structure remains, following " +
                    unexplained_words(d.screen_after->unexplained) + " (details below).";
    }
  } else if (!d.screen.unexplained.empty()) {
    // Structure that no candidate of the library explains: say what it follows.
    d.verdict = Diagnosis::Verdict::kMismatchUnexplained;
    d.headline = "Unexplained structure following " + unexplained_words(d.screen.unexplained) +
                 ": no candidate effect of the library explains it (details below).";
  } else if (misfit) {
    d.verdict = Diagnosis::Verdict::kMismatchUnexplained;
    d.headline = format(
        "The model does not explain the recording (chi^2 = %.1f for %d degrees of freedom), and "
        "no candidate effect explains the misfit.",
        d.screen.chi2, d.screen.dof);
  } else {
    d.verdict = Diagnosis::Verdict::kNoMismatch;
    d.headline = format(
        "No missing physics found: the residuals are consistent with the sensor noise (chi^2 = "
        "%.1f for %d degrees of freedom, p = %.3g).",
        d.screen.chi2, d.screen.dof, d.screen.p_value);
  }
  d.findings.push_back(d.headline);
  if (d.follow_up && d.follow_up->held_back) {
    const FollowUp& fu = *d.follow_up;
    d.findings.push_back(format(
        "Suspected, not proven: %s passed the tests beside the effects named, but with weak "
        "evidence (BIC %+.1f; p = %.3g on the second screen, %.3g after Holm's correction). "
        "Measure the %d proposed follow-up poses (they multiply the information on its parameters "
        "by %.1f), append them to this recording and diagnose again to decide.",
        fu.name.c_str(), fu.bic_delta, fu.p_value, fu.p_adjusted, static_cast<int>(fu.poses.size()),
        std::exp((fu.information_after - fu.information_before) / std::max(1, fu.parameters))));
  } else if (d.follow_up) {
    const FollowUp& fu = *d.follow_up;
    d.findings.push_back(format(
        "Suspected, not proven: %s (p = %.3g for it alone, %.3g after Holm's correction over the "
        "candidates). Measure the %d proposed follow-up poses (they multiply the information on "
        "its parameters by %.1f), append them to this recording and diagnose again to decide.",
        fu.name.c_str(), fu.p_value, fu.p_adjusted, static_cast<int>(fu.poses.size()),
        std::exp((fu.information_after - fu.information_before) / std::max(1, fu.parameters))));
  }
  for (const auto& f : d.accepted) {
    std::string s = f.name + ": ";
    for (std::size_t q = 0; q < f.parameters.size(); ++q) {
      if (q > 0) s += "; ";
      s += f.parameters[q].text;
    }
    s += format(
        " (LRT %.1f on %d parameters, p = %.3g; BIC %+.1f; held-out RMS %.3f -> %.3f mm; "
        "its family '%s' selected in %.0f %% of the bootstrap resamples%s)%s.",
        f.lrt_statistic, f.extra_parameters, f.lrt_p_value, f.bic_delta, 1e3 * f.cv_rms_before,
        1e3 * f.cv_rms_after, f.family.c_str(), 100 * f.family_inclusion_probability,
        f.round == 2 ? "; found by the second screening round, on what the effects before it leave"
                     : "",
        f.modelled_in_config ? "" : "; the config cannot carry it (report only)");
    d.findings.push_back(s);
  }
  if (!d.accepted.empty() && d.screen_after) {
    for (const auto& u : d.screen_after->unexplained) {
      d.findings.push_back("With the effects above modelled: " + u.description);
    }
  }
  for (const auto& c : d.confounded) {
    d.findings.push_back(format(
        "%s. Both fits: %s (chi^2 %.1f) and %s (chi^2 %.1f). %d extra poses would lower their "
        "canonical correlation from %.4f to %.4f.",
        c.description.c_str(), c.first.c_str(), c.first_fit.chi2_after, c.second.c_str(),
        c.second_fit.chi2_after, static_cast<int>(c.separating_poses.size()), c.correlation,
        c.correlation_with_extra));
  }
  if (d.verdict != Diagnosis::Verdict::kNoMismatch) {
    d.findings.push_back(format("Held-out length residual RMS (%s): %.3f mm before, %.3f mm after.",
                                d.held_out_source.c_str(), 1e3 * d.held_out_rms_before,
                                1e3 * d.held_out_rms_after));
  }
  for (std::size_t q = 0; q < d.screen.findings.size(); ++q) {
    // With nothing found, the headline already is the screen's overall fit test (its first line).
    if (q == 0 && d.verdict == Diagnosis::Verdict::kNoMismatch) continue;
    d.findings.push_back(d.screen.findings[q]);
  }
}

}  // namespace

const char* to_string(Diagnosis::Verdict v) {
  switch (v) {
    case Diagnosis::Verdict::kNoMismatch:
      return "no mismatch";
    case Diagnosis::Verdict::kMismatchNamed:
      return "mismatch named";
    case Diagnosis::Verdict::kMismatchUnexplained:
      return "mismatch unexplained";
    case Diagnosis::Verdict::kInconclusive:
      return "inconclusive";
  }
  return "unknown";
}

namespace {
// Every normalised residual of a fit, with where it comes from (the equilibrium of a pose is one
// reading: its whitened rows mix the cables' tensions).
std::vector<GrossReading> normalised_readings(const IdentificationReport& rep) {
  std::vector<GrossReading> all;
  auto add = [&](int j, const char* channel, int index, double si, double sigmas) {
    if (std::isfinite(sigmas)) all.push_back({j, channel, index, si, std::abs(sigmas)});
  };
  for (int j = 0; j < static_cast<int>(rep.residuals.size()); ++j) {
    const PoseResiduals& r = rep.residuals[static_cast<std::size_t>(j)];
    for (Eigen::Index i = 0; i < r.length_normalized.size(); ++i) {
      add(j, "cable length", static_cast<int>(i), r.length_m(i), r.length_normalized(i));
    }
    for (Eigen::Index i = 0; i < r.laser_normalized.size(); ++i) {
      add(j, "laser distance", static_cast<int>(i), r.laser_m(i), r.laser_normalized(i));
    }
    if (r.wrench_normalized.allFinite()) {
      add(j, "equilibrium", -1, r.wrench_si.head<3>().norm(),
          r.wrench_normalized.cwiseAbs().maxCoeff());
    }
    for (Eigen::Index i = 0; i < r.swivel_normalized.size(); ++i) {
      add(j, "swivel angle", static_cast<int>(i), r.swivel_rad(i), r.swivel_normalized(i));
    }
    if (r.inclination_normalized.allFinite()) {
      const int c =
          std::abs(r.inclination_normalized(0)) >= std::abs(r.inclination_normalized(1)) ? 0 : 1;
      add(j, "inclination", -1, r.inclination_rad(c), r.inclination_normalized(c));
    }
    add(j, "IMU yaw", -1, r.imu_yaw_rad, r.imu_yaw_normalized);
  }
  return all;
}

// The gate of each channel: max(gross_sigmas, gross_spread x the 95th percentile of the channel's
// normalised residuals). Each channel against its own spread: missing physics can leave the
// lengths thousands of their (sub-micrometre) sigmas out while a wild laser reading is hundreds of
// its own.
std::map<std::string, double> channel_gates(const std::vector<GrossReading>& all,
                                            const DiagnosisOptions& options) {
  std::map<std::string, std::vector<double>> mags;
  for (const auto& g : all) mags[g.channel].push_back(g.sigmas);
  std::map<std::string, double> gate;
  for (auto& [channel, v] : mags) {
    const auto q95 = v.begin() + static_cast<std::ptrdiff_t>(0.95 * (v.size() - 1));
    std::nth_element(v.begin(), q95, v.end());
    gate[channel] = std::max(options.gross_sigmas, options.gross_spread * *q95);
  }
  return gate;
}

// Whether the fit with the accepted effects brings every flagged reading within gross_sigmas:
// physics concentrated in a few readings (DiagnosisOptions::gross_effects_sigmas) is then
// modelled, while a wild reading stays out whatever effect is beside it.
bool explained_by_effects(const std::vector<GrossReading>& gross, const IdentificationReport& fit,
                          const DiagnosisOptions& options) {
  const std::vector<GrossReading> all = normalised_readings(fit);
  for (const GrossReading& g : gross) {
    const auto r = std::find_if(all.begin(), all.end(), [&](const GrossReading& a) {
      return a.pose == g.pose && a.channel == g.channel && a.index == g.index;
    });
    if (r == all.end() || !(r->sigmas <= options.gross_sigmas)) return false;
  }
  return true;
}
}  // namespace

// ---- Stage 0, gross readings (DiagnosisOptions::gross_sigmas): the standard model refitted with
// a Cauchy loss, which a few wild readings cannot drag, and the readings it leaves far out.
std::vector<GrossReading> find_gross_readings(const CalibratedModel& nominal,
                                              const MeasurementSet& set,
                                              const IdentificationReport& standard,
                                              const IdentificationOptions& identification,
                                              const DiagnosisOptions& options) {
  if (!(options.gross_sigmas > 0)) return {};
  IdentificationOptions robust = identification;
  robust.loss = RobustLoss::kCauchy;
  robust.loss_scale = 3.0;
  robust.progress = {};
  IdentificationOptions plain = identification;
  plain.progress = {};
  // The robust cost is not convex: from the nominal model (LARGE's anchors 3 cm = 300 sigmas off)
  // it flattens every residual and a pose can settle far off, leaving its clean readings metres
  // out; from the least-squares estimate it cannot reach a fit that a wild reading dragged to a
  // bound. Both starts, the lower robust cost kept.
  auto robust_fit = [&](const MeasurementSet& s) -> Result<IdentificationReport> {
    auto a = identify(nominal, s, robust);
    auto b = identify_from(nominal, standard.estimate, s, robust);
    if (!a.ok() || (b.ok() && b->final_cost < a->final_cost)) return b;
    return a;
  };
  // One reading at a time: the worst is taken out (marked missing) and the rest refitted, so a
  // wild length reading does not also flag the equilibrium it tilted.
  MeasurementSet rest = set;
  std::vector<GrossReading> out;
  while (true) {
    auto rep = robust_fit(rest);
    if (!rep) return {};
    std::vector<GrossReading> all = normalised_readings(*rep);
    if (all.empty()) return {};
    const std::size_t isolated = std::max<std::size_t>(1, all.size() / 50);
    const std::map<std::string, double> gate = channel_gates(all, options);
    const auto worst =
        std::max_element(all.begin(), all.end(), [&](const GrossReading& a, const GrossReading& b) {
          return a.sigmas / gate.at(a.channel) < b.sigmas / gate.at(b.channel);
        });
    if (!(worst->sigmas > gate.at(worst->channel))) break;
    out.push_back(*worst);
    if (out.size() > isolated) return {};  // structure, not a few wild readings
    PoseMeasurement& pm = rest.poses[static_cast<std::size_t>(worst->pose)];
    const double nan = std::numeric_limits<double>::quiet_NaN();
    if (worst->channel == "cable length") {
      pm.cable_lengths(worst->index) = nan;
    } else if (worst->channel == "laser distance") {
      pm.laser_distances(worst->index) = nan;
    } else if (worst->channel == "equilibrium") {
      pm.tensions.setConstant(nan);
    } else if (worst->channel == "swivel angle") {
      pm.swivel_angles(worst->index) = nan;
    } else if (worst->channel == "inclination") {
      pm.inclination.setConstant(nan);
    } else {
      pm.imu_yaw = nan;
    }
  }
  if (out.empty()) return out;
  // Taking them out must lower the least-squares chi^2 as wild readings do (at least a quarter of
  // gross_sigmas^2 each), not as clean readings of a misplaced robust fit would, and without them
  // the rest must fit within the noise or the drop must be most of the misfit (else: physics,
  // which can also leave a few readings far out of a robust fit where it sits in a few poses).
  auto rest_fit = identify(nominal, rest, plain);
  if (!rest_fit || rest_fit->dof <= 0) return {};
  const double drop = standard.chi2 - rest_fit->chi2;
  if (!(drop >=
        0.25 * options.gross_sigmas * options.gross_sigmas * static_cast<double>(out.size()))) {
    return {};
  }
  const bool rest_fits = chi2_upper_tail(rest_fit->chi2, rest_fit->dof) >= options.gross_rest_p;
  // When the rest does not fit, the readings must carry gross_share of the whole misfit beyond
  // the noise (chi^2 - dof): a wild reading beside a real effect carries nearly all of it (a laser
  // reading 100 mm off beside 20-30 % softer cables: 0.98), physics that a robust fit puts into
  // one reading a part (MINI's pulley friction at 3x noise: one length reading 60 sigmas out,
  // 0.30-0.34 of the misfit, the rest in the equilibrium).
  const double excess = standard.chi2 - static_cast<double>(standard.dof);
  if (!rest_fits && !(drop >= options.gross_share * excess)) return {};
  return out;
}

namespace {
// "the 3rd pose": people count the recording's poses from 1.
std::string nth_pose(int j) {
  const int n = j + 1;
  const char* suffix = (n % 100 >= 11 && n % 100 <= 13) ? "th"
                       : n % 10 == 1                    ? "st"
                       : n % 10 == 2                    ? "nd"
                       : n % 10 == 3                    ? "rd"
                                                        : "th";
  return format("the %d%s pose", n, suffix);
}
}  // namespace

std::string describe(const GrossReading& g) {
  std::string what = g.channel;
  if (g.index >= 0) what += format(" %d", g.index + 1);
  std::string size;
  if (g.channel == "equilibrium") {
    size = format("the force readings out of balance by %.0f N", g.residual);
  } else if (g.channel == "cable length" || g.channel == "laser distance") {
    size = format("off by %.1f mm", 1e3 * std::abs(g.residual));
  } else {
    size = format("off by %.1f mrad", 1e3 * std::abs(g.residual));
  }
  return format("%s of %s: %s (%.0f sigmas)", what.c_str(), nth_pose(g.pose).c_str(), size.c_str(),
                g.sigmas);
}

std::string describe(const std::vector<GrossReading>& readings) {
  std::string list;
  for (const GrossReading& g : readings) list += (list.empty() ? "" : "; ") + describe(g);
  return std::string(readings.size() == 1 ? "a reading is" : "readings are") +
         " far from every model (" + list +
         "): a corrupted or mistyped value, a unit slip or a sensor glitch";
}

Result<Diagnosis> diagnose(const CalibratedModel& nominal, const MeasurementSet& set,
                           const MeasurementSet* validation,
                           const IdentificationOptions& identification,
                           const DiagnosisOptions& options) {
  const RobotModel& robot = nominal.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  // Refuse what does not match.
  auto check_set = [&](const MeasurementSet& s, const char* what) -> Status {
    for (int j = 0; j < s.num_poses(); ++j) {
      const PoseMeasurement& p = s.poses[static_cast<std::size_t>(j)];
      if (p.cable_lengths.size() != m) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "diagnose: the %s has %d cable lengths per pose (pose %d), the model "
                             "has %d cables",
                             what, static_cast<int>(p.cable_lengths.size()), j, m);
      }
      if (p.laser_distances.size() != 0 && p.laser_distances.size() != nl) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "diagnose: the %s has %d laser distances per pose (pose %d), the "
                             "model has %d lasers",
                             what, static_cast<int>(p.laser_distances.size()), j, nl);
      }
    }
    Status st = validate(s, robot);
    if (!st.ok()) st.prepend(std::string("diagnose: ") + what + ": ");
    return st;
  };
  CDPR_RETURN_IF_ERROR(check_set(set, "recording"));
  if (validation != nullptr) {
    CDPR_RETURN_IF_ERROR(check_set(*validation, "validation recording"));
  }
  if (options.bootstrap_samples < 0 || (options.cv_folds < 2 && options.cv_folds != 0) ||
      options.max_effects < 0 ||
      !(options.inclusion_threshold >= 0 && options.inclusion_threshold <= 1)) {
    return Status(
        ErrorCode::kInvalidArgument,
        "diagnose: options need bootstrap_samples >= 0, cv_folds >= 2 (or 0: leave one pose "
        "out), max_effects >= 0 "
        "and 0 <= inclusion_threshold <= 1");
  }

  Diagnosis d;
  d.model_after = nominal;
  const int np = set.num_poses();
  if (np < options.min_poses || np < options.cv_folds) {
    d.verdict = Diagnosis::Verdict::kInconclusive;
    d.headline = format(
        "Inconclusive: %d poses are too few to tell the candidate effects apart (at least %d are "
        "needed); record more poses.",
        np, std::max(options.min_poses, options.cv_folds));
    d.findings.push_back(d.headline);
    auto rep = identify(nominal, set, identification);
    if (rep) {
      d.before = std::move(*rep);
      d.model_after = d.before.estimate;
    }
    return d;
  }

  // The standard identification (the "before" model) and the screen of locate_mismatch.
  auto before = identify(nominal, set, identification);
  if (!before) return before.status();
  d.before = std::move(*before);
  // Stage 0, gross readings: nothing is named on a recording with a wild reading; readings within
  // gross_effects_sigmas are tried against the effects accepted on the whole recording (stage 3d).
  d.gross_readings = find_gross_readings(nominal, set, d.before, identification, options);
  auto gross_verdict = [&] {
    Diagnosis g;
    g.before = std::move(d.before);
    g.gross_readings = std::move(d.gross_readings);
    g.model_after = nominal;
    state_gross_readings(g);
    return g;
  };
  if (std::any_of(d.gross_readings.begin(), d.gross_readings.end(), [&](const GrossReading& g) {
        return !(g.sigmas <= options.gross_effects_sigmas);
      })) {
    return gross_verdict();
  }
  auto screen = locate_mismatch(d.before, set, identification, options.screen);
  if (!screen) return screen.status();
  d.screen = std::move(*screen);
  d.model_after = d.before.estimate;
  auto design0 = state_design(nominal, d.before, set, identification, options.screen);
  if (!design0) return design0.status();
  const MismatchDesign& D0 = *design0;
  const int n = D0.num_rows();
  const double alpha = options.screen.alpha;

  // Stage 1, selection.
  const Selection selection = select_candidates(D0, d.screen, np, options);
  const Folds folds = assign_folds(D0, np, options);
  const int K = folds.K;
  const CvRms cv_before = cv_rms(D0, nullptr, folds.fold, K);
  const RefitContext ctx{options,
                         D0,
                         selection,
                         folds,
                         d.screen.dof,
                         m,
                         std::log(static_cast<double>(n)),
                         d.before.log_det_covariance,
                         bic_log_sizes(D0, options.bic_informing_rows),
                         nominal};
  const State standard{identification, set, d.before, D0, {}, {}, cv_before, {}, {}, {}};

  // Stages 2 and 3, refits and acceptance.
  Acceptance acc = accept_effects(ctx, standard, d.screen);
  // Stage 3b, the second screening round on what the accepted effects leave.
  if (!acc.accepted.empty()) d.screen_after = second_round(ctx, d.screen, acc);
  // Stage 3c, the backward check when the second round added an effect.
  const bool second = std::any_of(acc.accepted.begin(), acc.accepted.end(),
                                  [](const EffectFit& f) { return f.round == 2; });
  if (second && options.backward_check && backward_check(ctx, standard, acc)) {
    auto again =
        locate_mismatch(acc.current.report, acc.current.set, acc.current.opt, options.screen);
    if (again) d.screen_after = std::move(*again);
  }
  if (acc.held_back) {
    // Held back for weak evidence (DiagnosisOptions::weak_step_bic); taken after all by a swap of
    // the first round, it is no suspect.
    if (acc.ids_taken.count(acc.held_back->id)) {
      acc.held_back.reset();
    } else if (std::none_of(acc.candidates.begin(), acc.candidates.end(),
                            [&](const EffectFit& c) { return c.id == acc.held_back->id; })) {
      acc.candidates.push_back(*acc.held_back);
    }
  }
  std::string physics_in_few;
  // Stage 3d: flagged readings that the accepted effects bring within gross_sigmas are physics
  // concentrated in a few readings (DiagnosisOptions::gross_effects_sigmas).
  if (!d.gross_readings.empty()) {
    if (acc.accepted.empty() ||
        !explained_by_effects(d.gross_readings, acc.current.report, options)) {
      return gross_verdict();
    }
    physics_in_few = format(
        "%s far out of a robust fit of the standard model %s within %.0f sigmas of the fit with "
        "the effects named: physics concentrated in a few readings, not a gross error.",
        describe(d.gross_readings).c_str(), d.gross_readings.size() == 1 ? "comes" : "come",
        options.gross_sigmas);
    d.gross_readings.clear();
  }
  // Stage 4, naming: the pairs this recording cannot tell apart.
  const std::vector<ConfoundedPair> found = confounded_pairs(ctx, standard, d.screen, acc);
  if (options.polish_gauss_newton) refresh_gauss_newton_parameters(acc.current, acc.accepted);
  refresh_identified_parameters(acc.current, acc.accepted);
  d.accepted = std::move(acc.accepted);
  d.candidates = std::move(acc.candidates);

  // Stage 5, extra-pose design: separating poses for the confounded pairs, follow-up poses for a
  // suspect (the grid is built only when one of them needs it).
  std::optional<ExtraPoseGrid> grid;
  auto grid_of = [&]() -> const ExtraPoseGrid& {
    if (!grid) grid = extra_pose_grid(robot, d.before, set, identification, options);
    return *grid;
  };
  if (!found.empty()) d.confounded = separate(found, acc.trials, grid_of(), np, options);
  if (options.follow_up_poses > 0 && acc.held_back && d.screen_after) {
    // The effect held back for weak evidence (DiagnosisOptions::weak_step_bic), with its p-value
    // on the screen of the model with the accepted effects; not screened there, its trial's test
    // stands in.
    CandidateScreen cs;
    cs.id = acc.held_back->id;
    cs.name = acc.held_back->name;
    cs.p_value = cs.p_adjusted = acc.held_back->lrt_p_value;
    if (const CandidateScreen* found_there = d.screen_after->find(cs.id)) cs = *found_there;
    d.follow_up = follow_up_for(cs, d.before.estimate.robot, grid_of(), np, options);
    if (d.follow_up) {
      d.follow_up->held_back = true;
      d.follow_up->bic_delta = acc.held_back->bic_delta;
    }
  } else if (options.follow_up_poses > 0 && d.accepted.empty()) {
    d.follow_up = follow_up(d.screen, d.before.estimate.robot, grid_of, np, options);
  } else if (options.follow_up_poses > 0 && options.follow_up_beside_named && d.screen_after) {
    // Candidates confounded with a named effect on the first screen are not suspects here
    // (DiagnosisOptions::follow_up_skips_confounded_with_named).
    std::vector<std::string> not_suspects;
    if (options.follow_up_skips_confounded_with_named) {
      for (const EffectFit& f : d.accepted) {
        for (const ConfoundedPair& cp : d.screen.confounded) {
          if (cp.first == f.id) not_suspects.push_back(cp.second);
          if (cp.second == f.id) not_suspects.push_back(cp.first);
        }
      }
    }
    d.follow_up = follow_up(*d.screen_after, d.before.estimate.robot, grid_of, np, options,
                            /*misfit_clause=*/false, not_suspects);
  }
  // A suspect beside named effects (the second round's screen) gets no follow-up poses unless
  // follow_up_beside_named: measured (20 more poses) and diagnosed again, they cost more than they
  // found on the benchmark (session 8, 6 seeds of LARGE: the re-runs lost a correctly named
  // thermal drift in 5 of 12 runs and named a drum scale beside pulley friction in 5 of 6;
  // session 14 with leave one pose out, MINI compound 10 seeds: 63/80 instead of 67/80, a force
  // sensor offset named beside sag + Hooke + force gain in 7 of 10; session 17 with the suspects
  // confounded with a named effect skipped and a confirmatory re-run, follow_up_groups: MINI
  // 70/80, LARGE 79/90 instead of 67/80 and 78/90, still below the 90 % target).

  // Stage 6, the model with the accepted effects; stage 7, the verdict.
  CDPR_RETURN_IF_ERROR(model_the_effects(d, acc.current, cv_before, K, options.cv_folds == 0,
                                         validation, nominal, identification, nl));
  state_verdict(d, alpha);
  if (!physics_in_few.empty()) {
    const auto after = std::find(d.findings.begin(), d.findings.end(), d.headline);
    d.findings.insert(after == d.findings.end() ? after : after + 1, physics_in_few);
  }
  return d;
}

std::vector<std::string> follow_up_groups(const Diagnosis& d) {
  std::vector<std::string> groups;
  if (!d.follow_up || d.accepted.empty()) return groups;
  auto add = [&](const std::string& family) {
    const std::string g = selection_group(family);
    if (std::find(groups.begin(), groups.end(), g) == groups.end()) groups.push_back(g);
  };
  for (const EffectFit& f : d.accepted) add(f.family);
  if (const EffectDescriptor* e = find_effect(d.follow_up->suspect)) add(std::string(e->family));
  // Separating poses measured in the same round decide their pair: both sides stay screened.
  for (const ConfoundedFinding& cf : d.confounded) {
    add(cf.first_fit.family);
    add(cf.second_fit.family);
  }
  return groups;
}

}  // namespace cdpr
