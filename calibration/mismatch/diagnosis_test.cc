#include "cdpr/calibration/diagnosis.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"
#include "testing/mismatch_test_data.hpp"

namespace cdpr {
namespace {

using testing::conceal_elongation;
using testing::conceal_hooke;
using testing::rigid_mini;
using testing::RigidMini;
using testing::simulate;

// The verdict, headline and findings, for failure messages (the reports render a Diagnosis in
// drivers/report).
std::string trace(const Diagnosis& d) {
  std::string s = std::string("verdict: ") + to_string(d.verdict) + ". " + d.headline + "\n";
  for (const std::string& f : d.findings) s += "- " + f + "\n";
  return s;
}

DiagnosisOptions quick_options() {
  DiagnosisOptions o;
  o.bootstrap_samples = 40;
  return o;
}

const EffectFit* accepted(const Diagnosis& d, const std::string& id) {
  for (const auto& f : d.accepted) {
    if (f.id == id) return &f;
  }
  return nullptr;
}

const ConfoundedFinding* confounded(const Diagnosis& d, const std::string& a,
                                    const std::string& b) {
  for (const auto& c : d.confounded) {
    if ((c.first == a && c.second == b) || (c.first == b && c.second == a)) return &c;
  }
  return nullptr;
}

TEST(Diagnosis, NullDataGivesNoMismatchAcrossSeeds) {
  const RigidMini d = rigid_mini(25);
  int false_findings = 0;
  for (int seed = 1; seed <= 4; ++seed) {
    const SimulatedMeasurements sim = simulate(d, static_cast<std::uint64_t>(seed));
    auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
    ASSERT_TRUE(diag.ok()) << diag.status().to_string();
    if (diag->verdict != Diagnosis::Verdict::kNoMismatch) {
      ++false_findings;
      std::printf("seed %d:\n%s\n", seed, trace(*diag).c_str());
    }
    EXPECT_TRUE(diag->accepted.empty());
    EXPECT_FALSE(diag->mismatch_found() && !diag->accepted.empty());
    EXPECT_NE(diag->headline.find("No missing physics found"), std::string::npos) << diag->headline;
    ASSERT_FALSE(diag->channels.empty());
    // Nothing accepted: the model after is the standard identification's.
    EXPECT_DOUBLE_EQ(diag->channels.front().before, diag->channels.front().after);
  }
  EXPECT_EQ(false_findings, 0);
}

// A wild reading (a mistyped cell, a unit slip) is named where it is, not explained by physics:
// a least-squares fit spreads it over the geometry and the effects would fit the smear.
TEST(Diagnosis, AWildReadingIsNamedWhereItIsAndNothingElse) {
  const RigidMini d = rigid_mini(25);
  struct Wild {
    int pose, index;
    bool laser;
    double error;  // m
  };
  for (const Wild w : {Wild{7, 4, false, 0.30}, Wild{0, 7, false, -0.05}, Wild{12, 0, true, 0.1}}) {
    SimulatedMeasurements sim = simulate(d, 5);
    PoseMeasurement& pm = sim.set.poses[static_cast<std::size_t>(w.pose)];
    (w.laser ? pm.laser_distances : pm.cable_lengths)(w.index) += w.error;
    auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
    ASSERT_TRUE(diag.ok()) << diag.status().to_string();
    SCOPED_TRACE(trace(*diag));
    EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kInconclusive);
    EXPECT_TRUE(diag->accepted.empty());
    ASSERT_EQ(diag->gross_readings.size(), 1u);
    const GrossReading& g = diag->gross_readings.front();
    EXPECT_EQ(g.pose, w.pose);
    EXPECT_EQ(g.index, w.index);
    EXPECT_EQ(g.channel, w.laser ? "laser distance" : "cable length");
    // The robust fit leaves the whole error on the reading (model minus reading).
    EXPECT_NEAR(g.residual, -w.error, 0.02 * std::abs(w.error));
    EXPECT_NE(diag->headline.find(w.laser ? "laser distance 1"
                                          : "cable length " + std::to_string(w.index + 1)),
              std::string::npos);
  }
  // Two wild readings are both named, the larger first.
  SimulatedMeasurements two = simulate(d, 6);
  two.set.poses[3].cable_lengths(1) += 0.2;
  two.set.poses[9].cable_lengths(5) -= 0.1;
  auto both = diagnose(d.s.nominal, two.set, nullptr, {}, quick_options());
  ASSERT_TRUE(both.ok()) << both.status().to_string();
  ASSERT_EQ(both->gross_readings.size(), 2u) << trace(*both);
  EXPECT_EQ(both->gross_readings[0].pose, 3);
  EXPECT_EQ(both->gross_readings[1].pose, 9);
}

// A concealed effect leaves structure over many readings, not a few wild ones: no gross reading.
TEST(Diagnosis, AStrongEffectIsNotTakenForWildReadings) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 3);
  conceal_hooke(d, sim, 1.0e4);  // EA 10 kN: several mm of stretch, tens of sigmas
  // The elasticity and its rival, winch compliance: the gross-reading stage sees the readings
  // before any candidate, so the rest of the library changes nothing here.
  DiagnosisOptions o = quick_options();
  o.screen.only_groups = {"elasticity", "compliance"};
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  EXPECT_GT(diag->before.chi2, 100.0 * diag->before.dof);
  EXPECT_TRUE(diag->gross_readings.empty());
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kMismatchNamed);

  // A wild reading beside it carries most of the misfit: it is named although the rest still
  // misfits (the effect's). When only a rest within the noise may name it (gross_share out of
  // reach), it is left to the effects.
  sim.set.poses[9].cable_lengths(3) += 0.3;
  auto standard = identify(d.s.nominal, sim.set);
  ASSERT_TRUE(standard.ok()) << standard.status().to_string();
  const std::vector<GrossReading> g = find_gross_readings(d.s.nominal, sim.set, *standard);
  ASSERT_EQ(g.size(), 1u);
  EXPECT_EQ(g[0].pose, 9);
  EXPECT_EQ(g[0].channel, "cable length");
  EXPECT_EQ(g[0].index, 3);
  EXPECT_NEAR(std::abs(g[0].residual), 0.3, 0.01);
  DiagnosisOptions rest_only;
  rest_only.gross_share = 1e9;
  EXPECT_TRUE(find_gross_readings(d.s.nominal, sim.set, *standard, {}, rest_only).empty());
}

