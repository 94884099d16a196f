// The locator's acceptance (diagnosis_internal.hpp): every kept candidate refitted from the
// standard model, forward selection from the best passing first effects with swaps, the second
// screening round on the model with the accepted effects, the backward check, and the confounded
// pairs the recording cannot tell apart.
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

const EffectFit* trial_fit(const std::vector<Trial>& trials, const std::string& id) {
  for (const auto& t : trials) {
    if (t.fit.id == id) return &t.fit;
  }
  return nullptr;
}

namespace {

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
  double rival_p = 0.05;     // DiagnosisOptions::screen_gate_p (EffectFit::rival_p_value)
  std::string strong_group;  // empty: none
  double strong_bic = 0.0;
};

Gate gate_of(const DiagnosisOptions& options) {
  Gate g;
  g.alpha = options.screen.alpha;
  g.rival_p = options.screen_gate_p;
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
         f.cv_normalized_after < f.cv_normalized_before && !(f.rival_p_value < gate.rival_p);
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

}  // namespace

bool proxy_for_structure(const MismatchSummary& screen, const std::string& id, double gate) {
  const CandidateScreen* cs = screen.find(id);
  return cs != nullptr && cs->p_adjusted < gate && !(cs->p_beyond_structure < gate);
}

namespace {

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
// accepted; the Gauss-Newton ones polished beside each later one, RefitMemo::path); nullopt when
// one cannot be fitted.
struct JointFit {
  State state;
  std::vector<EffectFit> fits;
  double penalty = 0.0;  // the BIC penalty of the effects' extra parameters together
};

std::optional<JointFit> joint_refit(const RefitContext& ctx, const std::vector<std::string>& ids) {
  JointFit out;
  std::vector<std::string> prefix;
  for (const std::string& id : ids) {
    prefix.push_back(id);
    const Trial* t = ctx.memo->step(ctx, prefix);
    if (t == nullptr) return std::nullopt;
    EffectFit f = t->fit;
    out.penalty += f.extra_parameters * ctx.log_size(id);
    f.accepted = true;
    out.fits.push_back(std::move(f));
  }
  const State* st = ctx.memo->path(ctx, ids);
  if (st == nullptr) return std::nullopt;
  out.state = *st;
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

}  // namespace

namespace {

// A refinement (an accepted effect whose selection group holds a simpler family: nonlinear
// elasticity beside Hooke's) is named only when what it adds passes the gate of naming an effect:
// the set refitted jointly with the simpler member in its place, the likelihood ratio of the
// refinement's extra parameters, Bonferroni over the library, below
// DiagnosisOptions::refinement_gate_p; else the simpler member takes its place. (The paths' joint
// BIC charges one curvature parameter log n, ~6: LARGE's Hooke beside sag, seed 5, was named
// nonlinear elasticity at a deviance gain of 7.6.)
void keep_refinements_that_pass(const RefitContext& ctx, const MismatchSummary& screen,
                                Acceptance& acc) {
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
    auto joint = joint_refit(ctx, ids);
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

// The first effects of the forward paths: up to four of the trials that pass, the best by
// choose_trial first, then by BIC. A first effect must also be seen by the linear screen
// (Holm-adjusted over the library): on noise, a nonlinear refit can reach a far minimum (a beam
// tilt of 8 degrees on MINI's null data, LRT 20 on 2 parameters) whose likelihood ratio
// overstates its significance. An effect the screen sees only before the correction is a suspect
// (follow-up poses).
std::vector<const Trial*> first_effects(const std::vector<Trial>& trials,
                                        const MismatchSummary& screen,
                                        const DiagnosisOptions& options, const Gate& gate) {
  std::vector<const Trial*> firsts;
  std::vector<const Trial*> pool;
  std::vector<double> p;
  for (const auto& t : trials) {
    const CandidateScreen* cs = screen.find(t.fit.id);
    if (cs != nullptr && !(cs->p_adjusted < options.screen_gate_p)) continue;
    if (proxy_for_structure(screen, t.fit.id, options.screen_gate_p)) continue;
    pool.push_back(&t);
    p.push_back(t.fit.lrt_p_value);
  }
  const std::vector<double> adj = holm(p);
  if (const Trial* b = choose_trial(pool, adj, gate)) firsts.push_back(b);
  std::vector<std::size_t> order(pool.size());
  for (std::size_t q = 0; q < order.size(); ++q) order[q] = q;
  std::sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
    return pool[x]->fit.bic_delta < pool[y]->fit.bic_delta;
  });
  for (std::size_t q : order) {
    if (firsts.size() >= 4) break;
    if (!passes_tests(pool[q]->fit, adj[q], gate)) continue;
    if (std::find(firsts.begin(), firsts.end(), pool[q]) == firsts.end()) {
      firsts.push_back(pool[q]);
    }
  }
  return firsts;
}

// A forward path: its accepted effects, its state and joint BIC, and the step it stopped at for
// weak evidence.
struct ForwardPath {
  std::vector<EffectFit> accepted;
  State state;
  double bic = 0.0;
  std::optional<EffectFit> held_back;
};

// The forward path from `first`: further effects refitted jointly with the accepted ones and
// tested against them, while one passes (at most max_effects).
ForwardPath forward_from(const RefitContext& ctx, const MismatchSummary& screen, const Trial& first,
                         const Gate& gate) {
  const DiagnosisOptions& options = ctx.options;
  ForwardPath path{{first.fit}, first.state, 0.0, std::nullopt};
  path.accepted.front().accepted = true;
  std::set<std::string> groups{selection_group(first.fit.family)};
  std::set<std::string> ids{first.fit.id};
  std::vector<std::string> in_turn{first.fit.id};  // the accepted effects in the order added
  while (static_cast<int>(path.accepted.size()) < options.max_effects) {
    std::vector<Trial> more;
    for (const std::string& id : ctx.selection.to_refit) {
      const CandidateColumns* cc = find_columns(ctx.design0, id);
      if (cc == nullptr || !ctx.selection.kept.count(id) ||
          groups.count(selection_group(cc->family)) ||
          proxy_for_structure(screen, id, options.screen_gate_p))
        continue;
      bool clash = false;
      for (const std::string& t : ids) {
        clash = clash ||
                confounded_clash(screen.confounded, t, id, false, options.forward_own_directions);
      }
      if (clash) continue;
      std::vector<std::string> with = in_turn;
      with.push_back(id);
      if (const Trial* t = ctx.memo->step(ctx, with)) more.push_back(*t);
    }
    const Trial* best = best_step(more, gate);
    if (best == nullptr) break;
    if (held_back_step(best->fit, options)) {
      // The paths compete as if the step were taken: holding it back decides what is named, not
      // which path explains the recording best (a path ending at a weak step would lose to one
      // with a stand-in for its first effect: elasticity for creep beside force gains).
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
    in_turn.push_back(f.id);
    path.state = *ctx.memo->path(ctx, in_turn);
  }
  path.bic = joint_bic(ctx, path.state, bic_penalty(ctx, path.accepted));
  return path;
}

// One pass of the swaps: the accepted set with each effect replaced in turn by every other kept
// candidate, refitted jointly from the standard model; the best swap that lowers the joint BIC
// clearly is made (`acc.accepted`, `current`). False when none helps.
bool swap_once(const RefitContext& ctx, const MismatchSummary& screen, Acceptance& acc,
               State& current) {
  const DiagnosisOptions& options = ctx.options;
  const std::vector<ConfoundedPair>& pairs = screen.confounded;
  const double bic_now = joint_bic(ctx, current, bic_penalty(ctx, acc.accepted));
  double best_bic = bic_now - 2.0;  // a swap must gain clearly
  std::optional<State> best_state;
  std::vector<EffectFit> best_set;
  for (std::size_t pos = 0; pos < acc.accepted.size(); ++pos) {
    for (const std::string& id : ctx.selection.to_refit) {
      const CandidateColumns* cc = find_columns(ctx.design0, id);
      if (cc == nullptr || acc.ids_taken.count(id) ||
          proxy_for_structure(screen, id, options.screen_gate_p))
        continue;
      // A member of the replaced effect's own selection group with no more columns (Hooke for
      // nonlinear elasticity) may come in beside an effect that the replaced one was as
      // confounded with: the set is no more confounded than before, and no richer. (A richer
      // member let in so named nonlinear elasticity for LARGE's Hooke beside sag, seed 5.)
      const std::string& replaced = acc.accepted[pos].id;
      const CandidateColumns* rc = find_columns(ctx.design0, replaced);
      const bool same_group =
          rc != nullptr &&
          selection_group(acc.accepted[pos].family) == selection_group(cc->family) &&
          cc->X.cols() <= rc->X.cols();
      bool clash = false;
      for (std::size_t q = 0; q < acc.accepted.size(); ++q) {
        if (q == pos) continue;
        const std::string& other = acc.accepted[q].id;
        clash = clash || selection_group(acc.accepted[q].family) == selection_group(cc->family) ||
                (confounded_clash(pairs, other, id) &&
                 !(same_group && confounded_clash(pairs, other, replaced)));
      }
      if (clash) continue;
      std::vector<std::string> ids;
      for (std::size_t q = 0; q < acc.accepted.size(); ++q) {
        ids.push_back(q == pos ? id : acc.accepted[q].id);
      }
      auto joint = joint_refit(ctx, ids);
      const double b = joint ? joint_bic(ctx, joint->state, joint->penalty)
                             : std::numeric_limits<double>::infinity();
      acc.joint_bics[ids] = b;
      if (!joint) continue;
      // An effect whose per-cable rival is significant beside it is not swapped in either.
      if (std::any_of(joint->fits.begin(), joint->fits.end(), [&](const EffectFit& f) {
            return f.rival_p_value < options.screen_gate_p;
          })) {
        continue;
      }
      if (b < best_bic) {
        best_bic = b;
        best_state = std::move(joint->state);
        best_set = std::move(joint->fits);
      }
    }
  }
  if (!best_state) return false;
  current = std::move(*best_state);
  acc.accepted = std::move(best_set);
  acc.ids_taken.clear();
  for (const auto& f : acc.accepted) acc.ids_taken.insert(f.id);
  return true;
}

}  // namespace

Acceptance accept_effects(const RefitContext& ctx, const State& standard,
                          const MismatchSummary& screen) {
  const DiagnosisOptions& options = ctx.options;
  Acceptance out;
  for (const std::string& id : ctx.selection.to_refit) {
    if (const Trial* t = ctx.memo->step(ctx, {id})) out.trials.push_back(*t);
  }
  const Gate gate = gate_of(options);
  State current = standard;
  // Forward selection, started from each of the (up to four) best first effects that pass: the
  // greedy path from the single best may begin with a per-cable effect that also absorbs part of
  // a second one (winch compliance per winch for elasticity + drum scale). Each path adds
  // further effects refitted jointly with the accepted ones and tested against them; the path
  // with the lowest joint BIC wins.
  const std::vector<const Trial*> firsts = first_effects(out.trials, screen, options, gate);
  for (const auto& t : out.trials) out.candidates.push_back(t.fit);
  if (options.max_effects > 0 && !firsts.empty()) {
    std::optional<ForwardPath> best_path;
    for (const Trial* t : firsts) {
      ForwardPath path = forward_from(ctx, screen, *t, gate);
      if (!best_path || path.bic < best_path->bic) best_path = std::move(path);
    }
    out.accepted = std::move(best_path->accepted);
    current = std::move(best_path->state);
    out.held_back = std::move(best_path->held_back);
    for (const auto& f : out.accepted) out.ids_taken.insert(f.id);
  }
  // Swaps. The forward steps are greedy: a per-cable effect may take the first place by also
  // absorbing part of a second effect (winch compliance per winch for elasticity + drum scale).
  // With two or more accepted effects, each one is replaced in turn by every other kept
  // candidate, the set refitted jointly from the standard model, and the best swap that lowers
  // the joint BIC is made (repeated while one helps). A swap never brings in a candidate
  // confounded with one of the others, whatever its own directions: each swap is a joint refit of
  // the whole set.
  for (int pass = 0; pass < 3 && out.accepted.size() >= 2; ++pass) {
    if (!swap_once(ctx, screen, out, current)) break;
  }
  out.current = std::move(current);
  keep_refinements_that_pass(ctx, screen, out);
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
      // acc.current is the path of the accepted effects in their order (RefitMemo::path).
      std::vector<std::string> with;
      for (const auto& f : acc.accepted) with.push_back(f.id);
      with.push_back(cs.id);
      if (const Trial* t = ctx.memo->step(ctx, with)) more.push_back(*t);
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
    std::vector<std::string> in_turn;
    for (const auto& a : acc.accepted) in_turn.push_back(a.id);
    acc.current = *ctx.memo->path(ctx, in_turn);
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

bool backward_check(const RefitContext& ctx, Acceptance& acc) {
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
      auto joint = joint_refit(ctx, ids);
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

std::vector<ConfoundedPair> confounded_pairs(const RefitContext& ctx, const MismatchSummary& screen,
                                             Acceptance& acc) {
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
      auto joint = joint_refit(ctx, ids);
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
      const Trial* t = ctx.memo->step(ctx, {id});
      if (t == nullptr) continue;
      acc.trials.push_back(*t);
      acc.candidates.push_back(t->fit);
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

}  // namespace cdpr::diagnosis_detail
