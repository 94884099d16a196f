// Force distribution (tension planning): cable tensions within [f_min, f_max] that hold the
// platform at a pose against its weight (at the centre of mass) and an optional external wrench:
//
//   A^T f = -w,   f_min <= f <= f_max,   A^T = structure matrix (6 x m, kinematics.hpp)
//
// Two methods, both minimising ||f - f_ref|| (f_ref: a reference tension per cable, by default
// the middle of its range):
// - kClosedForm (Pott's closed-form method with the "improved" clipping iterations): the
//   least-norm correction f = f_ref - A (A^T A)^-1 (A^T f_ref + w); while a tension leaves its
//   range, the worst one is fixed at the violated limit and the rest is recomputed. Fast, but it
//   may give up (kNotFound) at poses where a feasible distribution exists.
// - kQuadraticProgram (exact): f = f_p + N lambda with N an orthonormal basis of the null space
//   of A^T (dimension m - 6, i.e. 2 for eight cables) and f_p the least-norm correction, so the
//   problem is the projection of lambda = 0 onto the polytope {f_min <= f_p + N lambda <= f_max};
//   solved by the dual active-set method of Goldfarb and Idnani (exact in finitely many steps).
//   kInfeasible then means the pose is outside the wrench-feasible workspace.
//
// Everything is sized for at most kMaxCables cables with fixed-capacity Eigen types: no heap
// allocation, safe for the real-time loop.
#pragma once

#include <Eigen/Core>
#include <optional>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

inline constexpr int kMaxCables = 16;

using StructureMatrix = Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, kMaxCables>;
using CableVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMaxCables, 1>;
using Wrench6 = Eigen::Matrix<double, 6, 1>;

enum class ForceDistributionMethod { kClosedForm, kQuadraticProgram };

struct ForceDistributionOptions {
  ForceDistributionMethod method = ForceDistributionMethod::kQuadraticProgram;
  // Reference tension for every cable, N; nullopt: the middle of each cable's [f_min, f_max].
  std::optional<double> reference_tension;
  // External wrench on the platform besides gravity: force (N) through the platform origin and
  // moment (N m), world frame.
  Wrench6 external_wrench = Wrench6::Zero();
  int max_iterations = 100;             // clipping rounds or active-set steps
  double feasibility_tolerance = 1e-9;  // N, allowed violation of a tension limit
  double rank_tolerance = 1e-10;        // relative, for the rank of the structure matrix
};

enum class ForceDistributionOutcome {
  kFeasible,      // tensions found
  kInfeasible,    // proven: no tensions within the limits balance the wrench (QP only)
  kNotFound,      // the closed form gave up (a feasible distribution may still exist)
  kDegenerate,    // a cable is degenerate at the pose, or the structure matrix has rank < 6
  kInvalidInput,  // sizes, non-finite values, more than kMaxCables cables, f_min > f_max
};

const char* to_string(ForceDistributionOutcome outcome);

struct ForceDistributionResult {
  ForceDistributionOutcome outcome = ForceDistributionOutcome::kInvalidInput;
  Status status;         // ok when feasible, else why
  CableVector tensions;  // N (the best attempt when not feasible)
  int iterations = 0;
  double balance_residual = 0.0;  // |A^T f + w|_inf, N or N m
  int cables_at_limits = 0;       // tensions on f_min or f_max

  bool feasible() const { return outcome == ForceDistributionOutcome::kFeasible; }
};

// Scratch (fixed capacity; construct once, reuse).
struct ForceDistributionData {
  explicit ForceDistributionData(int num_cables) : kinematics(num_cables) {}
  explicit ForceDistributionData(const RobotModel& model)
      : ForceDistributionData(model.num_cables()) {}
  KinematicsData kinematics;  // IK at the pose (only for the RobotModel overload)
};

// The part of the QP that depends only on the pose: the structure matrix A^T (6 x m) factored as
// A = Q [R; 0] P^T (column-pivoted Householder QR) and an orthonormal basis of its null space
// (m x (m - 6)). Every QP at the pose (other references, other limits, other wrenches) shares it,
// so a caller trying several plans at one pose factors once. Fixed capacity: compute() allocates
// nothing.
struct StructureFactor {
  using CableMatrix =
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxCables, kMaxCables>;

  // Factors `structure_matrix`; false when it has rank < 6 (relative `rank_tolerance`), is not
  // finite or has more than kMaxCables or fewer than 6 columns (then valid() is false and a QP
  // with this factor reports kDegenerate or kInvalidInput).
  bool compute(const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& structure_matrix,
               double rank_tolerance = 1e-10);
  bool valid() const { return status == Factored::kFullRank; }
  int num_cables() const { return static_cast<int>(structure.cols()); }
  // m x (m - 6), orthonormal columns spanning {f : A^T f = 0} (valid() only).
  auto null_basis() const { return q.rightCols(q.cols() - 6); }

  enum class Factored { kNone, kFullRank, kRankDeficient, kBadInput };
  Factored status = Factored::kNone;
  int rank = 0;
  StructureMatrix structure;                // A^T as factored
  Eigen::PermutationMatrix<6> permutation;  // P (valid() only)
  CableMatrix q;                            // Q (m x m), formed once (valid() only)
  Eigen::Matrix<double, 6, 6> r;            // R (upper triangular; valid() only)
};

// Gravity wrench (force and moment about the platform origin, world) at rotation R.
Wrench6 gravity_wrench(const RobotModel& model, const Eigen::Matrix3d& rotation);

// Tensions for the platform at `pose` of `model`. Allocates nothing.
ForceDistributionResult distribute_forces(const RobotModel& model, const Pose& pose,
                                          const ForceDistributionOptions& options,
                                          ForceDistributionData& data);

// The same from a structure matrix (6 x m) and the total wrench w on the platform (gravity
// included); options.external_wrench is added to w. Allocates nothing.
ForceDistributionResult distribute_forces(
    const Eigen::Ref<const Eigen::Matrix<double, 6, Eigen::Dynamic>>& structure_matrix,
    const Wrench6& wrench, const Eigen::Ref<const Eigen::VectorXd>& f_min,
    const Eigen::Ref<const Eigen::VectorXd>& f_max, const ForceDistributionOptions& options);

// The same with the structure matrix already factored (`factor`, computed with
// options.rank_tolerance): the exact QP whatever options.method says (the closed form needs no
// factor). Identical results; allocates nothing.
ForceDistributionResult distribute_forces(const StructureFactor& factor, const Wrench6& wrench,
                                          const Eigen::Ref<const Eigen::VectorXd>& f_min,
                                          const Eigen::Ref<const Eigen::VectorXd>& f_max,
                                          const ForceDistributionOptions& options);

// The reference tension used when none is given: the midpoint of the largest f_min and the
// smallest f_max over the cables, capped at 4 f_min_max (a moderate pretension).
double default_reference_tension(const RobotModel& model);

}  // namespace cdpr