// The normalisation of a trial's deviance (its log det part): deviance - chi^2.
double normalisation(const Diagnosis& d, const std::string& id) {
  for (const auto& f : d.candidates) {
    if (f.id == id) return f.deviance_after - f.chi2_after;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

TEST(Diagnosis, NonlinearElasticityMovedIntoTheLengthsCarriesTheForceNoiseOfTheIdentifiedEa) {
  // Elasticity fitted as an identified EA widens each length sigma by the force noise through
  // L / EA; fitted as nonlinear elasticity moved into the lengths (Gauss-Newton), the same
  // stretch must widen them alike, else the log det alone favours the nonlinear form.
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 3);
  conceal_hooke(d, sim, 5.0e4);
  DiagnosisOptions carried = quick_options();
  carried.gauss_newton_force_noise = true;
  DiagnosisOptions left = carried;
  left.gauss_newton_force_noise = false;
  auto with = diagnose(d.s.nominal, sim.set, nullptr, {}, carried);
  auto without = diagnose(d.s.nominal, sim.set, nullptr, {}, left);
  ASSERT_TRUE(with.ok() && without.ok());
  const double hooke = normalisation(*with, "hooke_shared");
  const double nonlinear = normalisation(*with, "nonlinear_elasticity_shared");
  const double nonlinear_left = normalisation(*without, "nonlinear_elasticity_shared");
  ASSERT_TRUE(std::isfinite(hooke) && std::isfinite(nonlinear) && std::isfinite(nonlinear_left));
  std::printf("log det part: EA %.3f, nonlinear %.3f (force noise left out: %.3f)\n", hooke,
              nonlinear, nonlinear_left);
  EXPECT_LT(std::abs(nonlinear - hooke), 0.5);
  EXPECT_GT(hooke - nonlinear_left, 2.0);
}

TEST(Diagnosis, RefinementIsNamedOnlyWhenWhatItAddsPassesTheNamingGate) {
  // A clearly nonlinear elongation (F / EA + k2 F^2) L: the curvature passes the gate and is named;
  // with a gate no curvature passes, the simpler member of its group (Hooke's EA) is named
  // instead, never both and never nothing.
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 4);
  constexpr double kEa = 5.0e4;
  constexpr double kCurvature = 6e-8;  // 1/N^2: +30 % of the stretch at 100 N
  conceal_elongation(d, sim, [&](double f) { return f / (kEa + f) + kCurvature * f * f; });
  DiagnosisOptions gated = quick_options();
  DiagnosisOptions closed = gated;
  closed.refinement_gate_p = 1e-300;
  auto named = diagnose(d.s.nominal, sim.set, nullptr, {}, gated);
  auto simpler = diagnose(d.s.nominal, sim.set, nullptr, {}, closed);
  ASSERT_TRUE(named.ok() && simpler.ok());
  {
    SCOPED_TRACE(trace(*named));
    EXPECT_NE(accepted(*named, "nonlinear_elasticity_shared"), nullptr);
    EXPECT_EQ(accepted(*named, "hooke_shared"), nullptr);
  }
  SCOPED_TRACE(trace(*simpler));
  EXPECT_EQ(accepted(*simpler, "nonlinear_elasticity_shared"), nullptr);
  EXPECT_NE(accepted(*simpler, "hooke_shared"), nullptr);
}

