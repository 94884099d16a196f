#include "cdpr/calibration/kinematics.hpp"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <cmath>
#include <numbers>
#include <random>

#include "alloc_counter.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

constexpr double kPi = std::numbers::pi;

// A robot symmetric under x -> -x, y -> -y and z -> -z (square frame and platform).
RobotModel symmetric_robot(bool with_pulleys) {
  testing::BoxRobotSpec spec = testing::mini_spec();
  spec.bottom_xy = {0.5, 0.5};
  spec.top_xy = {0.5, 0.5};
  spec.bottom_z = -0.4;
  spec.top_z = 0.4;
  spec.platform_half = {0.05, 0.05, 0.05};
  return testing::make_box_robot(spec, with_pulleys);
}

Eigen::VectorXd lengths_at(const RobotModel& model, const Eigen::Vector3d& r,
                           const Eigen::Matrix3d& R) {
  KinematicsData data(model);
  EXPECT_TRUE(inverse_kinematics(model, r, R, data));
  return data.lengths;
}

TEST(Kinematics, SymmetricPoseOfSymmetricRobotGivesEqualLengths) {
  for (const bool pulleys : {false, true}) {
    const RobotModel model = symmetric_robot(pulleys);
    KinematicsData data(model);
    ASSERT_TRUE(inverse_kinematics(model, Pose{}, data));
    for (int i = 1; i < 8; ++i) {
      EXPECT_NEAR(data.lengths(i), data.lengths(0), 1e-14) << "cable " << i;
      EXPECT_NEAR(data.wrap_angles(i), data.wrap_angles(0), 1e-14) << "cable " << i;
    }
    // Equal lengths and the symmetric layout: the unit vectors sum to zero (no net force).
    EXPECT_LT(data.unit_vectors.rowwise().sum().norm(), 1e-14);
    // A yaw of the symmetric robot keeps the four bottom (and four top) lengths equal.
    ASSERT_TRUE(inverse_kinematics(model, Pose{Eigen::Vector3d::Zero(), {0.0, 0.0, 0.2}}, data));
    for (int i = 1; i < 4; ++i) {
      EXPECT_NEAR(data.lengths(i), data.lengths(0), 1e-14);
      EXPECT_NEAR(data.lengths(4 + i), data.lengths(4), 1e-14);
    }
  }
}

TEST(Kinematics, MiniHomeHasMirrorSymmetricLengths) {
  // MINI is symmetric under x -> -x and y -> -y, not under z -> -z (top anchors differ).
  for (const bool pulleys : {false, true}) {
    const RobotModel model = testing::mini_robot(pulleys);
    KinematicsData data(model);
    ASSERT_TRUE(inverse_kinematics(model, model.home, data));
    for (int i = 1; i < 4; ++i) {
      EXPECT_NEAR(data.lengths(i), data.lengths(0), 1e-14);
      EXPECT_NEAR(data.lengths(4 + i), data.lengths(4), 1e-14);
    }
  }
}

TEST(Kinematics, PureTranslationsMatchTheVectorLoop) {
  const RobotModel model = testing::mini_robot(/*with_pulleys=*/false);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(-0.15, 0.15);
  KinematicsData data(model);
  for (int k = 0; k < 50; ++k) {
    const Eigen::Vector3d r(u(rng), u(rng), u(rng));
    ASSERT_TRUE(inverse_kinematics(model, Pose{r, Eigen::Vector3d::Zero()}, data));
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3d l = model.frame_anchors.col(i) - r - model.platform_anchors.col(i);
      EXPECT_NEAR(data.lengths(i), l.norm(), 1e-15);
      EXPECT_LT((data.unit_vectors.col(i) - l.normalized()).norm(), 1e-15);
      EXPECT_EQ(data.wrap_angles(i), 0.0);
    }
  }
  // Moving along +x by d lengthens a cable whose unit vector points along -x by about d u_x.
  Eigen::VectorXd l0 = lengths_at(model, Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity());
  KinematicsData home(model);
  ASSERT_TRUE(inverse_kinematics(model, model.home, home));
  const double d = 1e-7;
  const Eigen::VectorXd l1 =
      lengths_at(model, Eigen::Vector3d(d, 0, 0), Eigen::Matrix3d::Identity());
  for (int i = 0; i < 8; ++i) {
    EXPECT_NEAR((l1(i) - l0(i)) / d, -home.unit_vectors(0, i), 1e-6);
  }
}

