#include "cdpr/calibration/model_check.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

using ::testing::HasSubstr;
using ::testing::StartsWith;

std::string check(const RobotModel& model) {
  const Status s = check_model(model);
  EXPECT_FALSE(s.ok()) << "accepted";
  if (!s.ok()) {
    EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  }
  return std::string(s.message());
}

TEST(ModelCheck, TestRobotsPass) {
  for (bool pulleys : {false, true}) {
    EXPECT_TRUE(check_model(testing::mini_robot(pulleys)).ok())
        << check_model(testing::mini_robot(pulleys)).to_string();
    EXPECT_TRUE(check_model(testing::large_robot(pulleys)).ok())
        << check_model(testing::large_robot(pulleys)).to_string();
  }
}

TEST(ModelCheck, StructureConditioningOfMiniIsFullRankAndScaleFree) {
  RobotModel model = testing::mini_robot();
  const StructureConditioning a = structure_conditioning(model, model.home);
  ASSERT_TRUE(a.valid);
  EXPECT_EQ(a.rank, 6);
  EXPECT_GT(a.condition_number, 1.0);
  EXPECT_LT(a.condition_number, 100.0);
  // Moment rows are divided by the platform radius: shrinking the whole platform by 10 keeps the
  // directions of the cables almost the same, and the condition number does not blow up by 10.
  model.platform_anchors *= 0.1;
  const StructureConditioning b = structure_conditioning(model, model.home);
  ASSERT_TRUE(b.valid);
  EXPECT_LT(b.condition_number, 2.0 * a.condition_number);
}

TEST(ModelCheck, WrongArrayLength) {
  RobotModel model = testing::mini_robot();
  model.winches.pop_back();
  EXPECT_THAT(check(model), StartsWith("winches: expected one entry per cable (8"));
  model = testing::mini_robot();
  model.platform_anchors.conservativeResize(3, 7);
  EXPECT_THAT(check(model), StartsWith("platform_anchors: expected one entry per cable (8"));
  model = testing::mini_robot();
  model.force_sensors.push_back({});
  EXPECT_THAT(check(model), HasSubstr("force_sensors: expected one entry per cable (8, the number "
                                      "of frame anchors), got 9"));
}

TEST(ModelCheck, TooFewCables) {
  RobotModel model = testing::mini_robot();
  model.frame_anchors.conservativeResize(3, 4);
  EXPECT_THAT(check(model), StartsWith("cables: a spatial robot needs at least 6 cables, got 4"));
}

TEST(ModelCheck, NonFiniteValuesNameTheirField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  RobotModel model = testing::mini_robot();
  model.frame_anchors(1, 2) = nan;
  EXPECT_THAT(check(model), StartsWith("cables[2].frame_anchor: expected finite numbers"));
  model = testing::mini_robot();
  model.platform_anchors(0, 7) = inf;
  EXPECT_THAT(check(model), StartsWith("cables[7].platform_anchor: expected finite numbers"));
  model = testing::mini_robot();
  model.cables[5].mass_per_length = nan;
  EXPECT_THAT(check(model), StartsWith("cables[5].mass_per_length: expected finite numbers"));
  model = testing::mini_robot();
  model.platform.center_of_mass.x() = nan;
  EXPECT_THAT(check(model), StartsWith("platform.center_of_mass: expected finite numbers"));
  model = testing::mini_robot();
  model.home.rpy.z() = inf;
  EXPECT_THAT(check(model), StartsWith("home.rpy: expected finite numbers"));
  model = testing::mini_robot();
  model.pulleys[3].frame(0, 0) = nan;
  EXPECT_THAT(check(model), StartsWith("cables[3].pulley: expected finite numbers"));
}