TEST(Diagnosis, ConcealedHookeElasticityIsNamedModelledAndPredictsBetter) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 3);
  constexpr double kEa = 5.0e4;  // N: about 0.5-1 mm of stretch at MINI's tensions
  conceal_hooke(d, sim, kEa);
  const auto t0 = std::chrono::steady_clock::now();
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, DiagnosisOptions{});
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  std::printf("diagnose (MINI, 25 poses, 100 resamples): %.2f s wall\n", seconds);
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kMismatchNamed);
  const EffectFit* hooke = accepted(*diag, "hooke_shared");
  const ConfoundedFinding* pair = confounded(*diag, "hooke_shared", "compliance_shared");
  // Either named directly, or named with the winch compliance as its confounded alternative.
  ASSERT_TRUE(hooke != nullptr || (pair != nullptr && accepted(*diag, "compliance_shared")));
  if (hooke != nullptr) {
    ASSERT_EQ(hooke->parameters.size(), 1u);
    EXPECT_EQ(hooke->parameters[0].name, "EA");
    EXPECT_NEAR(hooke->parameters[0].value, kEa, 0.2 * kEa);
    EXPECT_NE(hooke->parameters[0].text.find("cable elasticity: EA = "), std::string::npos);
    EXPECT_TRUE(hooke->modelled_in_config);
    EXPECT_LT(hooke->lrt_p_value, 0.01);
    EXPECT_LT(hooke->bic_delta, 0.0);
    EXPECT_GT(hooke->family_inclusion_probability, 0.6);
    for (const auto& c : diag->model_after.robot.cables) {
      EXPECT_EQ(c.elongation, ElongationKind::kHooke);
      EXPECT_NEAR(c.ea, kEa, 0.2 * kEa);
    }
  }
  EXPECT_LT(diag->held_out_rms_after, 0.3 * diag->held_out_rms_before);
  ASSERT_TRUE(diag->after.has_value());
  EXPECT_LT(diag->after->chi2, diag->before.chi2);
  ASSERT_FALSE(diag->channels.empty());
  EXPECT_EQ(diag->channels.front().channel, "cable lengths");
  EXPECT_LT(diag->channels.front().after, 0.5 * diag->channels.front().before);
}

// MINI with a concealed EA of 50 kN, and options that report every pair with correlated columns,
// however clearly the fits differ (the default reports it only when the fits are within
// decisive_bic: CorrelatedCandidateThatFitsDecisivelyWorseIsNotReportedAsConfounded).
struct ElasticCase {
  RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 5);
  DiagnosisOptions o = quick_options();
  ElasticCase() {
    conceal_hooke(d, sim, 5.0e4);
    o.decisive_bic = std::numeric_limits<double>::infinity();
  }
};

TEST(Diagnosis, ConfoundedElasticityAndComplianceGetBothFitsAndSeparatingPoses) {
  const ElasticCase ec;
  const RigidMini& d = ec.d;
  const SimulatedMeasurements& sim = ec.sim;
  const DiagnosisOptions& o = ec.o;
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  const ConfoundedFinding* pair = confounded(*diag, "hooke_shared", "compliance_shared");
  ASSERT_NE(pair, nullptr);
  EXPECT_GT(pair->correlation, o.screen.confound_threshold);
  // Both fits are there, each explaining most of the misfit.
  EXPECT_FALSE(pair->first_fit.id.empty());
  EXPECT_FALSE(pair->second_fit.id.empty());
  EXPECT_GT(pair->first_fit.lrt_statistic, 0.0);
  EXPECT_GT(pair->second_fit.lrt_statistic, 0.0);
  // Extra poses from the feasible grid that make the two effects distinguishable.
  EXPECT_EQ(static_cast<int>(pair->separating_poses.size()), o.separating_poses);
  EXPECT_EQ(pair->separating_pretensions.size(), pair->separating_poses.size());
  EXPECT_LT(pair->correlation_with_extra, pair->correlation);
  const double f_ref = default_reference_tension(d.s.nominal.robot);
  for (const Pose& p : pair->separating_poses) {
    EXPECT_TRUE(simple_tension_distribution(diag->before.estimate.robot, p, f_ref).ok());
  }
}