// The hand-worked case of the header: r = 0.1, P = D + (0.2, 0, -0.1) in the pulley frame.
TEST(Kinematics, HandWorkedPulleyHalfTurn) {
  // Any pulley frame: the case is stated in pulley coordinates.
  const Eigen::Matrix3d frame =
      Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d d(0.4, -0.2, 1.0);
  const Eigen::Vector3d p = d + frame * Eigen::Vector3d(0.2, 0.0, -0.1);
  const CableGeometry<double> g = cable_geometry<double>(d, frame, 0.1, p);
  ASSERT_TRUE(g.valid);
  EXPECT_NEAR(g.free_length, 0.1, 1e-15);
  EXPECT_NEAR(g.wrap_angle, kPi, 1e-14);
  EXPECT_NEAR(g.length, 0.1 * kPi + 0.1, 1e-15);
  EXPECT_NEAR(g.swivel_angle, 0.0, 1e-15);
  EXPECT_LT((g.exit_point - (d + frame * Eigen::Vector3d(0.2, 0.0, 0.0))).norm(), 1e-15);
  // From P straight "up" (along ez) to the exit point.
  EXPECT_LT((g.unit - frame.col(2)).norm(), 1e-14);
}

TEST(Kinematics, HandWorkedPulleyQuarterTurn) {
  // Cable enters along +ez, wraps a quarter turn and leaves along e_gamma from (r, 0, r).
  const double r = 0.025;
  const Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();
  const Eigen::Vector3d d(0.0, 0.0, 0.0);
  const Eigen::Vector3d p(r + 1.0, 0.0, r);
  const CableGeometry<double> g = cable_geometry<double>(d, frame, r, p);
  ASSERT_TRUE(g.valid);
  EXPECT_NEAR(g.wrap_angle, kPi / 2, 1e-15);
  EXPECT_NEAR(g.free_length, 1.0, 1e-15);
  EXPECT_NEAR(g.length, r * kPi / 2 + 1.0, 1e-15);
  EXPECT_LT((g.exit_point - Eigen::Vector3d(r, 0, r)).norm(), 1e-15);
  EXPECT_LT((g.unit - Eigen::Vector3d(-1, 0, 0)).norm(), 1e-15);
}

TEST(Kinematics, SwivelAngleFollowsThePlatformAndLeavesTheLengthUnchanged) {
  const double r = 0.025;
  const Eigen::Matrix3d frame =
      Eigen::AngleAxisd(-0.8, Eigen::Vector3d(0.2, -1, 0.5).normalized()).toRotationMatrix();
  const Eigen::Vector3d d(1.0, 2.0, 3.0);
  const double rho = 0.4;
  const double h = 0.3;
  const CableGeometry<double> g0 =
      cable_geometry<double>(d, frame, r, Eigen::Vector3d(d + frame * Eigen::Vector3d(rho, 0, h)));
  for (const double gamma : {0.7, -2.0, 3.0, -0.1}) {
    const Eigen::Vector3d local(rho * std::cos(gamma), rho * std::sin(gamma), h);
    const CableGeometry<double> g =
        cable_geometry<double>(d, frame, r, Eigen::Vector3d(d + frame * local));
    ASSERT_TRUE(g.valid);
    EXPECT_NEAR(g.swivel_angle, gamma, 1e-14);
    EXPECT_NEAR(g.length, g0.length, 1e-15);
    EXPECT_NEAR(g.wrap_angle, g0.wrap_angle, 1e-14);
    // The exit point lies in the cable plane spanned by ez and e_gamma.
    const Eigen::Vector3d e_gamma = frame * Eigen::Vector3d(std::cos(gamma), std::sin(gamma), 0);
    const Eigen::Vector3d normal = frame.col(2).cross(e_gamma);
    EXPECT_NEAR((g.exit_point - d).dot(normal), 0.0, 1e-15);
    // The exit point is on the pulley circle: distance r from the centre D + r e_gamma.
    EXPECT_NEAR((g.exit_point - (d + r * e_gamma)).norm(), r, 1e-15);
    // The free cable is tangent there: perpendicular to the radius.
    EXPECT_NEAR(g.unit.dot(g.exit_point - (d + r * e_gamma)), 0.0, 1e-15);
  }
}

TEST(Kinematics, PulleyPathIsNeverShorterThanTheChord) {
  // D -> arc -> exit point -> P is a path from D to P: at least |P - D|; for the MINI's 25 mm
  // pulleys it is longer by at most the arc r beta (< r pi).
  const RobotModel with = testing::mini_robot(true);
  const RobotModel without = testing::mini_robot(false);
  KinematicsData a(with);
  KinematicsData b(without);
  std::mt19937_64 rng(3);
  for (int k = 0; k < 200; ++k) {
    const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
    ASSERT_TRUE(inverse_kinematics(with, pose, a));
    ASSERT_TRUE(inverse_kinematics(without, pose, b));
    for (int i = 0; i < 8; ++i) {
      EXPECT_GE(a.lengths(i), b.lengths(i));
      EXPECT_LE(a.lengths(i) - b.lengths(i), 0.025 * a.wrap_angles(i) + 1e-15);
      EXPECT_GT(a.wrap_angles(i), 0.0);
      EXPECT_LT(a.wrap_angles(i), kPi / 2);  // the cable enters towards the platform's height
    }
  }
}

