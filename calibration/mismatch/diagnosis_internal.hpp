// Shared by the stages of the mismatch locator (diagnose(), diagnosis.hpp; not installed): the
// model states and what the stages hand each other, one section per source file.
#pragma once

#include <Eigen/Dense>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/mismatch.hpp"

namespace cdpr::diagnosis_detail {

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

// Linearised K-fold cross-validation over poses: the geometry (and the effect columns `extra`)
// from a Gauss-Newton step on K-1 folds, the held-out poses re-located (their own pose columns
// projected out). `normalized`: RMS of all held-out residuals in sigmas (every channel: an
// effect of the laser or of the force sensors may leave the lengths alone); `length_m`: RMS of
// the held-out length residuals in m (what people read).
struct CvRms {
  double normalized = 0.0;
  double length_m = 0.0;
};

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

// Fold assignment of the cross-validation (deterministic, balanced).
struct Folds {
  int K = 0;              // folds
  std::vector<int> fold;  // per pose; -1: always in the training folds
};

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

class RefitMemo;

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
  // The refits from the standard model by a sequence of effects, each done once (RefitMemo).
  RefitMemo* memo = nullptr;

  double log_size(const std::string& id) const {
    const auto it = log_sizes.find(id);
    return it == log_sizes.end() ? logn : it->second;
  }
};

struct Trial {
  EffectFit fit;
  State state;
};

// The refits from the standard model by a sequence of effect ids, each done once per diagnosis:
// refit() depends only on the state it starts from and the effect, and the stages refit the same
// sequences again (the trials are the first steps of every forward path and of the swaps' joint
// refits; the swaps, the refinements, the backward check and the naming refit sets whose
// prefixes the forward paths or the swaps fitted before). The results are those of the refits
// done anew.
class RefitMemo {
 public:
  explicit RefitMemo(const State& standard) : standard_(standard) {}
  // The last effect of `ids` refitted on path(ids without it) (the standard model for one
  // effect), with its fit. nullptr: it cannot be fitted there (or the path cannot be).
  const Trial* step(const RefitContext& ctx, const std::vector<std::string>& ids);
  // The state after the effects of `ids` in turn: step(ids)'s, its Gauss-Newton effects polished
  // after the second and every later effect (DiagnosisOptions::polish_gauss_newton), as a forward
  // path and a joint refit have it. nullptr: cannot be fitted.
  const State* path(const RefitContext& ctx, const std::vector<std::string>& ids);

 private:
  const State& standard_;
  std::map<std::vector<std::string>, std::optional<Trial>> steps_;
  std::map<std::vector<std::string>, State> polished_;
};

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

// ---- diagnosis_selection.cc

// Symmetric pseudo-inverse with the eigenvalue threshold relative to the largest one (after a
// diagonal scaling, so that columns of very different units are treated alike).
Eigen::MatrixXd pinv_sym(const Eigen::MatrixXd& A, double tol = 1e-12);

const CandidateColumns* find_columns(const MismatchDesign& d, const std::string& id);

PoseGrams pose_grams(const MismatchDesign& d, const std::vector<const Eigen::MatrixXd*>& blocks,
                     bool with_geometry, bool keep_rows);

// Gram of the non-geometry columns (blocks and residual) with the geometry projected out.
Eigen::MatrixXd reduce_geometry(const Eigen::MatrixXd& M, int geometry);

// Greedy choice of extra poses: `M` is the information of the recorded poses (np of them in
// `g`), and the candidates are the poses after them. Each step adds the allowed candidate whose
// Gram raises `score` the most, and only while the score rises above `floor` (updated to the
// score reached). Returns the chosen candidates (0-based), in order; `M` includes them.
std::vector<int> greedy_extra_poses(const PoseGrams& g, int np, int count,
                                    const std::function<bool(int)>& allowed,
                                    const std::function<double(const Eigen::MatrixXd&)>& score,
                                    double floor, Eigen::MatrixXd& M);

// Rank of a candidate's projected columns relative to their unprojected norms.
int projected_rank(const Eigen::MatrixXd& S, const Eigen::VectorXd& raw_norm2, double tol);

