#include "cdpr/calibration/suspended_statics.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>
#include <string>

#include "cdpr/calibration/elastostatics.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

using ::testing::HasSubstr;

// Targets spread over the crane's workspace (positions well inside the anchors' footprint).
std::vector<Pose> crane_targets(int count, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Pose> out;
  for (int k = 0; k < count; ++k) {
    Pose p;
    p.position = Eigen::Vector3d(0.3 * u(rng), 0.35 * u(rng), 0.8 + 0.3 * u(rng));
    p.rpy = Eigen::Vector3d(0.0, 0.0, 0.03 * u(rng));
    out.push_back(p);
  }
  return out;
}

double wrench_imbalance(const RobotModel& model, const SuspendedState& s) {
  KinematicsData kin(model);
  EXPECT_TRUE(inverse_kinematics(model, s.pose, kin));
  const Eigen::Matrix<double, 6, 1> w =
      kin.structure_matrix * s.tensions + gravity_wrench(model, kin.rotation);
  return w.cwiseAbs().maxCoeff();
}

TEST(SuspendedStatics, EquilibriumPoseKeepsPositionAndYawAndBalancesGravityWithPositiveTensions) {
  for (bool pulleys : {false, true}) {
    const RobotModel crane = testing::crane_robot(pulleys);
    for (const Pose& target : crane_targets(20, 7)) {
      const Result<SuspendedState> s = suspended_equilibrium_pose(crane, target);
      ASSERT_TRUE(s.ok()) << s.status().to_string();
      EXPECT_EQ(s->pose.position, target.position);
      EXPECT_EQ(s->pose.rpy.z(), target.rpy.z());
      EXPECT_LT(wrench_imbalance(crane, *s), 1e-9 * crane.platform.mass * crane.gravity);
      EXPECT_GT(s->tensions.minCoeff(), 0.0);
      // Off centre the platform tilts: the equilibrium chose roll and pitch.
      EXPECT_TRUE(s->pose.rpy.head<2>().allFinite());
    }
  }
}

TEST(SuspendedStatics, RigidRoundTripPoseToLengthsToPoseIsExact) {
  for (bool pulleys : {false, true}) {
    const RobotModel crane = testing::crane_robot(pulleys);
    for (const Pose& target : crane_targets(20, 11)) {
      const Result<SuspendedState> truth = suspended_equilibrium_pose(crane, target);
      ASSERT_TRUE(truth.ok()) << truth.status().to_string();
      KinematicsData kin(crane);
      ASSERT_TRUE(inverse_kinematics(crane, truth->pose, kin));
      const Result<SuspendedState> fk = forward_kinematics_suspended(crane, kin.lengths);
      ASSERT_TRUE(fk.ok()) << fk.status().to_string();
      EXPECT_LT((fk->pose.position - truth->pose.position).cwiseAbs().maxCoeff(), 1e-9);
      EXPECT_LT((fk->rotation - truth->rotation).cwiseAbs().maxCoeff(), 1e-9);
      EXPECT_LT((fk->tensions - truth->tensions).cwiseAbs().maxCoeff(), 1e-7);
      EXPECT_GT(fk->tensions.minCoeff(), 0.0);
      EXPECT_LT((fk->lengths - kin.lengths).cwiseAbs().maxCoeff(), 1e-11);
    }
  }
}

TEST(SuspendedStatics, ElasticForwardKinematicsMatchesTheElastostaticModel) {
  const RobotModel crane = testing::crane_robot();
  for (const Pose& target : crane_targets(8, 3)) {
    const Result<SuspendedState> truth = suspended_equilibrium_pose(crane, target);
    ASSERT_TRUE(truth.ok()) << truth.status().to_string();
    // Unstretched commands that put the elastic platform exactly at the equilibrium pose:
    // l = L - F (routing + l) / EA  ->  l = (L - F routing / EA) / (1 + F / EA).
    Eigen::VectorXd commands(4);
    for (int i = 0; i < 4; ++i) {
      const CableModel& c = crane.cables[static_cast<std::size_t>(i)];
      const double F = truth->tensions(i);
      commands(i) = (truth->lengths(i) - F * c.routing_length / c.ea) / (1.0 + F / c.ea);
    }
    const Result<SuspendedState> fk = forward_kinematics_suspended_elastic(crane, commands);
    ASSERT_TRUE(fk.ok()) << fk.status().to_string();
    EXPECT_LT((fk->pose.position - truth->pose.position).cwiseAbs().maxCoeff(), 1e-8);
    EXPECT_LT((fk->pose.rpy - truth->pose.rpy).cwiseAbs().maxCoeff(), 1e-8);
    EXPECT_LT((fk->tensions - truth->tensions).cwiseAbs().maxCoeff(), 1e-5);
  }
}

TEST(SuspendedStatics, PoseOutsideTheAnchorsCannotHangAndIsRefusedWithAValue) {
  const RobotModel crane = testing::crane_robot();
  Pose outside;
  outside.position = Eigen::Vector3d(1.6, 0.0, 0.8);  // beyond the +x anchors (x = 1.0)
  const Result<SuspendedState> s = suspended_equilibrium_pose(crane, outside);
  ASSERT_FALSE(s.ok());
  EXPECT_THAT(std::string(s.status().message()), HasSubstr("cannot hang"));

  Pose above;
  above.position = Eigen::Vector3d(0.0, 0.0, 2.3);  // above the anchors: cables would push
  const Result<SuspendedState> t = suspended_equilibrium_pose(crane, above);
  ASSERT_FALSE(t.ok());
  EXPECT_EQ(t.status().code(), ErrorCode::kOutOfRange);
}

TEST(SuspendedStatics, LengthsNoPoseCanHangOnAreRefusedWithAValue) {
  const RobotModel crane = testing::crane_robot();
  KinematicsData kin(crane);
  ASSERT_TRUE(inverse_kinematics(crane, crane.home, kin));
  Eigen::VectorXd lengths = kin.lengths;
  lengths(0) += 1.5;  // far too long: cable 1 would be slack, the platform hangs on three
  const Result<SuspendedState> s = forward_kinematics_suspended(crane, lengths);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().code(), ErrorCode::kOk);

  const Eigen::VectorXd wrong_size = Eigen::VectorXd::Ones(3);
  EXPECT_EQ(forward_kinematics_suspended(crane, wrong_size).status().code(),
            ErrorCode::kInvalidArgument);
  Eigen::VectorXd nan = kin.lengths;
  nan(2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(forward_kinematics_suspended(crane, nan).status().code(), ErrorCode::kInvalidArgument);
}

TEST(SuspendedStatics, HomeOfTheCraneIsAnEquilibriumWithEqualTensions) {
  const RobotModel crane = testing::crane_robot();
  const Result<SuspendedState> s = suspended_tensions(crane, crane.home);
  ASSERT_TRUE(s.ok());
  EXPECT_LT(s->wrench_residual, 1e-9);
  // By symmetry every cable carries a quarter of the weight along its own direction.
  KinematicsData kin(crane);
  ASSERT_TRUE(inverse_kinematics(crane, crane.home, kin));
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(s->tensions(i) * kin.unit_vectors(2, i), crane.platform.mass * crane.gravity / 4,
                1e-9);
  }
}

}  // namespace
}  // namespace cdpr
