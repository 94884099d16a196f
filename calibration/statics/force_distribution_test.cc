#include "cdpr/calibration/force_distribution.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>

#include "alloc_counter.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

ForceDistributionOptions with(ForceDistributionMethod method) {
  ForceDistributionOptions o;
  o.method = method;
  return o;
}

void expect_valid(const RobotModel& model, const ForceDistributionResult& r, double tol = 1e-8) {
  ASSERT_TRUE(r.feasible()) << r.status.to_string();
  ASSERT_EQ(r.tensions.size(), model.num_cables());
  for (int i = 0; i < model.num_cables(); ++i) {
    EXPECT_GE(r.tensions(i), model.cables[static_cast<std::size_t>(i)].f_min - tol) << i;
    EXPECT_LE(r.tensions(i), model.cables[static_cast<std::size_t>(i)].f_max + tol) << i;
  }
  EXPECT_LT(r.balance_residual, 1e-9);
}

double distance_to_reference(const RobotModel& model, const CableVector& f) {
  double s = 0.0;
  for (int i = 0; i < model.num_cables(); ++i) {
    const CableModel& c = model.cables[static_cast<std::size_t>(i)];
    s += std::pow(f(i) - 0.5 * (c.f_min + c.f_max), 2);
  }
  return std::sqrt(s);
}

TEST(ForceDistribution, MiniAtHomeBothMethodsBalanceTheWeight) {
  const RobotModel model = testing::mini_robot();
  ForceDistributionData data(model);
  for (auto method :
       {ForceDistributionMethod::kClosedForm, ForceDistributionMethod::kQuadraticProgram}) {
    const ForceDistributionResult r = distribute_forces(model, model.home, with(method), data);
    expect_valid(model, r);
    // Independent balance check with the structure matrix and the weight.
    KinematicsData kin(model);
    ASSERT_TRUE(inverse_kinematics(model, model.home, kin));
    const Wrench6 w = kin.structure_matrix * r.tensions;
    EXPECT_NEAR(w(2), model.platform.mass * model.gravity, 1e-9);
    EXPECT_NEAR(w.head<2>().norm(), 0.0, 1e-9);
    // Top cables carry more than bottom ones (they hold the weight).
    EXPECT_GT(r.tensions.tail<4>().sum(), r.tensions.head<4>().sum());
  }
}

// When nothing is clipped, both methods give the least-norm correction: the same tensions.
TEST(ForceDistribution, MethodsAgreeWhenNoLimitIsActive) {
  const RobotModel model = testing::mini_robot();
  ForceDistributionData data(model);
  const ForceDistributionResult cf =
      distribute_forces(model, model.home, with(ForceDistributionMethod::kClosedForm), data);
  const ForceDistributionResult qp =
      distribute_forces(model, model.home, with(ForceDistributionMethod::kQuadraticProgram), data);
  ASSERT_TRUE(cf.feasible());
  ASSERT_TRUE(qp.feasible());
  ASSERT_EQ(cf.cables_at_limits, 0);
  EXPECT_LT((cf.tensions - qp.tensions).cwiseAbs().maxCoeff(), 1e-9);
}

// The QP is exact: where the closed form finds tensions the QP does too, never farther from the
// reference, and no feasible null-space move gets closer to the reference.
TEST(ForceDistribution, QuadraticProgramIsOptimalOverTheWorkspace) {
  RobotModel model = testing::mini_robot();
  for (CableModel& c : model.cables) c.f_max = 60.0;  // tight limits: clipping is common
  testing::WorkspaceBox box = testing::mini_workspace();
  std::mt19937 rng(3);
  std::normal_distribution<double> normal(0.0, 1.0);
  ForceDistributionData data(model);
  int both = 0, qp_only = 0, clipped = 0;
  for (int k = 0; k < 300; ++k) {
    const Pose pose = testing::random_pose(box, rng);
    const ForceDistributionResult cf =
        distribute_forces(model, pose, with(ForceDistributionMethod::kClosedForm), data);
    const ForceDistributionResult qp =
        distribute_forces(model, pose, with(ForceDistributionMethod::kQuadraticProgram), data);
    if (cf.feasible()) {
      ASSERT_TRUE(qp.feasible()) << "closed form found tensions the QP missed: "
                                 << qp.status.to_string();
      EXPECT_LE(distance_to_reference(model, qp.tensions),
                distance_to_reference(model, cf.tensions) + 1e-7);
      ++both;
    } else if (qp.feasible()) {
      ++qp_only;
    }
    if (!qp.feasible()) {
      EXPECT_EQ(qp.outcome, ForceDistributionOutcome::kInfeasible) << qp.status.to_string();
      continue;
    }
    expect_valid(model, qp);
    clipped += qp.cables_at_limits > 0;
    // Random moves in the null space of the structure matrix that stay feasible are not better.
    const Eigen::MatrixXd At = data.kinematics.structure_matrix;
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(At.transpose(), Eigen::ComputeFullU);
    const Eigen::MatrixXd N = svd.matrixU().rightCols(model.num_cables() - 6);
    const double best = distance_to_reference(model, qp.tensions);
    for (int t = 0; t < 50; ++t) {
      Eigen::VectorXd dir(N.cols());
      for (int j = 0; j < dir.size(); ++j) dir(j) = normal(rng);
      const CableVector moved = qp.tensions + N * dir * 0.5;
      bool feasible = true;
      for (int i = 0; i < 8; ++i) feasible = feasible && moved(i) >= 5.0 && moved(i) <= 60.0;
      if (feasible) {
        EXPECT_GE(distance_to_reference(model, moved), best - 1e-9);
      }
    }
  }
  EXPECT_GT(both, 50);
  EXPECT_GT(clipped, 10);  // the limits were active often enough to test the active set
  RecordProperty("closed_form_and_qp", both);
  RecordProperty("qp_only", qp_only);
}

