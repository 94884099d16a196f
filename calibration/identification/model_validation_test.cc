// Held-out validation (model_validation.hpp), a fixed model (nothing estimated) and the words of
// a rigid motion that a held home pose does not stop (issue 41).
#include "cdpr/calibration/model_validation.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

// MINI: the truth's recording (rigid physics, encoders homed with the nominal model) of home and
// `n` random poses.
struct Campaign {
  scenario::Scenario s;
  RobotModel truth;  // the truth with its encoder offsets folded into the winches, as a config
  MeasurementSet set;
};

Campaign mini_campaign(int n, std::uint64_t seed) {
  Campaign c{scenario::mini_scenario(), {}, {}};
  auto sim = scenario::simulate_random_poses(c.s, n + 1, static_cast<unsigned>(seed), seed);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  if (sim.ok()) c.set = sim->set;
  c.truth = c.s.truth.robot;
  for (int i = 0; i < c.truth.num_cables(); ++i) {
    c.truth.winches[static_cast<std::size_t>(i)].length_offset +=
        c.s.truth.readings.length_offsets(i);
  }
  return c;
}

TEST(ModelValidation, TheTruthPredictsAHeldOutRecordingWithinTheNoiseAndTheNominalDoesNot) {
  const Campaign c = mini_campaign(20, 11);
  auto truth = predict_recording(c.truth, c.s.nominal.robot, c.set);
  auto nominal = predict_recording(c.s.nominal.robot, c.s.nominal.robot, c.set);
  ASSERT_TRUE(truth.ok()) << truth.status().to_string();
  ASSERT_TRUE(nominal.ok()) << nominal.status().to_string();
  EXPECT_TRUE(truth->converged);
  // Every pose free: chi^2 about its dof for the truth, far above for the nominal anchors.
  EXPECT_LT(truth->chi2 / truth->dof, 1.5);
  EXPECT_GT(nominal->chi2 / nominal->dof, 10.0);
  EXPECT_TRUE(beats(*truth, *nominal));
  std::string why;
  EXPECT_FALSE(beats(*nominal, *truth, &why));
  EXPECT_THAT(why, HasSubstr("cable lengths"));
  ASSERT_FALSE(truth->channels.empty());
  EXPECT_EQ(truth->channels.front().channel, "cable lengths");
  // Every taut cable of the 21 poses (a slack one has no length row).
  EXPECT_LE(truth->channels.front().rows, 21 * c.truth.num_cables());
  EXPECT_GT(truth->channels.front().rows, 18 * c.truth.num_cables());
}

TEST(ModelValidation, ReadingsThroughAnotherWinchKeepTheCounts) {
  RobotModel made_with = testing::mini_robot();
  RobotModel model = made_with;
  model.winches[2].length_offset += 0.004;
  model.winches[2].drum_diameter *= 1.002;
  const ReadingModel r = readings_of(model, made_with);
  EXPECT_NEAR(r.length_scales(2), 0.002, 1e-6);
  EXPECT_NEAR(r.length_offsets(2), 0.004 - 0.002 * made_with.winches[2].length_offset, 1e-6);
  EXPECT_EQ(r.length_offsets(0), 0.0);
}

TEST(ModelValidation, AFixedModelFitsOnlyThePoses) {
  const Campaign c = mini_campaign(12, 3);
  IdentificationOptions none;
  for (const EstimateItem& item : estimate_items()) item.set(none, false);
  auto r = identify(CalibratedModel::from_robot(c.truth), c.set, none);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_TRUE(r->parameters.empty());
  EXPECT_EQ(r->rank, 0);
  EXPECT_EQ(r->num_parameters, 6 * 12);  // every pose but the home pose
}

// The crane's frame turning about the vertical with the home pose held: a rigid motion of the
// frame that the held pose does not stop, so "fix the home pose" would be the wrong advice.
TEST(Identifiability, ARigidMotionWithTheHomePoseHeldIsNotCalledAGaugeToFix) {
  const RobotModel crane = testing::crane_robot();
  GeometryInformation gi;
  const int m = crane.num_cables();
  gi.frame_anchors = crane.frame_anchors;
  gi.anchor_columns.resize(3, m);
  Eigen::VectorXd turn(3 * m);
  for (int i = 0; i < m; ++i) {
    for (int q = 0; q < 3; ++q) {
      gi.ids.push_back({ParameterKind::kFrameAnchor, i, q});
      gi.names.push_back(parameter_name(gi.ids.back()));
      gi.units.emplace_back("m");
      gi.anchor_columns(q, i) = 3 * i + q;
    }
    const Eigen::Vector3d a = crane.frame_anchors.col(i);
    turn.segment<3>(3 * i) = Eigen::Vector3d::UnitZ().cross(a);
  }
  gi.values = Eigen::VectorXd::Zero(3 * m);
  turn.normalize();
  gi.information = Eigen::MatrixXd::Identity(3 * m, 3 * m) - turn * turn.transpose();
  gi.home_cable_directions = Eigen::Matrix3Xd::Zero(3, m);
  gi.home_pose_fixed = true;
  const IdentifiabilityReport r = analyze_identifiability(gi, IdentifiabilityOptions{});
  EXPECT_EQ(r.rank, 3 * m - 1);
  ASSERT_FALSE(r.directions.empty());
  EXPECT_TRUE(r.directions.front().gauge);
  EXPECT_THAT(r.directions.front().description, Not(HasSubstr("fix the home pose")));
  EXPECT_THAT(r.directions.front().description, HasSubstr("held home pose does not stop it"));
  gi.home_pose_fixed = false;  // nothing holds the frame: then it is the gauge to fix
  EXPECT_THAT(analyze_identifiability(gi, IdentifiabilityOptions{}).directions.front().description,
              HasSubstr("fix the home pose"));
}

}  // namespace
}  // namespace cdpr
