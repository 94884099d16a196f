// The mismatch locator, first increment: where do the model and the recording disagree, and which
// missing physics would explain it? Pure statistics on an identification result (no I/O).
//
// Everything works on the whitened residual vector r of the identification (each residual divided
// by its sigma, IdentificationReport::residuals) and the whitened Jacobian J of ALL estimated
// quantities (geometry and free poses) at the estimate, recomputed with geometry_information(...,
// keep_jacobians = true). H = J (J^T J)^+ J^T is the hat matrix; under a correct model and correct
// sigmas r = (I - H) e with e ~ N(0, I), so E[r_k^2] = 1 - H_kk.
//
// 1. LOCATE
//    - Misfit per channel (cable lengths, each laser, equilibrium, reference pose), per cable and
//      per pose: RMS (SI and in sigmas), chi^2 = sum r^2 against its expected value
//      sum (1 - H_kk) (the effective degrees of freedom), p-value of a chi^2 test with that dof.
//    - Structure tests: the normalised length residuals of each cable (and of all cables pooled)
//      regressed on one explanatory variable at a time (tension x loaded length, tension,
//      kinematic length, time, platform tilt, cable direction in the pulley frame) with an
//      intercept; F-test of the slope(s), explained fraction R^2.
// 2. NAME (screen)
//    A library of candidate effects, each a set of columns X in residual space (whitened). The
//    added-variable (score) test with the identification Jacobian projected out: X_p = (I - H) X,
//    T = |P_{X_p} r|^2 (the chi^2 decrease if the effect were added and refitted, to first order).
//    Reported: T with its chi^2(k) p-value (stated sigmas), the F-test p-value with the sigma
//    estimated from the remaining misfit (used for significance; robust to a misstated sigma),
//    a Holm-adjusted p-value over the library, the explained fraction T / |r|^2 and a BIC change
//    n ln((RSS - T) / RSS) + k ln n (ranking: lowest first). A candidate whose columns lie in the
//    span of J is "already modelled" (k = 0). Two candidates of different selection groups whose
//    projected column spaces have a canonical correlation above a threshold are confounded: the
//    pose set cannot tell them apart.
//    The library (mismatch_design.cc): Hooke elasticity ~F L (shared, per cable); winch/sensor
//    compliance ~F (shared, per winch); nonlinear elasticity (a F + k2 F^2) L; creep
//    ~F L ln(1 + t / 10 s); encoder offsets and drifts ~t; transmission drift ~t L; sag (arc
//    length ~Lh^2 L / F^2 and the cable weight the platform carries, on the equilibrium rows);
//    from the identification's Jacobian: drum scale (per cable, shared), platform anchors,
//    force-sensor gain and offset, laser mounting, laser target plane; direction-dependent
//    (MismatchOptions::direction_candidates): cable hysteresis ~d (length rows) and pulley
//    friction ~d (the tension reading: equilibrium rows and, through the elongation, length
//    rows), d = +-1 the direction of the cable's last move (last_move_directions).
// 3. DESCRIBE what no candidate explains (MismatchOptions::describe_structure): for each channel
//    (cable lengths; cable tensions, seen through the equilibrium and elongation rows), cable and
//    measured variable v (direction of the last move, tension, cable length, time, platform
//    orientation, temperature), the column "an error of this cable's reading proportional to v"
//    (with a constant per cable as nuisance, J projected out) is tested by an F-test (Bonferroni
//    over all tests). A significant one is reported (MismatchSummary::unexplained) unless a
//    library candidate explains it: with the candidate's columns added, the test no longer
//    significant against the residual the candidate leaves (a candidate with a canonical
//    correlation above structure_coverage) or against the noise left once the candidate and every
//    selected structure are fitted (any candidate).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Upper tail P(X > x) of a chi^2 distribution with `dof` (> 0, real) degrees of freedom.
double chi2_upper_tail(double x, double dof);
// Upper tail P(X > x) of an F distribution with (d1, d2) degrees of freedom (> 0, real).
double f_upper_tail(double x, double d1, double d2);

// Candidate families that refine each other (a richer member nests the simpler one) share a
// selection group: "nonlinear elasticity" refines "elasticity". Within a group the candidates are
// compared by nested tests (the richer one only when significantly better), never reported as
// confounded, and at most one of the group is accepted.
std::string selection_group(const std::string& family);