// Largest canonical correlation of two column blocks from their (projected) Gram blocks.
double canonical_correlation(const Eigen::MatrixXd& Saa, const Eigen::MatrixXd& Sbb,
                             const Eigen::MatrixXd& Sab);

CvRms cv_rms(const MismatchDesign& d, const Eigen::MatrixXd* extra, const std::vector<int>& fold,
             int folds);

// Moves a fitted effect into the data: sigma * (X theta) added to the length and laser readings
// (both residuals are (model - reading) / sigma), and the effect on the equilibrium rows, in SI
// (CandidateColumns::si), taken off the pose's external wrench. With `force_noise`, an effect that
// follows the tension readings (CandidateColumns::dtension) adds its derivative by them to the
// lengths' extra compliance, so that the length sigmas carry the force noise the corrected
// readings now hold (DiagnosisOptions::gauss_newton_force_noise). False when the effect acts on
// rows that cannot take it (equilibrium rows without SI columns, reference-pose rows).
bool corrected_set(const MeasurementSet& set, const MismatchDesign& d, const CandidateColumns& c,
                   const Eigen::VectorXd& theta, bool force_noise, MeasurementSet& out);

// An identification parameter as an effect parameter in engineer words.
EffectParameter describe_parameter(const ParameterEstimate& p, const CalibratedModel& initial);

// The log of each candidate's BIC sample size (DiagnosisOptions::bic_informing_rows): the number
// of readings its columns act on, or every reading.
std::map<std::string, double> bic_log_sizes(const MismatchDesign& D, bool informing_rows);

Selection select_candidates(const MismatchDesign& D0, const MismatchSummary& screen, int np,
                            const DiagnosisOptions& options);

Folds assign_folds(const MismatchDesign& D0, int np, const DiagnosisOptions& options);

// ---- diagnosis_refit.cc

// The design of a state: its readings (made with the force sensors of `nominal`) with the tensions
// as its fit reads them (the columns of the effects that follow the tension, creep, compliance,
// nonlinear elasticity, then use the corrected tension once a force sensor gain or offset is
// estimated).
Result<MismatchDesign> state_design(const CalibratedModel& nominal, const IdentificationReport& rep,
                                    const MeasurementSet& set, const IdentificationOptions& opt,
                                    const MismatchOptions& mopt);

// identify() of a refit, started from an earlier state's estimate `from`. The recording's tension
// readings were made with the nominal force sensor calibration, and identify() reads a tension as
// made with its initial model's calibration (true_tension in identification_costs.hpp): the initial
// model keeps the nominal's force sensors, so that an estimated gain or offset is relative to the
// readings and is not applied twice (started from an estimate with a 2 % gain, the next refit's
// model carried 4 %).
Result<IdentificationReport> identify_from(const CalibratedModel& nominal,
                                           const CalibratedModel& from, const MeasurementSet& set,
                                           const IdentificationOptions& opt);

// -2 log likelihood of a state up to the constant shared by all states of this recording.
double deviance(const RefitContext& ctx, const State& st);

// BIC of a state with effects whose extra parameters cost `penalty` together (up to the shared
// constant).
double joint_bic(const RefitContext& ctx, const State& st, double penalty);

// The BIC penalty of the effects' extra parameters: k ln n of each.
double bic_penalty(const RefitContext& ctx, const std::vector<EffectFit>& effects);

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
void polish_gauss_newton(const RefitContext& ctx, State& st);

// The accepted Gauss-Newton effects' parameters as `st` has them (after polish_gauss_newton the
// coefficients differ from those of the trial that accepted them; the standard deviations stay
// the trial's).
void refresh_gauss_newton_parameters(const State& st, std::vector<EffectFit>& fits);

// The accepted effects estimated by identify() (elasticity, drum scales, force sensor gains, ...)
// as the model of `st` has them: the values and deviations of its identification, refitted beside
// every effect accepted after them (the model written, d.model_after, is this one; the trial that
// accepted an effect had the value before the later ones were in).
void refresh_identified_parameters(const State& st, std::vector<EffectFit>& fits);

