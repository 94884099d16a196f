#include "cdpr/calibration/forward_kinematics.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "alloc_counter.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

// Largest displacement of a platform anchor between two poses: position and rotation in metres.
double pose_error(const RobotModel& model, const Pose& a, const Eigen::Matrix3d& rb,
                  const Eigen::Vector3d& pb) {
  const Eigen::Matrix3d ra = rotation_from_rpy<double>(a.rpy);
  double e = 0.0;
  for (int i = 0; i < model.num_cables(); ++i) {
    const Eigen::Vector3d b = model.platform_anchors.col(i);
    e = std::max(e, ((a.position + ra * b) - (pb + rb * b)).norm());
  }
  return e;
}

struct RoundTripStats {
  int failures = 0;
  int max_iterations = 0;
  double max_position_error = 0.0;  // m
  double max_anchor_error = 0.0;    // m
};

RoundTripStats round_trip(const RobotModel& model, const testing::WorkspaceBox& box, int poses,
                          bool elastic, std::uint64_t seed) {
  RoundTripStats st;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> tension(model.cables[0].f_min, model.cables[0].f_max);
  KinematicsData ik(model);
  CableCommandData commands(model);
  ForwardKinematicsData fk(model);
  Eigen::VectorXd tensions(model.num_cables());
  const ForwardKinematicsOptions options;  // from home
  for (int k = 0; k < poses; ++k) {
    const Pose pose = testing::random_pose(box, rng);
    ForwardKinematicsSummary s;
    if (elastic) {
      for (int i = 0; i < model.num_cables(); ++i) tensions(i) = tension(rng);
      EXPECT_TRUE(inverse_kinematics_compensated(model, pose, tensions, commands));
      s = forward_kinematics_elastic(model, commands.length_commands, tensions, options, fk);
    } else {
      EXPECT_TRUE(inverse_kinematics(model, pose, ik));
      s = forward_kinematics(model, ik.lengths, options, fk);
    }
    if (!s.success()) {
      ++st.failures;
      ADD_FAILURE() << model.name << " pose " << k << ": " << s.status.to_string();
      continue;
    }
    st.max_iterations = std::max(st.max_iterations, s.iterations);
    st.max_position_error =
        std::max(st.max_position_error, (s.pose.position - pose.position).norm());
    st.max_anchor_error =
        std::max(st.max_anchor_error,
                 pose_error(model, s.pose, rotation_from_rpy<double>(pose.rpy), pose.position));
  }
  return st;
}

struct RobotCase {
  std::string label;
  RobotModel model;
  testing::WorkspaceBox box;
};

std::vector<RobotCase> robot_cases() {
  return {{"MINI point anchors", testing::mini_robot(false), testing::mini_workspace()},
          {"MINI pulleys", testing::mini_robot(true), testing::mini_workspace()},
          {"LARGE point anchors", testing::large_robot(false), testing::large_workspace()},
          {"LARGE pulleys", testing::large_robot(true), testing::large_workspace()}};
}

// Acceptance: FK(IK(x)) == x to 1e-9 m over thousands of random workspace poses, from home.
TEST(ForwardKinematics, RecoversIkPosesAcrossTheWorkspace) {
  for (const RobotCase& c : robot_cases()) {
    const RoundTripStats st = round_trip(c.model, c.box, 3000, /*elastic=*/false, 42);
    EXPECT_EQ(st.failures, 0) << c.label;
    EXPECT_LT(st.max_position_error, 1e-9) << c.label;
    EXPECT_LT(st.max_anchor_error, 1e-9) << c.label;
    RecordProperty(c.label + " max anchor error (m)", std::to_string(st.max_anchor_error));
    RecordProperty(c.label + " max iterations", st.max_iterations);
    std::printf("%-22s rigid:  max anchor error %.2e m, max iterations %d\n", c.label.c_str(),
                st.max_anchor_error, st.max_iterations);
  }
}

TEST(ForwardKinematics, RecoversCompensatedIkPosesWithHookeCables) {
  for (const RobotCase& c : robot_cases()) {
    const RoundTripStats st = round_trip(c.model, c.box, 1000, /*elastic=*/true, 43);
    EXPECT_EQ(st.failures, 0) << c.label;
    EXPECT_LT(st.max_anchor_error, 1e-9) << c.label;
    std::printf("%-22s Hooke:  max anchor error %.2e m, max iterations %d\n", c.label.c_str(),
                st.max_anchor_error, st.max_iterations);
  }
}

