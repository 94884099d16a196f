// The mismatch locator, complete: from a nominal model and a recording to a verdict on the missing
// physics, the model with it, and the proof that the fit improves (also on held-out data).
// Pure statistics on top of identification.hpp and mismatch.hpp (no I/O, no logging). The
// candidate effects are the entries of effect_library.hpp; how diagnose() decides (selection,
// refit, acceptance, naming, extra-pose design, the model with the effects, the verdict) is
// described in docs/mismatch-locator.md; diagnosis.cc runs the same named stages, each in a
// source of its own (diagnosis_*.cc, gross_readings.cc).
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
  // Cross-validation over poses: 0 (default) leaves one pose out (every pose that can be held out
  // is a fold of its own; the home pose, fixed by the gauge, never is); K >= 2: K folds (K <= N).
  // Few folds hold out together the few poses that carry an effect (the laser's beam direction)
  // and reject it for the extrapolation (docs/mismatch-benchmark.md).
  int cv_folds = 0;
  unsigned seed = 1;    // bootstrap and fold assignment (deterministic)
  int max_effects = 3;  // at most this many effects are accepted together
  int min_poses = 12;   // below this the verdict is kInconclusive
  // Two candidates that the screen finds confounded (canonical correlation above
  // screen.confound_threshold) are reported as "A or B" only when their full fits differ by less
  // than this in BIC; a larger difference is very strong evidence for the better one.
  double decisive_bic = 10.0;
  // The sample size of an effect's BIC penalty (k ln n): false, every reading of the recording;
  // true, the readings its columns act on (the laser's beam direction: the laser readings only).
  // Schwarz's penalty is the log of the information one parameter gains from the data, which grows
  // with the readings that carry it, not with readings of other channels.
  bool bic_informing_rows = false;
  // Once a further effect is accepted beside Gauss-Newton effects (creep, drifts, force gains:
  // moved into the readings), their coefficients are refitted beside it, and the sag's catenary is
  // recomputed at the new estimate (polish_gauss_newton, refresh_catenary); false keeps the
  // coefficients and the catenary each was accepted with.
  bool polish_gauss_newton = true;
  // A Gauss-Newton effect that follows the tension readings (nonlinear elasticity, compliance,
  // creep) moved into the lengths makes them depend on the readings: true adds its derivative by
  // the tension to the lengths' extra compliance (PoseMeasurement::extra_compliance), so that
  // their sigma carries the force noise as the identification's own elasticity does. False leaves
  // the sigma at the model's compliance: the log det of the deviance then favours such an effect
  // over the identified EA it competes with.
  bool gauss_newton_force_noise = false;
  // A refinement named in place of the simpler family of its selection group (nonlinear
  // elasticity for Hooke's) must pass the gate of naming an effect on what it adds: the
  // likelihood ratio of its extra parameters against the accepted set with the simpler member in
  // its place, Bonferroni over the library, below this; else the simpler member is named.
  // 0: off (the forward paths' joint BIC alone decides).
  double refinement_gate_p = 0.05;
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
  // Beside named effects, the second screening round's candidate with the lowest p-value is a
  // suspect when its corrected p-value is below suspect_p (the misfit clause above does not
  // apply there); its follow-up poses are proposed like those of a suspect with nothing named.
  bool follow_up_beside_named = false;
  // Beside named effects, a candidate confounded on the first screen (MismatchSummary::confounded)
  // with a named effect is not a suspect: what the second screen sees in its directions is
  // mostly the named effect's own residue, and 20 poses aimed at it lifted absent effects over the
  // gates. A suspect of another channel or family (the laser's beam direction beside
  // the cables' effects) still gets its follow-up poses.
  bool follow_up_skips_confounded_with_named = true;
  // The first accepted effect must also be seen by the linear screen: its screen p-value
  // (after Holm's correction over the library) below this. On noise, a nonlinear refit can reach a
  // far minimum whose likelihood ratio overstates its significance (chi^2 with the nominal degrees
  // of freedom assumes the linear regime).
  double screen_gate_p = 0.05;
  // Two candidates confounded on this pose set (a canonical correlation above
  // screen.confound_threshold) are not accepted together, unless the newcomer keeps at least this
  // many directions of its own: its rank minus the canonical correlations above the threshold
  // (ConfoundedPair::directions). Per-cable force gains (8) beside cable creep or one shared mass
  // per length keep 7 and are tried; creep beside the gains keeps none. The first round's forward
  // steps use forward_own_directions (its swaps, joint refits of the whole set, keep confounded
  // candidates exclusive); the second screening round uses second_round_own_directions (beside an
  // effect estimated by the identification it tries every candidate, its screen being conditional
  // on that effect). 0: never on that ground.
  int forward_own_directions = 4;
  int second_round_own_directions = 4;
  // The evidence a second-round effect must carry beside the tests of a forward step: its BIC
  // (2 ln of the Bayes factor, deviance units) at least this far below the accepted set's. The
  // first round's effects also pass Holm over the trials and the bootstrap; the second round's
  // only the screen and the step's tests, so at the design that sees the laser's beam direction a
  // noise realisation that looks like a tilt can pass them beside every effect. A threshold that
  // stops such a noise tilt also stops true small tilts beside other effects, so the default is
  // 0: the step's BIC < 0 alone, and weak steps are held back as suspects instead
  // (weak_step_bic). docs/mismatch-benchmark.md measures the trade ("Choices the figures
  // support").
  double second_round_min_evidence = 0.0;
  // Robot time instead of a threshold: a step that adds an effect beside accepted ones (the first
  // round's forward steps after the first effect, the second screening round) whose BIC is less
  // than this below the set without it (weak evidence, yet past every test) is not taken; the
  // effect is held back as a suspect (FollowUp::held_back) with follow_up_poses poses aimed at its
  // parameters, and the confirmatory re-run on the longer recording (follow_up_groups,
  // confirm_suspect) decides it. Applies only when follow_up_poses > 0 and the run is not itself
  // confirmatory (screen.only_groups empty). 6 is "strong" evidence on Kass and Raftery's scale
  // (the trade against the threshold of second_round_min_evidence is measured in
  // docs/mismatch-benchmark.md, "Choices the figures support"). 0: off (taken on BIC < 0
  // alone).
  double weak_step_bic = 6.0;
  // The re-run after a held-back suspect's follow-up poses: its candidate id (FollowUp::suspect of
  // a FollowUp with held_back). An effect of its selection group is then named only with strong
  // evidence, its BIC more than weak_step_bic below the set without it: the poses were
  // chosen to give that evidence (information on its parameters about doubled), and an effect
  // that stays weak with them is a noise realisation that looked like one (LARGE seed 0's laser
  // beam direction: BIC -1.1 on the 25 poses, -0.5 with its 20 follow-up poses). Empty: none.
  std::string confirm_suspect;
  // After the second round accepted an effect, each earlier one is tested for removal (the others
  // refitted jointly from the standard model without it; Holm over the accepted, alpha): an effect
  // that only stood in for the one found later is dropped.
  bool backward_check = true;
  // Gross readings (stage 0): a reading that a robust refit (Cauchy loss) of the standard model
  // leaves more than max(gross_sigmas, gross_spread x the 95th percentile of the normalised
  // residuals of its channel) sigmas away is a gross error of the recording (a corrupted or
  // mistyped cell, a unit slip, a sensor glitch, a laser beam on the wrong target), not missing
  // physics: when at most max(1, 2 % of the readings) are, the verdict is inconclusive and names
  // them; more are structure, left to the effects. A least-squares fit spreads one such reading
  // over the whole geometry, and the effects would fit the smear (several effects named for one
  // wrong length reading). They are named only when taking them out lowers
  // the standard identification's chi^2 by at least gross_sigmas^2 / 4 each, and either the rest
  // without them fits within the noise (chi^2 upper-tail p-value at least gross_rest_p) or that
  // drop is at least gross_share of the whole misfit beyond the noise (chi^2 - dof). A robust fit
  // can also leave readings far out on a recording with physics in it (a pose settled far off,
  // pulley friction put into one length reading), but then taking them out leaves most of the
  // misfit where it was: they are not called gross, the effects are left to explain them. A wild
  // reading beside a real effect
  // carries nearly all of it and is named (docs/mismatch-locator.md). 0: no check.
  double gross_sigmas = 20.0;
  double gross_spread = 10.0;
  double gross_rest_p = 1e-3;
  double gross_share = 0.5;
  // Flagged readings that are all within gross_effects_sigmas of the robust fit are tried against
  // the effects: stages 1-3 run on the whole recording, and when the accepted effects bring each
  // flagged reading within gross_sigmas of their fit, the readings are physics concentrated in a
  // few readings, not gross errors (a heavy cable's sag where tilted poses leave it near f_min put
  // four LARGE length readings 26-45 sigmas out of the robust fit at 3x noise while the whole
  // misfit was 3.4 sigmas, and one 101 sigmas on another seed). No effect of the library has a
  // parameter per reading, so none brings one wild reading from hundreds of sigmas within
  // gross_sigmas; the bound saves the stages' time on a smeared fit (a 0.3 m length error on MINI,
  // about 30 000 sigmas: 279 s). A reading further out is gross at once; 0: every flagged reading
  // is.
  double gross_effects_sigmas = 1000.0;
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
  // 1: found by the first screen (the standard model's residual); 2: by the second screening
  // round, on the residual the effects accepted before it leave.
  int round = 1;
  bool modelled_in_config = false;  // the calibrated config can carry it (else: report only)
  // Of an effect with a per-cable rival (EffectDescriptor::per_cable_rival: the platform's weight
  // and the force sensor gains): the screen's p-value of the rival on what this fit leaves,
  // Bonferroni over the library. Below DiagnosisOptions::screen_gate_p the misfit differs per
  // cable, which the shared effect cannot be, and it is not accepted.
  double rival_p_value = 1.0;
  // Of an accepted effect (Diagnosis::accepted): the values of the model after (refitted beside
  // every effect accepted with it; the deviations of the Gauss-Newton coefficients stay the
  // accepting trial's); of a candidate: its trial's.
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
  // An effect held back for weak evidence (DiagnosisOptions::weak_step_bic): its fit beside
  // the named effects passed the tests with this BIC (deviance units, negative).
  bool held_back = false;
  double bic_delta = 0.0;
};