TEST(Kinematics, DegenerateCablesAreReported) {
  RobotModel model = testing::mini_robot(false);
  KinematicsData data(model);
  // Platform anchor 3 exactly on its frame anchor.
  Pose pose;
  pose.position = model.frame_anchors.col(3) - model.platform_anchors.col(3);
  EXPECT_FALSE(inverse_kinematics(model, pose, data));
  EXPECT_EQ(data.invalid_cable, 3);
  // Inside the pulley circle: P at the pulley centre.
  const Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();
  const CableGeometry<double> g =
      cable_geometry<double>(Eigen::Vector3d::Zero(), frame, 0.1, Eigen::Vector3d(0.1, 0.0, 0.0));
  EXPECT_FALSE(g.valid);
  ASSERT_TRUE(inverse_kinematics(model, model.home, data));
  EXPECT_EQ(data.invalid_cable, -1);
}

TEST(Kinematics, RpyRoundTripAndExponentialMap) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int k = 0; k < 200; ++k) {
    const Eigen::Vector3d rpy(3.0 * u(rng), 1.5 * u(rng), 3.0 * u(rng));
    const Eigen::Matrix3d R = rotation_from_rpy<double>(rpy);
    EXPECT_LT((rpy_from_rotation(R) - rpy).norm(), 1e-12);
    // Euler convention: Rz(yaw) Ry(pitch) Rx(roll).
    const Eigen::Matrix3d expected = (Eigen::AngleAxisd(rpy(2), Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(rpy(1), Eigen::Vector3d::UnitY()) *
                                      Eigen::AngleAxisd(rpy(0), Eigen::Vector3d::UnitX()))
                                         .toRotationMatrix();
    EXPECT_LT((R - expected).norm(), 1e-14);
    const Eigen::Vector3d w(u(rng), u(rng), u(rng));
    for (const double scale : {1.0, 1e-3, 1e-9}) {
      const Eigen::Vector3d ws = scale * w;
      const Eigen::Matrix3d E = rotation_exp(ws);
      const Eigen::Matrix3d A = Eigen::AngleAxisd(ws.norm(), ws.normalized()).toRotationMatrix();
      EXPECT_LT((E - A).norm(), 1e-15);
    }
  }
  // Gimbal lock: still a valid decomposition.
  const Eigen::Matrix3d R = rotation_from_rpy<double>(0.3, kPi / 2, 0.0);
  EXPECT_LT((rotation_from_rpy<double>(rpy_from_rotation(R)) - R).norm(), 1e-12);
}

// Lengths for a pose perturbed by (dr, dtheta): r + dr, exp(dtheta) R.
Eigen::VectorXd perturbed_lengths(const RobotModel& model, const Pose& pose,
                                  const Eigen::Matrix<double, 6, 1>& delta) {
  return lengths_at(model, pose.position + delta.head<3>(),
                    rotation_exp(delta.tail<3>()) * rotation_from_rpy<double>(pose.rpy));
}

void expect_structure_matrix_matches_finite_differences(const RobotModel& model,
                                                        const testing::WorkspaceBox& box,
                                                        double tolerance) {
  std::mt19937_64 rng(5);
  KinematicsData data(model);
  for (int k = 0; k < 50; ++k) {
    const Pose pose = k == 0 ? model.home : testing::random_pose(box, rng);
    ASSERT_TRUE(inverse_kinematics(model, pose, data));
    const double h = 1e-6;
    for (int j = 0; j < 6; ++j) {
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      delta(j) = h;
      const Eigen::VectorXd fd =
          (perturbed_lengths(model, pose, delta) - perturbed_lengths(model, pose, -delta)) /
          (2 * h);
      // dL/d(dr, dtheta) = -A, A^T = structure matrix.
      const Eigen::VectorXd analytic = -data.structure_matrix.row(j).transpose();
      EXPECT_LT((fd - analytic).cwiseAbs().maxCoeff(), tolerance)
          << model.name << " pose " << k << " direction " << j;
    }
  }
}

TEST(Kinematics, StructureMatrixIsTheLengthJacobian) {
  expect_structure_matrix_matches_finite_differences(testing::mini_robot(false),
                                                     testing::mini_workspace(), 1e-8);
  expect_structure_matrix_matches_finite_differences(testing::mini_robot(true),
                                                     testing::mini_workspace(), 1e-8);
  expect_structure_matrix_matches_finite_differences(testing::large_robot(false),
                                                     testing::large_workspace(), 1e-8);
  expect_structure_matrix_matches_finite_differences(testing::large_robot(true),
                                                     testing::large_workspace(), 1e-8);
}

