// The DESCRIBE step of locate_mismatch (mismatch_internal.hpp): structure of the residual that no
// candidate of the library explains. Each (channel, cable, variable) is a test column; the
// significant ones are selected forward, those a candidate explains dropped, the rest described.
#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/mismatch.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr::mismatch_detail {
namespace {

// "2", "2 and 5", "1, 3 and 5" from 0-based indices (+ `base`).
std::string index_list(const std::vector<int>& v, int base) {
  std::string out;
  for (std::size_t q = 0; q < v.size(); ++q) {
    if (q > 0) out += q + 1 == v.size() ? " and " : ", ";
    out += std::to_string(v[q] + base);
  }
  return out;
}

struct Variable {
  const char* name;
  const Eigen::MatrixXd* values;
  const char* unit;
};

constexpr int kVariables = 6;
constexpr const char* kChannels[] = {"cable lengths", "cable tensions"};
constexpr const char* kChannelUnit[] = {"m", "N"};

// The measured variables per (pose, cable) the readings may follow.
std::array<Variable, kVariables> variables(const DesignData& D) {
  return {{{"direction of the last move", &D.move, ""},
           {"tension", &D.pc_tension, "N"},
           {"cable length", &D.pc_length, "m"},
           {"time", &D.pc_time, "s"},
           {"platform orientation", &D.pc_tilt, "rad"},
           {"temperature", &D.pc_temperature, "K"}}};
}

struct Test {
  int channel = 0, cable = 0, var = 0;
  double t = 0.0, p = 1.0, slope = 0.0;
  Eigen::VectorXd z;
  Eigen::VectorXd constant;  // the cable's constant on the channel (the nuisance), projected
};

// Every (channel, cable, variable) column with the identification and the cable's constant on
// the channel projected out, tested alone against the residual.
std::vector<Test> structure_tests(const DesignData& D, const Eigen::MatrixXd& Q1, int d2) {
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(r.size());
  const int np = static_cast<int>(D.pose_start.size()) - 1;
  const int m = static_cast<int>(D.move.cols());
  const double rss = r.squaredNorm();
  const std::array<Variable, kVariables> vars = variables(D);
  std::vector<Test> tests;
  for (int ch = 0; ch < 2; ++ch) {
    for (int i = 0; i < m; ++i) {
      for (int v = 0; v < kVariables; ++v) {
        const Eigen::MatrixXd& val = *vars[static_cast<std::size_t>(v)].values;
        Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n), x = Eigen::VectorXd::Zero(n);
        int count = 0;
        for (int j = 0; j < np; ++j) {
          const auto uj = static_cast<std::size_t>(j);
          const double value = val(j, i);
          if (!std::isfinite(value)) continue;
          if (ch == 0 && D.length_row[uj][static_cast<std::size_t>(i)] < 0) continue;
          const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
          const Eigen::VectorXd col =
              ch == 0 ? D.length_white[uj].col(i) : D.tension_white[uj].col(i);
          if (col.squaredNorm() == 0.0) continue;
          x0.segment(r0, nr) += col;
          x.segment(r0, nr) += value * col;
          ++count;
        }
        if (count < 4) continue;
        const Eigen::VectorXd x0p = x0 - Q1 * (Q1.transpose() * x0);
        const Eigen::VectorXd xp = x - Q1 * (Q1.transpose() * x);
        Eigen::VectorXd z = xp;
        if (x0p.squaredNorm() > 1e-18 * x0.squaredNorm()) {
          z -= x0p * (x0p.dot(xp) / x0p.squaredNorm());
        }
        // A constant variable (given the constant per cable) or one the identification models.
        if (!(z.norm() > 1e-6 * x.norm())) continue;
        Test t;
        t.channel = ch;
        t.cable = i;
        t.var = v;
        t.slope = z.dot(r) / z.squaredNorm();
        t.t = z.dot(r) * t.slope;
        const double rest = std::max(rss - t.t, 1e-300);
        t.p = f_upper_tail(t.t / (rest / d2), 1.0, d2);
        t.z = std::move(z);
        t.constant = x0p;
        tests.push_back(std::move(t));
      }
    }
  }
  return tests;
}

struct Pick {
  const Test* test = nullptr;
  double p = 1.0;  // Bonferroni-adjusted, given the picks before it
  std::string closest;
  double rho = 0.0;
};

