// Direction-dependent physics (issue 15, item 5): the virtual robot's cable hysteresis and pulley
// friction (sim/, scenario.hpp) against the mismatch locator (calibration/mismatch). On MINI as
// shipped (the benchmark's robot and path: lock-step physics, recording, measurement set):
// - each candidate model represents its simulated effect exactly (noise-free: residual 0);
// - with the candidates in the library, the locator names them (noise-free and realistic noise);
// - with them taken out (MismatchOptions::direction_candidates = false), it reports the
//   unexplained structure: the direction of the last move of cables 2 and 5, not "no mismatch"
//   and not a wrong name.
// Each realistic-noise case runs on one seed (a diagnosis takes a minute or more): how often the
// locator names the effects over many seeds is the benchmark's figure (bench/mismatch_bench.cc,
// docs/mismatch-benchmark.md), not this test's. The slowest compound tests screen only the
// selection groups of the simulated effects and their rivals (MismatchOptions::only_groups, so no
// weak step is held back there either): each refit of a further candidate costs seconds, and the
// behaviour each proves is among those.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

SensorNoise stated_noise() {
  SensorNoise n;
  n.sigma_length = 1e-4;
  n.sigma_laser = 1e-3;
  n.sigma_force = 1.0;
  return n;
}

struct Mini {
  CalibratedModel nominal;
  RobotModel truth;  // measured anchors, encoders homed with the nominal model
  std::vector<Pose> poses;
};

// A robot as the benchmark (bench/mismatch_bench.cc) has it: the scenario's nominal model, its
// truth with the encoders homed, 25 designed poses in a box of `half_extent`.
Mini designed_robot(const scenario::Scenario& s, const Eigen::Vector3d& half_extent,
                    int angle_steps = PoseDesignOptions{}.angle_steps,
                    double emphasis_weight = PoseDesignOptions{}.emphasis_weight) {
  Mini r;
  r.nominal = s.nominal;
  r.truth = s.truth.robot;
  for (int i = 0; i < r.truth.num_cables(); ++i) {
    r.truth.winches[static_cast<std::size_t>(i)].length_offset +=
        s.truth.readings.length_offsets(i);
  }
  PoseDesignOptions d;
  d.noise = stated_noise();
  d.num_poses = 25;
  d.half_extent = half_extent;
  d.exchange_passes = 1;
  d.angle_steps = angle_steps;
  d.emphasis_weight = emphasis_weight;
  Result<PoseDesign> design = design_poses(r.nominal, d);
  EXPECT_TRUE(design.ok()) << design.status().to_string();
  if (design.ok()) r.poses = design->poses;
  return r;
}

const Mini& mini() {
  static const Mini m =
      designed_robot(scenario::mini_config_scenario(), Eigen::Vector3d::Constant(0.156));
  return m;
}

// MINI with the design cdprd uses (half tilts, the laser's beam direction emphasised).
const Mini& mini_emphasised() {
  static const Mini m =
      designed_robot(scenario::mini_config_scenario(), Eigen::Vector3d::Constant(0.156), 2, 3.0);
  return m;
}

// The benchmark's 17 m frame (LARGE).
const Mini& large() {
  static const Mini m = designed_robot(scenario::large_scenario(), Eigen::Vector3d(4.0, 2.8, 1.0));
  return m;
}

// Cables 2 and 5 (0-based 1 and 4).
std::vector<double> on_cables_2_and_5(double v) {
  return {0.0, v, 0.0, 0.0, v, 0.0, 0.0, 0.0};
}

using Hide = std::function<void(sim::HiddenEffects&, RobotModel&)>;

// A recording of `m` (MINI unless given) at `poses` (in that order, 20 s each) with the hidden
// effects that `hide` sets (it may also change the truth).
MeasurementSet record_poses(const Hide& hide, bool noise, std::uint64_t seed,
                            const std::vector<Pose>& poses, const Mini& m = mini()) {
  sim::Scenario s;
  s.name = "direction effects";
  RobotModel base = m.truth;
  hide(s.effects, base);
  const RobotModel& nom = m.nominal.robot;
  if (noise) {
    s.noise.encoder_counts = stated_noise().sigma_length / winch_metres_per_count(nom.winches[0]);
    s.noise.force_raw = stated_noise().sigma_force * std::abs(nom.force_sensors[0].gain);
    s.noise.laser = stated_noise().sigma_laser;
  }
  Result<RobotModel> truth = sim::resolve_truth(s, base);
  EXPECT_TRUE(truth.ok()) << truth.status().to_string();
  Result<sim::Physics> physics = sim::Physics::create(*truth, s, seed);
  EXPECT_TRUE(physics.ok()) << physics.status().to_string();
  sim::LockstepOptions lo;
  lo.dwell_s = 20.0;
  auto samples = sim::run_lockstep(*physics, nom, poses, lo);
  EXPECT_TRUE(samples.ok()) << samples.status().to_string();
  auto rec = sim::make_recording(*samples, nom, s, sim::RecordingProvenance{});
  EXPECT_TRUE(rec.ok()) << rec.status().to_string();
  auto set = recording::to_measurement_set(*rec, stated_noise());
  EXPECT_TRUE(set.ok()) << set.status().to_string();
  set->noise = stated_noise();
  return *set;
}