TEST(ForceDistribution, TooHeavyIsOutsideTheWrenchFeasibleWorkspace) {
  RobotModel model = testing::mini_robot();
  model.platform.mass = 500.0;  // 4.9 kN on 200 N cables
  ForceDistributionData data(model);
  const ForceDistributionResult qp =
      distribute_forces(model, model.home, with(ForceDistributionMethod::kQuadraticProgram), data);
  EXPECT_EQ(qp.outcome, ForceDistributionOutcome::kInfeasible);
  EXPECT_EQ(qp.status.code(), ErrorCode::kOutOfRange);
  EXPECT_THAT(std::string(qp.status.message()), ::testing::HasSubstr("wrench-feasible workspace"));
  const ForceDistributionResult cf =
      distribute_forces(model, model.home, with(ForceDistributionMethod::kClosedForm), data);
  EXPECT_FALSE(cf.feasible());
}

TEST(ForceDistribution, ExternalWrenchIsBalancedToo) {
  const RobotModel model = testing::mini_robot();
  ForceDistributionData data(model);
  ForceDistributionOptions options;
  options.external_wrench << 5.0, -3.0, 2.0, 0.1, 0.0, -0.2;
  const ForceDistributionResult r = distribute_forces(model, model.home, options, data);
  expect_valid(model, r);
  const Wrench6 w = data.kinematics.structure_matrix * r.tensions +
                    gravity_wrench(model, data.kinematics.rotation) + options.external_wrench;
  EXPECT_LT(w.cwiseAbs().maxCoeff(), 1e-9);
}

TEST(ForceDistribution, ReferenceTensionIsHonoured) {
  const RobotModel model = testing::mini_robot();
  ForceDistributionData data(model);
  ForceDistributionOptions low, high;
  low.reference_tension = 30.0;
  high.reference_tension = 120.0;
  const ForceDistributionResult a = distribute_forces(model, model.home, low, data);
  const ForceDistributionResult b = distribute_forces(model, model.home, high, data);
  expect_valid(model, a);
  expect_valid(model, b);
  // The difference lies in the null space: same wrench, more internal force.
  EXPECT_GT(b.tensions.minCoeff(), a.tensions.minCoeff() + 50.0);
}

TEST(ForceDistribution, SixCablesHaveOneSolution) {
  RobotModel model = testing::mini_robot(false);
  // Keep cables 1, 2, 3 (bottom) and 5, 6, 8 (top): a 6-cable robot.
  const int keep[6] = {0, 1, 2, 4, 5, 7};
  RobotModel six = model;
  six.frame_anchors.resize(3, 6);
  six.platform_anchors.resize(3, 6);
  six.pulleys.clear();
  six.winches.clear();
  six.cables.clear();
  six.force_sensors.clear();
  for (int k = 0; k < 6; ++k) {
    six.frame_anchors.col(k) = model.frame_anchors.col(keep[k]);
    six.platform_anchors.col(k) = model.platform_anchors.col(keep[k]);
    six.pulleys.push_back(model.pulleys[static_cast<std::size_t>(keep[k])]);
    six.winches.push_back(model.winches[static_cast<std::size_t>(keep[k])]);
    six.cables.push_back(model.cables[static_cast<std::size_t>(keep[k])]);
    six.force_sensors.push_back(model.force_sensors[static_cast<std::size_t>(keep[k])]);
  }
  for (CableModel& c : six.cables) c.f_min = -1e6;  // let the solution show, whatever its sign
  ForceDistributionData data(six);
  const ForceDistributionResult r = distribute_forces(six, six.home, {}, data);
  ASSERT_TRUE(r.feasible()) << r.status.to_string();
  KinematicsData kin(six);
  ASSERT_TRUE(inverse_kinematics(six, six.home, kin));
  const Eigen::Matrix<double, 6, 6> At = kin.structure_matrix;
  const Wrench6 exact = At.lu().solve(-gravity_wrench(six, kin.rotation));
  EXPECT_LT((r.tensions - exact).cwiseAbs().maxCoeff(), 1e-8);
}