// Forward selection over every test (channel x cable x variable): the test with the largest
// statistic given the ones already selected (their columns projected out of its column and of the
// residual), while that conditional test is significant (Bonferroni over all tests). A reading
// error on two cables shows, weaker, on the columns of the other cables (the pose is estimated
// from all of them, and the equilibrium rows mix every cable's tension): the conditional test
// leaves those shadows out.
std::vector<Pick> select_structures(const std::vector<Test>& tests, const Eigen::VectorXd& r,
                                    int d2, int m, double alpha) {
  const int n = static_cast<int>(r.size());
  const double K = static_cast<double>(tests.size());
  std::vector<Pick> picks;
  Eigen::MatrixXd U(n, 0);  // orthonormal basis of the selected columns
  std::vector<bool> used(tests.size(), false);
  for (std::size_t step = 0; step < tests.size() && step < static_cast<std::size_t>(2 * m);
       ++step) {
    const Eigen::VectorXd rp = r - U * (U.transpose() * r);
    const double dof_p = d2 - static_cast<double>(U.cols());
    if (dof_p <= 0) break;
    std::size_t best = tests.size();
    double best_t = 0.0;
    for (std::size_t q = 0; q < tests.size(); ++q) {
      if (used[q]) continue;
      const Eigen::VectorXd zp = tests[q].z - U * (U.transpose() * tests[q].z);
      if (!(zp.squaredNorm() > 1e-12 * tests[q].z.squaredNorm())) continue;
      const double tq = std::pow(zp.dot(rp), 2) / zp.squaredNorm();
      if (tq > best_t) {
        best_t = tq;
        best = q;
      }
    }
    if (best == tests.size()) break;
    const double rest = std::max(rp.squaredNorm() - best_t, 1e-300);
    const double p = std::min(1.0, K * f_upper_tail(best_t / (rest / dof_p), 1.0, dof_p));
    if (!(p < alpha)) break;
    used[best] = true;
    const Eigen::VectorXd q = tests[best].z - U * (U.transpose() * tests[best].z);
    U.conservativeResize(Eigen::NoChange, U.cols() + 1);
    U.col(U.cols() - 1) = q.normalized();
    Pick pk;
    pk.test = &tests[best];
    pk.p = p;
    picks.push_back(std::move(pk));
  }
  return picks;
}

// The picks no candidate explains. Explained by a candidate when, with that candidate's columns
// added, the structure is no longer significant (a partial test). Two partial tests, either
// suffices:
// - a candidate whose columns come close to the structure's (canonical correlation above
//   structure_coverage), tested against the residual it leaves;
// - any candidate, tested against the noise left once it and every selected structure are
//   fitted. One law for all cables (cable creep) shows most on the cables where it is largest, so
//   "the readings of cable 2 follow the tension" is significant on its residual though the creep
//   column is far from that cable's (canonical correlation 0.3-0.8); fitted, creep leaves it
//   insignificant. (With the first test alone such shadows were reported as physics outside the
//   library, and creep, a shared EA and the force gains counted as their proxies.) The noise
//   estimate excludes the other structures: left in, a second one (pulley friction in the
//   tensions beside hysteresis in the lengths) inflates it, and a candidate that takes a little of
//   the first would seem to explain it.
std::vector<Pick> unexplained_picks(std::vector<Pick> picks, const DesignData& D,
                                    const std::vector<Eigen::MatrixXd>& bases, int d2, double K,
                                    const MismatchOptions& mopt) {
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(r.size());
  Eigen::MatrixXd Z(n, static_cast<Eigen::Index>(picks.size()));
  for (std::size_t q = 0; q < picks.size(); ++q)
    Z.col(static_cast<Eigen::Index>(q)) = picks[q].test->z;
  // Per candidate (computed once, for the first structure that needs it): the residual sum of
  // squares and degrees of freedom once it and every selected structure are fitted.
  std::vector<std::optional<std::pair<double, double>>> noise_left(bases.size());
  auto noise_with = [&](std::size_t c) {
    if (!noise_left[c]) {
      Eigen::MatrixXd W(n, bases[c].cols() + Z.cols());
      W << bases[c], Z;
      const Eigen::MatrixXd full = column_basis(W, mopt.rank_tolerance);
      noise_left[c] = std::make_pair((r - full * (full.transpose() * r)).squaredNorm(),
                                     d2 - static_cast<double>(full.cols()));
    }
    return *noise_left[c];
  };
  std::vector<Pick> kept;
  for (Pick& pk : picks) {
    const Eigen::VectorXd& z = pk.test->z;
    bool explained = false;
    for (std::size_t c = 0; c < bases.size() && !explained; ++c) {
      const Eigen::MatrixXd& B = bases[c];
      if (B.cols() == 0) continue;
      const double rho = (B.transpose() * z.normalized()).norm();
      if (rho > pk.rho) {
        pk.rho = rho;
        pk.closest = D.lib[c].name;
      }
      const Eigen::VectorXd zp = z - B * (B.transpose() * z);
      const double k = static_cast<double>(B.cols());
      // Inside the candidate's span (to rounding): the candidate has the structure's shape.
      if (!(zp.squaredNorm() > 1e-12 * z.squaredNorm())) {
        explained = true;
        continue;
      }
      // No degrees of freedom left: a close candidate may be it; nothing can be tested.
      if (d2 - k <= 0) {
        explained = rho > mopt.structure_coverage;
        continue;
      }
      const Eigen::VectorXd rp = r - B * (B.transpose() * r);
      const double tp = std::pow(zp.dot(rp), 2) / zp.squaredNorm();
      auto insignificant = [&](double rest, double dof_p) {
        const double pp = f_upper_tail(tp / (std::max(rest, 1e-300) / dof_p), 1.0, dof_p);
        return !(std::min(1.0, K * pp) < mopt.alpha);
      };
      if (rho > mopt.structure_coverage && insignificant(rp.squaredNorm() - tp, d2 - k)) {
        explained = true;
        continue;
      }
      const auto [rss_left, dof_left] = noise_with(c);
      explained = dof_left > 0 && insignificant(rss_left, dof_left);
    }
    if (!explained) kept.push_back(std::move(pk));
  }
  return kept;
}