// The same at the benchmark's 25 designed poses.
MeasurementSet record_with(const Hide& hide, bool noise, std::uint64_t seed) {
  return record_poses(hide, noise, seed, mini().poses);
}

MeasurementSet record(double hysteresis_m, double friction_n, bool noise, std::uint64_t seed,
                      const Mini& m = mini()) {
  return record_poses(
      [&](sim::HiddenEffects& e, RobotModel&) {
        if (hysteresis_m > 0) e.cable_hysteresis.values = on_cables_2_and_5(hysteresis_m);
        if (friction_n > 0) e.pulley_friction.values = on_cables_2_and_5(friction_n);
      },
      noise, seed, m.poses, m);
}

// Whether every move of cable i between the recorded poses is past the deadband of
// last_move_directions (the direction of each is then known from the readings). The noise-free
// tests below need it: a smaller move's direction is not in the readings, and the simulator
// counts it (on cdprd's design cable 2 moves 0.12 mm from home to the first pose: chi^2 1.7 and
// 5.6 left noise-free).
bool directions_known(const MeasurementSet& set, int i) {
  const double deadband = 5.0 * set.noise.sigma_length;
  for (int j = 1; j < set.num_poses(); ++j) {
    const double change = std::abs(set.poses[static_cast<std::size_t>(j)].cable_lengths(i) -
                                   set.poses[static_cast<std::size_t>(j - 1)].cable_lengths(i));
    if (change <= deadband) return false;
  }
  return true;
}

DiagnosisOptions options(bool in_library) {
  DiagnosisOptions o;
  o.screen.direction_candidates = in_library;
  return o;
}

const EffectFit* accepted(const Diagnosis& d, const std::string& family) {
  for (const auto& f : d.accepted)
    if (f.family == family) return &f;
  return nullptr;
}

double parameter(const EffectFit& f, const std::string& name) {
  for (const auto& p : f.parameters)
    if (p.name == name) return p.value;
  ADD_FAILURE() << "no parameter " << name << " in " << f.id;
  return 0.0;
}

TEST(DirectionEffects, TheDirectionOfTheLastMoveIsDerivedFromTheRecordedLengths) {
  const MeasurementSet set = record(0.0, 0.0, false, 1);
  const Eigen::MatrixXd d = last_move_directions(set);
  ASSERT_EQ(d.rows(), set.num_poses());
  EXPECT_EQ(d.row(0).cwiseAbs().sum(), 0.0);  // nothing has moved before the first pose
  for (int j = 1; j < set.num_poses(); ++j) {
    for (int i = 0; i < d.cols(); ++i) {
      const double change = set.poses[static_cast<std::size_t>(j)].cable_lengths(i) -
                            set.poses[static_cast<std::size_t>(j - 1)].cable_lengths(i);
      if (std::abs(change) > 5e-4) {
        EXPECT_EQ(d(j, i), change > 0 ? 1.0 : -1.0);
      }
    }
  }
}

TEST(DirectionEffects, NoiseFreeHysteresisIsRepresentedExactlyAndNamed) {
  const MeasurementSet set = record(5e-4, 0.0, false, 1);
  ASSERT_TRUE(directions_known(set, 1) && directions_known(set, 4));
  EXPECT_FALSE(directions_known(record(5e-4, 0.0, false, 1, mini_emphasised()), 1));
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
  ASSERT_EQ(d->accepted.size(), 1u) << d->headline;
  const EffectFit* f = accepted(*d, "cable hysteresis");
  ASSERT_NE(f, nullptr) << d->headline;
  EXPECT_NEAR(parameter(*f, "h_2"), 5e-4, 1e-6);
  EXPECT_NEAR(parameter(*f, "h_5"), 5e-4, 1e-6);
  EXPECT_NEAR(parameter(*f, "h_1"), 0.0, 1e-6);
  ASSERT_TRUE(d->after.has_value());
  // Residual 0: chi^2 after the refit is far below one per residual (it was hundreds).
  EXPECT_GT(d->before.chi2, 100.0);
  EXPECT_LT(d->after->chi2, 1e-2) << d->after->chi2;
}

