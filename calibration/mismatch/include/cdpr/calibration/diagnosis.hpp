// The mismatch locator, complete: from a nominal model and a recording to a verdict on the missing
// physics, the model with it, and the proof that the fit improves (also on held-out data).
// Pure statistics on top of identification.hpp and mismatch.hpp (no I/O, no logging).
//
// diagnose(nominal, set, validation?, ...):
//  1. Standard identification (IdentificationOptions as given: the "before" model) and the screen
//     of locate_mismatch (where the misfit is, with what structure, which candidates score).
//  2. Selection. Bootstrap over poses (resample the N poses with replacement B times, redo the
//     projected screen on each resample, forward-select candidates by BIC with a family-wise
//     significance gate): the inclusion probability of every candidate. Candidates whose
//     inclusion probability exceeds DiagnosisOptions::inclusion_threshold are kept.
//  3. Refits. For each kept candidate (and each confounded alternative), the model with the effect
//     added is refitted in full (nonlinear identification with the effect's parameters estimated
//     where identification.hpp has them, else the Gauss-Newton augmented fit). Ranked by
//     likelihood-ratio test against the standard model (the drop of the deviance chi^2 + log det
//     of the residual covariance, chi^2-distributed with the extra parameters as degrees of
//     freedom: the length and equilibrium sigmas depend on the compliance), BIC change counting
//     only the parameters that differ between the candidates, and K-fold cross-validation over
//     poses (the geometry from K-1 folds, the held-out
//     poses re-located from their own readings with the geometry fixed, the RMS of their
//     residuals in sigmas over every channel).
//  4. Naming. The accepted effects in words with their fitted parameters and standard deviations
//     ("cable elasticity: EA = 21.4 +- 0.6 kN"). Two candidates that this pose set cannot tell
//     apart (highly correlated projected columns AND full fits within
//     DiagnosisOptions::decisive_bic of each other) are reported as confounded, with both fits
//     and a set of extra poses (from the feasible candidate grid) that would separate them.
//  5. Model it: the calibrated model carries the accepted effects (EA, polynomial surface, drum
//     scale in the winch model, encoder zero, force sensor gain/offset, laser mount/plane, mass
//     per length for sag); per-channel residual RMS before/after, held-out RMS before/after.
//  6. Verdict: kNoMismatch ("no missing physics found": residuals consistent with noise),
//     kMismatchNamed, kMismatchUnexplained (misfit, but no candidate explains it; or, with no
//     effect named, structure that no candidate explains, MismatchSummary::unexplained: the
//     headline says which variable it follows on which cables, e.g. "Unexplained structure
//     following the direction of the last move of cables 2 and 5 (cable tensions)"), or
//     kInconclusive (too few poses / residuals to tell the effects apart; says so, never guesses).
//
// How it is done (diagnosis.cc):
//  - Bootstrap: per-pose cross products of [geometry Jacobian | candidate columns | residual] with
//    the pose's own Jacobian projected out (mismatch_design); a resample is a weighted sum of
//    them (a pose drawn twice counts twice), so no refit per resample. Poses fixed by the gauge
//    (the home pose) are always kept. Forward selection: F-test p-values, Holm over the
//    contenders of each step, lowest BIC first, one candidate per family, and within a family the
//    simplest member (shared before per cable) unless the richer one is significantly better.
//    A candidate is kept when its family, or a family confounded with it on this pose set, was
//    selected in at least inclusion_threshold of the resamples (confounded families split the
//    resamples between them; a strong effect makes the first-order screen pick the richer family
//    member by its nonlinearity). Every member of a kept family is refitted.
//  - Refits: identify() with the effect's option on (from the standard estimate; the laser
//    mounting falls back to the beam direction alone when the origin trades against the target
//    plane), else Gauss-Newton: the effect's coefficients from the projected columns, the effect
//    moved into the data (length and laser readings; on the equilibrium rows through
//    PoseMeasurement::external_wrench and the SI columns), identify() redone, repeated until the
//    deviance settles. Families that refine each other share a selection group
//    (mismatch.hpp: nonlinear elasticity refines elasticity) and are compared by nested tests.
//  - Sag is refitted on the exact elastic catenary (sag_effect, mismatch.hpp) as one parameter,
//    the mass per length, by Gauss-Newton; the corrected lengths carry the sag's dependence on
//    the tension reading in their sigma (PoseMeasurement::extra_compliance).
//  - Acceptance: forward selection started from each of the (up to four) best passing first
//    effects (Holm-adjusted LRT p < alpha, BIC decrease, held-out RMS in sigmas decrease; a first
//    effect must also be significant in the screen after Holm, screen_gate_p); each
//    path adds further kept candidates refitted jointly with the accepted ones and tested
//    against them (their EffectFit is then relative to the model with the earlier effects); the
//    path with the lowest joint BIC wins. Then swaps: with two or more effects, each is replaced
//    in turn by every other kept candidate and the set refitted from the standard model; a swap
//    that lowers the joint BIC by more than 2 is made. Two candidates confounded on this pose
//    set are never accepted together.
//  - Cross-validation is linearised about each fit: the geometry (and Gauss-Newton effect
//    coefficients) from one Gauss-Newton step on K-1 folds, held-out poses re-located to first
//    order; the home pose always stays in the training folds.
//  - Validation recording: its poses are re-located by identify() with the encoder zeros
//    re-estimated and everything else fixed (identify() refuses a problem without parameters;
//    a new recording is homed again anyway).
//  - Separating and follow-up poses: a 4 x 4 x 4 grid over the region the recording visited
//    (its estimated poses' extent around home, capped by fit_design_box_to_robot's box, scaled by
//    separating_half_extent_scale) x {level, +-tilt roll, +-tilt pitch} (tilt: the largest the
//    recording used, at most 0.2 rad), kept where simple_tension_distribution finds feasible
//    tensions for the estimate and the nominal model, each at the planned pretension and at twice
//    it; greedy (separating: lowest canonical correlation of the pair; follow-up: largest log det
//    of the suspect's projected information). Near the edge of the model's workspace the real
//    robot may not hold the platform, so no pose goes beyond where the recording already went.
//  - Follow-up: with no effect named, the screen candidate with the lowest p-value is a suspect
//    when its p-value after Holm's correction over the library is below suspect_p (so at most
//    about suspect_p of the recordings of a correct model get one); the follow_up_poses grid
//    poses that most increase the log det of its projected information are proposed
//    (Diagnosis::follow_up).
//  - model_after: identify()'s estimate with the effects it can estimate; Gauss-Newton effects
//    written where the config has a field (encoder offsets, common drum scale, mass per length,
//    EA or a polynomial surface when the cables were rigid); otherwise modelled_in_config = false
//    (creep, drifts: report only).
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/mismatch.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct DiagnosisOptions {
  MismatchOptions screen;            // alpha, confounding threshold, rank tolerance
  int bootstrap_samples = 100;       // resamples over poses for inclusion probabilities
  ProgressCallback progress;         // "bootstrap resamples" b of bootstrap_samples; empty: none
  double inclusion_threshold = 0.6;  // keep candidates selected in at least this fraction
  int cv_folds = 5;                  // K-fold cross-validation over poses (2 <= K <= N)
  unsigned seed = 1;                 // bootstrap and fold assignment (deterministic)
  int max_effects = 3;               // at most this many effects are accepted together
  int min_poses = 12;                // below this the verdict is kInconclusive
  // Two candidates that the screen finds confounded (canonical correlation above
  // screen.confound_threshold) are reported as "A or B" only when their full fits differ by less
  // than this in BIC; a larger difference is very strong evidence for the better one.
  double decisive_bic = 10.0;
  int separating_poses = 6;                   // extra poses proposed for each confounded pair
  double separating_half_extent_scale = 1.0;  // of the extra-pose grid (the visited region)
  // With no effect named, the candidate with the lowest screen p-value is a suspect when its
  // p-value AFTER Holm's correction over the library (CandidateScreen::p_adjusted) is below
  // suspect_p; follow_up_poses extra poses that add the most information on it are then proposed
  // (Diagnosis::follow_up). The corrected p-value is a family-wise error rate, so suspect_p is
  // about the fraction of recordings of a correct model that get a suspect (and cost
  // follow_up_poses poses of robot time); docs/mismatch-benchmark.md measures the trade against
  // detection. 0: never; above 1: always (the lowest p-value). When the screen's overall misfit
  // test fails and nothing is named (verdict "mismatch unexplained"), the candidate with the lowest
  // p-value is a suspect whatever this threshold (more poses are the next step there anyway).
  double suspect_p = 0.2;
  int follow_up_poses = 20;
  // The first accepted effect must also be seen by the linear screen: its screen p-value
  // (after Holm's correction over the library) below this. On noise, a nonlinear refit can reach a
  // far minimum whose likelihood ratio overstates its significance (chi^2 with the nominal degrees
  // of freedom assumes the linear regime).
  double screen_gate_p = 0.05;
};