TEST(ModelCheck, CablePhysics) {
  RobotModel model = testing::mini_robot();
  model.cables[3].ea = -5.0;
  EXPECT_EQ(check(model), "cables[3].ea: expected a positive number (N), got -5");
  model = testing::mini_robot();
  model.cables[0].ea = 0.0;
  EXPECT_THAT(check(model), StartsWith("cables[0].ea: expected a positive number (N), got 0"));
  model = testing::mini_robot();
  model.winches[6].drum_diameter = 0.0;
  EXPECT_THAT(check(model), StartsWith("cables[6].winch.drum_diameter: expected a positive"));
  model = testing::mini_robot();
  model.winches[6].direction = 0;
  EXPECT_THAT(check(model), StartsWith("cables[6].winch.direction: expected 1 or -1, got 0"));
  model = testing::mini_robot();
  model.cables[1].f_min = 300.0;
  EXPECT_THAT(check(model), StartsWith("cables[1].f_min: the minimum tension 300 N is above the "
                                       "maximum f_max = 200 N"));
  model = testing::mini_robot();
  model.cables[2].elongation = ElongationKind::kPolynomial;
  model.cables[2].polynomial.order = 2;
  model.cables[2].polynomial.coefficients = {1.0, 2.0};
  EXPECT_THAT(check(model),
              StartsWith("cables[2].elongation.coefficients: order 2 needs 6 coefficients, got 2"));
  model.cables[2].polynomial.coefficients.assign(6, 0.0);
  model.cables[2].polynomial.length_scale = 0.0;
  EXPECT_THAT(check(model), StartsWith("cables[2].elongation.length_scale: expected a positive"));
  model = testing::mini_robot();
  model.force_sensors[4].gain = 0.0;
  EXPECT_THAT(check(model), StartsWith("cables[4].force_sensor.gain: expected a non-zero"));
}

TEST(ModelCheck, PulleyFrameMustBeARightHandedOrthonormalFrame) {
  RobotModel model = testing::mini_robot();
  model.pulleys[5].frame.col(0) *= 1.01;  // not unit
  EXPECT_THAT(check(model), StartsWith("cables[5].pulley: the pulley frame"));
  model = testing::mini_robot();
  model.pulleys[5].frame.col(1) *= -1.0;  // left-handed
  EXPECT_THAT(check(model), StartsWith("cables[5].pulley: the pulley frame"));
  model = testing::mini_robot();
  model.pulleys[5].frame.col(0) = model.pulleys[5].frame.col(2);  // two equal columns
  EXPECT_THAT(check(model), StartsWith("cables[5].pulley: the pulley frame"));
}

TEST(ModelCheck, Lasers) {
  RobotModel model = testing::mini_robot();
  model.lasers.push_back({});
  EXPECT_TRUE(check_model(model).ok()) << check_model(model).to_string();
  model.lasers[0].direction = Eigen::Vector3d::Zero();
  EXPECT_THAT(check(model), StartsWith("lasers[0].direction: expected a unit vector"));
  model.lasers[0].direction = Eigen::Vector3d(0.0, 0.0, -0.9);
  EXPECT_THAT(check(model), StartsWith("lasers[0].direction: expected a unit vector"));
  model.lasers[0].direction = -Eigen::Vector3d::UnitZ();
  model.lasers[0].plane_normal = Eigen::Vector3d(0.0, 0.0, 2.0);
  EXPECT_THAT(check(model), StartsWith("lasers[0].plane_normal: expected a unit vector"));
  model.lasers[0].plane_normal = Eigen::Vector3d::UnitZ();
  model.lasers[0].range_min = 2.0;
  model.lasers[0].range_max = 1.0;
  EXPECT_THAT(check(model), StartsWith("lasers[0].range: expected [min, max]"));
}

TEST(ModelCheck, PlatformMassAndInertia) {
  RobotModel model = testing::mini_robot();
  model.platform.mass = 0.0;
  EXPECT_THAT(check(model), StartsWith("platform.mass: expected a positive number (kg)"));
  model = testing::mini_robot();
  model.platform.inertia(0, 1) = 0.5;
  EXPECT_THAT(check(model), StartsWith("platform.inertia: expected a symmetric matrix"));
  model.platform.inertia(1, 0) = 0.5;  // symmetric, but indefinite
  EXPECT_THAT(check(model), StartsWith("platform.inertia: expected a positive definite"));
}