// A reading far from every model (DiagnosisOptions::gross_sigmas).
struct GrossReading {
  int pose = 0;           // 0-based, in the recording's order
  std::string channel;    // "cable length", "laser distance", "equilibrium", "swivel angle", ...
  int index = -1;         // 0-based cable or laser; -1: the pose's equilibrium or a platform sensor
  double residual = 0.0;  // robust model minus reading, SI (m, rad; N or N m for the equilibrium)
  double sigmas = 0.0;    // the same in sigmas of its channel
};

struct Diagnosis {
  enum class Verdict { kNoMismatch, kMismatchNamed, kMismatchUnexplained, kInconclusive };
  Verdict verdict = Verdict::kNoMismatch;
  std::string headline;               // one sentence: the verdict in words
  std::vector<std::string> findings;  // plain-language sentences, most important first
  IdentificationReport before;        // the standard identification
  MismatchSummary screen;             // locate_mismatch on `before`
  // locate_mismatch on the model with the accepted effects (the second screening round; its
  // `unexplained` is what that model still leaves). Empty when nothing was accepted.
  std::optional<MismatchSummary> screen_after;
  std::vector<EffectFit> candidates;  // refitted candidates, best first
  std::vector<EffectFit> accepted;    // the named effects (subset of candidates)
  std::vector<ConfoundedFinding> confounded;
  std::optional<FollowUp> follow_up;  // with no effect named: a suspect and poses to decide it
  std::optional<IdentificationReport> after;  // identification with the accepted effects
  CalibratedModel model_after;                // the calibrated model carrying the accepted effects
  std::vector<ChannelRms> channels;           // residual RMS before/after per channel
  // Readings far from every model (stage 0); when any, the verdict is inconclusive, nothing
  // further is diagnosed and model_after stays the nominal (the identification is dragged).
  std::vector<GrossReading> gross_readings;
  // Held-out length residual RMS (m): the validation recording when given, else K-fold CV.
  std::string held_out_source;  // "validation recording", "leave-one-pose-out cross-validation"
                                // or "K-fold cross-validation"
  double held_out_rms_before = 0.0, held_out_rms_after = 0.0;