// The extra poses are judged at the time they will be measured (after the recording): for a pair
// with no time dependence that time changes nothing, however the recording's clock runs, even
// when the next time stamp would overflow.
TEST(Diagnosis, SeparatingPosesOfATimelessPairDoNotDependOnTheRecordingsClock) {
  const ElasticCase ec;
  const RigidMini& d = ec.d;
  const SimulatedMeasurements& sim = ec.sim;
  const DiagnosisOptions& o = ec.o;
  auto poses_of = [&](const MeasurementSet& set) {
    auto diag = diagnose(d.s.nominal, set, nullptr, {}, o);
    EXPECT_TRUE(diag.ok()) << diag.status().to_string();
    if (!diag.ok()) return std::vector<Pose>{};
    for (const ConfoundedFinding& c : diag->confounded) {
      EXPECT_TRUE(std::isfinite(c.correlation_with_extra)) << c.first << " / " << c.second;
    }
    const ConfoundedFinding* pair = confounded(*diag, "hooke_shared", "compliance_shared");
    EXPECT_NE(pair, nullptr);
    return pair != nullptr ? pair->separating_poses : std::vector<Pose>{};
  };
  const std::vector<Pose> reference = poses_of(sim.set);
  ASSERT_EQ(static_cast<int>(reference.size()), o.separating_poses);
  MeasurementSet late = sim.set;
  const double np = static_cast<double>(late.num_poses());
  for (int j = 0; j < late.num_poses(); ++j) {
    // The last time stamp is the largest double; the next one would be infinite.
    late.poses[static_cast<std::size_t>(j)].time =
        std::numeric_limits<double>::max() * (1.0 - 0.5 * (np - 1.0 - j) / np);
  }
  const std::vector<Pose> moved = poses_of(late);
  ASSERT_EQ(moved.size(), reference.size());
  for (std::size_t q = 0; q < moved.size(); ++q) {
    EXPECT_TRUE(moved[q].vector().isApprox(reference[q].vector())) << q;
  }
}

// cv_folds 0 holds out one pose at a time (every pose but the home pose, which the gauge fixes):
// the same folds as K = the number of poses, and the report says which it was.
TEST(Diagnosis, LeaveOnePoseOutIsAFoldForEveryPoseThatCanBeHeldOut) {
  const ElasticCase ec;
  DiagnosisOptions loo = ec.o, each = ec.o;
  loo.cv_folds = 0;
  each.cv_folds = ec.sim.set.num_poses();
  auto a = diagnose(ec.d.s.nominal, ec.sim.set, nullptr, {}, loo);
  auto b = diagnose(ec.d.s.nominal, ec.sim.set, nullptr, {}, each);
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  ASSERT_TRUE(b.ok()) << b.status().to_string();
  ASSERT_FALSE(a->accepted.empty());
  // The same folds; the fits agree to rounding (the solver's sums are not ordered).
  EXPECT_NEAR(a->held_out_rms_before, b->held_out_rms_before, 1e-9 * b->held_out_rms_before);
  EXPECT_NEAR(a->held_out_rms_after, b->held_out_rms_after, 1e-9 * b->held_out_rms_after);
  EXPECT_EQ(a->held_out_source, "leave-one-pose-out cross-validation");
  EXPECT_EQ(b->held_out_source, std::to_string(each.cv_folds) + "-fold cross-validation");
  DiagnosisOptions one = ec.o;
  one.cv_folds = 1;
  EXPECT_FALSE(diagnose(ec.d.s.nominal, ec.sim.set, nullptr, {}, one).ok());
}

TEST(Diagnosis, SuspectWithoutANamedEffectGetsFeasibleFollowUpPosesThatAddInformation) {
  const RigidMini d = rigid_mini(25);
  const SimulatedMeasurements sim = simulate(d, 2);
  DiagnosisOptions o = quick_options();
  o.suspect_p = 2.0;  // above every p-value: the candidate with the lowest p-value is a suspect
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  ASSERT_TRUE(diag->accepted.empty());
  ASSERT_TRUE(diag->follow_up.has_value());
  const FollowUp& fu = *diag->follow_up;
  // The suspect is the screen's candidate with the lowest p-value.
  const CandidateScreen* s = diag->screen.find(fu.suspect);
  ASSERT_NE(s, nullptr);
  for (const auto& c : diag->screen.candidates) {
    if (!c.modelled && c.rank > 0) {
      EXPECT_LE(s->p_value, c.p_value) << c.id;
    }
  }
  EXPECT_EQ(static_cast<int>(fu.poses.size()), o.follow_up_poses);
  EXPECT_EQ(fu.pretensions.size(), fu.poses.size());
  EXPECT_GT(fu.information_after, fu.information_before);
  const double f_ref = default_reference_tension(d.s.nominal.robot);
  for (const Pose& p : fu.poses) {
    EXPECT_TRUE(simple_tension_distribution(d.s.nominal.robot, p, f_ref).ok());
    EXPECT_TRUE(simple_tension_distribution(diag->before.estimate.robot, p, f_ref).ok());
  }
  // The text says what to do.
  EXPECT_NE(trace(*diag).find("follow-up poses"), std::string::npos);

  // No suspect below the threshold, or follow-up switched off: nothing proposed.
  o.suspect_p = 0.0;
  auto none = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->follow_up.has_value());
  o.suspect_p = 2.0;
  o.follow_up_poses = 0;
  auto off = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(off.ok());
  EXPECT_FALSE(off->follow_up.has_value());
}

