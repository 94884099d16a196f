#include "cdpr/calibration/residual_explanation.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "cdpr/calibration/kinematics.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

TEST(ResidualExplanation, EachEffectIsPlottedAgainstItsExplainingVariable) {
  EXPECT_EQ(explaining_variable("elasticity").name, "tension x loaded length");
  EXPECT_EQ(explaining_variable("compliance").name, "tension");
  EXPECT_EQ(explaining_variable("drum scale").name, "loaded length");
  EXPECT_EQ(explaining_variable("encoder drift").name, "time");
  EXPECT_EQ(explaining_variable("laser plane").name, "pose index");
}

// A diagnosis that names cable elasticity, built by hand on MINI at two poses.
struct Fixture {
  RobotModel robot = testing::mini_robot();
  MeasurementSet set;
  Diagnosis d;
  Fixture() {
    const int m = robot.num_cables();
    d.before.estimate = CalibratedModel::from_robot(robot);
    for (int j = 0; j < 2; ++j) {
      Pose p = robot.home;
      p.position.x() = 0.05 * j;
      d.before.poses.push_back(p);
      PoseMeasurement meas;
      meas.tensions = Eigen::VectorXd::LinSpaced(m, 10.0 + j, 30.0 + j);
      meas.time = 2.0 * j;
      set.poses.push_back(meas);
      PoseResiduals r;
      r.length_normalized = Eigen::VectorXd::Constant(m, 0.5 * (j + 1));
      r.length_normalized(3) = std::nan("");  // cable 4 not measured at this pose
      d.before.residuals.push_back(r);
    }
    EffectFit e;
    e.id = "hooke_shared";
    e.name = "cable elasticity";
    e.family = "elasticity";
    d.candidates = {e};
    d.accepted = {e};
  }
};

TEST(ResidualExplanation, ElasticityResidualsAreAgainstTensionTimesLoadedLength) {
  const Fixture f;
  const std::vector<ExplainedResiduals> plots = explained_residuals(f.d, f.set);
  ASSERT_EQ(plots.size(), 1u);
  const ExplainedResiduals& p = plots[0];
  EXPECT_EQ(p.title, "cable elasticity [hooke_shared]");
  EXPECT_EQ(p.variable, "tension x loaded length");
  EXPECT_EQ(p.unit, "N m");
  const int m = f.robot.num_cables();
  ASSERT_EQ(p.x.size(), static_cast<std::size_t>(2 * (m - 1)));  // cable 4 left out
  EXPECT_TRUE(p.after.empty());
  // The second pose's cable 6: tension times (routing + inverse-kinematics length).
  KinematicsData kin(m);
  ASSERT_TRUE(inverse_kinematics(f.robot, f.d.before.poses[1], kin));
  const double expected =
      f.set.poses[1].tensions(5) * (f.robot.cables[5].routing_length + kin.lengths(5));
  const std::size_t k = static_cast<std::size_t>(m - 1) + 4;  // pose 1, 5th finite cable
  EXPECT_EQ(p.cable[k], 5);
  EXPECT_DOUBLE_EQ(p.x[k], expected);
  EXPECT_EQ(p.before[k], 1.0);
}

TEST(ResidualExplanation, WithoutTheVariableTheResidualsAreAgainstThePoseIndex) {
  Fixture f;
  for (PoseMeasurement& meas : f.set.poses) meas.tensions.resize(0);
  const std::vector<ExplainedResiduals> plots = explained_residuals(f.d, f.set);
  ASSERT_EQ(plots.size(), 1u);
  EXPECT_EQ(plots[0].variable, "pose index");
  EXPECT_EQ(plots[0].title,
            "cable elasticity [hooke_shared] (tension x loaded length not recorded)");
  EXPECT_EQ(plots[0].x.back(), 1.0);
}

}  // namespace
}  // namespace cdpr