TEST(ForceDistribution, DegenerateAndInvalidInput) {
  RobotModel model = testing::mini_robot();
  model.platform_anchors.setZero();  // no moments: rank 3
  ForceDistributionData data(model);
  for (auto method :
       {ForceDistributionMethod::kClosedForm, ForceDistributionMethod::kQuadraticProgram}) {
    const ForceDistributionResult r = distribute_forces(model, model.home, with(method), data);
    EXPECT_EQ(r.outcome, ForceDistributionOutcome::kDegenerate) << to_string(r.outcome);
  }
  const RobotModel mini = testing::mini_robot();
  CableVector lo = CableVector::Constant(8, 5.0), hi = CableVector::Constant(8, 1.0);
  KinematicsData kin(mini);
  ASSERT_TRUE(inverse_kinematics(mini, mini.home, kin));
  EXPECT_EQ(distribute_forces(kin.structure_matrix, Wrench6::Zero(), lo, hi, {}).outcome,
            ForceDistributionOutcome::kInvalidInput);
}

// One factorization serves every QP at the pose: the same result as factoring for each call,
// at other references and limits, and no allocation.
TEST(ForceDistribution, OneFactorServesEveryPlanAtThePose) {
  RobotModel model = testing::mini_robot();
  for (CableModel& c : model.cables) c.f_max = 60.0;
  KinematicsData kin(model);
  std::mt19937_64 rng(4);
  StructureFactor factor;
  int feasible = 0, infeasible = 0;
  for (int k = 0; k < 40; ++k) {
    const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
    if (!inverse_kinematics(model, pose, kin)) continue;
    ASSERT_TRUE(factor.compute(kin.structure_matrix));
    // The null-space basis is orthonormal and annihilated by the structure matrix.
    const Eigen::MatrixXd N = factor.null_basis();
    EXPECT_LT((kin.structure_matrix * N).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT(
        (N.transpose() * N - Eigen::MatrixXd::Identity(N.cols(), N.cols())).cwiseAbs().maxCoeff(),
        1e-12);
    const Wrench6 w = gravity_wrench(model, kin.rotation);
    for (const double reference : {10.0, 20.0, 40.0}) {
      for (const double margin : {0.0, 5.0}) {
        const CableVector lo = CableVector::Constant(8, 1.0 + margin);
        const CableVector hi = CableVector::Constant(8, 60.0 - margin);
        ForceDistributionOptions o;
        o.reference_tension = reference;
        const ForceDistributionResult a = distribute_forces(kin.structure_matrix, w, lo, hi, o);
        cdpr::test::AllocationCounter count;
        const ForceDistributionResult b = distribute_forces(factor, w, lo, hi, o);
        EXPECT_EQ(count.allocations(), 0u);
        ASSERT_EQ(a.outcome, b.outcome) << to_string(a.outcome);
        EXPECT_EQ(a.tensions, b.tensions);
        feasible += a.feasible();
        infeasible += !a.feasible();
      }
    }
  }
  // Both kinds of outcome were compared.
  EXPECT_GT(feasible, 20);
  EXPECT_GT(infeasible, 20);
  // A rank-deficient structure: the factor says so and the QP reports it degenerate.
  RobotModel flat = testing::mini_robot();
  flat.platform_anchors.setZero();
  KinematicsData kf(flat);
  ASSERT_TRUE(inverse_kinematics(flat, flat.home, kf));
  EXPECT_FALSE(factor.compute(kf.structure_matrix));
  EXPECT_EQ(distribute_forces(factor, Wrench6::Zero(), CableVector::Constant(8, 1.0),
                              CableVector::Constant(8, 60.0), {})
                .outcome,
            ForceDistributionOutcome::kDegenerate);
}

TEST(ForceDistribution, RepeatedCallsDoNotAllocate) {
  RobotModel model = testing::mini_robot();
  for (CableModel& c : model.cables) c.f_max = 60.0;
  ForceDistributionData data(model);
  Pose pose;
  pose.position = Eigen::Vector3d(0.1, -0.08, 0.1);
  pose.rpy = Eigen::Vector3d(0.1, 0.05, -0.1);
  for (auto method :
       {ForceDistributionMethod::kClosedForm, ForceDistributionMethod::kQuadraticProgram}) {
    const ForceDistributionOptions options = with(method);
    (void)distribute_forces(model, pose, options, data);
    cdpr::test::AllocationCounter count;
    const ForceDistributionResult r = distribute_forces(model, pose, options, data);
    EXPECT_EQ(count.allocations(), 0u) << to_string(r.outcome);
  }
}

}  // namespace
}  // namespace cdpr