// Beside named effects (follow_up_beside_named), a candidate confounded on the first screen with a
// named effect is not a suspect (follow_up_skips_confounded_with_named): its directions mostly
// carry what the named effect's fit leaves. follow_up_groups() then lists what the confirmatory
// re-run screens: the named effects', the suspect's and the confounded pairs' groups.
TEST(Diagnosis, SuspectBesideNamedEffectsIsNotOneConfoundedWithThem) {
  const ElasticCase ec;
  DiagnosisOptions o = ec.o;
  o.follow_up_beside_named = true;
  o.suspect_p = 2.0;  // every candidate below it: the lowest p-value that is allowed is the suspect
  auto skip = diagnose(ec.d.s.nominal, ec.sim.set, nullptr, {}, o);
  ASSERT_TRUE(skip.ok()) << skip.status().to_string();
  SCOPED_TRACE(trace(*skip));
  ASSERT_FALSE(skip->accepted.empty());
  ASSERT_TRUE(skip->follow_up.has_value());
  ASSERT_TRUE(skip->screen_after.has_value());
  auto confounded_with_named = [&](const std::string& id) {
    for (const EffectFit& f : skip->accepted) {
      for (const ConfoundedPair& cp : skip->screen.confounded) {
        if ((cp.first == f.id && cp.second == id) || (cp.second == f.id && cp.first == id)) {
          return true;
        }
      }
    }
    return false;
  };
  EXPECT_FALSE(confounded_with_named(skip->follow_up->suspect)) << skip->follow_up->suspect;

  // Allowed, the suspect is the lowest p-value whatever its confounding; here that is one
  // confounded with the named elasticity (winch compliance or a force gain).
  o.follow_up_skips_confounded_with_named = false;
  auto any = diagnose(ec.d.s.nominal, ec.sim.set, nullptr, {}, o);
  ASSERT_TRUE(any.ok()) << any.status().to_string();
  ASSERT_TRUE(any->follow_up.has_value());
  EXPECT_LE(any->follow_up->p_value, skip->follow_up->p_value);
  EXPECT_TRUE(confounded_with_named(any->follow_up->suspect)) << any->follow_up->suspect;

  // The confirmatory re-run's groups.
  const std::vector<std::string> groups = follow_up_groups(*skip);
  auto listed = [&](const std::string& family) {
    return std::find(groups.begin(), groups.end(), selection_group(family)) != groups.end();
  };
  for (const EffectFit& f : skip->accepted) EXPECT_TRUE(listed(f.family)) << f.family;
  EXPECT_TRUE(listed(std::string(find_effect(skip->follow_up->suspect)->family)));
  for (const ConfoundedFinding& cf : skip->confounded) {
    EXPECT_TRUE(listed(cf.first_fit.family) && listed(cf.second_fit.family)) << cf.first;
  }
  EXPECT_LT(groups.size(), skip->screen.candidates.size());
  // Nothing named (or no follow-up): a full re-run, no groups.
  Diagnosis nothing = *skip;
  nothing.accepted.clear();
  EXPECT_TRUE(follow_up_groups(nothing).empty());
  nothing = *skip;
  nothing.follow_up.reset();
  EXPECT_TRUE(follow_up_groups(nothing).empty());
}

TEST(Diagnosis, CorrelatedCandidateThatFitsDecisivelyWorseIsNotReportedAsConfounded) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 5);
  conceal_hooke(d, sim, 5.0e4);
  const DiagnosisOptions o = quick_options();
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  // The screen finds the two column spaces correlated ...
  bool correlated = false;
  for (const auto& p : diag->screen.confounded) {
    correlated = correlated || (p.first == "hooke_shared" && p.second == "compliance_shared") ||
                 (p.first == "compliance_shared" && p.second == "hooke_shared");
  }
  ASSERT_TRUE(correlated);
  // ... but the full fits tell them apart: elasticity is named alone.
  ASSERT_EQ(diag->accepted.size(), 1u);
  EXPECT_EQ(diag->accepted.front().id, "hooke_shared");
  const EffectFit* compliance = nullptr;
  for (const auto& c : diag->candidates) {
    if (c.id == "compliance_shared") compliance = &c;
  }
  ASSERT_NE(compliance, nullptr);
  EXPECT_GT(compliance->bic_delta - diag->accepted.front().bic_delta, o.decisive_bic);
  EXPECT_EQ(confounded(*diag, "hooke_shared", "compliance_shared"), nullptr);
}

