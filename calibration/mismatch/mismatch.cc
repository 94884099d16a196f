// The screen (locate_mismatch, mismatch.hpp): where the identification's misfit is (channels,
// cables, poses), what structure the length residuals have, which candidate effects of the
// library score on the residual with the identification projected out, which are confounded, and
// the findings in words. The design it screens is mismatch_design.cc's.
#include "cdpr/calibration/mismatch.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/effect_library.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr {
namespace {

using mismatch_detail::Candidate;
using mismatch_detail::column_basis;
using mismatch_detail::DesignData;
using mismatch_detail::format;
using mismatch_detail::kNaN;
using mismatch_detail::Row;
using mismatch_detail::RowKind;

MisfitGroup make_group(std::string name, const std::vector<int>& rows, const Eigen::VectorXd& r,
                       const Eigen::VectorXd& leverage, const std::vector<double>& si,
                       std::string unit, double alpha) {
  MisfitGroup g;
  g.name = std::move(name);
  g.unit = std::move(unit);
  g.count = static_cast<int>(rows.size());
  double s2 = 0.0;
  bool si_ok = !g.unit.empty();
  for (int k : rows) {
    const auto uk = static_cast<std::size_t>(k);
    g.chi2 += r(k) * r(k);
    g.expected_chi2 += 1.0 - leverage(k);
    if (si_ok && std::isfinite(si[uk])) s2 += si[uk] * si[uk];
  }
  if (g.count == 0) return g;
  g.rms_normalized = std::sqrt(g.chi2 / g.count);
  g.rms_si = si_ok ? std::sqrt(s2 / g.count) : kNaN;
  g.ratio = g.expected_chi2 > 0 ? std::sqrt(g.chi2 / g.expected_chi2) : kNaN;
  g.p_value = g.expected_chi2 > 1e-9 ? chi2_upper_tail(g.chi2, g.expected_chi2) : 1.0;
  g.flagged = g.p_value < alpha;
  return g;
}

// Regression of y on [1, X]: F-test of the slopes.
StructureTest regress(const std::string& variable, int cable, const Eigen::VectorXd& y,
                      const Eigen::MatrixXd& X) {
  StructureTest t;
  t.variable = variable;
  t.cable = cable;
  t.samples = static_cast<int>(y.size());
  if (t.samples < 3 || X.cols() == 0) return t;
  Eigen::MatrixXd Xc = X.rowwise() - X.colwise().mean();
  const Eigen::VectorXd yc = y.array() - y.mean();
  // Drop constant regressors (relative to their magnitude).
  for (Eigen::Index c = 0; c < Xc.cols(); ++c) {
    const double scale = std::max(X.col(c).cwiseAbs().maxCoeff(), 1e-300);
    if (Xc.col(c).norm() < 1e-9 * scale * std::sqrt(static_cast<double>(Xc.rows()))) {
      Xc.col(c).setZero();
    }
  }
  const Eigen::MatrixXd Q = column_basis(Xc, 1e-8);
  t.slopes = static_cast<int>(Q.cols());
  const double tss = yc.squaredNorm();
  if (t.slopes == 0 || tss <= 0 || t.samples - t.slopes - 1 <= 0) return t;
  const double ess = (Q.transpose() * yc).squaredNorm();
  t.explained_fraction = ess / tss;
  const double d2 = t.samples - t.slopes - 1;
  const double rss = std::max(tss - ess, 1e-300);
  t.f_statistic = (ess / t.slopes) / (rss / d2);
  t.p_value = f_upper_tail(t.f_statistic, t.slopes, d2);
  return t;
}

// The basis of the column space of the identification's full Jacobian J (geometry and free
// poses) on the design's rows.
Eigen::MatrixXd identification_basis(const DesignData& D, double rank_tolerance) {
  const GeometryInformation& base = D.base;
  const std::vector<int>& pose_start = D.pose_start;
  const int n = static_cast<int>(D.rows.size());
  const int np = static_cast<int>(pose_start.size()) - 1;
  const int P = static_cast<int>(base.names.size());
  std::vector<int> pose_col(static_cast<std::size_t>(np), -1);
  int cols = P;
  for (int j = 0; j < np; ++j) {
    if (base.jacobian_pose[static_cast<std::size_t>(j)].norm() > 0) {
      pose_col[static_cast<std::size_t>(j)] = cols;
      cols += 6;
    }
  }
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, cols);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int r0 = pose_start[uj];
    const int nr = pose_start[uj + 1] - r0;
    J.block(r0, 0, nr, P) = base.jacobian_geometry[uj];
    if (pose_col[uj] >= 0) J.block(r0, pose_col[uj], nr, 6) = base.jacobian_pose[uj];
  }
  return column_basis(J, rank_tolerance);
}

