#include "cdpr/calibration/pose_design.hpp"

#include <gtest/gtest.h>

#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

TEST(PoseDesign, DesignedSetIsFeasibleAndBeatsRandom) {
  scenario::Scenario s = scenario::mini_scenario();
  PoseDesignOptions o;
  o.points_per_axis = 3;
  o.exchange_passes = 1;
  o.num_poses = 10;
  auto d = design_poses(s.nominal, o);
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(static_cast<int>(d->poses.size()), o.num_poses);
  EXPECT_EQ((d->poses[0].vector() - s.nominal.robot.home.vector()).norm(), 0.0);
  const double f_ref = default_reference_tension(s.nominal.robot);
  for (const Pose& p : d->poses)
    EXPECT_TRUE(simple_tension_distribution(s.nominal.robot, p, f_ref).ok());
  AccuracyBox box;
  box.points_per_axis = 3;
  auto cmp = compare_pose_sets(s.nominal, o, box, 3);
  ASSERT_TRUE(cmp.ok()) << cmp.status().to_string();
  ASSERT_EQ(cmp->size(), 3u);
  EXPECT_LT((*cmp)[0].anchor_rms_std_m, (*cmp)[1].anchor_rms_std_m);
}

}  // namespace
}  // namespace cdpr