TEST(Diagnosis, ConcealedDrumScaleErrorIsNamedWithItsValue) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 4);
  const std::vector<double> scale = {6e-3, -5e-3, 5e-3, -6e-3, 5e-3, -6e-3, 6e-3, -5e-3};
  for (auto& p : sim.set.poses) {
    for (int i = 0; i < p.cable_lengths.size(); ++i) {
      p.cable_lengths(i) *= 1.0 + scale[static_cast<std::size_t>(i)];
    }
  }
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kMismatchNamed);
  const EffectFit* drum = accepted(*diag, "drum_scale_per_cable");
  ASSERT_NE(drum, nullptr);
  EXPECT_TRUE(drum->modelled_in_config);
  ASSERT_EQ(drum->parameters.size(), scale.size());
  for (std::size_t i = 0; i < scale.size(); ++i) {
    const EffectParameter& p = drum->parameters[i];
    EXPECT_EQ(p.name, "s_" + std::to_string(i + 1));
    // Readings scaled by (1 + e): the identification's s undoes it, s = 1 / (1 + e) - 1.
    const double expected = 1.0 / (1.0 + scale[i]) - 1.0;
    EXPECT_NEAR(p.value, expected, std::max(0.1 * std::abs(expected), 4.0 * p.std_dev));
    EXPECT_NE(p.text.find("drum scale error of winch " + std::to_string(i + 1)), std::string::npos);
    EXPECT_NEAR(diag->model_after.readings.length_scales(static_cast<Eigen::Index>(i)), p.value,
                1e-3 * p.std_dev);
  }
  // The effect is about twice the noise: held-out prediction improves towards the noise floor.
  EXPECT_LT(diag->held_out_rms_after, 0.6 * diag->held_out_rms_before);
  EXPECT_LT(diag->held_out_rms_after, 1.2 * sim.set.noise.sigma_length);
}

TEST(Diagnosis, ConcealedCommonDrumScaleErrorIsNamedAndModelled) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 8);
  constexpr double kScale = 8e-3;  // every drum 0.8 % off (e.g. the cable diameter misstated)
  for (auto& p : sim.set.poses) p.cable_lengths *= 1.0 + kScale;
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kMismatchNamed);
  ASSERT_FALSE(diag->accepted.empty());
  const EffectFit& f = diag->accepted.front();
  EXPECT_EQ(f.family, "drum scale");
  EXPECT_TRUE(f.modelled_in_config);
  // The readings are (1 + e) too long: the scale correction is 1 / (1 + e) - 1 on every winch.
  const double expected = 1.0 / (1.0 + kScale) - 1.0;
  for (int i = 0; i < diag->model_after.readings.length_scales.size(); ++i) {
    EXPECT_NEAR(diag->model_after.readings.length_scales(i), expected, 0.2 * std::abs(expected));
  }
  ASSERT_FALSE(f.parameters.empty());
  EXPECT_NE(f.parameters.front().text.find("drum scale error"), std::string::npos);
  EXPECT_LT(diag->held_out_rms_after, diag->held_out_rms_before);
}

TEST(Diagnosis, TooFewPosesIsInconclusive) {
  const RigidMini d = rigid_mini(8);
  const SimulatedMeasurements sim = simulate(d, 2);
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kInconclusive);
  EXPECT_NE(diag->headline.find("8 poses are too few"), std::string::npos) << diag->headline;
  EXPECT_FALSE(diag->mismatch_found());
  EXPECT_TRUE(diag->accepted.empty());
}

TEST(Diagnosis, WrongCableCountIsRefusedNamingTheCounts) {
  const RigidMini d = rigid_mini(15);
  SimulatedMeasurements sim = simulate(d, 2);
  for (auto& p : sim.set.poses) {
    p.cable_lengths.conservativeResize(6);
    p.tensions.conservativeResize(6);
  }
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
  ASSERT_FALSE(diag.ok());
  EXPECT_EQ(diag.status().code(), ErrorCode::kInvalidArgument);
  const std::string msg(diag.status().message());
  EXPECT_NE(msg.find("6 cable lengths"), std::string::npos) << msg;
  EXPECT_NE(msg.find("8 cables"), std::string::npos) << msg;
}

// Force sensor gains beside encoder drift: the refits after the gains start from a model that
// carries them, while the readings were made with the nominal sensors. The model after holds each
// named gain once (it held (1 + g)^2 - 1 when a later refit read the readings with the estimated
// sensors).
TEST(Diagnosis, ForceGainsBesideEncoderDriftAreWrittenIntoTheModelOnce) {
  RigidMini d = rigid_mini(25);
  const int m = d.s.truth.robot.num_cables();
  for (int i = 0; i < m; ++i) {
    d.s.truth.robot.force_sensors[static_cast<std::size_t>(i)].gain *=
        1.0 + (i % 2 == 0 ? 0.04 : -0.04) * (1.0 + 0.1 * i);
  }
  SimulatedMeasurements sim = simulate(d, 3);
  // Encoder drift, up to 40 um/s per cable (about 1 mm over the recording): a Gauss-Newton effect,
  // so the readings are identified again after the gains are in (polish_gauss_newton).
  for (PoseMeasurement& pm : sim.set.poses) {
    for (int i = 0; i < m; ++i) pm.cable_lengths(i) += (i % 3 - 1) * 4.0e-5 * pm.time;
  }
  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, quick_options());
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  const EffectFit* gains = accepted(*diag, "force_gain_per_cable");
  ASSERT_NE(gains, nullptr);
  ASSERT_GE(diag->accepted.size(), 2u);
  int compared = 0;
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    const double written =
        diag->model_after.robot.force_sensors[ui].gain / d.s.nominal.robot.force_sensors[ui].gain -
        1.0;
    for (const EffectParameter& p : gains->parameters) {
      if (p.name != "force_gain_" + std::to_string(i + 1)) continue;
      EXPECT_NEAR(written, p.value, 1e-9) << "cable " << i + 1;
      EXPECT_GT(std::abs(p.value), 0.2 * p.std_dev) << "cable " << i + 1;
      ++compared;
    }
  }
  EXPECT_EQ(compared, m);
}