// One fitted effect parameter, in SI units (and as shown to people).
struct EffectParameter {
  std::string name;  // "EA", "s_3", "o_2", "mass_per_length", ...
  std::string unit;  // "N", "-", "m", "kg/m"
  double value = 0.0;
  double std_dev = 0.0;
  std::string text;  // "EA = 21.4 +- 0.6 kN"
};

// A candidate effect after selection and refit.
struct EffectFit {
  std::string id;    // candidate id of mismatch.hpp ("hooke_shared", ...)
  std::string name;  // plain language
  std::string family;
  double inclusion_probability = 0.0;  // bootstrap over poses
  // Fraction of the resamples that selected any member of the family (shared or per cable).
  double family_inclusion_probability = 0.0;
  int extra_parameters = 0;  // parameters the effect adds
  double chi2_before = 0.0, chi2_after = 0.0;
  // chi2 + IdentificationReport::log_det_covariance (-2 log likelihood up to one constant): the
  // sigmas of the length and equilibrium rows depend on the compliance, so an elongation effect
  // also changes the normalisation.
  double deviance_before = 0.0, deviance_after = 0.0;
  double lrt_statistic = 0.0;  // deviance_before - deviance_after
  double lrt_p_value = 1.0;    // chi^2(extra_parameters) upper tail
  double bic_delta = 0.0;      // negative: the effect is worth its parameters
  double cv_rms_before = 0.0;  // held-out length residual RMS over the folds, m (standard model)
  double cv_rms_after = 0.0;   // same with the effect modelled
  // Held-out RMS of all residuals (every channel) in sigmas over the folds, before/after: the
  // acceptance test (an effect of the laser or the force sensors may leave the lengths alone).
  double cv_normalized_before = 0.0, cv_normalized_after = 0.0;
  bool accepted = false;
  bool modelled_in_config = false;  // the calibrated config can carry it (else: report only)
  std::vector<EffectParameter> parameters;
};