TEST(DirectionEffects, NoiseFreePulleyFrictionIsRepresentedExactlyAndNamed) {
  const MeasurementSet set = record(0.0, 3.0, false, 1);
  ASSERT_TRUE(directions_known(set, 1) && directions_known(set, 4));
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
  ASSERT_EQ(d->accepted.size(), 1u) << d->headline;
  const EffectFit* f = accepted(*d, "pulley friction");
  ASSERT_NE(f, nullptr) << d->headline;
  EXPECT_NEAR(parameter(*f, "f_2"), 3.0, 1e-2);
  EXPECT_NEAR(parameter(*f, "f_5"), 3.0, 1e-2);
  EXPECT_NEAR(parameter(*f, "f_1"), 0.0, 1e-2);
  ASSERT_TRUE(d->after.has_value());
  EXPECT_GT(d->before.chi2, 100.0);
  EXPECT_LT(d->after->chi2, 1e-2) << d->after->chi2;
}

// LARGE's realistic friction (30 N on cables 2 and 5): at some designed poses cable 5 is slack in
// truth and its reading is the friction alone (+-30 N), above the slack threshold, so the standard
// identification fits a length row of a sagging cable. The fitted friction corrects the readings
// themselves (CandidateColumns::tension_readings) and the row drops out; moved into the length
// and equilibrium rows to first order instead, the refit settled at 31.6 N with chi^2 516 left and
// two effects named beside it.
TEST(DirectionEffects, NoiseFreeFrictionOnACableSlackInTruthIsRepresentedExactly) {
  const MeasurementSet set = record(0.0, 30.0, false, 1, large());
  const Eigen::MatrixXd d = last_move_directions(set);
  int lifted = 0;  // readings that are the friction alone: the cable slack in truth
  for (int j = 0; j < set.num_poses(); ++j) {
    const double t = set.poses[static_cast<std::size_t>(j)].tensions(4);
    lifted += d(j, 4) != 0.0 && std::abs(t - 30.0 * d(j, 4)) < 1e-6 ? 1 : 0;
  }
  ASSERT_GT(lifted, 0) << "the premise: cable 5 slack at some pose";
  Result<Diagnosis> diag = diagnose(large().nominal, set, nullptr, {}, options(true));
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  ASSERT_EQ(diag->accepted.size(), 1u) << diag->headline;
  const EffectFit* f = accepted(*diag, "pulley friction");
  ASSERT_NE(f, nullptr) << diag->headline;
  EXPECT_NEAR(parameter(*f, "f_2"), 30.0, 1e-2);
  EXPECT_NEAR(parameter(*f, "f_5"), 30.0, 1e-2);
  ASSERT_TRUE(diag->after.has_value());
  EXPECT_GT(diag->before.chi2, 1000.0);
  EXPECT_LT(diag->after->chi2, 1e-2) << diag->after->chi2;
}

TEST(DirectionEffects, EachIsNamedWithRealisticNoise) {
  // One at a time: on MINI the two are confounded (canonical correlation about 0.85: a length
  // error at a free pose shows mostly in the equilibrium rows, like a tension error).
  for (const bool hysteresis : {true, false}) {
    const MeasurementSet set = record(hysteresis ? 5e-4 : 0.0, hysteresis ? 0.0 : 3.0, true, 1001);
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    EXPECT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
    ASSERT_EQ(d->accepted.size(), 1u) << d->headline;
    EXPECT_EQ(d->accepted[0].family, hysteresis ? "cable hysteresis" : "pulley friction")
        << d->headline;
  }
}

void expect_described(const Diagnosis& d) {
  EXPECT_EQ(d.verdict, Diagnosis::Verdict::kMismatchUnexplained) << d.headline;
  EXPECT_TRUE(d.accepted.empty()) << d.headline;
  EXPECT_NE(d.headline.find("direction of the last move of cables 2 and 5"), std::string::npos)
      << d.headline;
  ASSERT_FALSE(d.screen.unexplained.empty());
  // The channel: on MINI a length error at a free pose shows mostly in the equilibrium rows (the
  // pose moves), so the hysteresis and the friction of one cable leave one structure, seen in the
  // cable tensions; each finding names the direction of the last move and cables 2 and 5 only.
  for (const auto& u : d.screen.unexplained) {
    EXPECT_EQ(u.variable, "direction of the last move") << u.description;
    EXPECT_EQ(u.cables, (std::vector<int>{1, 4})) << u.description;
    EXPECT_FALSE(u.poses.empty());
    EXPECT_NE(u.description.find("after paying out"), std::string::npos) << u.description;
  }
}

TEST(DirectionEffects, OutOfTheLibraryTheyAreDescribedNotMisnamedNoiseFree) {
  const MeasurementSet set = record(5e-4, 3.0, false, 1);
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(false));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  expect_described(*d);
}