// Lengths as a function of (position, rpy, pulley radius, frame anchor of cable `c`), templated.
template <typename T>
Eigen::Matrix<T, 8, 1> lengths_templated(const RobotModel& model, const Eigen::Matrix<T, 10, 1>& q,
                                         int c) {
  const Vec3<T> r = q.template head<3>();
  const Mat3<T> R = rotation_from_rpy<T>(q(3), q(4), q(5));
  Eigen::Matrix<T, 8, 1> out;
  for (int i = 0; i < 8; ++i) {
    const PulleyModel& p = model.pulleys[static_cast<std::size_t>(i)];
    Vec3<T> d = model.frame_anchors.col(i).cast<T>();
    if (i == c) d = q.template tail<3>();
    const T radius = p.radius > 0.0 ? q(6) : T(0);
    const Vec3<T> b = model.platform_anchors.col(i).cast<T>();
    out(i) = cable_geometry<T>(d, p.frame, radius, platform_anchor_world<T>(r, R, b)).length;
  }
  return out;
}

TEST(Kinematics, AutodiffThroughJetMatchesFiniteDifferences) {
  using Jet = ceres::Jet<double, 10>;
  for (const bool pulleys : {false, true}) {
    const RobotModel model = testing::mini_robot(pulleys);
    std::mt19937_64 rng(9);
    for (int k = 0; k < 20; ++k) {
      const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
      const int c = k % 8;
      Eigen::Matrix<double, 10, 1> q;
      q << pose.position, pose.rpy, 0.025, model.frame_anchors.col(c);
      Eigen::Matrix<Jet, 10, 1> qj;
      for (int j = 0; j < 10; ++j) qj(j) = Jet(q(j), j);
      const Eigen::Matrix<Jet, 8, 1> lj = lengths_templated<Jet>(model, qj, c);
      const Eigen::Matrix<double, 8, 1> l = lengths_templated<double>(model, q, c);
      for (int j = 0; j < 10; ++j) {
        const double h = 1e-6;
        Eigen::Matrix<double, 10, 1> qp = q, qm = q;
        qp(j) += h;
        qm(j) -= h;
        const Eigen::Matrix<double, 8, 1> fd =
            (lengths_templated<double>(model, qp, c) - lengths_templated<double>(model, qm, c)) /
            (2 * h);
        for (int i = 0; i < 8; ++i) {
          EXPECT_NEAR(lj(i).a, l(i), 1e-15);
          EXPECT_NEAR(lj(i).v(j), fd(i), 1e-8) << "cable " << i << " parameter " << j;
        }
      }
      // Without pulleys the radius does not enter.
      if (!pulleys) {
        EXPECT_EQ(lj(0).v(6), 0.0);
      }
    }
  }
}

TEST(Kinematics, TestRobotsAreWellConditionedAndWrenchClosedAtHome) {
  for (int which = 0; which < 4; ++which) {
    const RobotModel model =
        which < 2 ? testing::mini_robot(which == 0) : testing::large_robot(which == 2);
    KinematicsData data(model);
    ASSERT_TRUE(inverse_kinematics(model, model.home, data));
    double lc = 0.0;
    for (int i = 0; i < 8; ++i) lc = std::max(lc, model.platform_anchors.col(i).norm());
    Eigen::Matrix<double, 6, Eigen::Dynamic> s = data.structure_matrix;
    s.bottomRows(3) /= lc;
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(s, Eigen::ComputeFullV);
    const Eigen::Matrix<double, 6, 1> sv = svd.singularValues();
    EXPECT_LT(sv(0) / sv(5), 30.0) << model.name;
    // Wrench closure: the 2-D null space holds a strictly positive tension vector. Search the
    // unit circle of the null space for the best worst-case entry.
    const Eigen::MatrixXd null = svd.matrixV().rightCols(2);
    double best = -1.0;
    for (int k = 0; k < 3600; ++k) {
      const double a = 2 * kPi * k / 3600;
      const Eigen::VectorXd f = std::cos(a) * null.col(0) + std::sin(a) * null.col(1);
      best = std::max(best, f.minCoeff());
    }
    EXPECT_GT(best, 0.05) << model.name;
  }
}

TEST(Kinematics, BatchInverseKinematicsDoesNotAllocate) {
  const RobotModel model = testing::mini_robot(true);
  KinematicsData data(model);
  const Pose pose{Eigen::Vector3d(0.05, -0.02, 0.1), Eigen::Vector3d(0.1, -0.05, 0.2)};
  const cdpr::test::AllocationCounter count;
  for (int k = 0; k < 100; ++k) ASSERT_TRUE(inverse_kinematics(model, pose, data));
  EXPECT_EQ(count.allocations(), 0u);
}

}  // namespace
}  // namespace cdpr
