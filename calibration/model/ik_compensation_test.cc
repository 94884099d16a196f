#include "cdpr/calibration/ik_compensation.hpp"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <random>

#include "alloc_counter.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

TEST(IkCompensation, RigidCablesCommandTheKinematicLength) {
  RobotModel model = testing::mini_robot(true);
  for (CableModel& c : model.cables) c.elongation = ElongationKind::kRigid;
  const Pose pose{Eigen::Vector3d(0.1, -0.05, 0.02), Eigen::Vector3d(0.1, 0.0, -0.1)};
  CableCommandData data(model);
  ASSERT_TRUE(
      inverse_kinematics_compensated(model, pose, Eigen::VectorXd::Constant(8, 80.0), data));
  KinematicsData ik(model);
  ASSERT_TRUE(inverse_kinematics(model, pose, ik));
  for (int i = 0; i < 8; ++i) {
    EXPECT_EQ(data.length_commands(i), ik.lengths(i));
    EXPECT_EQ(data.elongations(i), 0.0);
    EXPECT_NEAR(data.counts(i), ik.lengths(i) / winch_metres_per_count(model.winches[0]), 1e-6);
  }
}

TEST(IkCompensation, HookeCommandsAreTheUnstretchedLengths) {
  RobotModel model = testing::mini_robot(true);
  model.winches[3].length_offset = 0.7;
  model.winches[5].direction = -1;
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<double> tension(5.0, 200.0);
  CableCommandData data(model);
  Eigen::VectorXd f(8);
  for (int k = 0; k < 100; ++k) {
    const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
    for (int i = 0; i < 8; ++i) f(i) = tension(rng);
    ASSERT_TRUE(inverse_kinematics_compensated(model, pose, f, data));
    for (int i = 0; i < 8; ++i) {
      const CableModel& c = model.cables[static_cast<std::size_t>(i)];
      const WinchModel& w = model.winches[static_cast<std::size_t>(i)];
      // Whole cable: unstretched (command + routing) times (1 + F / EA) is the loaded length.
      EXPECT_NEAR((data.length_commands(i) + c.routing_length) * (1.0 + f(i) / c.ea),
                  data.loaded_lengths(i), 1e-15);
      EXPECT_NEAR(data.loaded_lengths(i), data.kinematics.lengths(i) + c.routing_length, 1e-15);
      EXPECT_GT(data.elongations(i), 0.0);
      // The counts bring the winch to the command.
      EXPECT_NEAR(winch_counts_to_length(w, data.counts(i)), data.length_commands(i), 1e-13);
      EXPECT_EQ(data.counts_rounded(i), std::llround(data.counts(i)));
    }
  }
}

TEST(IkCompensation, LengthCommandDifferentiatesThroughJet) {
  using Jet = ceres::Jet<double, 2>;
  CableModel c;
  c.ea = 2e4;
  c.routing_length = 0.5;
  const double lk = 0.8, f = 120.0;
  const Jet cmd = cable_length_command<Jet>(c, Jet(lk, 0), Jet(f, 1));
  const double h = 1e-6;
  EXPECT_NEAR(cmd.a, cable_length_command<double>(c, lk, f), 1e-16);
  EXPECT_NEAR(
      cmd.v(0),
      (cable_length_command<double>(c, lk + h, f) - cable_length_command<double>(c, lk - h, f)) /
          (2 * h),
      1e-9);
  EXPECT_NEAR(
      cmd.v(1),
      (cable_length_command<double>(c, lk, f + h) - cable_length_command<double>(c, lk, f - h)) /
          (2 * h),
      1e-9);
}

TEST(IkCompensation, DoesNotAllocate) {
  RobotModel model = testing::mini_robot(true);
  CableCommandData data(model);
  const Eigen::VectorXd f = Eigen::VectorXd::Constant(8, 60.0);
  const Pose pose{Eigen::Vector3d(0.02, 0.03, -0.01), Eigen::Vector3d(0.05, 0.02, 0.1)};
  std::uint64_t allocations = 0;
  for (const ElongationKind kind :
       {ElongationKind::kRigid, ElongationKind::kHooke, ElongationKind::kPolynomial}) {
    for (CableModel& c : model.cables) {
      c.elongation = kind;
      c.polynomial.order = 2;
      c.polynomial.coefficients = {1e-3, 2e-3, 3e-3, 1e-4, 2e-4, 3e-4};
    }
    const cdpr::test::AllocationCounter count;
    for (int k = 0; k < 100; ++k) ASSERT_TRUE(inverse_kinematics_compensated(model, pose, f, data));
    allocations += count.allocations();
  }
  EXPECT_EQ(allocations, 0u);
}

}  // namespace
}  // namespace cdpr
