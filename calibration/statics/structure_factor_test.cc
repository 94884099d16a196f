// StructureFactor against Eigen's ColPivHouseholderQR with Q formed (the general algorithm): the
// same rank, R, particular solution and null space, and the QP on either factor gives the same
// outcome and tensions, on MINI and on random 7-, 8- and 12-cable geometries.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/QR>
#include <optional>
#include <random>

#include "alloc_counter.hpp"
#include "cdpr/calibration/force_distribution.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

using Qr = Eigen::ColPivHouseholderQR<Eigen::Matrix<double, Eigen::Dynamic, 6>>;

// The factor filled from Eigen's QR (same conventions: A P = Q R, H_k = I - tau_k v v^T with
// v_k = 1 below the diagonal), Q formed explicitly for the null basis.
StructureFactor eigen_factor(const StructureMatrix& at) {
  const int m = static_cast<int>(at.cols());
  const Qr qr(Eigen::Matrix<double, Eigen::Dynamic, 6>(at.transpose()));
  StructureFactor f;
  f.structure = at;
  f.reflectors = qr.matrixQR();
  f.tau = qr.hCoeffs();
  f.r = qr.matrixQR().topRows<6>().triangularView<Eigen::Upper>();
  f.permutation = qr.colsPermutation();
  Eigen::MatrixXd q = Eigen::MatrixXd::Identity(m, m);
  q.applyOnTheLeft(qr.householderQ());
  f.null = q.rightCols(m - 6);
  f.rank = static_cast<int>(qr.rank());
  f.status = StructureFactor::Factored::kFullRank;
  return f;
}

// The structure matrix (6 x m) of m cables from frame anchors on a 2 m box to platform anchors
// within 0.15 m, the platform moved and turned at random.
StructureMatrix random_structure(int m, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(0.3 * unit(rng), Eigen::Vector3d::UnitZ()) *
                             Eigen::AngleAxisd(0.2 * unit(rng), Eigen::Vector3d::UnitY()) *
                             Eigen::AngleAxisd(0.2 * unit(rng), Eigen::Vector3d::UnitX()))
                                .toRotationMatrix();
  const Eigen::Vector3d p(0.3 * unit(rng), 0.3 * unit(rng), 0.3 * unit(rng));
  StructureMatrix at(6, m);
  for (int i = 0; i < m; ++i) {
    // Alternately high and low frame corners, jittered, so that the cables can hold a weight.
    const Eigen::Vector3d a(i % 4 < 2 ? 1.0 : -1.0, (i % 2 == 0 ? 1.0 : -1.0),
                            (i / 4) % 2 == 0 ? 1.0 : -1.0);
    const Eigen::Vector3d anchor = a + 0.1 * Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
    const Eigen::Vector3d b = 0.15 * Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
    const Eigen::Vector3d u = (anchor - p - R * b).normalized();
    at.col(i) << u, (R * b).cross(u);
  }
  return at;
}

// Largest |a - b| relative to max(1, |b|_inf).
double relative_gap(const CableVector& a, const CableVector& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1.0, b.cwiseAbs().maxCoeff());
}