struct MismatchOptions {
  double alpha = 0.01;              // significance level (family-wise for the candidates)
  double confound_threshold = 0.8;  // canonical correlation above which a pair is confounded
  double rank_tolerance = 1e-9;     // relative, for the rank of J and of projected candidates
  // Screen force-sensor gain and offset and the platform mass and centre of mass (equilibrium
  // rows). On since the equilibrium rows are whitened conditionally on the length rows
  // (identification.hpp): before, the gain candidate's statistic on null data averaged 17.9
  // instead of its 8 degrees of freedom.
  bool force_sensor_candidates = true;
  // Screen the direction-dependent candidates: cable hysteresis (a length error that depends on
  // whether the cable was last paid out or reeled in) and pulley friction (a tension-reading error
  // with the same dependence), both per cable, with the direction of each cable's last move from
  // last_move_directions(). Off: these effects are outside the library, and the structure scan
  // (MismatchSummary::unexplained) is what still describes them.
  bool direction_candidates = true;
  // Scan the residual for structure that no candidate explains (MismatchSummary::unexplained).
  bool describe_structure = true;
  // A structure whose projected column has a canonical correlation above this with a library
  // candidate's projected columns may be that candidate's: it is unexplained only if it stays
  // significant with the candidate's columns added (a partial F-test against the residual the
  // candidate leaves). Any candidate explains it also when the test, against the noise left once
  // the candidate and every selected structure are fitted, is no longer significant.
  double structure_coverage = 0.8;
  // Not empty: only the candidates of these selection groups (selection_group()) are screened, a
  // confirmatory screen. The re-run after follow-up poses for a suspect beside named effects uses
  // it (DiagnosisOptions::follow_up_confirms): the poses were measured to decide the suspect, so
  // the re-run decides it beside the named effects and names nothing new besides.
  std::vector<std::string> only_groups;
};

// The direction of each cable's last move at each pose (poses x cables): +1 when the cable was
// last paid out (its length reading grew), -1 when last reeled in, 0 before its first move. A
// move is a change of the length reading between consecutive poses (the recording's order: the
// robot moved from each pose straight to the next) larger than `deadband_sigmas` x
// set.noise.sigma_length; smaller changes keep the previous direction.
Eigen::MatrixXd last_move_directions(const MeasurementSet& set, double deadband_sigmas = 5.0);

// Structure in the residual that no candidate of the library explains, in words a robot engineer
// can act on: which channel, which cables, which poses, and which measured variable it follows.
struct UnexplainedStructure {
  std::string channel;      // "cable lengths" or "cable tensions"
  std::string variable;     // "direction of the last move", "tension", "cable length", "time",
                            // "platform orientation" or "temperature"
  std::vector<int> cables;  // 0-based
  // Per listed cable: the residual's change per unit of the variable (the channel's unit, m or N,
  // per the variable's unit; for the direction: the error when last paid out, minus when reeled
  // in, halved), and the Bonferroni-adjusted p-value of its test.
  std::vector<double> slopes, p_values;
  std::string unit;        // of the slopes: "m", "m/N", "N/s", ...
  std::vector<int> poses;  // 0-based: the poses that carry most of it (at most 10)
  // The library candidate whose columns come closest (canonical correlation below
  // MismatchOptions::structure_coverage), and that correlation.
  std::string closest_candidate;
  double closest_correlation = 0.0;
  std::string description;  // one sentence
  // Rows x listed cables: each test's column in the screen's residual space (whitened, the
  // identification and the per-cable constant projected out), for partial tests against it.
  Eigen::MatrixXd columns;
  // The same cables' constants on the channel (the tests' nuisance), projected the same way.
  Eigen::MatrixXd constants;
};

// Misfit of one group of residuals (a channel, a cable or a pose).
struct MisfitGroup {
  std::string name;             // "cable lengths", "cable 3", "pose 12", "laser 1", ...
  int count = 0;                // residuals in the group
  double rms_si = 0.0;          // RMS in SI units (NaN where the group mixes units)
  std::string unit;             // "m", "N", "" (mixed)
  double rms_normalized = 0.0;  // RMS in sigmas
  double chi2 = 0.0;            // sum of squared normalised residuals
  double expected_chi2 = 0.0;   // effective dof: sum over the group of (1 - H_kk)
  double ratio = 0.0;           // sqrt(chi2 / expected_chi2): 1 when the noise explains it
  double p_value = 1.0;         // chi^2 upper tail with expected_chi2 degrees of freedom
  bool flagged = false;         // p_value < alpha
};

