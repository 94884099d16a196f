// The locator's selection (diagnosis_internal.hpp): the per-pose cross products of the projected
// screen, forward selection by BIC on them, the bootstrap over poses with the inclusion
// probability of every candidate, the cross-validation folds and their held-out RMS.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <utility>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/model_validation.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "diagnosis_internal.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr::diagnosis_detail {

using mismatch_detail::column_basis;
using mismatch_detail::format;
using mismatch_detail::kNaN;

Eigen::MatrixXd pinv_sym(const Eigen::MatrixXd& A, double tol) {
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

const CandidateColumns* find_columns(const MismatchDesign& d, const std::string& id) {
  for (const auto& c : d.candidates) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

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

Eigen::MatrixXd reduce_geometry(const Eigen::MatrixXd& M, int geometry) {
  const Eigen::Index rest = M.rows() - geometry;
  if (geometry == 0) return M;
  const Eigen::MatrixXd Gi = pinv_sym(M.topLeftCorner(geometry, geometry));
  const Eigen::MatrixXd B = M.topRightCorner(geometry, rest);
  return M.bottomRightCorner(rest, rest) - B.transpose() * Gi * B;
}

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

namespace {

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

}  // namespace

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
  } else if (p.id.kind == ParameterKind::kPlatformMass) {
    const int dg = digits_for(p.std_dev);
    e.text = format("platform mass: %.*f +- %.*f kg (configured %.*f kg)", dg, p.value, dg,
                    p.std_dev, dg, p.initial);
  } else if (p.id.kind == ParameterKind::kPlatformCom) {
    const int dg = digits_for(1e3 * p.std_dev);
    e.text = format("platform centre of mass %c: ", "xyz"[std::clamp(p.id.component, 0, 2)]) +
             signed_number(1e3 * p.value, dg) +
             format(" +- %.*f mm (configured ", dg, 1e3 * p.std_dev) +
             signed_number(1e3 * p.initial, dg) + " mm, platform frame)";
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

}  // namespace cdpr::diagnosis_detail