// LOCATE: the misfit per channel, cable and pose.
void locate_misfit(const DesignData& D, const Eigen::VectorXd& leverage, int m, int nl,
                   double alpha, MismatchSummary& out) {
  const std::vector<Row>& rows = D.rows;
  const std::vector<double>& si = D.si;
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(rows.size());
  const int np = static_cast<int>(D.pose_start.size()) - 1;
  std::vector<int> len, wr, ref, swv, inc, yaw;
  std::vector<std::vector<int>> las(static_cast<std::size_t>(nl));
  std::vector<std::vector<int>> cab(static_cast<std::size_t>(m));
  for (int k = 0; k < n; ++k) {
    const Row& row = rows[static_cast<std::size_t>(k)];
    switch (row.kind) {
      case RowKind::kLength:
        len.push_back(k);
        cab[static_cast<std::size_t>(row.index)].push_back(k);
        break;
      case RowKind::kLaser:
        las[static_cast<std::size_t>(row.index)].push_back(k);
        break;
      case RowKind::kWrench:
        wr.push_back(k);
        break;
      case RowKind::kReference:
        ref.push_back(k);
        break;
      case RowKind::kSwivel:
        swv.push_back(k);
        break;
      case RowKind::kInclination:
        inc.push_back(k);
        break;
      case RowKind::kImuYaw:
        yaw.push_back(k);
        break;
    }
  }
  auto channel = [&](const std::string& name, const std::vector<int>& idx, const char* unit) {
    if (!idx.empty()) out.channels.push_back(make_group(name, idx, r, leverage, si, unit, alpha));
  };
  channel("cable lengths", len, "m");
  for (int l = 0; l < nl; ++l)
    channel("laser " + std::to_string(l + 1), las[static_cast<std::size_t>(l)], "m");
  channel("equilibrium", wr, "");
  channel("reference pose", ref, "");
  channel("swivel angles", swv, "rad");
  channel("inclinometer", inc, "rad");
  channel("IMU yaw", yaw, "rad");
  for (int i = 0; i < m; ++i) {
    if (cab[static_cast<std::size_t>(i)].empty()) continue;
    out.cables.push_back(make_group("cable " + std::to_string(i + 1),
                                    cab[static_cast<std::size_t>(i)], r, leverage, si, "m", alpha));
  }
  for (int j = 0; j < np; ++j) {
    std::vector<int> pr;
    for (int k = D.pose_start[static_cast<std::size_t>(j)];
         k < D.pose_start[static_cast<std::size_t>(j) + 1]; ++k) {
      pr.push_back(k);
    }
    out.poses.push_back(make_group("pose " + std::to_string(j), pr, r, leverage, si, "", alpha));
  }
}