// One regression of normalised length residuals on an explanatory variable.
struct StructureTest {
  std::string variable;  // "tension x length", "tension", "cable length", "time", ...
  int cable = -1;        // 0-based cable, -1 = all cables pooled
  int samples = 0;
  int slopes = 0;  // regressors besides the intercept
  double f_statistic = 0.0;
  double p_value = 1.0;
  double explained_fraction = 0.0;  // R^2 of the slopes (about the mean)
  bool significant = false;         // p_value < alpha / number of tests (Bonferroni)
};

// One screened candidate effect.
struct CandidateScreen {
  std::string id;            // "hooke_shared", "compliance_per_cable", ...
  std::string name;          // plain language: "cable elasticity (Hooke, ~F*L), one EA for all"
  std::string family;        // candidates of one family are refinements of each other
  int columns = 0;           // regressor columns
  int rank = 0;              // of the projected columns (0 = already modelled / no data)
  bool modelled = false;     // columns lie in the span of the identification Jacobian
  double statistic = 0.0;    // T, chi^2 decrease (stated sigmas)
  double p_score = 1.0;      // chi^2(rank) upper tail of T
  double f_statistic = 0.0;  // (T / k) / ((RSS - T) / (dof - k))
  double p_value = 1.0;      // F upper tail
  double p_adjusted = 1.0;   // Holm over the screened library
  // The same test with the unexplained structures' columns (MismatchSummary::unexplained) also
  // projected out, Holm over the library: a candidate significant only through a structure it
  // does not explain is a proxy for it (diagnose() does not name it). The structures enter with
  // their per-cable constants. Equal to p_adjusted when nothing is unexplained.
  double p_beyond_structure = 1.0;
  double explained_fraction = 0.0;  // T / RSS
  double bic_delta = 0.0;           // n ln((RSS - T) / RSS) + k ln n; negative = worth adding
  bool significant = false;         // p_adjusted < alpha
  Eigen::VectorXd coefficients;     // least-squares coefficients of the (unprojected) columns
};

struct ConfoundedPair {
  std::string first, second;  // candidate ids
  double correlation = 0.0;   // largest canonical correlation of the projected columns
  std::string description;    // one sentence in words
  // Canonical correlations above the threshold (directions the two share), and each one's rank
  // (projected columns): first_rank - directions of the first's directions are its own.
  int directions = 0;
  int first_rank = 0, second_rank = 0;
};

struct MismatchSummary {
  double chi2 = 0.0;  // sum of squared normalised residuals
  int num_residuals = 0;
  int jacobian_rank = 0;  // rank of J (estimated quantities that the data fix)
  int dof = 0;            // num_residuals - jacobian_rank
  double p_value = 1.0;   // overall chi^2 test
  std::vector<MisfitGroup> channels;
  std::vector<MisfitGroup> cables;  // length residuals per cable
  std::vector<MisfitGroup> poses;   // all residuals per pose
  std::vector<StructureTest> structure;
  std::vector<CandidateScreen> candidates;  // ranked: lowest bic_delta first, modelled last
  std::vector<ConfoundedPair> confounded;
  // Significant structure (Bonferroni over every channel x cable x variable test, at alpha) that
  // no library candidate covers; grouped by channel and variable, strongest first.
  std::vector<UnexplainedStructure> unexplained;
  std::vector<std::string> findings;  // plain-language sentences, most important first

  // The top-ranked candidate if it is significant, else nullptr.
  const CandidateScreen* best() const;
  const CandidateScreen* find(const std::string& id) const;
  std::string text() const;  // the findings and the tables as text
};

// The residual-space view of the screen, exposed for the bootstrap, cross-validation and pose
// design of diagnosis.hpp. Rows follow the identification's order (per pose: lengths, lasers,
// equilibrium, reference pose); everything is whitened (divided by the row's sigma).
enum class ResidualKind { kLength, kLaser, kWrench, kReference, kSwivel, kInclination, kImuYaw };