TEST(ModelCheck, SingularStructureMatrixAtHome) {
  // All platform anchors at the platform origin: no cable exerts a moment, rank 3.
  RobotModel model = testing::mini_robot();
  model.platform_anchors.setZero();
  EXPECT_THAT(check(model), StartsWith("cables: the structure matrix at the home pose has rank 3"));
  // All platform anchors on the x axis: nothing resists a roll, rank 5.
  model = testing::mini_robot(false);
  model.platform_anchors.row(1).setZero();
  model.platform_anchors.row(2).setZero();
  EXPECT_THAT(check(model), StartsWith("cables: the structure matrix at the home pose has rank 5"));
  // Nearly on the x axis: full rank but badly conditioned.
  model.platform_anchors.row(1) = testing::mini_robot(false).platform_anchors.row(1) * 1e-5;
  EXPECT_THAT(check(model), StartsWith("cables: the structure matrix at the home pose is badly "
                                       "conditioned"));
}

TEST(ModelCheck, DegenerateCableAtHome) {
  RobotModel model = testing::mini_robot(false);
  model.home.position = model.frame_anchors.col(4) - model.platform_anchors.col(4);
  EXPECT_THAT(check(model), StartsWith("cables[4].frame_anchor: at the home pose the platform "
                                       "anchor lies on the frame anchor"));
}

// Issue 18: a suspended robot with fewer than six cables (the 4-cable crane).
TEST(ModelCheck, SuspendedCraneWithFourCablesPassesWhenItHangsAtHome) {
  for (bool pulleys : {false, true}) {
    const RobotModel crane = testing::crane_robot(pulleys);
    EXPECT_TRUE(check_model(crane).ok()) << check_model(crane).to_string();
  }
}

TEST(ModelCheck, FourCablesAreRefusedUnlessSuspendedAndTheMessageSaysHow) {
  RobotModel crane = testing::crane_robot();
  crane.suspended = false;
  const std::string msg = check(crane);
  EXPECT_THAT(msg, HasSubstr("at least 6 cables, got 4"));
  EXPECT_THAT(msg, HasSubstr("suspended: true"));
}

TEST(ModelCheck, SuspendedCraneNotInEquilibriumAtHomeNamesTheHangingAttitude) {
  RobotModel crane = testing::crane_robot();
  crane.home.rpy.x() = 0.1;  // tilted: the four cables cannot hold it there
  const std::string msg = check(crane);
  EXPECT_THAT(msg, StartsWith("home.rpy: a suspended robot with 4 cables must be in static "
                              "equilibrium at home"));
  EXPECT_THAT(msg, HasSubstr("it would hang at rpy"));
}

TEST(ModelCheck, SuspendedCraneWhoseCablesWouldPushAtHomeIsRefused) {
  RobotModel crane = testing::crane_robot();
  crane.home.position.z() = 2.5;  // above the anchors: the cables would have to push
  const std::string msg = check(crane);
  EXPECT_THAT(msg, HasSubstr("would have to push"));
}

TEST(ModelCheck, SuspendedCraneOverloadedAtHomeNamesTheTensionLimit) {
  RobotModel crane = testing::crane_robot();
  crane.platform.mass = 200.0;  // about 500 N per cable, f_max is 300 N
  const std::string msg = check(crane);
  EXPECT_THAT(msg, StartsWith("cables[0]: hanging at home needs"));
  EXPECT_THAT(msg, HasSubstr("[f_min, f_max]"));
}

// Issue 41: a calibrated crane whose geometry leaves a cable below f_min at home (diagnose --out
// wrote "hanging at home needs 8.381 N, outside [f_min, f_max]" and its own loader refused it):
// the platform hangs there on its own, so the config loads.
TEST(ModelCheck, SuspendedCraneHangingBelowFMinAtHomeIsAccepted) {
  RobotModel crane = testing::crane_robot();
  for (CableModel& c : crane.cables) c.f_min = 60.0;  // every cable hangs at about 53 N
  const Status s = check_model(crane);
  EXPECT_TRUE(s.ok()) << s.to_string();
}

TEST(ModelCheck, SuspendedRobotNeedsThreeCables) {
  RobotModel crane = testing::crane_robot();
  crane.frame_anchors.conservativeResize(3, 2);
  crane.platform_anchors.conservativeResize(3, 2);
  crane.pulleys.resize(2);
  crane.winches.resize(2);
  crane.cables.resize(2);
  crane.force_sensors.resize(2);
  EXPECT_THAT(check(crane), HasSubstr("at least 3 cables, got 2"));
}

}  // namespace
}  // namespace cdpr