// The slopes of the picks fitted jointly (the selected structures together).
std::vector<double> joint_slopes(const std::vector<Pick>& picks, const Eigen::VectorXd& r) {
  std::vector<double> joint_slope(picks.size(), 0.0);
  if (picks.empty()) return joint_slope;
  Eigen::MatrixXd Z(r.size(), static_cast<Eigen::Index>(picks.size()));
  for (std::size_t q = 0; q < picks.size(); ++q)
    Z.col(static_cast<Eigen::Index>(q)) = picks[q].test->z;
  const Eigen::VectorXd b = Z.colPivHouseholderQr().solve(r);
  for (std::size_t q = 0; q < picks.size(); ++q) joint_slope[q] = b(static_cast<Eigen::Index>(q));
  return joint_slope;
}

// The poses where structure `u` shows most (at most 10, above a quarter of the top one).
void most_affected_poses(const Eigen::VectorXd& per_pose, UnexplainedStructure& u) {
  const int np = static_cast<int>(per_pose.size());
  std::vector<int> order(static_cast<std::size_t>(np));
  for (int j = 0; j < np; ++j) order[static_cast<std::size_t>(j)] = j;
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return per_pose(a) > per_pose(b); });
  const double top = np > 0 ? per_pose(order[0]) : 0.0;
  for (int j : order) {
    if (u.poses.size() >= 10 || !(per_pose(j) > 0.25 * top)) break;
    u.poses.push_back(j);
  }
  std::sort(u.poses.begin(), u.poses.end());
}

// The words of structure `u` on channel `ch` against variable `v`.
std::string structure_words(const UnexplainedStructure& u, int ch, int v) {
  std::string detail;
  for (std::size_t q = 0; q < u.cables.size(); ++q) {
    if (q > 0) detail += "; ";
    const double b = u.slopes[q];
    const bool len = ch == 0;
    const std::string cable = "cable " + std::to_string(u.cables[q] + 1);
    if (v == 0) {
      detail += len ? format("%s: %+.2f mm after paying out, %+.2f mm after reeling in",
                             cable.c_str(), 1e3 * b, -1e3 * b)
                    : format("%s: %+.2f N after paying out, %+.2f N after reeling in",
                             cable.c_str(), b, -b);
    } else {
      detail += format("%s: %.3g %s", cable.c_str(), b, u.unit.c_str());
    }
    detail += format(" (p = %.2g)", u.p_values[q]);
  }
  return format(
      "Unexplained structure in the %s: the %s of cable%s %s follow the %s (%s), most at "
      "pose%s %s. No candidate effect of the library has this shape (closest: %s, canonical "
      "correlation %.2f).",
      u.channel.c_str(), ch == 0 ? "length readings" : "tension readings",
      u.cables.size() > 1 ? "s" : "", index_list(u.cables, 1).c_str(), u.variable.c_str(),
      detail.c_str(), u.poses.size() > 1 ? "s" : "", index_list(u.poses, 0).c_str(),
      u.closest_candidate.empty() ? "none" : u.closest_candidate.c_str(), u.closest_correlation);
}