// One candidate effect of the library as regressor columns in residual space.
struct CandidateColumns {
  std::string id, name, family;
  Eigen::MatrixXd X;  // rows x k, whitened
  // The same columns in SI units (m on length and laser rows; N and N m of the platform's net
  // wrench, world axes, on the six equilibrium rows of a pose) for a candidate that acts on the
  // equilibrium rows (so that a fitted effect can be moved into the data); else empty.
  Eigen::MatrixXd si;
  // For a candidate whose columns follow each cable's own tension reading (elasticity, compliance,
  // creep, nonlinear elasticity): the derivative of X by that reading on the length rows (whitened,
  // per N; 0 elsewhere), so that a fitted effect moved into the lengths also carries how the force
  // noise reaches them (PoseMeasurement::extra_compliance). Empty for the others.
  Eigen::MatrixXd dtension;
  // For a candidate that is an error of the tension readings themselves (pulley friction): the
  // error of cable i's reading at pose j per unit coefficient, row j * cables + i (N). A fitted
  // effect is then moved out of the readings exactly (each reading corrected), not through its
  // linearised effect on the length and equilibrium rows: a cable slack in truth whose reading
  // the error lifts above the slack threshold has a length row that no linear correction mends,
  // while its corrected reading drops the row (LARGE's friction of 30 N, noise-free: chi^2 516
  // left over the linearised way, 0 this way). Empty for the others.
  Eigen::MatrixXd tension_readings;
};

struct MismatchDesign {
  std::vector<ResidualKind> kind;  // per row
  std::vector<int> pose, index;    // per row: pose, and cable / laser / component
  std::vector<int> pose_start;     // num_poses + 1: first row of each pose
  Eigen::VectorXd residuals;       // whitened residuals (zero when built without residuals)
  Eigen::VectorXd sigma_length;    // m, sigma of each length row (NaN elsewhere)
  std::vector<std::string> geometry_names;
  std::vector<Eigen::MatrixXd> jacobian_geometry;  // per pose: rows x P (estimated parameters)
  std::vector<Eigen::MatrixXd> jacobian_pose;      // per pose: rows x 6 (zero for a fixed pose)
  std::vector<CandidateColumns> candidates;        // the library (unprojected)

  int num_rows() const { return static_cast<int>(kind.size()); }
  int num_poses() const { return static_cast<int>(pose_start.size()) - 1; }
};

// The design at `model` and `poses` (e.g. an identification's estimate and poses). `residuals`
// (optional, e.g. IdentificationReport::residuals) fill MismatchDesign::residuals and the length
// sigmas; without them the residuals are zero and the length sigma is set.noise.sigma_length
// (enough for pose design, where only the columns matter).
Result<MismatchDesign> mismatch_design(const CalibratedModel& model, const MeasurementSet& set,
                                       const std::vector<Pose>& poses,
                                       const std::vector<PoseResiduals>* residuals,
                                       const IdentificationOptions& options,
                                       const MismatchOptions& mismatch = {});

// The exact effect of cable sag on the rows of `d` (Irvine's elastic catenary, catenary.hpp):
// every cable weighs `mass_per_length` (kg/m), its tension reading is taken at the frame end (the
// pulley exit), where the force sensors measure it, and the model of `d` has straight cables.
// Column 0 of X is the effect on the whitened residuals (model - reading): on a length row
// (L0_straight - L0_catenary) / sigma, the unstretched free span a straight cable needs at the
// reading minus the one the sagging cable needs (< 0: the encoder pays out the arc); on the six
// equilibrium rows of a pose the straight cables' wrench minus the sagging cables' (the platform
// carries part of each cable's weight, and the force leaves the platform along the catenary's
// tangent), whitened as the screen whitens the equilibrium rows. `si` holds the same in SI units.
// A cable without a catenary solution (very slack) or below the slack threshold contributes 0.
// mass_per_length = 0 gives zero columns. `compliance` (optional, per row, m/N): on the length
// rows the derivative of the length effect by the tension reading, i.e. how the force noise
// reaches a residual corrected for the sag (PoseMeasurement::extra_compliance); 0 elsewhere.
// Errors: kInvalidArgument (sizes).
Result<CandidateColumns> sag_effect(const CalibratedModel& model, const MeasurementSet& set,
                                    const std::vector<Pose>& poses, const MismatchDesign& d,
                                    const IdentificationOptions& options, double mass_per_length,
                                    Eigen::VectorXd* compliance = nullptr);

// Screens `report` (from identify(initial, set, options)) against `set`. Errors: kInvalidArgument
// (sizes do not match), kFailedPrecondition (no residuals / dof <= 0), kInternal (the residual
// layout does not match the Jacobian), and whatever geometry_information returns.
Result<MismatchSummary> locate_mismatch(const IdentificationReport& report,
                                        const MeasurementSet& set,
                                        const IdentificationOptions& options,
                                        const MismatchOptions& mismatch = {});

}  // namespace cdpr