// DiagnosisOptions::weak_step_bic: an effect added beside named ones with weak evidence is not
// named but held back as a suspect with follow-up poses aimed at it. The re-run on the recording
// with those poses measured (confirmatory: follow_up_groups, confirm_suspect) names it with strong
// evidence; on the recording alone the same gate leaves it out. Without robot time for it
// (follow_up_poses 0) it is named by the ordinary tests, as before.
TEST(Diagnosis, AWeakStepBesideNamedEffectsIsHeldBackUntilItsFollowUpPosesGiveStrongEvidence) {
  // Cable elasticity, found first, and a laser beam tilted by 0.7 degrees, found beside it.
  RigidMini d = rigid_mini(25);
  ASSERT_FALSE(d.s.truth.robot.lasers.empty());
  Eigen::Vector3d& beam = d.s.truth.robot.lasers[0].direction;
  beam = (Eigen::AngleAxisd(0.7 * M_PI / 180.0, Eigen::Vector3d::UnitX()) * beam).normalized();
  SimulatedMeasurements sim = simulate(d, 3);
  conceal_hooke(d, sim, 5.0e4);
  DiagnosisOptions o = quick_options();
  // The two effects' rivals (compliance, the laser's mounting and plane) stay in the library; the
  // force sensors' and the direction-dependent candidates are left out.
  o.screen.force_sensor_candidates = false;
  o.screen.direction_candidates = false;
  o.weak_step_bic = 0.0;  // off: taken on BIC < 0
  auto named = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(named.ok()) << named.status().to_string();
  const auto second = std::find_if(named->accepted.begin(), named->accepted.end(),
                                   [](const EffectFit& f) { return f.round == 2; });
  ASSERT_NE(second, named->accepted.end()) << trace(*named);
  EXPECT_FALSE(named->follow_up.has_value()) << trace(*named);
  // Weak evidence by the default bound too (a BIC between -weak_step_bic and 0).
  EXPECT_LT(second->bic_delta, 0.0);
  EXPECT_GT(second->bic_delta, -DiagnosisOptions{}.weak_step_bic);
  auto in_group = [&](const Diagnosis& x) {
    return std::any_of(x.accepted.begin(), x.accepted.end(), [&](const EffectFit& f) {
      return selection_group(f.family) == selection_group(second->family);
    });
  };

  // Weak: the bound above its evidence.
  o.weak_step_bic = -second->bic_delta + 2.0;
  auto held = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(held.ok()) << held.status().to_string();
  SCOPED_TRACE(trace(*held));
  EXPECT_FALSE(in_group(*held));
  EXPECT_EQ(held->accepted.size() + 1, named->accepted.size());
  ASSERT_TRUE(held->follow_up.has_value());
  const FollowUp& fu = *held->follow_up;
  EXPECT_TRUE(fu.held_back);
  EXPECT_EQ(fu.suspect, second->id);
  EXPECT_NEAR(fu.bic_delta, second->bic_delta, 1e-6 * (1.0 + std::abs(second->bic_delta)));
  EXPECT_EQ(static_cast<int>(fu.poses.size()), o.follow_up_poses);
  EXPECT_GT(fu.information_after, fu.information_before);
  EXPECT_NE(trace(*held).find("weak evidence"), std::string::npos);
  const std::vector<std::string> groups = follow_up_groups(*held);
  ASSERT_NE(std::find(groups.begin(), groups.end(), selection_group(second->family)), groups.end());
  DiagnosisOptions confirm = o;
  confirm.screen.only_groups = groups;
  confirm.confirm_suspect = fu.suspect;

  // The follow-up poses measured and appended: strong evidence, named. (They are feasible for the
  // nominal and the estimated model; the few that the true robot cannot hold are left out, as the
  // robot would refuse them.)
  RigidMini longer = d;
  for (const Pose& p : fu.poses) {
    SimulationOptions so;
    so.controller = &d.s.nominal;
    if (simulate_measurements(d.s.truth, {p}, SensorNoise{}, 3, so).ok()) {
      longer.poses.push_back(p);
    }
  }
  ASSERT_GE(longer.poses.size(), d.poses.size() + fu.poses.size() * 3 / 4);
  SimulatedMeasurements sim2 = simulate(longer, 3);
  conceal_hooke(longer, sim2, 5.0e4);
  auto decided = diagnose(d.s.nominal, sim2.set, nullptr, {}, confirm);
  ASSERT_TRUE(decided.ok()) << decided.status().to_string();
  EXPECT_TRUE(in_group(*decided)) << trace(*decided);
  for (const EffectFit& f : decided->accepted) {
    if (selection_group(f.family) == selection_group(second->family)) {
      EXPECT_LT(f.bic_delta, -confirm.weak_step_bic) << trace(*decided);
    }
  }
  EXPECT_FALSE(decided->follow_up.has_value()) << trace(*decided);
  // Without the poses, the confirming gate leaves the weak effect out.
  auto still_weak = diagnose(d.s.nominal, sim.set, nullptr, {}, confirm);
  ASSERT_TRUE(still_weak.ok()) << still_weak.status().to_string();
  EXPECT_FALSE(in_group(*still_weak)) << trace(*still_weak);
  // Without robot time for it, the effect is named as before.
  o.follow_up_poses = 0;
  auto no_time = diagnose(d.s.nominal, sim.set, nullptr, {}, o);
  ASSERT_TRUE(no_time.ok()) << no_time.status().to_string();
  EXPECT_TRUE(in_group(*no_time)) << trace(*no_time);
}