// The picks on channel `ch` against variable `v` as one structure (empty: none), its cables in
// cable order.
UnexplainedStructure group_of(const DesignData& D, const std::vector<Pick>& picks,
                              const std::vector<double>& joint_slope,
                              const std::vector<std::size_t>& pick_order, int ch, int v) {
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(r.size());
  const int np = static_cast<int>(D.pose_start.size()) - 1;
  const Variable var = variables(D)[static_cast<std::size_t>(v)];
  UnexplainedStructure u;
  u.channel = kChannels[ch];
  u.variable = var.name;
  u.unit = var.unit[0] == '\0' ? std::string(kChannelUnit[ch])
                               : std::string(kChannelUnit[ch]) + "/" + var.unit;
  Eigen::VectorXd per_pose = Eigen::VectorXd::Zero(np);
  for (std::size_t q : pick_order) {
    const Pick& pk = picks[q];
    const Test& t = *pk.test;
    if (t.channel != ch || t.var != v) continue;
    u.cables.push_back(t.cable);
    u.slopes.push_back(joint_slope[q]);
    u.p_values.push_back(pk.p);
    u.columns.conservativeResize(n, u.columns.cols() + 1);
    u.columns.col(u.columns.cols() - 1) = t.z;
    u.constants.conservativeResize(n, u.constants.cols() + 1);
    u.constants.col(u.constants.cols() - 1) = t.constant;
    if (pk.rho > u.closest_correlation) {
      u.closest_correlation = pk.rho;
      u.closest_candidate = pk.closest;
    }
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
      per_pose(j) += joint_slope[q] * t.z.segment(r0, nr).dot(r.segment(r0, nr));
    }
  }
  if (u.cables.empty()) return u;
  most_affected_poses(per_pose, u);
  u.description = structure_words(u, ch, v);
  return u;
}

}  // namespace

std::vector<UnexplainedStructure> describe_structure(const DesignData& D, const Eigen::MatrixXd& Q1,
                                                     const std::vector<Eigen::MatrixXd>& bases,
                                                     const MismatchSummary& summary,
                                                     const MismatchOptions& mopt) {
  std::vector<UnexplainedStructure> out;
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(r.size());
  const int m = static_cast<int>(D.move.cols());
  const double rss = r.squaredNorm();
  const int d2 = summary.dof - 2;
  if (n == 0 || d2 <= 0 || rss <= 0) return out;
  const std::vector<Test> tests = structure_tests(D, Q1, d2);
  const double K = static_cast<double>(tests.size());
  // Each selected test is unexplained when no candidate reproduces its column.
  const std::vector<Pick> picks =
      unexplained_picks(select_structures(tests, r, d2, m, mopt.alpha), D, bases, d2, K, mopt);
  const std::vector<double> joint_slope = joint_slopes(picks, r);
  std::vector<std::size_t> pick_order(picks.size());
  for (std::size_t q = 0; q < picks.size(); ++q) pick_order[q] = q;
  std::stable_sort(pick_order.begin(), pick_order.end(), [&](std::size_t a, std::size_t b) {
    return picks[a].test->cable < picks[b].test->cable;
  });
  // Grouped by channel and variable.
  for (int ch = 0; ch < 2; ++ch) {
    for (int v = 0; v < kVariables; ++v) {
      UnexplainedStructure u = group_of(D, picks, joint_slope, pick_order, ch, v);
      if (!u.cables.empty()) out.push_back(std::move(u));
    }
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const UnexplainedStructure& a, const UnexplainedStructure& b) {
                     return *std::min_element(a.p_values.begin(), a.p_values.end()) <
                            *std::min_element(b.p_values.begin(), b.p_values.end());
                   });
  return out;
}

}  // namespace cdpr::mismatch_detail