// LOCATE: structure tests of the normalised length residuals (all cables and each cable against
// each variable), Bonferroni over the tests.
std::vector<StructureTest> length_structure_tests(const DesignData& D, int m, double alpha) {
  const int n = static_cast<int>(D.rows.size());
  struct Variable {
    std::string name;
    Eigen::MatrixXd values;  // n x q
  };
  std::vector<Variable> vars;
  vars.push_back({"tension x length", D.tension.cwiseProduct(D.loaded)});
  vars.push_back({"tension", D.tension});
  vars.push_back({"cable length", D.kin_len});
  vars.push_back({"time", D.time});
  vars.push_back({"platform tilt", D.tilt});
  vars.push_back({"cable direction in the pulley frame", D.direction});
  std::vector<StructureTest> tests;
  for (int i = -1; i < m; ++i) {
    for (const Variable& v : vars) {
      std::vector<int> idx;
      for (int k = 0; k < n; ++k) {
        const Row& row = D.rows[static_cast<std::size_t>(k)];
        if (row.kind != RowKind::kLength || (i >= 0 && row.index != i)) continue;
        if (!v.values.row(k).allFinite()) continue;
        idx.push_back(k);
      }
      if (static_cast<int>(idx.size()) < 4) continue;
      Eigen::VectorXd y(static_cast<Eigen::Index>(idx.size()));
      Eigen::MatrixXd X(static_cast<Eigen::Index>(idx.size()), v.values.cols());
      for (std::size_t q = 0; q < idx.size(); ++q) {
        y(static_cast<Eigen::Index>(q)) = D.r(idx[q]);
        X.row(static_cast<Eigen::Index>(q)) = v.values.row(idx[q]);
      }
      StructureTest t = regress(v.name, i, y, X);
      if (t.slopes > 0) tests.push_back(t);
    }
  }
  const double bonferroni = alpha / std::max<double>(1.0, static_cast<double>(tests.size()));
  for (auto& t : tests) t.significant = t.p_value < bonferroni;
  return tests;
}

// NAME: every candidate screened on the residual with the identification (basis Q1) projected
// out; the candidates' projected column bases, in the library's order.
std::vector<Eigen::MatrixXd> screen_candidates(const DesignData& D, const Eigen::MatrixXd& Q1,
                                               const MismatchOptions& mopt, MismatchSummary& out) {
  const std::vector<Candidate>& lib = D.lib;
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(r.size());
  const double rss = out.chi2;
  std::vector<Eigen::MatrixXd> bases(lib.size());
  for (std::size_t c = 0; c < lib.size(); ++c) {
    CandidateScreen s;
    s.id = lib[c].id;
    s.name = lib[c].name;
    s.family = lib[c].family;
    s.columns = static_cast<int>(lib[c].X.cols());
    const Eigen::MatrixXd Xp = lib[c].X - Q1 * (Q1.transpose() * lib[c].X);
    // Rank relative to the unprojected column norms: a column that loses (almost) all of its
    // length in the projection is already modelled by the identification.
    Eigen::MatrixXd Xs = Xp;
    for (Eigen::Index q = 0; q < Xs.cols(); ++q) {
      const double nx = lib[c].X.col(q).norm();
      Xs.col(q) = nx > 0 ? Eigen::VectorXd(Xs.col(q) / nx) : Eigen::VectorXd::Zero(n);
    }
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(Xs, Eigen::ComputeThinU);
    int rk = 0;
    for (Eigen::Index q = 0; q < svd.singularValues().size(); ++q) {
      if (svd.singularValues()(q) > std::sqrt(mopt.rank_tolerance)) ++rk;
    }
    bases[c] = svd.matrixU().leftCols(rk);
    s.rank = rk;
    s.modelled = rk == 0;
    if (rk > 0 && out.dof - rk > 0) {
      s.statistic = (bases[c].transpose() * r).squaredNorm();
      s.p_score = chi2_upper_tail(s.statistic, rk);
      s.explained_fraction = rss > 0 ? s.statistic / rss : 0.0;
      const double rest = std::max(rss - s.statistic, 1e-300);
      s.f_statistic = (s.statistic / rk) / (rest / (out.dof - rk));
      s.p_value = f_upper_tail(s.f_statistic, rk, out.dof - rk);
      s.bic_delta = n * std::log(rest / rss) + rk * std::log(static_cast<double>(n));
      s.coefficients = Xp.completeOrthogonalDecomposition().solve(r);
    }
    out.candidates.push_back(std::move(s));
  }
  return bases;
}

