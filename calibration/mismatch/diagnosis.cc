// The mismatch locator (diagnose(), diagnosis.hpp; docs/mismatch-locator.md): the stages in
// order, each a function of diagnosis_internal.hpp that hands an explicit result to the next.
#include "cdpr/calibration/diagnosis.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>

#include "cdpr/calibration/effect_library.hpp"
#include "diagnosis_internal.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr {

using namespace diagnosis_detail;
using mismatch_detail::format;

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

// A recording that does not match the model (cable count, laser count, validate()).
Status check_recording(const MeasurementSet& s, const RobotModel& robot, const char* what) {
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
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
}

Status check_inputs(const RobotModel& robot, const MeasurementSet& set,
                    const MeasurementSet* validation, const DiagnosisOptions& options) {
  CDPR_RETURN_IF_ERROR(check_recording(set, robot, "recording"));
  if (validation != nullptr) {
    CDPR_RETURN_IF_ERROR(check_recording(*validation, robot, "validation recording"));
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
  return Status::success();
}

// Too few poses to tell the candidates apart: inconclusive, with the standard identification.
Diagnosis too_few_poses(const CalibratedModel& nominal, const MeasurementSet& set,
                        const IdentificationOptions& identification,
                        const DiagnosisOptions& options) {
  Diagnosis d;
  d.model_after = nominal;
  const int np = set.num_poses();
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

// The verdict on gross readings: the standard fit and the readings, nothing else diagnosed.
Diagnosis gross_verdict(Diagnosis& d, const CalibratedModel& nominal) {
  Diagnosis g;
  g.before = std::move(d.before);
  g.gross_readings = std::move(d.gross_readings);
  g.model_after = nominal;
  state_gross_readings(g);
  return g;
}

// An effect held back for weak evidence (DiagnosisOptions::weak_step_bic): taken after all by a
// swap of the first round, it is no suspect; else it is listed among the candidates.
void settle_held_back(Acceptance& acc) {
  if (!acc.held_back) return;
  if (acc.ids_taken.count(acc.held_back->id)) {
    acc.held_back.reset();
  } else if (std::none_of(acc.candidates.begin(), acc.candidates.end(),
                          [&](const EffectFit& c) { return c.id == acc.held_back->id; })) {
    acc.candidates.push_back(*acc.held_back);
  }
}

// Stage 5, extra-pose design: separating poses for the confounded pairs `found`, follow-up poses
// for a suspect (the grid is built only when one of them needs it). A suspect beside named
// effects (the second round's screen) gets follow-up poses only with follow_up_beside_named:
// measured and diagnosed again, they cost more than they found on the benchmark
// (docs/mismatch-benchmark.md).
void design_extra_poses(Diagnosis& d, const Acceptance& acc,
                        const std::vector<ConfoundedPair>& found, const CalibratedModel& nominal,
                        const MeasurementSet& set, const IdentificationOptions& identification,
                        const DiagnosisOptions& options) {
  const int np = set.num_poses();
  std::optional<ExtraPoseGrid> grid;
  auto grid_of = [&]() -> const ExtraPoseGrid& {
    if (!grid) grid = extra_pose_grid(nominal.robot, d.before, set, identification, options);
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
}

}  // namespace

Result<Diagnosis> diagnose(const CalibratedModel& nominal, const MeasurementSet& set,
                           const MeasurementSet* validation,
                           const IdentificationOptions& identification,
                           const DiagnosisOptions& options) {
  const RobotModel& robot = nominal.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  CDPR_RETURN_IF_ERROR(check_inputs(robot, set, validation, options));
  const int np = set.num_poses();
  if (np < options.min_poses || np < options.cv_folds) {
    return too_few_poses(nominal, set, identification, options);
  }
  Diagnosis d;
  d.model_after = nominal;

  // The standard identification (the "before" model) and the screen of locate_mismatch.
  auto before = identify(nominal, set, identification);
  if (!before) return before.status();
  d.before = std::move(*before);
  // Stage 0, gross readings: nothing is named on a recording with a wild reading; readings within
  // gross_effects_sigmas are tried against the effects accepted on the whole recording (stage 3d).
  d.gross_readings = find_gross_readings(nominal, set, d.before, identification, options);
  if (std::any_of(d.gross_readings.begin(), d.gross_readings.end(), [&](const GrossReading& g) {
        return !(g.sigmas <= options.gross_effects_sigmas);
      })) {
    return gross_verdict(d, nominal);
  }
  auto screen = locate_mismatch(d.before, set, identification, options.screen);
  if (!screen) return screen.status();
  d.screen = std::move(*screen);
  d.model_after = d.before.estimate;
  auto design0 = state_design(nominal, d.before, set, identification, options.screen);
  if (!design0) return design0.status();
  const MismatchDesign& D0 = *design0;
  const int n = D0.num_rows();

  // Stage 1, selection.
  const Selection selection = select_candidates(D0, d.screen, np, options);
  const Folds folds = assign_folds(D0, np, options);
  const CvRms cv_before = cv_rms(D0, nullptr, folds.fold, folds.K);
  const State standard{identification, set, d.before, D0, {}, {}, cv_before, {}, {}, {}};
  RefitMemo memo(standard);
  const RefitContext ctx{options,
                         D0,
                         selection,
                         folds,
                         d.screen.dof,
                         m,
                         std::log(static_cast<double>(n)),
                         d.before.log_det_covariance,
                         bic_log_sizes(D0, options.bic_informing_rows),
                         nominal,
                         &memo};

  // Stages 2 and 3, refits and acceptance.
  Acceptance acc = accept_effects(ctx, standard, d.screen);
  // Stage 3b, the second screening round on what the accepted effects leave.
  if (!acc.accepted.empty()) d.screen_after = second_round(ctx, d.screen, acc);
  // Stage 3c, the backward check when the second round added an effect.
  const bool second = std::any_of(acc.accepted.begin(), acc.accepted.end(),
                                  [](const EffectFit& f) { return f.round == 2; });
  if (second && options.backward_check && backward_check(ctx, acc)) {
    auto again =
        locate_mismatch(acc.current.report, acc.current.set, acc.current.opt, options.screen);
    if (again) d.screen_after = std::move(*again);
  }
  settle_held_back(acc);
  std::string physics_in_few;
  // Stage 3d: flagged readings that the accepted effects bring within gross_sigmas are physics
  // concentrated in a few readings (DiagnosisOptions::gross_effects_sigmas).
  if (!d.gross_readings.empty()) {
    if (acc.accepted.empty() ||
        !explained_by_effects(d.gross_readings, acc.current.report, options)) {
      return gross_verdict(d, nominal);
    }
    physics_in_few = format(
        "%s far out of a robust fit of the standard model %s within %.0f sigmas of the fit with "
        "the effects named: physics concentrated in a few readings, not a gross error.",
        describe(d.gross_readings).c_str(), d.gross_readings.size() == 1 ? "comes" : "come",
        options.gross_sigmas);
    d.gross_readings.clear();
  }
  // Stage 4, naming: the pairs this recording cannot tell apart.
  const std::vector<ConfoundedPair> found = confounded_pairs(ctx, d.screen, acc);
  if (options.polish_gauss_newton) refresh_gauss_newton_parameters(acc.current, acc.accepted);
  refresh_identified_parameters(acc.current, acc.accepted);
  d.accepted = std::move(acc.accepted);
  d.candidates = std::move(acc.candidates);
  design_extra_poses(d, acc, found, nominal, set, identification, options);

  // Stage 6, the model with the accepted effects; stage 7, the verdict.
  CDPR_RETURN_IF_ERROR(model_the_effects(d, acc.current, cv_before, folds.K, options.cv_folds == 0,
                                         validation, nominal, identification, nl));
  state_verdict(d, options.screen.alpha);
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