TEST(DirectionEffects, OutOfTheLibraryTheyAreDescribedNotMisnamedWithRealisticNoise) {
  const MeasurementSet set = record(5e-4, 3.0, true, 1001);
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(false));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  expect_described(*d);
  for (const auto& u : d->screen.unexplained) {
    if (u.channel != "cable tensions") continue;
    for (double f : u.slopes) EXPECT_GT(f, 1.0) << u.description;  // 3 N of friction and more
  }
}

TEST(DirectionEffects, NullDataNamesNothingAndDescribesNothing) {
  const MeasurementSet set = record(0.0, 0.0, true, 1001);
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  EXPECT_EQ(d->verdict, Diagnosis::Verdict::kNoMismatch) << d->headline;
  EXPECT_TRUE(d->screen.unexplained.empty());
}

}  // namespace
}  // namespace cdpr

namespace cdpr {
namespace {

const UnexplainedStructure* structure_in(const std::vector<UnexplainedStructure>& all,
                                         const std::string& channel) {
  for (const auto& u : all)
    if (u.channel == channel && u.variable == "direction of the last move") return &u;
  return nullptr;
}

// The scan selects its structures forward (each test given the ones before it) and fits their
// sizes jointly: on noise-free data the hysteresis (a length error) and the friction (a tension
// reading error) of cables 2 and 5 come out as two structures, each on cables 2 and 5 only, each
// with its simulated size.
TEST(DirectionEffects, OutOfTheLibraryTheHysteresisAndTheFrictionComeOutWithTheirSizes) {
  const MeasurementSet set = record(5e-4, 3.0, false, 1);
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(false));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  expect_described(*d);
  const UnexplainedStructure* len = structure_in(d->screen.unexplained, "cable lengths");
  const UnexplainedStructure* ten = structure_in(d->screen.unexplained, "cable tensions");
  ASSERT_NE(len, nullptr) << d->screen.text();
  ASSERT_NE(ten, nullptr) << d->screen.text();
  for (double h : len->slopes) EXPECT_NEAR(h, 5e-4, 0.1 * 5e-4) << len->description;
  for (double f : ten->slopes) EXPECT_NEAR(f, 3.0, 0.1 * 3.0) << ten->description;
  EXPECT_EQ(len->columns.cols(), 2);
  EXPECT_EQ(len->columns.rows(), ten->columns.rows());
}

// A library candidate that fits only part of physics outside the library is not named: on the
// LARGE robot of the benchmark 30 N of pulley friction was named "force sensor gain" (it explains
// 28 % of the misfit). Here, friction of 15 N on MINI: the per-cable force gain is significant in
// the screen, but no longer once the unexplained structure is projected out, so it is a proxy.
TEST(DirectionEffects, ACandidateSignificantOnlyThroughUnexplainedStructureIsNotNamed) {
  const MeasurementSet set = record(0.0, 15.0, true, 1001);
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(false));
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  const CandidateScreen* gain = d->screen.find("force_gain_per_cable");
  ASSERT_NE(gain, nullptr);
  const DiagnosisOptions o = options(false);
  EXPECT_LT(gain->p_adjusted, o.screen_gate_p) << d->screen.text();
  EXPECT_GE(gain->p_beyond_structure, o.screen_gate_p) << d->screen.text();
  expect_described(*d);
}

// Force sensor gain errors of 1-2 %, signs per cable (the compound tests' second effect).
std::vector<double> force_gains() {
  return {0.02, -0.02, 0.015, -0.01, -0.02, 0.02, -0.015, 0.01};
}