TEST(Diagnosis, ValidationRecordingIsTheHeldOutSet) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 6);
  SimulatedMeasurements val = simulate(d, 7);
  conceal_hooke(d, sim, 5.0e4);
  conceal_hooke(d, val, 5.0e4);
  auto diag = diagnose(d.s.nominal, sim.set, &val.set, {}, quick_options());
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  EXPECT_EQ(diag->held_out_source, "validation recording");
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kMismatchNamed);
  EXPECT_LT(diag->held_out_rms_after, 0.5 * diag->held_out_rms_before);
}

// Physics concentrated in a few readings is not called gross when the effects named on the whole
// recording bring those readings inside the noise: a weak elasticity (EA 300 kN) stretches the
// few high-tension cables most, and with low gates the robust fit of the rigid model leaves two of
// them out. A wild reading beside a strong effect stays gross whatever is named beside it.
TEST(Diagnosis, ReadingsThatTheNamedEffectExplainsAreNotGross) {
  const RigidMini d = rigid_mini(25);
  SimulatedMeasurements sim = simulate(d, 3);
  conceal_hooke(d, sim, 3.0e5);
  DiagnosisOptions low = quick_options();
  low.gross_sigmas = 5.0;
  low.gross_spread = 1.25;
  low.gross_share = 0.0;
  auto standard = identify(d.s.nominal, sim.set);
  ASSERT_TRUE(standard.ok()) << standard.status().to_string();
  const std::vector<GrossReading> flagged =
      find_gross_readings(d.s.nominal, sim.set, *standard, {}, low);
  ASSERT_FALSE(flagged.empty()) << "the premise: the low gates flag the stretched readings";

  DiagnosisOptions at_once = low;
  at_once.gross_effects_sigmas = 0.0;
  auto before = diagnose(d.s.nominal, sim.set, nullptr, {}, at_once);
  ASSERT_TRUE(before.ok()) << before.status().to_string();
  EXPECT_EQ(before->verdict, Diagnosis::Verdict::kInconclusive) << trace(*before);
  EXPECT_EQ(before->gross_readings.size(), flagged.size());

  auto diag = diagnose(d.s.nominal, sim.set, nullptr, {}, low);
  ASSERT_TRUE(diag.ok()) << diag.status().to_string();
  SCOPED_TRACE(trace(*diag));
  EXPECT_EQ(diag->verdict, Diagnosis::Verdict::kMismatchNamed);
  EXPECT_TRUE(diag->gross_readings.empty());
  ASSERT_FALSE(diag->accepted.empty());
  // Hooke's elasticity or a winch compliance: on these random poses the two are confounded.
  const std::string family = diag->accepted.front().family;
  EXPECT_TRUE(family == "elasticity" || family == "compliance") << family;
  ASSERT_GE(diag->findings.size(), 2u);
  EXPECT_NE(diag->findings[1].find("physics concentrated in a few readings"), std::string::npos);

  // A 0.3 m error in one length beside a strong elasticity (EA 10 kN): thousands of sigmas, beyond
  // gross_effects_sigmas, so it is named gross at once and nothing is accepted.
  SimulatedMeasurements strong = simulate(d, 3);
  conceal_hooke(d, strong, 1.0e4);
  strong.set.poses[9].cable_lengths(3) += 0.3;
  auto wild = diagnose(d.s.nominal, strong.set, nullptr, {}, quick_options());
  ASSERT_TRUE(wild.ok()) << wild.status().to_string();
  EXPECT_EQ(wild->verdict, Diagnosis::Verdict::kInconclusive) << trace(*wild);
  ASSERT_EQ(wild->gross_readings.size(), 1u) << trace(*wild);
  EXPECT_EQ(wild->gross_readings[0].pose, 9);
  EXPECT_EQ(wild->gross_readings[0].index, 3);
  EXPECT_TRUE(wild->accepted.empty());
}

}  // namespace
}  // namespace cdpr
