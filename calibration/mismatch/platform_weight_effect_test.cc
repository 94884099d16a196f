// Issue 41: the platform's weight (mass and centre of mass) as a locator effect. Before any
// statistics: on noise-free recordings of the suspended crane (elastic physics) and the
// over-constrained MINI (rigid) with a platform 12 % heavier than configured and its centre of mass
// off by (15, -10, 20) mm, diagnose() names the weight, with the true values, and nothing else;
// the model it writes carries them.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/mismatch_test_data.hpp"
#include "testing/platform_weight_scenario.hpp"

namespace cdpr {
namespace {

using testing::conceal_weight;

// Few poses and resamples (noise-free: the statistics are not what is tested).
DiagnosisOptions quick() {
  DiagnosisOptions o;
  o.bootstrap_samples = 20;
  o.follow_up_poses = 0;
  o.separating_poses = 0;
  return o;
}

const EffectParameter* parameter(const EffectFit& f, const std::string& name) {
  for (const EffectParameter& p : f.parameters) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

void expect_weight_named(const Diagnosis& d, const RobotModel& truth) {
  ASSERT_EQ(d.verdict, Diagnosis::Verdict::kMismatchNamed) << d.headline;
  ASSERT_EQ(d.accepted.size(), 1u) << d.headline;
  const EffectFit& f = d.accepted[0];
  EXPECT_EQ(f.id, "platform_weight") << d.headline;
  const EffectParameter* mass = parameter(f, "platform.mass");
  ASSERT_NE(mass, nullptr) << d.headline;
  EXPECT_NEAR(mass->value, truth.platform.mass, 1e-6 * truth.platform.mass);
  EXPECT_NE(mass->text.find("platform mass"), std::string::npos) << mass->text;
  EXPECT_NEAR(d.model_after.robot.platform.mass, truth.platform.mass, 1e-6 * truth.platform.mass);
  for (int q = 0; q < 3; ++q) {
    const EffectParameter* c = parameter(f, parameter_name({ParameterKind::kPlatformCom, -1, q}));
    ASSERT_NE(c, nullptr) << q;
    EXPECT_NEAR(c->value, truth.platform.center_of_mass(q), 1e-6) << c->text;
    EXPECT_NE(c->text.find("mm"), std::string::npos) << c->text;
    EXPECT_NEAR(d.model_after.robot.platform.center_of_mass(q), truth.platform.center_of_mass(q),
                1e-6);
  }
  ASSERT_TRUE(d.after.has_value());
  EXPECT_LT(d.after->chi2, 1e-6);
}

TEST(PlatformWeightEffect, NoiseFreeCraneNamesTheWeightWithItsTrueValues) {
  const testing::HeavyCrane c = testing::heavy_crane();
  auto d = diagnose(c.s.nominal, c.sim.set, nullptr, c.options, quick());
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  expect_weight_named(*d, c.s.truth.robot);
}

TEST(PlatformWeightEffect, NoiseFreeMiniNamesTheWeightWithItsTrueValues) {
  testing::RigidMini m = testing::rigid_mini(12);
  conceal_weight(m.s.truth.robot);
  SimulationOptions so;
  so.controller = &m.s.nominal;
  so.add_noise = false;
  auto sim = simulate_measurements(m.s.truth, m.poses, SensorNoise{}, 3, so);
  ASSERT_TRUE(sim.ok()) << sim.status().to_string();
  IdentificationOptions o;
  auto d = diagnose(m.s.nominal, sim->set, nullptr, o, quick());
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  expect_weight_named(*d, m.s.truth.robot);
}

}  // namespace
}  // namespace cdpr