TEST(ForwardKinematics, RecoversCompensatedIkPosesWithPolynomialCables) {
  RobotModel model = testing::mini_robot(true);
  // A stiffening cable: dL = F L / EA (1 - F / 1000) + 1e-6 F, written as a polynomial in
  // scaled variables (centre 1 m, 100 N; scales 0.5 m, 100 N).
  PolynomialSurface p;
  p.order = 3;
  p.length_center = 1.0;
  p.length_scale = 0.5;
  p.tension_center = 100.0;
  p.tension_scale = 100.0;
  p.coefficients.assign(static_cast<std::size_t>(polynomial_surface_size(3)), 0.0);
  p.coefficients[0] = 4e-3;
  p.coefficients[1] = 2e-3;    // s
  p.coefficients[2] = 3.5e-3;  // t
  p.coefficients[4] = 1.5e-3;  // s t
  p.coefficients[5] = -5e-4;   // t^2
  p.coefficients[8] = -2e-4;   // s t^2
  for (CableModel& cable : model.cables) {
    cable.elongation = ElongationKind::kPolynomial;
    cable.polynomial = p;
  }
  const RoundTripStats st = round_trip(model, testing::mini_workspace(), 500, true, 44);
  EXPECT_EQ(st.failures, 0);
  EXPECT_LT(st.max_anchor_error, 1e-9);
}

TEST(ForwardKinematics, ElongationIsCompensatedNotIgnored) {
  // Feeding the unstretched commands to the rigid FK lands elsewhere: the compensation matters.
  const RobotModel model = testing::mini_robot(true);
  const Pose pose{Eigen::Vector3d(0.05, 0.03, -0.04), Eigen::Vector3d(0.05, 0.0, 0.1)};
  Eigen::VectorXd tensions = Eigen::VectorXd::Constant(8, 100.0);
  CableCommandData commands(model);
  ASSERT_TRUE(inverse_kinematics_compensated(model, pose, tensions, commands));
  ForwardKinematicsData fk(model);
  ForwardKinematicsOptions options;
  options.max_residual = std::numeric_limits<double>::infinity();
  const ForwardKinematicsSummary rigid =
      forward_kinematics(model, commands.length_commands, options, fk);
  const ForwardKinematicsSummary elastic =
      forward_kinematics_elastic(model, commands.length_commands, tensions, options, fk);
  ASSERT_TRUE(elastic.success()) << elastic.status.to_string();
  EXPECT_LT((elastic.pose.position - pose.position).norm(), 1e-10);
  // dL ~ F L / EA ~ 100 * 1.1 / 2e4 = 5.5 mm per cable: a millimetre-scale pose error.
  EXPECT_GT((rigid.pose.position - pose.position).norm(), 1e-3);
  for (int i = 0; i < 8; ++i) {
    EXPECT_NEAR(fk.elongations(i), commands.elongations(i), 1e-12);
  }
}

TEST(ForwardKinematics, InconsistentLengthsGiveTheLeastSquaresPoseAndSaySo) {
  const RobotModel model = testing::mini_robot(true);
  KinematicsData ik(model);
  ASSERT_TRUE(inverse_kinematics(
      model, Pose{Eigen::Vector3d(0.02, 0.0, 0.05), Eigen::Vector3d::Zero()}, ik));
  Eigen::VectorXd lengths = ik.lengths;
  lengths(5) += 0.005;  // 5 mm: no pose has these lengths
  ForwardKinematicsData fk(model);
  ForwardKinematicsOptions options;
  options.max_residual = 1e-3;
  ForwardKinematicsSummary s = forward_kinematics(model, lengths, options, fk);
  EXPECT_EQ(s.termination, ForwardKinematicsTermination::kInconsistentLengths);
  EXPECT_FALSE(s.success());
  EXPECT_FALSE(s.status.ok());
  EXPECT_NE(s.status.message().find("inconsistent"), std::string_view::npos);
  EXPECT_GT(s.max_abs_residual, 1e-3);

  options.max_residual = std::numeric_limits<double>::infinity();
  s = forward_kinematics(model, lengths, options, fk);
  ASSERT_TRUE(s.success()) << s.status.to_string();
  // A least-squares minimum: the gradient A^T r vanishes, the residuals do not.
  KinematicsData at(model);
  ASSERT_TRUE(inverse_kinematics(model, s.pose, at));
  const Eigen::VectorXd r = at.lengths - lengths;
  EXPECT_LT((at.structure_matrix * r).norm(), 1e-8 * r.norm());
  EXPECT_GT(r.norm(), 1e-3);
  EXPECT_LT((r - fk.residuals).norm(), 1e-12);
  EXPECT_NEAR(s.max_abs_residual, fk.residuals.cwiseAbs().maxCoeff(), 1e-15);
}

