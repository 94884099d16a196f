// Monitor::assess: attribution of the window's residuals to a candidate change, the predicted
// position error over the ISO box now vs at acceptance, and the re-identification proposal.
#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/monitoring.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "monitoring_effects.hpp"

namespace cdpr {
namespace {

using monitoring::EffectEntry;

// Upper quantile of chi^2 with k dof at tail probability p (Wilson-Hilferty).
double chi2_quantile(double p, int k) {
  double lo = 0.0, hi = 40.0;  // z with 0.5 erfc(z / sqrt 2) = p
  for (int it = 0; it < 200; ++it) {
    const double mid = 0.5 * (lo + hi);
    (0.5 * std::erfc(mid / std::sqrt(2.0)) > p ? lo : hi) = mid;
  }
  const double a = 2.0 / (9.0 * k);
  const double c = 1.0 - a + lo * std::sqrt(a);
  return k * c * c * c;
}

std::string format(const char* fmt, int cable) {
  char buf[160];
  std::snprintf(buf, sizeof buf, fmt, cable + 1);
  return buf;
}

// The box poses the model can hold (planned tensions within limits), with their linearisations.
struct BoxPoint {
  Pose pose;
  Monitor::Linearisation lin;
  Monitor::RowMatrix w;
};

std::vector<BoxPoint> box_points(Monitor& scratch) {
  const RobotModel& robot = scratch.model().robot;
  const MonitorOptions& o = scratch.options();
  const double f_ref =
      std::isfinite(o.reference_tension) ? o.reference_tension : default_reference_tension(robot);
  std::vector<BoxPoint> out;
  for (const Pose& pose : o.box.grid()) {
    Result<Eigen::VectorXd> f = simple_tension_distribution(robot, pose, f_ref);
    if (!f.ok()) continue;
    Result<Eigen::VectorXd> l = unstretched_lengths(robot, pose, *f);
    if (!l.ok()) continue;
    MonitorSample s;
    s.time_s = 0.0;
    s.pose = pose;
    for (int i = 0; i < robot.num_cables(); ++i) {
      s.lengths[static_cast<std::size_t>(i)] = (*l)(i);
      s.tensions[static_cast<std::size_t>(i)] = (*f)(i);
    }
    BoxPoint b;
    b.pose = pose;
    scratch.resize_linearisation(b.lin);
    b.w.resize(scratch.rows(), scratch.rows());
    if (!scratch.linearise(s, b.lin) || !monitoring::projected_precision(b.lin, b.w)) continue;
    out.push_back(std::move(b));
  }
  return out;
}

// Position change (3 x k) of the platform per unit of the effect's columns at a box point: the
// commanded lengths stay, the true lengths change by the signature; least squares over the cables
// (predicted_accuracy.hpp: dx = -pinv(dL/dx) dL).
Eigen::MatrixXd position_sensitivity(const BoxPoint& b, int col, int k, int m) {
  const Eigen::MatrixXd lengths_by_pose = b.lin.nuisance.topRows(m);
  const Eigen::MatrixXd sig = b.lin.signature.block(0, col, m, k);
  return -(lengths_by_pose.colPivHouseholderQr().solve(sig)).topRows(3);
}

double mean_position_variance(const std::vector<BoxPoint>& box, int col, int k, int m,
                              const Eigen::MatrixXd& cov) {
  double sum = 0.0;
  for (const BoxPoint& b : box) {
    const Eigen::MatrixXd d = position_sensitivity(b, col, k, m);
    sum += (d * cov * d.transpose()).trace();
  }
  return box.empty() ? 0.0 : sum / static_cast<double>(box.size());
}

void propose(const Monitor& mon, const EffectEntry& e, const EffectEstimate& best,
             const std::vector<BoxPoint>& box, ReidentificationProposal& p) {
  const MonitorOptions& o = mon.options();
  const int m = mon.model().robot.num_cables();
  const int col = monitoring::first_column(e, best.cable, m);
  const int k = e.columns;
  p.needed = true;
  p.parameters.push_back(e.per_cable ? format(e.parameters, best.cable) : e.parameters);
  const double target = e.moves_platform ? o.reidentify_position_m : o.reidentify_force_n;
  Eigen::MatrixXd info = Eigen::MatrixXd::Zero(k, k);
  std::vector<bool> used(box.size(), false);
  auto precision_of = [&](const Eigen::MatrixXd& inf) {
    Eigen::LDLT<Eigen::MatrixXd> ldlt(inf);
    if (ldlt.info() != Eigen::Success || ldlt.vectorD().minCoeff() <= 1e-12 * inf.trace()) {
      return std::numeric_limits<double>::infinity();
    }
    const Eigen::MatrixXd cov = ldlt.solve(Eigen::MatrixXd::Identity(k, k));
    return e.moves_platform ? std::sqrt(mean_position_variance(box, col, k, m, cov))
                            : std::sqrt(cov.diagonal().maxCoeff());
  };
  double reached = std::numeric_limits<double>::infinity();
  while (static_cast<int>(p.poses.size()) < o.full_sequence_poses && reached > target) {
    int pick = -1;
    double best_score = -std::numeric_limits<double>::infinity();
    Eigen::MatrixXd pick_info;
    for (std::size_t j = 0; j < box.size(); ++j) {
      if (used[j]) continue;
      const auto s = box[j].lin.signature.middleCols(col, k);
      const Eigen::MatrixXd add = o.samples_per_pose * (s.transpose() * box[j].w * s);
      const Eigen::MatrixXd trial = info + add;
      const Eigen::MatrixXd ridge =
          trial + 1e-9 * (trial.trace() + 1e-30) * Eigen::MatrixXd::Identity(k, k);
      const double score = Eigen::LDLT<Eigen::MatrixXd>(ridge).vectorD().array().log().sum();
      if (score > best_score) {
        best_score = score;
        pick = static_cast<int>(j);
        pick_info = trial;
      }
    }
    if (pick < 0) break;
    used[static_cast<std::size_t>(pick)] = true;
    info = pick_info;
    p.poses.push_back(box[static_cast<std::size_t>(pick)].pose);
    reached = precision_of(info);
  }
  p.predicted_position_m = reached;
  p.full_sequence = !(reached <= target);
  char buf[320];
  const double scale = e.moves_platform ? 1e3 : 1.0;
  const char* unit = e.moves_platform ? "mm" : "N";
  if (p.full_sequence) {
    std::snprintf(buf, sizeof buf,
                  "the full calibration sequence: %d poses do not bring the re-identified %s "
                  "below %.3g %s",
                  o.full_sequence_poses, p.parameters[0].c_str(), target * scale, unit);
  } else {
    std::snprintf(buf, sizeof buf,
                  "stop after %d pose%s of %d samples each: the predicted %s of the "
                  "re-identified change is then %.3g %s (target %.3g %s)",
                  static_cast<int>(p.poses.size()), p.poses.size() == 1 ? "" : "s",
                  o.samples_per_pose,
                  e.moves_platform ? "position error over the box" : "standard deviation",
                  reached * scale, unit, target * scale, unit);
  }
  p.stopping_rule = buf;
}

// Least squares of one candidate on its normal equations: value, std and the chi^2 it removes.
bool fit(const Eigen::MatrixXd& g, const Eigen::VectorXd& b, EffectEstimate& est) {
  if (!(g.diagonal().minCoeff() > 0.0)) return false;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(g);
  if (ldlt.info() != Eigen::Success || ldlt.vectorD().minCoeff() <= 1e-12 * g.trace()) {
    return false;
  }
  est.value = ldlt.solve(b);
  est.std = ldlt.solve(Eigen::MatrixXd::Identity(g.rows(), g.cols())).diagonal().cwiseSqrt();
  est.chi2_drop = b.dot(est.value);
  return true;
}

}  // namespace

Result<MonitorAssessment> Monitor::assess() const {
  MonitorAssessment a;
  a.samples = samples_;
  const double w = weight_ > 0.0 ? weight_ : 1.0;
  for (int r = 0; r < n_; ++r) {
    const auto u = static_cast<std::size_t>(r);
    a.rows.push_back(
        {names_[u], detectors_[u].statistic(), threshold_, mean_sigma_(r) / w, row_alarms_[u]});
  }
  int candidates = 0;
  for (const EffectEntry& e : monitoring::effect_table()) candidates += e.per_cable ? m_ : 1;
  // The blocks, newest first, for the change-point fits.
  std::vector<const Block*> recent;
  for (int j = 0; j < options_.history_blocks; ++j) {
    const int idx = (block_ - j + options_.history_blocks) % options_.history_blocks;
    const Block& b = blocks_[static_cast<std::size_t>(idx)];
    if (b.samples == 0) break;
    recent.push_back(&b);
  }
  const double tried = 1.0 + static_cast<double>(recent.size());
  std::vector<const EffectEntry*> entry_of;
  for (const EffectEntry& e : monitoring::effect_table()) {
    for (int i = e.per_cable ? 0 : -1; i < (e.per_cable ? m_ : 0); ++i) {
      const int col = monitoring::first_column(e, i, m_);
      EffectEstimate est;
      if (!fit(gram_.block(col, col, e.columns, e.columns), moment_.segment(col, e.columns), est)) {
        continue;
      }
      est.bic_drop = est.chi2_drop - e.columns * std::log(std::max(w, 2.0)) - std::log(tried);
      Eigen::MatrixXd g = Eigen::MatrixXd::Zero(e.columns, e.columns);
      Eigen::VectorXd b = Eigen::VectorXd::Zero(e.columns);
      int n = 0;
      for (const Block* block : recent) {
        g += block->gram.block(col, col, e.columns, e.columns);
        b += block->moment.segment(col, e.columns);
        n += block->samples;
        EffectEstimate since;
        if (!fit(g, b, since)) continue;
        since.bic_drop = since.chi2_drop - e.columns * std::log(std::max(n, 2)) - std::log(tried);
        if (since.bic_drop > est.bic_drop) {
          since.since_s = block->start_s;
          est = since;
        }
      }
      est.effect = e.effect;
      est.cable = i;
      est.id = e.id;
      est.words = e.per_cable ? format(e.words, i) : e.words;
      est.significant =
          est.chi2_drop > chi2_quantile(options_.gate_alpha / (candidates * tried), e.columns);
      a.effects.push_back(est);
      entry_of.push_back(&e);
    }
  }
  std::vector<std::size_t> order(a.effects.size());
  for (std::size_t j = 0; j < order.size(); ++j) order[j] = j;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
    return a.effects[x].bic_drop > a.effects[y].bic_drop;
  });
  std::vector<EffectEstimate> sorted;
  std::vector<const EffectEntry*> sorted_entry;
  for (std::size_t j : order) {
    sorted.push_back(a.effects[j]);
    sorted_entry.push_back(entry_of[j]);
  }
  a.effects = std::move(sorted);

  a.position_rms_acceptance_m = options_.acceptance_position_rms_m;
  a.position_rms_now_m = a.position_rms_acceptance_m;
  a.changed = !a.effects.empty() && a.effects.front().significant;
  if (!a.changed) return a;
  Monitor scratch = *this;
  const std::vector<BoxPoint> box = box_points(scratch);
  if (box.empty()) return Status(ErrorCode::kOutOfRange, "monitor: no pose of the box is feasible");
  const EffectEntry& e = *sorted_entry.front();
  const EffectEstimate& best = a.effects.front();
  if (e.moves_platform) {
    const int col = monitoring::first_column(e, best.cable, m_);
    const Eigen::MatrixXd dyad = best.value * best.value.transpose();
    const double bias2 = mean_position_variance(box, col, e.columns, m_, dyad);
    a.position_rms_now_m =
        std::sqrt(a.position_rms_acceptance_m * a.position_rms_acceptance_m + bias2);
  }
  propose(*this, e, best, box, a.proposal);
  return a;
}

