// Typed parameter ids: the names for people are derived from them, and the identification reports
// the id of every estimated parameter.
#include <gtest/gtest.h>

#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

// MINI, 20 random poses, default noise: the recording every identification below runs on.
const MeasurementSet& mini_recording() {
  static const MeasurementSet set = [] {
    auto sim = scenario::simulate_random_poses(scenario::mini_scenario(), 20, 11, 5);
    EXPECT_TRUE(sim.ok()) << sim.status().to_string();
    return sim.ok() ? sim->set : MeasurementSet{};
  }();
  return set;
}

TEST(ParameterId, NamesForPeopleAreDerivedFromTheId) {
  using K = ParameterKind;
  struct Case {
    ParameterId id;
    const char* name;
  };
  const Case cases[] = {
      {{K::kFrameAnchor, 2, 0}, "a_3.x"},
      {{K::kPlatformAnchor, 0, 2}, "b_1.z"},
      {{K::kLengthOffset, 4, -1}, "o_5"},
      {{K::kLengthScale, 7, -1}, "s_8"},
      {{K::kStiffness, -1, -1}, "ea_scale"},
      {{K::kStiffness, 1, -1}, "ea_scale_2"},
      {{K::kForceGain, 0, -1}, "force_gain_1"},
      {{K::kForceOffset, 5, -1}, "force_offset_6"},
      {{K::kLaserOrigin, 0, 1}, "laser_1.origin.y"},
      {{K::kLaserDirection, 1, 1}, "laser_2.direction.v"},
      {{K::kLaserPlaneNormal, 0, 0}, "laser_1.plane.normal.u"},
      {{K::kLaserPlaneOffset, 0, -1}, "laser_1.plane.c"},
      {{K::kSwivelZero, 3, -1}, "swivel_zero_4"},
      {{K::kInclinometerMount, -1, 1}, "inclinometer.mount.pitch"},
      {{K::kImuYawZero, -1, -1}, "imu.yaw_zero"},
      {{K::kHomePose, -1, 3}, "home.roll"},
      {{K::kHomePose, -1, 4}, "home.pitch"},
      // A vector kind without its component names the whole vector.
      {{K::kFrameAnchor, 2, -1}, "a_3"},
      {{K::kPlatformAnchor, 0, -1}, "b_1"},
      {{K::kLaserOrigin, 0, -1}, "laser_1.origin"},
      {{K::kLaserPlaneNormal, 1, -1}, "laser_2.plane.normal"},
      {{K::kInclinometerMount, -1, -1}, "inclinometer.mount"},
      {{K::kHomePose, -1, -1}, "home"},
  };
  for (const Case& c : cases) EXPECT_EQ(parameter_name(c.id), c.name);
}

// Every estimate carries its id, its name is the id's, and no two estimates share an id.
TEST(ParameterId, EveryEstimateCarriesItsId) {
  const scenario::Scenario s = scenario::mini_scenario();
  IdentificationOptions opt;
  opt.estimate_stiffness = StiffnessEstimate::kPerCable;
  opt.estimate_force_gains = true;
  auto rep = identify(s.nominal, mini_recording(), opt);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  std::set<std::string> names;
  int anchors = 0, stiffness = 0;
  for (const ParameterEstimate& p : rep->parameters) {
    EXPECT_EQ(p.name, parameter_name(p.id));
    EXPECT_TRUE(names.insert(p.name).second) << p.name;
    anchors += p.id.kind == ParameterKind::kFrameAnchor ? 1 : 0;
    stiffness += p.id.kind == ParameterKind::kStiffness ? 1 : 0;
  }
  const int m = s.nominal.robot.num_cables();
  EXPECT_EQ(anchors, 3 * m);
  EXPECT_EQ(stiffness, m);
}

// The --estimate words: each switches its kinds on from nothing estimated, and off again; the
// estimates of an identification with it on include its kinds.
TEST(ParameterId, EachEstimateWordSwitchesOnItsKinds) {
  std::set<std::string_view> words;
  for (const EstimateItem& item : estimate_items()) {
    SCOPED_TRACE(std::string(item.word));
    EXPECT_TRUE(words.insert(item.word).second);
    EXPECT_FALSE(item.kinds.empty());
    EXPECT_EQ(find_estimate_item(item.word), &item);
    IdentificationOptions o;
    for (const EstimateItem& other : estimate_items()) other.set(o, false);
    EXPECT_FALSE(item.is_set(o));
    item.set(o, true);
    EXPECT_TRUE(item.is_set(o));
    item.set(o, false);
    EXPECT_FALSE(item.is_set(o));
  }
  EXPECT_EQ(find_estimate_item("no-such-item"), nullptr);
  // The word that estimates one kind alone (what the pose design's emphasis switches on).
  ASSERT_NE(estimate_item_of(ParameterKind::kLaserDirection), nullptr);
  EXPECT_EQ(estimate_item_of(ParameterKind::kLaserDirection)->word, "laser-direction");
  EXPECT_EQ(estimate_item_of(ParameterKind::kHomePose), nullptr);
  // Switched on in an identification, a word's kinds are among the estimates.
  const scenario::Scenario s = scenario::mini_scenario();
  ASSERT_GT(mini_recording().num_poses(), 0);
  for (const char* word : {"scales", "force-offsets", "stiffness"}) {
    SCOPED_TRACE(word);
    IdentificationOptions o;
    find_estimate_item(word)->set(o, true);
    auto rep = identify(s.nominal, mini_recording(), o);
    ASSERT_TRUE(rep.ok()) << rep.status().to_string();
    int of_word = 0;
    for (const ParameterEstimate& p : rep->parameters) {
      for (ParameterKind k : find_estimate_item(word)->kinds) of_word += p.id.kind == k ? 1 : 0;
    }
    EXPECT_GT(of_word, 0);
  }
}

// One vocabulary for cdpr-fit's --estimate and cdprd's identification.estimate: the words switch on
// exactly what they name; an empty list keeps the caller's defaults; errors name the word.
TEST(SetEstimate, SwitchesOnExactlyTheNamedItemsAndNamesAnUnknownWord) {
  IdentificationOptions defaults;
  IdentificationOptions o = defaults;
  ASSERT_TRUE(set_estimate({}, 8, o).ok());
  EXPECT_EQ(estimate_words(o), estimate_words(defaults));
  ASSERT_TRUE(set_estimate({"scales", "force-gains"}, 8, o).ok());
  EXPECT_EQ(estimate_words(o), (std::vector<std::string>{"scales", "force-gains"}));
  IdentificationOptions kept = o;
  const Status unknown = set_estimate({"scales", "ofsets"}, 8, o);
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.to_string().find("'ofsets'"), std::string::npos) << unknown.to_string();
  EXPECT_EQ(estimate_words(o), estimate_words(kept));  // unchanged on error
  EXPECT_FALSE(set_estimate({"paper-anchors"}, 4, o).ok());
  EXPECT_TRUE(set_estimate({"paper-anchors"}, 8, o).ok());
  EXPECT_TRUE(set_estimate({"paper-anchors"}, 0, o).ok());  // cable count not known yet
  ASSERT_TRUE(set_estimate({"none"}, 8, o).ok());           // a fixed model
  EXPECT_TRUE(estimate_words(o).empty());
  EXPECT_FALSE(set_estimate({"none", "anchors"}, 8, o).ok());
}

}  // namespace
}  // namespace cdpr
