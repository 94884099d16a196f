#include "cdpr/calibration/calibration_verdict.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

// MINI as shipped (nominal config anchors, truth the measured ones, homed encoders), 25 poses
// designed on the nominal model, elastic simulation, the default (realistic) noise: laser 1 mm,
// encoder 0.1 mm, force 1 N.
struct MiniCase {
  scenario::Scenario s;
  std::vector<Pose> poses;
};

const MiniCase& mini_case() {
  static const MiniCase c = [] {
    MiniCase m;
    m.s = scenario::mini_config_scenario();
    PoseDesignOptions po;
    po.num_poses = 25;
    auto design = design_poses(m.s.nominal, po);
    EXPECT_TRUE(design.ok()) << design.status().to_string();
    if (design.ok()) m.poses = design->poses;
    return m;
  }();
  return c;
}

// The truth with a drum (transmission) scale error of `scale` on every winch, signs alternating
// per cable. Homing sets the readings at home, so the error scales the length paid out from
// home: o_i' = o_i - s_i r_home,i with r_home the reading there (the nominal model's length).
CalibratedModel with_drum_scale(const scenario::Scenario& s, double scale) {
  CalibratedModel t = s.truth;
  const RobotModel& nom = s.nominal.robot;
  auto f = simple_tension_distribution(nom, nom.home, default_reference_tension(nom));
  EXPECT_TRUE(f.ok());
  auto r_home = unstretched_lengths(nom, nom.home, *f);
  EXPECT_TRUE(r_home.ok());
  static const double kSigns[8] = {1, -1, 1, -1, -1, 1, -1, 1};
  for (int i = 0; i < t.robot.num_cables(); ++i) {
    const double si = scale * kSigns[i % 8];
    t.readings.length_scales(i) += si;
    t.readings.length_offsets(i) -= si * (*r_home)(i);
  }
  return t;
}

Result<IdentificationReport> calibrate_once(const CalibratedModel& truth, std::uint64_t seed) {
  const MiniCase& c = mini_case();
  SimulationOptions so;
  so.physics = SimulationOptions::Physics::kElastic;
  so.controller = &c.s.nominal;
  auto sim = simulate_measurements(truth, c.poses, SensorNoise{}, seed, so);
  if (!sim.ok()) return sim.status();
  return identify(c.s.nominal, sim->set);
}

TEST(CalibrationVerdict, MiniDrumScaleFailsAndNullDataPasses) {
  const MiniCase& c = mini_case();
  ASSERT_EQ(c.poses.size(), 25u);
  const CalibratedModel drum = with_drum_scale(c.s, 0.003);
  // Ten seeds: each must come out right (null data passes, the drum scale fails; at 2000-2039 all
  // 40 do). The rates over many seeds and sizes are bench/calibrate_verdict_bench.cc's figures.
  const int seeds = 10;
  int null_passed = 0, drum_failed = 0;
  for (int k = 0; k < seeds; ++k) {
    const std::uint64_t seed = 2000 + static_cast<std::uint64_t>(k);
    auto null_fit = calibrate_once(c.s.truth, seed);
    ASSERT_TRUE(null_fit.ok()) << null_fit.status().to_string();
    auto drum_fit = calibrate_once(drum, seed);
    ASSERT_TRUE(drum_fit.ok()) << drum_fit.status().to_string();
    const CalibrationVerdict vn = judge_calibration(*null_fit);
    const CalibrationVerdict vd = judge_calibration(*drum_fit);
    std::printf("seed %d: null chi2 %.1f/%d p %.3g %s | drum chi2 %.1f/%d p %.3g %s\n",
                static_cast<int>(seed), vn.chi2, vn.dof, vn.p_value, to_string(vn.kind), vd.chi2,
                vd.dof, vd.p_value, to_string(vd.kind));
    null_passed += vn.passed() ? 1 : 0;
    drum_failed += vd.passed() ? 0 : 1;
  }
  std::printf("null data passed %d/%d, drum scale 0.3 %% failed %d/%d\n", null_passed, seeds,
              drum_failed, seeds);
  EXPECT_GE(null_passed, (95 * seeds + 99) / 100);
  EXPECT_GE(drum_failed, (90 * seeds + 99) / 100);
}

TEST(ChiSquareFitTest, PassesAtTheMedianFailsFarOutAndNeverWithoutDegreesOfFreedom) {
  // chi^2(k) has mean k: a fit whose chi^2 equals its dof sits near the median and passes.
  const FitTest median = chi_square_fit_test(40.0, 40, 0.01);
  EXPECT_TRUE(median.passed);
  EXPECT_GT(median.p_value, 0.3);
  EXPECT_LT(median.p_value, 0.7);
  // Twice the dof on 40 dof is far out in the tail.
  const FitTest far = chi_square_fit_test(80.0, 40, 0.01);
  EXPECT_FALSE(far.passed);
  EXPECT_LT(far.p_value, 0.01);
  // The same p-value as the verdict reports.
  IdentificationReport r;
  r.chi2 = 80.0;
  r.dof = 40;
  r.converged = true;
  EXPECT_DOUBLE_EQ(judge_calibration(r).p_value, far.p_value);
  // Nothing to test: never passes, and a NaN chi^2 never passes either.
  EXPECT_FALSE(chi_square_fit_test(0.0, 0, 0.01).passed);
  EXPECT_FALSE(chi_square_fit_test(std::nan(""), 10, 0.01).passed);
}

}  // namespace
}  // namespace cdpr