// Holm's step-down adjustment of the p-values `p` of the candidates `order` (sorted in place).
template <typename Set>
void holm(std::vector<std::size_t>& order, const std::vector<double>& p, Set set) {
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return p[a] < p[b]; });
  double running = 0.0;
  const double K = static_cast<double>(order.size());
  for (std::size_t q = 0; q < order.size(); ++q) {
    running = std::max(running, std::min(1.0, (K - static_cast<double>(q)) * p[order[q]]));
    set(order[q], running);
  }
}

// Holm over the screened candidates: the adjusted p-value and whether it is significant.
void adjust_screen(MismatchSummary& out, double alpha) {
  std::vector<std::size_t> order;
  std::vector<double> p(out.candidates.size(), 1.0);
  for (std::size_t c = 0; c < out.candidates.size(); ++c) {
    p[c] = out.candidates[c].p_value;
    if (out.candidates[c].rank > 0) order.push_back(c);
  }
  holm(order, p, [&](std::size_t c, double adjusted) {
    out.candidates[c].p_adjusted = adjusted;
    out.candidates[c].significant = adjusted < alpha;
  });
}

// Confounded pairs: candidates of different selection groups, both screened, whose projected
// columns have a canonical correlation above confound_threshold.
std::vector<ConfoundedPair> confounded_candidates(const std::vector<Candidate>& lib,
                                                  const std::vector<Eigen::MatrixXd>& bases,
                                                  const MismatchOptions& mopt) {
  std::vector<ConfoundedPair> out;
  // One grows with time, the other does not: no pose measured after the recording tells them
  // apart as well as a pose measured again after a long wait (creep has nearly levelled off by
  // the end of a recording, so new poses see it as a constant compliance).
  auto timed = [](const Candidate& c) {
    const EffectDescriptor* e = find_effect(c.id);
    return e != nullptr && e->plotted_against.name == "time";
  };
  for (std::size_t a = 0; a < lib.size(); ++a) {
    for (std::size_t b = a + 1; b < lib.size(); ++b) {
      if (selection_group(lib[a].family) == selection_group(lib[b].family) ||
          bases[a].cols() == 0 || bases[b].cols() == 0) {
        continue;  // refinements of one effect are compared by nested tests, not confounded
      }
      const Eigen::MatrixXd M = bases[a].transpose() * bases[b];
      const Eigen::VectorXd cc = Eigen::JacobiSVD<Eigen::MatrixXd>(M).singularValues();
      const double rho = cc(0);
      if (rho <= mopt.confound_threshold) continue;
      ConfoundedPair p;
      p.first = lib[a].id;
      p.second = lib[b].id;
      p.correlation = rho;
      p.directions = static_cast<int>((cc.array() > mopt.confound_threshold).count());
      p.first_rank = static_cast<int>(bases[a].cols());
      p.second_rank = static_cast<int>(bases[b].cols());
      const char* hint = (lib[a].family == "elasticity" && lib[b].family == "compliance")
                             ? " (equal tension at very different free lengths)"
                         : timed(lib[a]) != timed(lib[b])
                             ? " (a loaded pose held and measured again after a long wait)"
                             : "";
      p.description = format(
          "%s and %s are confounded on this pose set (canonical correlation %.2f after the "
          "identification is projected out): the data cannot tell them apart; separate them with "
          "poses that excite one without the other%s, or a bench test",
          lib[a].name.c_str(), lib[b].name.c_str(), rho, hint);
      out.push_back(std::move(p));
    }
  }
  return out;
}

