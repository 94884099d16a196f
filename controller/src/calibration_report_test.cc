#include "cdpr/controller/calibration_report.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/mismatch.hpp"
#include "testing/test_robots.hpp"

namespace cdpr::controller {
namespace {

Pose pose_at(double x) {
  Pose p;
  p.position = Eigen::Vector3d(x, 0.0, 0.0);
  return p;
}

// A diagnosis that named Hooke's elasticity, found it confounded with winch compliance (two
// separating poses) and held back a laser beam tilt for weak evidence (three follow-up poses).
Diagnosis named_with_pair_and_suspect() {
  Diagnosis d;
  EffectFit hooke;
  hooke.id = "hooke_shared";
  hooke.family = std::string(find_effect("hooke_shared")->family);
  d.accepted.push_back(hooke);
  ConfoundedFinding cf;
  cf.first = "hooke_shared";
  cf.second = "compliance_shared";
  cf.first_fit = hooke;
  cf.second_fit.id = "compliance_shared";
  cf.second_fit.family = std::string(find_effect("compliance_shared")->family);
  cf.separating_poses = {pose_at(0.1), pose_at(0.2)};
  cf.separating_pretensions = {40.0, 80.0};
  d.confounded.push_back(cf);
  FollowUp fu;
  fu.suspect = "laser_direction";
  fu.held_back = true;
  fu.bic_delta = -1.1;
  fu.poses = {pose_at(0.3), pose_at(0.4), pose_at(0.5)};
  fu.pretensions = {40.0, 40.0, 40.0};
  d.follow_up = fu;
  return d;
}

bool has(const std::vector<std::string>& groups, const std::string& id) {
  const std::string g = selection_group(std::string(find_effect(id)->family));
  return std::find(groups.begin(), groups.end(), g) != groups.end();
}

TEST(ExtraPoseRound, SeparatingThenFollowUpPosesAndAConfirmatoryNextDiagnosisForAHeldBackSuspect) {
  const Diagnosis d = named_with_pair_and_suspect();
  const ExtraPoseRound r = extra_pose_round(d);
  ASSERT_EQ(r.poses.size(), 5u);
  ASSERT_EQ(r.pretensions.size(), 5u);
  for (std::size_t q = 0; q < r.poses.size(); ++q) {
    EXPECT_DOUBLE_EQ(r.poses[q].position.x(), 0.1 * static_cast<double>(q + 1)) << q;
  }
  EXPECT_DOUBLE_EQ(r.pretensions[1], 80.0);
  EXPECT_DOUBLE_EQ(r.pretensions[4], 40.0);
  EXPECT_TRUE(has(r.confirm_groups, "hooke_shared"));
  EXPECT_TRUE(has(r.confirm_groups, "compliance_shared"));
  EXPECT_TRUE(has(r.confirm_groups, "laser_direction"));
  EXPECT_EQ(r.confirm_suspect, "laser_direction");
}

TEST(ExtraPoseRound, ASuspectThatWasNotHeldBackIsScreenedButNotHeldToStrongEvidence) {
  Diagnosis d = named_with_pair_and_suspect();
  d.follow_up->held_back = false;  // follow_up_beside_named proposed it
  const ExtraPoseRound r = extra_pose_round(d);
  EXPECT_EQ(r.poses.size(), 5u);
  EXPECT_TRUE(has(r.confirm_groups, "laser_direction"));
  EXPECT_TRUE(r.confirm_suspect.empty());
}

TEST(ExtraPoseRound, WithNothingNamedTheNextDiagnosisScreensTheWholeLibrary) {
  Diagnosis d = named_with_pair_and_suspect();
  d.accepted.clear();
  d.confounded.clear();
  d.follow_up->held_back = false;
  const ExtraPoseRound r = extra_pose_round(d);
  EXPECT_EQ(r.poses.size(), 3u);
  EXPECT_TRUE(r.confirm_groups.empty());
  EXPECT_TRUE(r.confirm_suspect.empty());
}

TEST(ExtraPoseRound, SeparatingPosesAloneLeaveTheNextDiagnosisFull) {
  Diagnosis d = named_with_pair_and_suspect();
  d.follow_up.reset();
  const ExtraPoseRound r = extra_pose_round(d);
  EXPECT_EQ(r.poses.size(), 2u);
  EXPECT_TRUE(r.confirm_groups.empty());
  EXPECT_TRUE(r.confirm_suspect.empty());
  d.confounded.clear();
  EXPECT_TRUE(extra_pose_round(d).poses.empty());  // nothing asked: the sequence is done
}

// cdprd's pose design (the daemon's and iso9283_bench's): the config's design settings, the larger
// of the design and planning margins, the candidate box fitted to the robot.
TEST(MeasuringDesignOptions, TakesTheConfigsDesignWithTheLargerOfTheTwoMargins) {
  const RobotModel robot = cdpr::testing::mini_robot();
  DaemonConfig c;
  c.measuring.poses = 17;
  c.measuring.max_angle = 0.1;
  c.measuring.design_angle_steps = 3;
  c.measuring.design_emphasis_weight = 2.5;
  c.measuring.design_tension_margin = 4.0;
  c.motion.tension_margin = 7.0;
  const PoseDesignOptions o = measuring_design_options(c, robot);
  EXPECT_EQ(o.num_poses, 17);
  EXPECT_EQ(o.max_angle, 0.1);
  EXPECT_EQ(o.angle_steps, 3);
  EXPECT_EQ(o.emphasis_weight, 2.5);
  EXPECT_EQ(o.tension_margin, 7.0);
  c.measuring.design_tension_margin = 12.0;
  EXPECT_EQ(measuring_design_options(c, robot).tension_margin, 12.0);
  PoseDesignOptions fitted;
  fit_design_box_to_robot(robot, fitted);
  EXPECT_TRUE(o.center.isApprox(fitted.center));
  EXPECT_TRUE(o.half_extent.isApprox(fitted.half_extent));
  EXPECT_FALSE(o.half_extent.isApprox(PoseDesignOptions{}.half_extent));
}

}  // namespace
}  // namespace cdpr::controller