// Compound effects: cable elasticity (the true EA 25 % below the nominal) and force sensor gain
// errors (2 %, signs per cable) together, realistic noise. The elasticity dominates the first
// screen, so the bootstrap selects it and the gain misses the inclusion threshold (before the
// second screening round, only elasticity was named). On the residual the elasticity leaves, the
// gain is significant; the second round refits it jointly and names both. The first round's
// forward steps also try the gains beside the elasticity (they keep 7 of their 8 directions,
// DiagnosisOptions::forward_own_directions) and name both there; with that rule off, the second
// round is what finds them.
TEST(CompoundEffects, ASmallerEffectHiddenByALargerOneIsNamedByTheSecondRound) {
  const double ea = mini().truth.cables[0].ea;
  for (std::uint64_t seed : {1001u}) {  // one seed (see the top of the file); 1002 too
    SCOPED_TRACE(seed);
    const MeasurementSet set = record_with(
        [&](sim::HiddenEffects& e, RobotModel&) {
          e.hooke_ea.values = {0.75 * ea};
          e.force_gain_error.values = force_gains();
        },
        true, seed);
    DiagnosisOptions o = options(true);
    // The two effects and their rivals: the gains' common mode looks like a softer cable.
    o.screen.only_groups = {"elasticity", "force sensor gain", "compliance", "creep"};
    o.separating_poses = 0;
    Result<Diagnosis> first = diagnose(mini().nominal, set, nullptr, {}, o);
    ASSERT_TRUE(first.ok()) << first.status().to_string();
    EXPECT_EQ(first->accepted.size(), 2u) << first->headline;
    EXPECT_NE(accepted(*first, "elasticity"), nullptr) << first->headline;
    EXPECT_NE(accepted(*first, "force sensor gain"), nullptr) << first->headline;

    o.forward_own_directions = 0;
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, o);
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    ASSERT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
    EXPECT_EQ(d->accepted.size(), 2u) << d->headline;
    const EffectFit* elastic = accepted(*d, "elasticity");
    const EffectFit* gains = accepted(*d, "force sensor gain");
    ASSERT_NE(elastic, nullptr) << d->headline;
    ASSERT_NE(gains, nullptr) << d->headline;
    EXPECT_EQ(elastic->round, 1);
    EXPECT_EQ(gains->round, 2) << d->headline;
    ASSERT_TRUE(d->screen_after.has_value());
    // The model with both leaves nothing unexplained.
    EXPECT_TRUE(d->screen_after->unexplained.empty());
  }
}

// Per-cable force gains beside cable creep: the gains' common mode looks like a softer cable, so
// the two share one direction; the gains keep seven of their own. The first round tries the
// gains beside creep (DiagnosisOptions::forward_own_directions) and the second round too
// (second_round_own_directions): both are named, nothing else. Before (the pair never tried
// together), these two seeds named creep alone; over seeds 1001-1008 both were named in 4 of 8
// runs before and in 7 of 8 after (1006: elasticity for creep, the two share their direction).
// Beside creep the gains' evidence can be weak (they share creep's direction: BIC -3.5 on seed
// 1004); they are then held back with follow-up poses (DiagnosisOptions::weak_step_bic), and the
// confirmatory re-run with those poses measured names both, as cdprd does.
TEST(CompoundEffects, ForceGainsBesideCreepAreBothNamedThoughTheyShareOneDirection) {
  const double ea = mini().truth.cables[0].ea;
  int held = 0;
  // One seed (see the top of the file): 1004, whose gains beside creep are weak evidence, held
  // back and confirmed by the re-run with their follow-up poses (1003's are strong at once).
  for (std::uint64_t seed : {1004u}) {
    SCOPED_TRACE(seed);
    const Hide hide = [&](sim::HiddenEffects& e, RobotModel&) {
      sim::CreepEffect c;
      c.tau_s = 10.0;
      c.coefficient = 0.1 / (ea * std::log1p(500.0 / c.tau_s));
      e.creep = c;
      e.force_gain_error.values = force_gains();
    };
    const MeasurementSet set = record_with(hide, true, seed);
    // Without the direction candidates (neither is simulated): the first run must screen the rest
    // of the library, not only some groups, for the weak gains to be held back.
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(false));
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    if (d->follow_up && d->follow_up->held_back) {
      ++held;
      EXPECT_EQ(d->follow_up->suspect, "force_gain_per_cable") << d->headline;
      std::vector<Pose> more = mini().poses;
      more.insert(more.end(), d->follow_up->poses.begin(), d->follow_up->poses.end());
      DiagnosisOptions confirm = options(false);
      confirm.screen.only_groups = follow_up_groups(*d);
      confirm.confirm_suspect = d->follow_up->suspect;
      d = diagnose(mini().nominal, record_poses(hide, true, seed, more), nullptr, {}, confirm);
      ASSERT_TRUE(d.ok()) << d.status().to_string();
    }
    ASSERT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
    EXPECT_NE(accepted(*d, "creep"), nullptr) << d->headline;
    EXPECT_NE(accepted(*d, "force sensor gain"), nullptr) << d->headline;
    EXPECT_EQ(d->accepted.size(), 2u) << d->headline;
  }
  EXPECT_EQ(held, 1);  // the path through the held-back suspect was taken
}

// MINI with cable creep (compliance +10 % of 1/EA over the 500 s recording, tau 10 s) and drum
// scale errors `scale` per winch, realistic noise. Homed at the home pose: the scale acts on the
// length paid out from there.
Hide creep_and_drum_scales(const std::vector<double>& scale) {
  return [scale](sim::HiddenEffects& e, RobotModel& truth) {
    const double ea = mini().truth.cables[0].ea;
    const Eigen::VectorXd home_counts =
        sim::nominal_counts(mini().nominal.robot, mini().nominal.robot.home).value();
    sim::CreepEffect c;
    c.tau_s = 10.0;
    c.coefficient = 0.1 / (ea * std::log1p(500.0 / c.tau_s));
    e.creep = c;
    e.transmission_scale.values = scale;
    for (int i = 0; i < truth.num_cables(); ++i) {
      auto& w = truth.winches[static_cast<std::size_t>(i)];
      w.length_offset -=
          scale[static_cast<std::size_t>(i)] * winch_length_change<double>(w, home_counts(i));
    }
  };
}