// Each candidate's test beyond the unexplained structures (Holm-adjusted).
void test_beyond_structure(const Eigen::VectorXd& r, const std::vector<Eigen::MatrixXd>& bases,
                           const MismatchOptions& mopt, MismatchSummary& out) {
  const Eigen::Index n = r.size();
  Eigen::MatrixXd U(n, 0);
  for (const auto& u : out.unexplained) {
    // The structure with its nuisance: a constant per listed cable (friction on a cable paid out
    // more often than reeled in also shifts its mean reading).
    Eigen::MatrixXd W(n, U.cols() + u.columns.cols() + u.constants.cols());
    W << U, u.columns, u.constants;
    U = W;
  }
  if (U.cols() > 0) U = column_basis(U, mopt.rank_tolerance);
  const Eigen::VectorXd rU = r - U * (U.transpose() * r);
  std::vector<std::size_t> order;
  std::vector<double> p(out.candidates.size(), 1.0);
  for (std::size_t c = 0; c < out.candidates.size(); ++c) {
    if (out.candidates[c].rank == 0) continue;
    order.push_back(c);
    if (U.cols() == 0) {
      p[c] = out.candidates[c].p_value;
      continue;
    }
    // bases[c] is orthonormal: the singular values of its part outside U say how much of each
    // direction is left.
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(bases[c] - U * (U.transpose() * bases[c]),
                                          Eigen::ComputeThinU);
    int rk = 0;
    for (Eigen::Index q = 0; q < svd.singularValues().size(); ++q) {
      if (svd.singularValues()(q) > std::sqrt(mopt.rank_tolerance)) ++rk;
    }
    const Eigen::MatrixXd B = svd.matrixU().leftCols(rk);
    const double dof_c = out.dof - static_cast<double>(U.cols() + B.cols());
    if (B.cols() == 0 || dof_c <= 0) continue;
    const double t = (B.transpose() * rU).squaredNorm();
    const double rest = std::max(rU.squaredNorm() - t, 1e-300);
    p[c] = f_upper_tail((t / static_cast<double>(B.cols())) / (rest / dof_c),
                        static_cast<double>(B.cols()), dof_c);
  }
  holm(order, p,
       [&](std::size_t c, double adjusted) { out.candidates[c].p_beyond_structure = adjusted; });
}

// The summary's findings in words.
void state_findings(double alpha, MismatchSummary& out) {
  if (out.p_value < alpha) {
    out.findings.push_back(
        format("The model does not explain the recording: chi^2 = %.1f for %d degrees of freedom "
               "(%.2f times the noise, p = %.3g).",
               out.chi2, out.dof, std::sqrt(out.chi2 / out.dof), out.p_value));
  } else {
    out.findings.push_back(format(
        "The residuals are consistent with the stated sensor noise: chi^2 = %.1f for %d degrees "
        "of freedom (p = %.3g).",
        out.chi2, out.dof, out.p_value));
  }
  for (const auto& g : out.channels) {
    if (!g.flagged) continue;
    out.findings.push_back(
        format("Channel '%s' misfits: %.2f times its expected noise (chi^2 = %.1f against %.1f, "
               "p = %.3g).",
               g.name.c_str(), g.ratio, g.chi2, g.expected_chi2, g.p_value));
  }
  for (const auto& g : out.cables) {
    if (!g.flagged) continue;
    out.findings.push_back(format("Cable %s misfits: %.2f times its expected noise (p = %.3g).",
                                  g.name.c_str() + 6, g.ratio, g.p_value));
  }
  for (const auto& t : out.structure) {
    if (!t.significant) continue;
    out.findings.push_back(
        format("The length residuals of %s follow %s (F = %.1f, p = %.3g, explains %.0f %%).",
               t.cable < 0 ? "all cables" : ("cable " + std::to_string(t.cable + 1)).c_str(),
               t.variable.c_str(), t.f_statistic, t.p_value, 100.0 * t.explained_fraction));
  }
  for (const auto& u : out.unexplained) out.findings.push_back(u.description);
  if (const CandidateScreen* b = out.best()) {
    out.findings.push_back(
        format("Most likely missing physics: %s; it explains %.0f %% of the misfit (p = %.3g after "
               "Holm's correction).",
               b->name.c_str(), 100.0 * b->explained_fraction, b->p_adjusted));
  } else {
    out.findings.push_back(format("No candidate effect is significant at alpha = %.3g.", alpha));
  }
  for (const auto& p : out.confounded) out.findings.push_back(p.description + ".");
}

}  // namespace