TEST(ForwardKinematics, ReportsWhyItFails) {
  const RobotModel model = testing::mini_robot(true);
  KinematicsData ik(model);
  ASSERT_TRUE(inverse_kinematics(
      model, Pose{Eigen::Vector3d(0.15, -0.15, 0.15), Eigen::Vector3d(0.2, -0.2, 0.2)}, ik));
  ForwardKinematicsData fk(model);
  ForwardKinematicsOptions options;

  options.max_iterations = 1;
  ForwardKinematicsSummary s = forward_kinematics(model, ik.lengths, options, fk);
  EXPECT_EQ(s.termination, ForwardKinematicsTermination::kMaxIterations);
  EXPECT_EQ(s.status.code(), ErrorCode::kNumericalFailure);
  EXPECT_NE(s.status.message().find("did not converge in max_iterations 1"), std::string_view::npos)
      << s.status.message();

  options = {};
  const Eigen::VectorXd short_lengths = ik.lengths.head(7);
  s = forward_kinematics(model, short_lengths, options, fk);
  EXPECT_EQ(s.termination, ForwardKinematicsTermination::kInvalidInput);
  EXPECT_EQ(s.status.code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(s.status.message().find("7 lengths given for 8 cables"), std::string_view::npos);

  Eigen::VectorXd bad = ik.lengths;
  bad(2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(forward_kinematics(model, bad, options, fk).termination,
            ForwardKinematicsTermination::kInvalidInput);
  bad(2) = -1.0;
  EXPECT_EQ(forward_kinematics(model, bad, options, fk).termination,
            ForwardKinematicsTermination::kInvalidInput);

  // Start with platform anchor 0 inside its pulley (on D).
  options.initial_pose =
      Pose{model.frame_anchors.col(0) - model.platform_anchors.col(0), Eigen::Vector3d::Zero()};
  s = forward_kinematics(model, ik.lengths, options, fk);
  EXPECT_EQ(s.termination, ForwardKinematicsTermination::kDegenerateGeometry);
  EXPECT_NE(s.status.message().find("cable 0"), std::string_view::npos);

  // Lengths no pose of this robot can have (every cable 3 m): it says so.
  options = {};
  s = forward_kinematics(model, Eigen::VectorXd::Constant(8, 3.0), options, fk);
  EXPECT_FALSE(s.success());
  EXPECT_FALSE(s.status.ok());

  // Wrong workspace size.
  ForwardKinematicsData small(6);
  EXPECT_EQ(forward_kinematics(model, ik.lengths, options, small).termination,
            ForwardKinematicsTermination::kInvalidInput);
}

TEST(ForwardKinematics, StartsFromTheGivenInitialPose) {
  const RobotModel model = testing::large_robot(true);
  const Pose target{Eigen::Vector3d(3.0, -2.0, 0.5), Eigen::Vector3d(0.1, 0.05, -0.2)};
  KinematicsData ik(model);
  ASSERT_TRUE(inverse_kinematics(model, target, ik));
  ForwardKinematicsData fk(model);
  ForwardKinematicsOptions from_home;
  ForwardKinematicsOptions nearby;
  nearby.initial_pose = Pose{target.position + Eigen::Vector3d(0.01, 0.0, 0.0), target.rpy};
  const ForwardKinematicsSummary a = forward_kinematics(model, ik.lengths, from_home, fk);
  const ForwardKinematicsSummary b = forward_kinematics(model, ik.lengths, nearby, fk);
  ASSERT_TRUE(a.success());
  ASSERT_TRUE(b.success());
  EXPECT_LT(b.iterations, a.iterations);
  EXPECT_LT((b.pose.position - target.position).norm(), 1e-9);
}

TEST(ForwardKinematics, RepeatedCallsDoNotAllocate) {
  const RobotModel model = testing::mini_robot(true);
  std::mt19937_64 rng(1);
  std::vector<Eigen::VectorXd> lengths;
  std::vector<Eigen::VectorXd> commands;
  const Eigen::VectorXd tensions = Eigen::VectorXd::Constant(8, 50.0);
  CableCommandData ik(model);
  for (int k = 0; k < 20; ++k) {
    const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
    ASSERT_TRUE(inverse_kinematics_compensated(model, pose, tensions, ik));
    lengths.push_back(ik.kinematics.lengths);
    commands.push_back(ik.length_commands);
  }
  ForwardKinematicsData fk(model);
  const ForwardKinematicsOptions options;
  int converged = 0;
  const cdpr::test::AllocationCounter count;
  for (std::size_t k = 0; k < lengths.size(); ++k) {
    converged += forward_kinematics(model, lengths[k], options, fk).success() ? 1 : 0;
    converged +=
        forward_kinematics_elastic(model, commands[k], tensions, options, fk).success() ? 1 : 0;
  }
  // Failing solves (inconsistent lengths: all restarts run) do not allocate either.
  EXPECT_FALSE(forward_kinematics_elastic(model, lengths[0], tensions, options, fk).success());
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(converged, 40);
}

}  // namespace
}  // namespace cdpr