MeasurementSet record_creep_and_drum_scales(const std::vector<double>& scale, std::uint64_t seed) {
  return record_with(creep_and_drum_scales(scale), true, seed);
}

// Cable creep (one law for all cables) beside per-winch drum scale errors, realistic noise (the
// benchmark's creep + drum sizes). The creep shows most on a few cables, so the residual's tests
// "the length readings of cable i follow the tension" are significant there. Fitted, the single
// creep column (or a shared EA, confounded with it on these poses, 0.95) leaves them
// insignificant, though it is far from any one cable's column: the structure is explained, not
// reported as physics outside the library. Before, these seeds reported it as unexplained (the
// candidate had to contain the structure's column, canonical correlation above 0.8), and every
// candidate it shadowed counted as its proxy and was never a first effect.
TEST(CompoundEffects, CreepSeenOnAFewCablesIsExplainedNotReportedAsStructureOutsideTheLibrary) {
  const std::vector<double> scale = {0.002, -0.0015, 0.001, -0.002, 0.0015, -0.001, 0.002, -0.0005};
  for (std::uint64_t seed : {1001u}) {  // one seed (see the top of the file); 1002, 1004 too
    SCOPED_TRACE(seed);
    const MeasurementSet set = record_creep_and_drum_scales(scale, seed);
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    EXPECT_TRUE(d->screen.unexplained.empty()) << d->screen.text();
    EXPECT_NE(accepted(*d, "drum scale"), nullptr) << d->headline;
    EXPECT_TRUE(accepted(*d, "creep") != nullptr || accepted(*d, "elasticity") != nullptr)
        << d->headline;
    EXPECT_EQ(d->accepted.size(), 2u) << d->headline;
  }
}

// Creep beside per-winch drum scale errors named as a constant elasticity: the common mode of the
// drum scales takes creep's constant part (with similar tensions F L ~ L), and beside them a
// shared EA (or EA per cable) fits as well as the creep's time law, though alone creep is
// decisively better or worse than it. The recording cannot tell them apart, so the pair is
// reported with separating poses: whatever took creep's place is listed as confounded with creep.
// Before (the pair judged by the two fits alone from the standard model), seeds 1003-1005 named
// drum scale + elasticity with no pair to creep; 1001-1010 now all name creep or list it.
TEST(CompoundEffects, AnEffectStandingInForCreepBesideDrumScalesIsReportedAsConfoundedWithIt) {
  const std::vector<double> scale = {0.002, -0.002, 0.0015, -0.001, -0.002, 0.002, -0.0015, 0.001};
  for (std::uint64_t seed : {1003u}) {  // one seed (see the top of the file); 1004, 1005 too
    SCOPED_TRACE(seed);
    const MeasurementSet set = record_creep_and_drum_scales(scale, seed);
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    ASSERT_EQ(d->accepted.size(), 2u) << d->headline;
    EXPECT_NE(accepted(*d, "drum scale"), nullptr) << d->headline;
    if (accepted(*d, "creep") != nullptr) continue;
    const EffectFit& other =
        d->accepted[0].family == "drum scale" ? d->accepted[1] : d->accepted[0];
    const ConfoundedFinding* with_creep = nullptr;
    for (const ConfoundedFinding& c : d->confounded) {
      if ((c.first == other.id && c.second == "creep_shared") ||
          (c.second == other.id && c.first == "creep_shared"))
        with_creep = &c;
    }
    ASSERT_NE(with_creep, nullptr) << other.id << " named for the creep, not listed with it";
    EXPECT_FALSE(with_creep->separating_poses.empty());
    EXPECT_LT(with_creep->correlation_with_extra, with_creep->correlation);
  }
}