struct ChannelRms {
  std::string channel;  // "cable lengths", "laser 1", "equilibrium", ...
  std::string unit;     // "m", "N"
  double before = 0.0;  // RMS after the standard identification
  double after = 0.0;   // RMS with the accepted effects modelled
};

struct ConfoundedFinding {
  std::string first, second;  // candidate ids
  double correlation = 0.0;
  std::string description;  // "cable elasticity (~F*L) or winch compliance (~F): confounded..."
  EffectFit first_fit, second_fit;
  std::vector<Pose> separating_poses;          // extra poses that would tell them apart
  std::vector<double> separating_pretensions;  // N, planned pretension at each of those poses
  double correlation_with_extra = 0.0;         // canonical correlation with the extra poses added
};

// A suspect (an effect visible in the screen but not proven) and the poses that would decide it.
struct FollowUp {
  std::string suspect;                     // candidate id
  std::string name;                        // plain language
  int parameters = 0;                      // of the candidate
  double p_value = 1.0, p_adjusted = 1.0;  // screen, before / after Holm's correction
  std::vector<Pose> poses;                 // extra poses to measure, in this order
  std::vector<double> pretensions;         // N, planned pretension at each of them
  // log det of the projected information on the suspect's parameters, without / with the poses.
  double information_before = 0.0, information_after = 0.0;
};

struct Diagnosis {
  enum class Verdict { kNoMismatch, kMismatchNamed, kMismatchUnexplained, kInconclusive };
  Verdict verdict = Verdict::kNoMismatch;
  std::string headline;               // one sentence: the verdict in words
  std::vector<std::string> findings;  // plain-language sentences, most important first
  IdentificationReport before;        // the standard identification
  MismatchSummary screen;             // locate_mismatch on `before`
  std::vector<EffectFit> candidates;  // refitted candidates, best first
  std::vector<EffectFit> accepted;    // the named effects (subset of candidates)
  std::vector<ConfoundedFinding> confounded;
  std::optional<FollowUp> follow_up;  // with no effect named: a suspect and poses to decide it
  std::optional<IdentificationReport> after;  // identification with the accepted effects
  CalibratedModel model_after;                // the calibrated model carrying the accepted effects
  std::vector<ChannelRms> channels;           // residual RMS before/after per channel
  // Held-out length residual RMS (m): the validation recording when given, else K-fold CV.
  std::string held_out_source;  // "validation recording" or "5-fold cross-validation"
  double held_out_rms_before = 0.0, held_out_rms_after = 0.0;

  bool mismatch_found() const {
    return verdict == Verdict::kMismatchNamed || verdict == Verdict::kMismatchUnexplained;
  }
  // Rendered for people (text, JSON, HTML) by drivers/report (cdpr/report/report.hpp).
};

const char* to_string(Diagnosis::Verdict v);

// Diagnoses `set` against `nominal`. `validation` (optional) is a second recording of the same
// robot used only for held-out prediction. Errors: kInvalidArgument (the set does not match the
// model: cable count, laser count; bad options), and those of identify().
Result<Diagnosis> diagnose(const CalibratedModel& nominal, const MeasurementSet& set,
                           const MeasurementSet* validation,
                           const IdentificationOptions& identification = {},
                           const DiagnosisOptions& options = {});

}  // namespace cdpr