// Stage 2, refit: the model of `cur` with candidate `id` added, fitted in full by the refit hook
// of the candidate's descriptor (effect_library.hpp); `fit` says how much better it is. nullopt:
// the candidate cannot be fitted on this state.
std::optional<State> refit(const RefitContext& ctx, const State& cur, const std::string& id,
                           EffectFit& fit);

// ---- diagnosis_acceptance.cc

const EffectFit* trial_fit(const std::vector<Trial>& trials, const std::string& id);

// A candidate the screen sees only through a structure it does not explain: significant, but no
// longer once the unexplained structures (MismatchSummary::unexplained) are projected out. It
// would take part of physics outside the library under a wrong name (a force sensor gain for
// pulley friction on LARGE), so it is not named.
bool proxy_for_structure(const MismatchSummary& screen, const std::string& id, double gate);

Acceptance accept_effects(const RefitContext& ctx, const State& standard,
                          const MismatchSummary& screen);

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
                             Acceptance& acc);

// ---- Stage 3c, the backward check: once the second round accepted an effect, an earlier one may
// only have stood in for it (winch compliance per winch for per-cable force gains). Each accepted
// effect is tested for removal: the others refitted jointly from the standard model, the
// likelihood ratio of the full set against that (Holm over the accepted effects). The effect with
// the weakest evidence is dropped while its corrected p-value is not below alpha. Returns whether
// an effect was dropped.
bool backward_check(const RefitContext& ctx, Acceptance& acc);

// ---- Stage 4, naming: the screen's confounded pairs that this recording cannot tell apart (both
// fitted from the standard model; the fits not yet tried are added to the trials and candidates).
std::vector<ConfoundedPair> confounded_pairs(const RefitContext& ctx, const MismatchSummary& screen,
                                             Acceptance& acc);

// ---- diagnosis_extra_poses.cc

ExtraPoseGrid extra_pose_grid(const RobotModel& robot, const IdentificationReport& before,
                              const MeasurementSet& set,
                              const IdentificationOptions& identification,
                              const DiagnosisOptions& options);

// The separating poses of each confounded pair: greedy over the grid, lowest canonical
// correlation of the pair.
std::vector<ConfoundedFinding> separate(const std::vector<ConfoundedPair>& found,
                                        const std::vector<Trial>& trials, const ExtraPoseGrid& grid,
                                        int np, const DiagnosisOptions& options);

// The follow_up_poses poses that add the most information on `suspect`'s parameters (log det of
// its projected information, the identification profiled out; greedy over the grid at the planned
// pretension); nullopt when the grid has none for it.
std::optional<FollowUp> follow_up_for(const CandidateScreen& suspect, const RobotModel& estimate,
                                      const ExtraPoseGrid& grid, int np,
                                      const DiagnosisOptions& options);

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
                                  const std::vector<std::string>& not_suspects = {});

// ---- diagnosis_verdict.cc

void state_gross_readings(Diagnosis& d);

// ---- Stage 6, the model with the accepted effects: `after`, model_after (the Gauss-Newton effects
// written where the config can hold them), the held-out RMS (cross-validation or the validation
// recording) and the per-channel RMS.
Status model_the_effects(Diagnosis& d, const State& current, const CvRms& cv_before, int K,
                         bool leave_one_out, const MeasurementSet* validation,
                         const CalibratedModel& nominal,
                         const IdentificationOptions& identification, int nl);

// ---- Stage 7, verdict and findings.
void state_verdict(Diagnosis& d, double alpha);

// ---- gross_readings.cc

// Whether the fit with the accepted effects brings every flagged reading within gross_sigmas:
// physics concentrated in a few readings (DiagnosisOptions::gross_effects_sigmas) is then
// modelled, while a wild reading stays out whatever effect is beside it.
bool explained_by_effects(const std::vector<GrossReading>& gross, const IdentificationReport& fit,
                          const DiagnosisOptions& options);

}  // namespace cdpr::diagnosis_detail
