// The locator's refits (diagnosis_internal.hpp): a model state with one candidate added, by the
// hook of the candidate's refit kind (identification, Gauss-Newton, catenary), the Gauss-Newton
// effects and the catenary refreshed beside every later effect, and the named values of the
// accepted effects.
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

namespace {

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

}  // namespace

Result<MismatchDesign> state_design(const CalibratedModel& nominal, const IdentificationReport& rep,
                                    const MeasurementSet& set, const IdentificationOptions& opt,
                                    const MismatchOptions& mopt) {
  return mismatch_design(rep.estimate, tensions_read_with(set, nominal.robot, rep.estimate.robot),
                         rep.poses, &rep.residuals, opt, mopt);
}

Result<IdentificationReport> identify_from(const CalibratedModel& nominal,
                                           const CalibratedModel& from, const MeasurementSet& set,
                                           const IdentificationOptions& opt) {
  CalibratedModel initial = from;
  initial.robot.force_sensors = nominal.robot.force_sensors;
  // The inclinometer's mounting is estimated as a tilt (roll, pitch) of the initial model's: from
  // an estimated mounting, some mountings are out of reach (a heading appears at second order; the
  // noise-free crane with a concealed weight kept chi^2 0.012 and its mass 1e-5 off).
  if (opt.estimate_inclinometer_mounting) {
    initial.robot.inclinometer.mounting_rpy = nominal.robot.inclinometer.mounting_rpy;
  }
  return identify(initial, set, opt);
}

namespace {

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

// The screen's F-test of the columns of candidate `rival` on what state `st` leaves (its design:
// the identification with the effect just added projected out pose by pose), Bonferroni over the
// library's candidates: the gate a first effect passes in the screen. 1 when the design has no
// such candidate or no degrees of freedom are left.
double rival_p_value(const RefitContext& ctx, const State& st, const std::string& rival) {
  const CandidateColumns* c = find_columns(st.design, rival);
  if (c == nullptr || c->X.cols() == 0) return 1.0;
  const auto k = c->X.cols();
  const PoseGrams g = pose_grams(st.design, {&c->X}, true, false);
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
  for (const auto& Mj : g.M) M += Mj;
  const Eigen::MatrixXd S = reduce_geometry(M, g.geometry);
  const int rank = projected_rank(S.topLeftCorner(k, k), M.diagonal().segment(g.geometry, k),
                                  ctx.options.screen.rank_tolerance);
  const int d2 = st.report.dof - rank;
  if (rank == 0 || d2 <= 0) return 1.0;
  const Eigen::VectorXd b = S.block(0, k, k, 1);
  const Eigen::VectorXd x = pinv_sym(S.topLeftCorner(k, k), 1e-9) * b;
  const double taken = std::clamp(b.dot(x), 0.0, S(k, k));
  const double f = (taken / rank) / (std::max(S(k, k) - taken, 1e-300) / d2);
  const double library = static_cast<double>(std::max<std::size_t>(1, st.design.candidates.size()));
  return std::min(1.0, library * f_upper_tail(f, rank, d2));
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

}  // namespace

double deviance(const RefitContext& ctx, const State& st) {
  return st.report.chi2 + st.report.log_det_covariance - ctx.log_det0;
}

double joint_bic(const RefitContext& ctx, const State& st, double penalty) {
  return deviance(ctx, st) + penalty;
}

double bic_penalty(const RefitContext& ctx, const std::vector<EffectFit>& effects) {
  double p = 0.0;
  for (const auto& f : effects) p += f.extra_parameters * ctx.log_size(f.id);
  return p;
}

namespace {

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

}  // namespace

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
  if (effect != nullptr && !effect->per_cable_rival.empty()) {
    fit.rival_p_value = rival_p_value(ctx, *next, std::string(effect->per_cable_rival));
  }
  return next;
}

const Trial* RefitMemo::step(const RefitContext& ctx, const std::vector<std::string>& ids) {
  if (ids.empty()) return nullptr;
  const auto known = steps_.find(ids);
  if (known != steps_.end()) return known->second ? &*known->second : nullptr;
  const State* from = ids.size() == 1
                          ? &standard_
                          : path(ctx, std::vector<std::string>(ids.begin(), ids.end() - 1));
  std::optional<Trial> t;
  if (from != nullptr) {
    EffectFit fit;
    auto st = refit(ctx, *from, ids.back(), fit);
    if (st) t = Trial{std::move(fit), std::move(*st)};
  }
  auto& slot = steps_[ids];
  slot = std::move(t);
  return slot ? &*slot : nullptr;
}

const State* RefitMemo::path(const RefitContext& ctx, const std::vector<std::string>& ids) {
  if (ids.empty()) return &standard_;
  const Trial* t = step(ctx, ids);
  if (t == nullptr) return nullptr;
  if (ids.size() < 2 || !ctx.options.polish_gauss_newton) return &t->state;
  const auto known = polished_.find(ids);
  if (known != polished_.end()) return &known->second;
  State st = t->state;
  polish_gauss_newton(ctx, st);
  return &polished_.emplace(ids, std::move(st)).first->second;
}

}  // namespace cdpr::diagnosis_detail