// Strong creep (the cables' compliance doubling over the 500 s recording) beside strong drum scale
// errors (0.5-1 % per winch), as on LARGE where both are 20-25 sigma. Creep is moved into the
// readings (a Gauss-Newton effect) and accepted first; its coefficient was the one fitted without
// the drum scales. Left there (DiagnosisOptions::polish_gauss_newton off), the misfit along its own
// column made a third, absent effect pass every test beside the two (winch compliance per winch
// here; seeds 1002 and 1003 the same or EA per cable; on LARGE creep stayed significant at p 1e-27
// beside itself). Refitted beside the drum scales, creep's column is not significant on what the
// model leaves, and the two present effects are named, nothing else. With the polish off, three
// effects are named on this recording and the test fails (that diagnosis is not run here: it
// took half of the test's minutes).
TEST(CompoundEffects, ACreepFittedBeforeTheDrumScalesIsRefittedBesideThem) {
  const std::vector<double> scale = {0.01, -0.008, 0.006, -0.01, 0.008, -0.006, 0.01, -0.005};
  const double ea = mini().truth.cables[0].ea;
  const MeasurementSet set = record_with(
      [&](sim::HiddenEffects& e, RobotModel& truth) {
        creep_and_drum_scales(scale)(e, truth);
        e.creep->coefficient = 1.0 / (ea * std::log1p(500.0 / e.creep->tau_s));
      },
      true, 1001);
  DiagnosisOptions o = options(true);
  ASSERT_TRUE(o.polish_gauss_newton);  // the default
  // The two effects and the third ones named with the polish off (compliance, EA per cable).
  o.screen.only_groups = {"creep", "drum scale", "compliance", "elasticity"};
  o.separating_poses = 0;
  Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, o);
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
  EXPECT_EQ(d->accepted.size(), 2u) << d->headline;
  EXPECT_NE(accepted(*d, "creep"), nullptr) << d->headline;
  EXPECT_NE(accepted(*d, "drum scale"), nullptr) << d->headline;
  ASSERT_TRUE(d->screen_after.has_value());
  const CandidateScreen* creep = d->screen_after->find("creep_shared");
  ASSERT_NE(creep, nullptr);
  EXPECT_GT(creep->p_value, 0.05) << d->screen_after->text();
}

// The separating poses are measured after the recording, so the time-dependent candidates are
// judged there: what the diagnosis promises for them (the pair's canonical correlation with them
// appended) is what the recording with them appended gives. Before, the extra-pose grid was
// simulated as if measured at the start (pose g at g seconds), where creep's column is near zero:
// diagnose promised that 6 poses would lower creep against elasticity from 0.95 to 0.1-0.2, and
// measured after the 500 s recording (where creep has nearly levelled off) they left it near 0.9.
TEST(CompoundEffects, SeparatingPosesArePredictedAtTheTimeTheyWillBeMeasured) {
  const std::vector<double> scale = {0.002, -0.002, 0.0015, -0.001, -0.002, 0.002, -0.0015, 0.001};
  const Hide hide = creep_and_drum_scales(scale);
  int checked = 0;
  for (std::uint64_t seed : {1003u}) {  // one seed (see the top of the file); 1004 too
    SCOPED_TRACE(seed);
    const MeasurementSet set = record_with(hide, true, seed);
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    for (const ConfoundedFinding& c : d->confounded) {
      if (c.first != "creep_shared" && c.second != "creep_shared") continue;
      if (c.separating_poses.empty()) continue;
      SCOPED_TRACE(c.first + " / " + c.second);
      std::vector<Pose> more = mini().poses;
      more.insert(more.end(), c.separating_poses.begin(), c.separating_poses.end());
      const MeasurementSet longer = record_poses(hide, true, seed, more);
      Result<IdentificationReport> rep = identify(mini().nominal, longer, {});
      ASSERT_TRUE(rep.ok()) << rep.status().to_string();
      MismatchOptions all_pairs;
      all_pairs.confound_threshold = 0.0;
      Result<MismatchSummary> s = locate_mismatch(*rep, longer, {}, all_pairs);
      ASSERT_TRUE(s.ok()) << s.status().to_string();
      double measured = -1.0;
      for (const ConfoundedPair& p : s->confounded) {
        if ((p.first == c.first && p.second == c.second) ||
            (p.first == c.second && p.second == c.first)) {
          measured = p.correlation;
        }
      }
      ASSERT_GE(measured, 0.0) << "the pair is not screened on the longer recording";
      EXPECT_NEAR(c.correlation_with_extra, measured, 0.05)
          << "promised " << c.correlation_with_extra << " from " << c.correlation;
      ++checked;
    }
  }
  EXPECT_GT(checked, 0) << "no pair with creep had separating poses";
}