const CandidateScreen* MismatchSummary::best() const {
  if (candidates.empty() || !candidates.front().significant) return nullptr;
  return &candidates.front();
}

const CandidateScreen* MismatchSummary::find(const std::string& id) const {
  for (const auto& c : candidates) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

std::string MismatchSummary::text() const {
  std::string s;
  for (const auto& f : findings) s += "- " + f + "\n";
  s += format("\n%-34s %5s %10s %10s %9s %8s %10s\n", "candidate", "k", "T", "p(F)", "p(Holm)",
              "explains", "dBIC");
  for (const auto& c : candidates) {
    s += format("%-34s %5d %10.2f %10.3g %9.3g %7.1f%% %10.1f%s\n", c.id.c_str(), c.rank,
                c.statistic, c.p_value, c.p_adjusted, 100.0 * c.explained_fraction, c.bic_delta,
                c.modelled ? " (already modelled)" : (c.significant ? " *" : ""));
  }
  s += format("\n%-22s %6s %10s %10s %10s\n", "channel", "n", "RMS/sigma", "ratio", "p");
  for (const auto& g : channels) {
    s += format("%-22s %6d %10.3f %10.3f %10.3g%s\n", g.name.c_str(), g.count, g.rms_normalized,
                g.ratio, g.p_value, g.flagged ? " *" : "");
  }
  for (const auto& g : cables) {
    s += format("%-22s %6d %10.3f %10.3f %10.3g%s\n", g.name.c_str(), g.count, g.rms_normalized,
                g.ratio, g.p_value, g.flagged ? " *" : "");
  }
  return s;
}

Result<MismatchSummary> locate_mismatch(const IdentificationReport& report,
                                        const MeasurementSet& set,
                                        const IdentificationOptions& options,
                                        const MismatchOptions& mopt) {
  auto dd = mismatch_detail::build_design(report.estimate, set, report.poses, &report.residuals,
                                          options, mopt);
  if (!dd) return dd.status();
  const DesignData& D = *dd;
  const RobotModel& robot = report.estimate.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  const int n = static_cast<int>(D.rows.size());
  const Eigen::VectorXd& r = D.r;
  const Eigen::MatrixXd Q1 = identification_basis(D, mopt.rank_tolerance);
  const int rankJ = static_cast<int>(Q1.cols());
  const Eigen::VectorXd leverage = Q1.rowwise().squaredNorm();

  MismatchSummary out;
  out.num_residuals = n;
  out.chi2 = r.squaredNorm();
  out.jacobian_rank = rankJ;
  out.dof = n - rankJ;
  if (n == 0 || out.dof <= 0) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "mismatch: %d residuals and %d fitted quantities leave no degrees of "
                         "freedom",
                         n, rankJ);
  }
  out.p_value = chi2_upper_tail(out.chi2, out.dof);
  const double alpha = mopt.alpha;
  locate_misfit(D, leverage, m, nl, alpha, out);
  out.structure = length_structure_tests(D, m, alpha);
  const std::vector<Eigen::MatrixXd> bases = screen_candidates(D, Q1, mopt, out);
  adjust_screen(out, alpha);
  out.confounded = confounded_candidates(D.lib, bases, mopt);
  // DESCRIBE: structure that no candidate explains.
  if (mopt.describe_structure)
    out.unexplained = mismatch_detail::describe_structure(D, Q1, bases, out, mopt);
  test_beyond_structure(r, bases, mopt, out);
  std::stable_sort(out.candidates.begin(), out.candidates.end(),
                   [](const CandidateScreen& a, const CandidateScreen& b) {
                     if ((a.rank == 0) != (b.rank == 0)) return b.rank == 0;
                     return a.bic_delta < b.bic_delta;
                   });
  std::sort(out.confounded.begin(), out.confounded.end(),
            [](const ConfoundedPair& a, const ConfoundedPair& b) {
              return a.correlation > b.correlation;
            });
  state_findings(alpha, out);
  return out;
}

}  // namespace cdpr