  bool mismatch_found() const {
    return verdict == Verdict::kMismatchNamed || verdict == Verdict::kMismatchUnexplained;
  }
  // Rendered for people (text, JSON, HTML) by drivers/report (cdpr/report/report.hpp).
};

const char* to_string(Diagnosis::Verdict v);

// Stage 0 of diagnose() on its own (DiagnosisOptions::gross_sigmas, gross_spread, gross_rest_p):
// the readings of `set` far from every model, in the order taken out (largest first); empty when
// there are none, or more than a few (then they are structure), or a refit fails. `standard` is
// identify(nominal, set, identification), which the caller already has. `cdpr-fit calibrate`
// names them when its verdict fails.
std::vector<GrossReading> find_gross_readings(const CalibratedModel& nominal,
                                              const MeasurementSet& set,
                                              const IdentificationReport& standard,
                                              const IdentificationOptions& identification = {},
                                              const DiagnosisOptions& options = {});
// "cable length 3 of the 5th pose: off by 250.1 mm (2115 sigmas)" (poses counted from 1).
std::string describe(const GrossReading& g);
// "a reading is far from every model (<each>): a corrupted or mistyped value, a unit slip or a
// sensor glitch" (the words of diagnose's verdict and of calibrate's reason).
std::string describe(const std::vector<GrossReading>& readings);

// Diagnoses `set` against `nominal`. `validation` (optional) is a second recording of the same
// robot used only for held-out prediction. Errors: kInvalidArgument (the set does not match the
// model: cable count, laser count; bad options), and those of identify().
Result<Diagnosis> diagnose(const CalibratedModel& nominal, const MeasurementSet& set,
                           const MeasurementSet* validation,
                           const IdentificationOptions& identification = {},
                           const DiagnosisOptions& options = {});

// The selection groups (selection_group()) a confirmatory re-run after the follow-up poses of a
// suspect BESIDE named effects screens (MismatchOptions::only_groups): the named effects', the
// suspect's and both sides of each confounded pair (its separating poses are measured in the same
// round). The poses were chosen to decide that suspect; a full re-run on the longer recording
// also lifted absent effects over the gates (docs/mismatch-benchmark.md, "Choices the figures
// support"). Empty when `d` has no follow-up or names nothing (a suspect with nothing named gets a
// full re-run).
std::vector<std::string> follow_up_groups(const Diagnosis& d);

}  // namespace cdpr