// The factor and Eigen's: same rank, |R| diagonal, particular solution, null space.
void expect_same_factor(const StructureMatrix& at, const Wrench6& w, double f_ref) {
  const int m = static_cast<int>(at.cols());
  StructureFactor ours;
  ASSERT_TRUE(ours.compute(at));
  const StructureFactor ref = eigen_factor(at);
  EXPECT_EQ(ours.rank, ref.rank);
  for (int k = 0; k < 6; ++k) {
    EXPECT_NEAR(std::abs(ours.r(k, k)), std::abs(ref.r(k, k)), 1e-12 * std::abs(ref.r(0, 0)));
  }
  // The particular solution as it was computed from the formed Q: f_ref - Q1 (Q1^T f_ref + y).
  const Qr qr(Eigen::Matrix<double, Eigen::Dynamic, 6>(at.transpose()));
  Eigen::MatrixXd q = Eigen::MatrixXd::Identity(m, m);
  q.applyOnTheLeft(qr.householderQ());
  const Wrench6 y =
      ref.r.transpose().triangularView<Eigen::Lower>().solve(qr.colsPermutation().transpose() * w);
  const CableVector reference = CableVector::Constant(m, f_ref);
  const CableVector a = ours.particular(reference, w);
  const CableVector b = reference - q.leftCols<6>() * (q.leftCols<6>().transpose() * reference + y);
  EXPECT_LT(relative_gap(a, b), 1e-9);
  EXPECT_LT((at * a + w).cwiseAbs().maxCoeff(), 1e-9);
  if (m == 6) return;  // no null space
  const Eigen::MatrixXd N = ours.null_basis(), Nref = ref.null_basis();
  EXPECT_LT((at * N).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((N.transpose() * N - Eigen::MatrixXd::Identity(m - 6, m - 6)).cwiseAbs().maxCoeff(),
            1e-12);
  // Same space: the same orthogonal projector.
  EXPECT_LT((N * N.transpose() - Nref * Nref.transpose()).cwiseAbs().maxCoeff(), 1e-12);
}

// The QP on our factor and on Eigen's: the same outcome and tensions; counts both outcomes.
void expect_same_qp(const StructureMatrix& at, const Wrench6& w, double lo, double hi,
                    double reference, int& feasible, int& infeasible) {
  const int m = static_cast<int>(at.cols());
  StructureFactor ours;
  ASSERT_TRUE(ours.compute(at));
  const StructureFactor ref = eigen_factor(at);
  ForceDistributionOptions o;
  o.reference_tension = reference;
  const CableVector f_min = CableVector::Constant(m, lo), f_max = CableVector::Constant(m, hi);
  const ForceDistributionResult a = distribute_forces(ours, w, f_min, f_max, o);
  const ForceDistributionResult b = distribute_forces(ref, w, f_min, f_max, o);
  ASSERT_EQ(a.outcome, b.outcome) << to_string(a.outcome) << " vs " << to_string(b.outcome);
  if (a.feasible()) {
    EXPECT_LT(relative_gap(a.tensions, b.tensions), 1e-9);
  }
  feasible += a.feasible();
  infeasible += a.outcome == ForceDistributionOutcome::kInfeasible;
}

// The QP's answer by enumeration, for null spaces of dimension 1 or 2: the projection of the
// origin onto {lambda : C lambda >= d} is the nearest feasible point among the origin, the
// projections onto each constraint's line and the constraints' pairwise intersections (none
// feasible: the polytope is empty). Independent of the active-set method.
std::optional<CableVector> enumerated_qp(const StructureFactor& f, const Wrench6& w, double lo,
                                         double hi, double reference) {
  const int m = f.num_cables(), r = m - 6;
  const CableVector f_p = f.particular(CableVector::Constant(m, reference), w);
  const Eigen::MatrixXd N = f.null_basis();
  Eigen::MatrixXd C(2 * m, r);
  Eigen::VectorXd d(2 * m);
  for (int i = 0; i < m; ++i) {
    C.row(2 * i) = N.row(i);
    d(2 * i) = lo - f_p(i);
    C.row(2 * i + 1) = -N.row(i);
    d(2 * i + 1) = f_p(i) - hi;
  }
  std::optional<Eigen::VectorXd> best;
  const auto consider = [&](const Eigen::VectorXd& x) {
    if (((C * x - d).array() < -1e-9).any()) return;
    if (!best || x.norm() < best->norm()) best = x;
  };
  consider(Eigen::VectorXd::Zero(r));
  for (int j = 0; j < 2 * m; ++j) consider(C.row(j).transpose() * d(j) / C.row(j).squaredNorm());
  for (int j = 0; r == 2 && j < 2 * m; ++j) {
    for (int k = j + 1; k < 2 * m; ++k) {
      Eigen::Matrix2d M;
      M << C.row(j), C.row(k);
      if (std::abs(M.determinant()) > 1e-12) consider(M.inverse() * Eigen::Vector2d(d(j), d(k)));
    }
  }
  if (!best) return std::nullopt;
  return CableVector(f_p + N * *best);
}

TEST(StructureFactor, QpIsTheEnumeratedProjectionForSevenAndEightCables) {
  std::mt19937_64 rng(15);
  const RobotModel model = testing::mini_robot();
  KinematicsData kin(model);
  int feasible = 0, infeasible = 0;
  for (int k = 0; k < 600; ++k) {
    StructureMatrix at;
    Wrench6 w;
    w << 0.0, 0.0, -100.0, 0.0, 0.0, 0.0;
    if (k % 3 == 0) {  // MINI
      if (!inverse_kinematics(model, testing::random_pose(testing::mini_workspace(), rng), kin)) {
        continue;
      }
      at = kin.structure_matrix;
      w = gravity_wrench(model, kin.rotation);
    } else {
      at = random_structure(k % 3 == 1 ? 7 : 8, rng);
    }
    StructureFactor f;
    ASSERT_TRUE(f.compute(at));
    for (const double hi : {40.0, 80.0, 150.0}) {
      for (const double reference : {15.0, 30.0, 60.0}) {
        ForceDistributionOptions o;
        o.reference_tension = reference;
        const int m = f.num_cables();
        const ForceDistributionResult qp = distribute_forces(f, w, CableVector::Constant(m, 10.0),
                                                             CableVector::Constant(m, hi), o);
        const std::optional<CableVector> ref = enumerated_qp(f, w, 10.0, hi, reference);
        ASSERT_EQ(qp.feasible(), ref.has_value()) << to_string(qp.outcome) << " k " << k;
        if (!ref) {
          EXPECT_EQ(qp.outcome, ForceDistributionOutcome::kInfeasible);
          ++infeasible;
          continue;
        }
        EXPECT_LT(relative_gap(qp.tensions, *ref), 1e-9) << k;
        ++feasible;
      }
    }
  }
  EXPECT_GT(feasible, 300);
  EXPECT_GT(infeasible, 300);
}

TEST(StructureFactor, MatchesEigensColumnPivotedQrOnMini) {
  const RobotModel model = testing::mini_robot();
  KinematicsData kin(model);
  std::mt19937_64 rng(11);
  int feasible = 0, infeasible = 0;
  for (int k = 0; k < 200; ++k) {
    const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
    if (!inverse_kinematics(model, pose, kin)) continue;
    const Wrench6 w = gravity_wrench(model, kin.rotation);
    expect_same_factor(kin.structure_matrix, w, 30.0);
    for (const double hi : {40.0, 60.0, 200.0}) {
      for (const double reference : {15.0, 30.0, 60.0}) {
        expect_same_qp(kin.structure_matrix, w, 10.0, hi, reference, feasible, infeasible);
      }
    }
  }
  EXPECT_GT(feasible, 200);
  EXPECT_GT(infeasible, 200);
}

TEST(StructureFactor, MatchesEigensColumnPivotedQrOnSevenEightAndTwelveCables) {
  std::mt19937_64 rng(12);
  for (const int m : {6, 7, 8, 12}) {
    int feasible = 0, infeasible = 0;
    for (int k = 0; k < 200; ++k) {
      const StructureMatrix at = random_structure(m, rng);
      Wrench6 w;
      w << 0.0, 0.0, -100.0, 0.0, 0.0, 0.0;
      expect_same_factor(at, w, 50.0);
      for (const double hi : {80.0, 150.0, 400.0}) {
        expect_same_qp(at, w, 10.0, hi, 50.0, feasible, infeasible);
      }
    }
    SCOPED_TRACE(m);
    // (six cables: one solution, rarely inside the limits)
    EXPECT_GT(feasible, m == 6 ? 5 : 20);
    EXPECT_GT(infeasible, 20);
  }
}

TEST(StructureFactor, ReportsTheRankDeficiencyEigensQrFinds) {
  RobotModel flat = testing::mini_robot();
  flat.platform_anchors.setZero();  // every cable through one point: no moment
  KinematicsData kin(flat);
  ASSERT_TRUE(inverse_kinematics(flat, flat.home, kin));
  StructureFactor f;
  EXPECT_FALSE(f.compute(kin.structure_matrix));
  EXPECT_EQ(f.status, StructureFactor::Factored::kRankDeficient);
  const Qr qr(Eigen::Matrix<double, Eigen::Dynamic, 6>(kin.structure_matrix.transpose()));
  EXPECT_LT(qr.rank(), 6);
  // Five cables: never rank 6.
  std::mt19937_64 rng(13);
  EXPECT_FALSE(f.compute(random_structure(5, rng)));
  EXPECT_FALSE(f.valid());
}

TEST(StructureFactor, ComputeAllocatesNothing) {
  std::mt19937_64 rng(14);
  StructureFactor f;
  for (const int m : {8, 12}) {
    const StructureMatrix at = random_structure(m, rng);
    cdpr::test::AllocationCounter count;
    EXPECT_TRUE(f.compute(at));
    const CableVector p = f.particular(CableVector::Constant(m, 50.0), Wrench6::UnitZ());
    EXPECT_EQ(count.allocations(), 0u);
    EXPECT_EQ(p.size(), m);
  }
}

}  // namespace
}  // namespace cdpr