// A tilted laser mount (0.5 degree about x and y, the benchmark's realistic size: 0.57 sigma left
// on the laser after the standard identification) is the beam direction alone. The screen tests the
// candidate `laser_direction` on its 2 directions: noise-free it explains the whole misfit, and
// with realistic noise its test is stronger than the whole mounting's (origin and direction, 4
// directions once the plane offset is estimated) on the same data. The whole mounting alone had
// to carry the tilt before, and with its extra directions missed the screen's gate more often.
TEST(LaserMounting, ATiltedMountIsTestedOnTheBeamDirectionsAlone) {
  constexpr double kDeg = 3.14159265358979323846 / 180.0;
  auto tilt = [&](sim::HiddenEffects& e, RobotModel&) {
    e.laser_mount_tilt = Eigen::Vector3d(0.5 * kDeg, -0.5 * kDeg, 0.0);
  };
  {
    const MeasurementSet set = record_with(tilt, false, 1);
    Result<Diagnosis> d = diagnose(mini().nominal, set, nullptr, {}, options(true));
    ASSERT_TRUE(d.ok()) << d.status().to_string();
    const CandidateScreen* beam = d->screen.find("laser_direction");
    const CandidateScreen* mount = d->screen.find("laser_mounting");
    ASSERT_NE(beam, nullptr);
    ASSERT_NE(mount, nullptr);
    EXPECT_EQ(beam->rank, 2);
    EXPECT_GT(mount->rank, beam->rank);
    EXPECT_GT(beam->explained_fraction, 0.99) << "the beam direction is the whole misfit";
  }
  int stronger = 0;
  for (std::uint64_t seed = 1001; seed <= 1006; ++seed) {
    const MeasurementSet set = record_with(tilt, true, seed);
    Result<MismatchSummary> s = [&]() -> Result<MismatchSummary> {
      Result<IdentificationReport> rep = identify(mini().nominal, set, {});
      if (!rep.ok()) return rep.status();
      return locate_mismatch(*rep, set, {}, MismatchOptions{});
    }();
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    const CandidateScreen* beam = s->find("laser_direction");
    const CandidateScreen* mount = s->find("laser_mounting");
    ASSERT_NE(beam, nullptr);
    ASSERT_NE(mount, nullptr);
    stronger += beam->p_value < mount->p_value ? 1 : 0;
  }
  // 5 of 6: with seed 1002 the mounting's origin directions also take some of the noise.
  EXPECT_GE(stronger, 5) << "of 6 seeds, the beam direction's test was the stronger one in "
                         << stronger;
}

// LARGE (the benchmark's 17 m frame) with heavy cables (100 g/m), the true EA 25 % below the
// nominal and force sensor gain errors, noise-free: the method's first check, the model with the
// named effects represents the simulated ones exactly. The catenary depends on the true tension
// (its arc ~1/T^2) and on the EA, so a catenary moved into the readings before the gains or the EA
// were in is wrong once they are (refresh_catenary in diagnosis_refit.cc recomputes it at every
// later acceptance); and nonlinear elasticity, taken greedily first for the elasticity, comes back
// to Hooke by a swap within the elasticity group though both are confounded with the gains. Before
// (session 17): nonlinear elasticity + sag + gains left chi^2 94 over 188 degrees of freedom.
TEST(CompoundEffects, NoiseFreeSagBesideElasticityAndForceGainsIsRepresentedExactly) {
  const Mini& robot = large();
  const double ea = 0.75 * robot.truth.cables[0].ea;
  const MeasurementSet set = record_poses(
      [&](sim::HiddenEffects& e, RobotModel& truth) {
        e.sag = true;
        for (auto& c : truth.cables) c.mass_per_length = 0.10;
        e.hooke_ea.values = {ea};
        e.force_gain_error.values = force_gains();
      },
      false, 1, robot.poses, robot);
  DiagnosisOptions o = options(true);
  o.separating_poses = 0;  // the first diagnosis is the one checked
  // The three effects and compliance, the elasticity's rival.
  o.screen.only_groups = {"sag", "elasticity", "force sensor gain", "compliance"};
  Result<Diagnosis> d = diagnose(robot.nominal, set, nullptr, {}, o);
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(d->verdict, Diagnosis::Verdict::kMismatchNamed) << d->headline;
  const EffectFit* sag = accepted(*d, "sag");
  const EffectFit* elastic = accepted(*d, "elasticity");
  const EffectFit* gains = accepted(*d, "force sensor gain");
  ASSERT_NE(sag, nullptr) << d->headline;
  ASSERT_NE(elastic, nullptr) << d->headline;
  ASSERT_NE(gains, nullptr) << d->headline;
  EXPECT_EQ(d->accepted.size(), 3u) << d->headline;
  EXPECT_NEAR(parameter(*sag, "mass_per_length"), 0.10, 0.002);
  EXPECT_NEAR(parameter(*elastic, "EA"), ea, 0.002 * ea);
  const std::vector<double> truth = force_gains();
  for (std::size_t i = 0; i < truth.size(); ++i) {
    EXPECT_NEAR(parameter(*gains, "force_gain_" + std::to_string(i + 1)), truth[i], 0.001)
        << "cable " << i + 1;
  }
  ASSERT_TRUE(d->after.has_value());
  EXPECT_LT(d->after->chi2, 1.0) << "over " << d->after->dof << " degrees of freedom";
}

}  // namespace
}  // namespace cdpr