std::string describe(const MonitorAssessment& a) {
  std::string out;
  char buf[400];
  std::snprintf(
      buf, sizeof buf,
      "%d samples; predicted position error over the box: %.3f mm now, %.3f mm at acceptance\n",
      a.samples, a.position_rms_now_m * 1e3, a.position_rms_acceptance_m * 1e3);
  out += buf;
  for (const MonitorRow& r : a.rows) {
    std::snprintf(buf, sizeof buf, "  %-16s mean %+.2f sigma, detector %.1f of %.1f, %d alarms\n",
                  r.name.c_str(), r.mean_sigma, r.statistic, r.threshold, r.alarms);
    out += buf;
  }
  if (!a.changed) return out + "no change beyond the noise\n";
  const EffectEstimate& e = a.effects.front();
  for (const EffectEntry& entry : monitoring::effect_table()) {
    if (entry.effect != e.effect) continue;
    std::snprintf(buf, sizeof buf, "looks like: %s (chi2 drop %.1f):", e.words.c_str(),
                  e.chi2_drop);
    out += buf;
    for (Eigen::Index j = 0; j < e.value.size(); ++j) {
      std::snprintf(buf, sizeof buf, " %.3g +- %.2g", e.value(j) * entry.to_people,
                    e.std(j) * entry.to_people);
      out += buf;
    }
    out += std::string(" ") + entry.unit + "\n";
  }
  const ReidentificationProposal& p = a.proposal;
  out += "proposal: re-identify";
  for (const std::string& s : p.parameters) out += " " + s;
  out += "; " + p.stopping_rule + "\n";
  return out;
}

}  // namespace cdpr
