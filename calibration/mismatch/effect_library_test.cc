// The candidate effects' descriptor table (effect_library.hpp): one entry per candidate, complete
// for its refit kind, and the lookups that replaced the per-id branches read it.
#include "cdpr/calibration/effect_library.hpp"

#include <gtest/gtest.h>

#include <set>
#include <string>

#include "cdpr/calibration/mismatch.hpp"
#include "testing/mismatch_test_data.hpp"

namespace cdpr {
namespace {

TEST(EffectLibrary, EveryEntryIsCompleteForItsRefitKind) {
  std::set<std::string_view> ids;
  for (const EffectDescriptor& e : effect_library()) {
    SCOPED_TRACE(std::string(e.id));
    EXPECT_TRUE(ids.insert(e.id).second) << "duplicate id";
    EXPECT_FALSE(e.name.empty());
    EXPECT_FALSE(e.family.empty());
    EXPECT_FALSE(e.group.empty());
    EXPECT_FALSE(e.bounds.empty());
    EXPECT_FALSE(e.plotted_against.name.empty());
    EXPECT_EQ(find_effect(e.id), &e);
    switch (e.refit) {
      case EffectRefit::kIdentification: {
        ASSERT_NE(e.estimate, nullptr);
        // The switch estimates what an identification without it does not (the laser plane is
        // estimated by default: a candidate when the user switched it off).
        IdentificationOptions o;
        o.estimate_laser_plane = false;
        const IdentificationOptions before = o;
        e.estimate(o);
        EXPECT_TRUE(o.estimate_stiffness != before.estimate_stiffness ||
                    o.estimate_length_scales != before.estimate_length_scales ||
                    o.estimate_platform_anchors != before.estimate_platform_anchors ||
                    o.estimate_force_gains != before.estimate_force_gains ||
                    o.estimate_force_offsets != before.estimate_force_offsets ||
                    o.estimate_laser_origin != before.estimate_laser_origin ||
                    o.estimate_laser_direction != before.estimate_laser_direction ||
                    o.estimate_laser_plane != before.estimate_laser_plane ||
                    o.estimate_platform_mass != before.estimate_platform_mass);
        break;
      }
      case EffectRefit::kGaussNewton:
      case EffectRefit::kCatenary:
        EXPECT_EQ(e.estimate, nullptr);
        EXPECT_NE(e.describe, nullptr);
        break;
    }
  }
  EXPECT_EQ(find_effect("no_such_effect"), nullptr);
}

TEST(EffectLibrary, RefinementsShareTheirSelectionGroup) {
  EXPECT_EQ(selection_group("nonlinear elasticity"), "elasticity");
  EXPECT_EQ(selection_group("elasticity"), "elasticity");
  EXPECT_EQ(selection_group("compliance"), "compliance");
  EXPECT_EQ(selection_group("not a family"), "not a family");
}

TEST(EffectLibrary, GaussNewtonCoefficientsAreDescribedInEngineerUnits) {
  // Hooke's columns are the compliance 1 / EA: 5e-5 1/N is EA = 20 kN.
  const EffectParameter ea = describe_coefficient("hooke_shared", 0, 1, 5e-5, 1e-6);
  EXPECT_EQ(ea.name, "EA");
  EXPECT_EQ(ea.unit, "N");
  EXPECT_DOUBLE_EQ(ea.value, 1.0 / 5e-5);
  EXPECT_DOUBLE_EQ(ea.std_dev, 1e-6 / (5e-5 * 5e-5));
  // The standard deviation (0.4 kN) with two significant figures, the value to the same digit.
  EXPECT_NE(ea.text.find("EA = 20.00 +- 0.40 kN"), std::string::npos) << ea.text;
  // Per cable: the coefficient's cable in the name.
  EXPECT_EQ(describe_coefficient("encoder_offset_per_cable", 2, 8, 1e-3, 1e-4).name, "o_3");
  // The drum scale's Jacobian column has the opposite sign of the parameter.
  EXPECT_DOUBLE_EQ(describe_coefficient("drum_scale_shared", 0, 1, 0.003, 1e-4).value, -0.003);
  // Without words of its own: the id and the coefficient's number.
  EXPECT_EQ(describe_coefficient("platform_anchors", 4, 24, 1.0, 0.1).name, "platform_anchors_5");
}

TEST(EffectLibrary, FittedEffectsAreWrittenIntoTheModelWhereTheConfigCanHoldThem) {
  const CalibratedModel rigid = testing::rigid_mini(2).s.nominal;
  const int m = rigid.robot.num_cables();
  for (const CableModel& c : rigid.robot.cables) ASSERT_EQ(c.elongation, ElongationKind::kRigid);
  CalibratedModel hooke = rigid;
  ASSERT_TRUE(write_effect("hooke_shared", Eigen::VectorXd::Constant(1, 5e-5), hooke));
  for (const CableModel& c : hooke.robot.cables) {
    EXPECT_EQ(c.elongation, ElongationKind::kHooke);
    EXPECT_DOUBLE_EQ(c.ea, 1.0 / 5e-5);
  }
  // An elastic config is not overwritten by a second elasticity.
  CalibratedModel again = hooke;
  EXPECT_FALSE(write_effect("hooke_shared", Eigen::VectorXd::Constant(1, 1e-4), again));
  CalibratedModel offsets = rigid;
  const Eigen::VectorXd o = Eigen::VectorXd::LinSpaced(m, 1e-4, 8e-4);
  ASSERT_TRUE(write_effect("encoder_offset_per_cable", o, offsets));
  EXPECT_TRUE(offsets.readings.length_offsets.isApprox(rigid.readings.length_offsets + o));
  CalibratedModel sag = rigid;
  ASSERT_TRUE(write_effect("sag_shared", Eigen::VectorXd::Constant(1, 0.02), sag));
  EXPECT_DOUBLE_EQ(sag.robot.cables[0].mass_per_length, 0.02);
  EXPECT_FALSE(write_effect("sag_shared", Eigen::VectorXd::Constant(1, -0.02), sag));
  // Report only: drifts and creep have no field in the config.
  CalibratedModel creep = rigid;
  EXPECT_FALSE(write_effect("creep_shared", Eigen::VectorXd::Constant(1, 1e-6), creep));
  EXPECT_FALSE(write_effect("no_such_effect", Eigen::VectorXd::Constant(1, 1.0), creep));
}

TEST(EffectLibrary, EachFamilyIsPlottedAgainstItsExplainingVariable) {
  for (const EffectDescriptor& e : effect_library()) {
    EXPECT_EQ(explaining_variable(std::string(e.family)).name, e.plotted_against.name) << e.id;
  }
  EXPECT_EQ(explaining_variable("not a family").name, "pose index");
}

// mismatch_design builds its candidates from the library: each is an entry, with the entry's
// words and family, in the library's order (the screen's ties and the selection depend on it).
TEST(EffectLibrary, TheScreensCandidatesAreTheLibrarysEntriesInItsOrder) {
  const testing::RigidMini d = testing::rigid_mini(25);
  const SimulatedMeasurements sim = testing::simulate(d, 3);
  const IdentificationOptions opt;
  auto rep = identify(d.s.nominal, sim.set, opt);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  auto des = mismatch_design(rep->estimate, sim.set, rep->poses, &rep->residuals, opt);
  ASSERT_TRUE(des.ok()) << des.status().to_string();
  ASSERT_GT(des->candidates.size(), 10u);
  long last = -1;
  for (const CandidateColumns& c : des->candidates) {
    const EffectDescriptor* e = find_effect(c.id);
    ASSERT_NE(e, nullptr) << c.id;
    EXPECT_EQ(c.name, e->name);
    EXPECT_EQ(c.family, e->family);
    const long at = e - effect_library().data();
    EXPECT_GT(at, last) << c.id;
    last = at;
  }
}

}  // namespace
}  // namespace cdpr
