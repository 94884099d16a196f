#include "cdpr/calibration/forward_kinematics.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <utility>

#include "cdpr/calibration/elongation.hpp"

namespace cdpr {

const char* to_string(ForwardKinematicsTermination termination) {
  switch (termination) {
    case ForwardKinematicsTermination::kConverged:
      return "converged";
    case ForwardKinematicsTermination::kInconsistentLengths:
      return "inconsistent lengths";
    case ForwardKinematicsTermination::kMaxIterations:
      return "maximum iterations";
    case ForwardKinematicsTermination::kInvalidInput:
      return "invalid input";
    case ForwardKinematicsTermination::kDegenerateGeometry:
      return "degenerate geometry";
    case ForwardKinematicsTermination::kNumericalFailure:
      return "numerical failure";
  }
  return "unknown";
}

ForwardKinematicsData::ForwardKinematicsData(int num_cables)
    : current(num_cables),
      trial(num_cables),
      target_lengths(num_cables),
      residuals(num_cables),
      trial_residuals(num_cables),
      elongations(num_cables) {}

namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

ForwardKinematicsSummary invalid(const Status& status) {
  ForwardKinematicsSummary s;
  s.termination = ForwardKinematicsTermination::kInvalidInput;
  s.status = status;
  return s;
}

// Checks that do not depend on the lengths; empty Status when fine.
Status check_model_and_data(const RobotModel& model, const ForwardKinematicsOptions& options,
                            const ForwardKinematicsData& data, Eigen::Index num_lengths) {
  const int m = model.num_cables();
  if (m < 6) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "forward kinematics needs at least 6 cables for a 6-DOF pose, model "
                         "has %d",
                         m);
  }
  if (model.platform_anchors.cols() != m || static_cast<int>(model.pulleys.size()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "forward kinematics: model has %d frame anchors, %d platform anchors, "
                         "%zu pulleys",
                         m, static_cast<int>(model.platform_anchors.cols()), model.pulleys.size());
  }
  if (num_lengths != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "forward kinematics: %d lengths given for %d cables",
                         static_cast<int>(num_lengths), m);
  }
  if (data.residuals.size() != m || data.current.lengths.size() != m ||
      data.trial.lengths.size() != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "forward kinematics: workspace built for %d cables, model has %d",
                         static_cast<int>(data.residuals.size()), m);
  }
  if (options.max_iterations < 0 || !(options.initial_lambda > 0.0) ||
      !(options.residual_tolerance >= 0.0) || !(options.step_tolerance >= 0.0) ||
      !(options.function_tolerance >= 0.0) || !(options.max_residual >= 0.0)) {
    return Status(ErrorCode::kInvalidArgument,
                  "forward kinematics: options need max_iterations >= 0, initial_lambda > 0 "
                  "and non-negative tolerances");
  }
  return Status::success();
}

void residual_stats(const Eigen::VectorXd& r, ForwardKinematicsSummary& s) {
  s.max_abs_residual = 0.0;
  s.worst_cable = -1;
  for (Eigen::Index i = 0; i < r.size(); ++i) {
    if (std::abs(r(i)) >= s.max_abs_residual) {
      s.max_abs_residual = std::abs(r(i));
      s.worst_cable = static_cast<int>(i);
    }
  }
  s.rms_residual = std::sqrt(r.squaredNorm() / static_cast<double>(r.size()));
  s.final_cost = 0.5 * r.squaredNorm();
}

// Levenberg-Marquardt on data.target_lengths (Nielsen's damping update, Marquardt scaling).
ForwardKinematicsSummary solve(const RobotModel& model, const ForwardKinematicsOptions& options,
                               ForwardKinematicsData& data) {
  ForwardKinematicsSummary s;
  const int m = model.num_cables();
  const Pose& start = options.initial_pose ? *options.initial_pose : model.home;
  Eigen::Vector3d position = start.position;
  Eigen::Matrix3d rotation = rotation_from_rpy<double>(start.rpy);
  const double lc = model.platform_radius();

  KinematicsData* cur = &data.current;
  KinematicsData* tri = &data.trial;
  Eigen::VectorXd* res = &data.residuals;
  Eigen::VectorXd* tres = &data.trial_residuals;

  auto finish = [&](ForwardKinematicsTermination t) {
    if (cur != &data.current) {
      data.current = *cur;  // same sizes: no allocation
      data.residuals = *res;
    }
    s.termination = t;
    s.pose.position = position;
    s.pose.rpy = rpy_from_rotation(rotation);
    s.rotation = rotation;
    residual_stats(data.residuals, s);
    switch (t) {
      case ForwardKinematicsTermination::kConverged:
        if (s.max_abs_residual > options.max_residual) {
          s.termination = ForwardKinematicsTermination::kInconsistentLengths;
          s.status = Status::error(
              ErrorCode::kNumericalFailure,
              "forward kinematics converged to a pose where cable %d misses its length by "
              "%.3g m (> max_residual %.3g m): lengths inconsistent with the model, or a local "
              "minimum",
              s.worst_cable, s.max_abs_residual, options.max_residual);
        } else {
          s.status = Status::success();
        }
        break;
      case ForwardKinematicsTermination::kMaxIterations:
        s.status =
            Status::error(ErrorCode::kNumericalFailure,
                          "forward kinematics did not converge in max_iterations %d (%d "
                          "orientation restarts; max |residual| %.3g m at cable %d)",
                          options.max_iterations, s.restarts, s.max_abs_residual, s.worst_cable);
        break;
      case ForwardKinematicsTermination::kDegenerateGeometry:
        s.status = Status::error(ErrorCode::kFailedPrecondition,
                                 "forward kinematics: cable %d is degenerate at the initial pose "
                                 "(platform anchor on the frame anchor or inside its pulley)",
                                 cur->invalid_cable);
        break;
      case ForwardKinematicsTermination::kNumericalFailure:
        s.status = Status::error(ErrorCode::kNumericalFailure,
                                 "forward kinematics: singular or non-finite normal equations "
                                 "after %d iterations (max |residual| %.3g m)",
                                 s.iterations, s.max_abs_residual);
        break;
      case ForwardKinematicsTermination::kInconsistentLengths:
      case ForwardKinematicsTermination::kInvalidInput:
        break;
    }
    return s;
  };

  if (!position.allFinite() || !rotation.allFinite()) {
    return invalid(
        Status(ErrorCode::kInvalidArgument, "forward kinematics: non-finite initial pose"));
  }
  if (!inverse_kinematics(model, position, rotation, *cur)) {
    res->setZero();
    return finish(ForwardKinematicsTermination::kDegenerateGeometry);
  }
  *res = cur->lengths - data.target_lengths;
  double cost = 0.5 * res->squaredNorm();
  s.initial_cost = cost;

  // One Levenberg-Marquardt run from the current state. Position-only runs keep the rotation
  // fixed (rotation block of the normal equations replaced by the identity, zero gradient).
  enum class Outcome { kConverged, kMaxIterations, kNumericalFailure };
  auto run = [&](bool position_only, int iteration_limit, double step_tolerance) {
    double lambda = options.initial_lambda;
    double nu = 2.0;
    while (s.iterations < iteration_limit) {
      if (res->cwiseAbs().maxCoeff() <= options.residual_tolerance) return Outcome::kConverged;
      // J = -A (m x 6), A^T = structure matrix: J^T J = S S^T, J^T r = -S r.
      Matrix6d jtj = Matrix6d::Zero();
      Vector6d g = Vector6d::Zero();
      for (int i = 0; i < m; ++i) {
        const Vector6d col = cur->structure_matrix.col(i);
        jtj.noalias() += col * col.transpose();
        g.noalias() -= col * (*res)(i);
      }
      if (position_only) {
        jtj.bottomRows<3>().setZero();
        jtj.rightCols<3>().setZero();
        jtj.bottomRightCorner<3, 3>().setIdentity();
        g.tail<3>().setZero();
      }
      const Vector6d diag = jtj.diagonal().cwiseMax(1e-12 * jtj.diagonal().maxCoeff());
      ++s.iterations;
      Matrix6d damped = jtj;
      damped.diagonal() += lambda * diag;
      const Eigen::LDLT<Matrix6d> ldlt(damped);
      const Vector6d step = ldlt.solve(-g);
      if (ldlt.info() != Eigen::Success || !step.allFinite()) return Outcome::kNumericalFailure;
      const double step_norm =
          std::sqrt(step.head<3>().squaredNorm() + lc * lc * step.tail<3>().squaredNorm());
      if (step_norm <= step_tolerance) return Outcome::kConverged;
      const Eigen::Vector3d trial_position = position + step.head<3>();
      const Eigen::Matrix3d trial_rotation =
          position_only ? rotation : Eigen::Matrix3d(rotation_exp(step.tail<3>()) * rotation);
      bool improved = false;
      if (inverse_kinematics(model, trial_position, trial_rotation, *tri)) {
        *tres = tri->lengths - data.target_lengths;
        const double trial_cost = 0.5 * tres->squaredNorm();
        // Predicted decrease of the linear model: 0.5 step^T (lambda D step - g).
        const double predicted = 0.5 * step.dot(lambda * diag.cwiseProduct(step) - g);
        if (std::isfinite(trial_cost) && trial_cost < cost) {
          improved = true;
          const double rho = predicted > 0.0 ? (cost - trial_cost) / predicted : 1.0;
          const double relative_decrease = (cost - trial_cost) / cost;
          position = trial_position;
          rotation = trial_rotation;
          std::swap(cur, tri);
          std::swap(res, tres);
          cost = trial_cost;
          ++s.accepted_steps;
          lambda *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3));
          nu = 2.0;
          if (relative_decrease <= options.function_tolerance) return Outcome::kConverged;
        }
      }
      if (!improved) {
        lambda *= nu;
        nu *= 2.0;
        // No decrease even for a vanishing gradient step: at a minimum within rounding.
        if (!(lambda < 1e32)) return Outcome::kConverged;
      }
    }
    return Outcome::kMaxIterations;
  };

  // Position first (orientation held), then the full pose, from the current state.
  auto attempt = [&]() {
    const int first = s.iterations;
    if (options.position_first) {
      // Orientation fixed at the start: a well-behaved 3-DOF problem that brings the platform
      // close before the rotation is freed.
      const double loose = 1e-6 * std::max(1.0, data.target_lengths.maxCoeff());
      const Outcome o = run(true, first + std::min(options.max_iterations, 50), loose);
      if (o == Outcome::kNumericalFailure) return o;
    }
    return run(false, first + options.max_iterations, options.step_tolerance);
  };
  Outcome outcome = attempt();
  if (outcome == Outcome::kNumericalFailure) {
    return finish(ForwardKinematicsTermination::kNumericalFailure);
  }
  // A local minimum (or no convergence): restart from the position found with other
  // orientations, keep the best. Seeds: start rpy + {-a, 0, a}^3, single axes first.
  if (options.orientation_restarts &&
      (outcome != Outcome::kConverged || res->cwiseAbs().maxCoeff() > options.max_residual)) {
    const Eigen::Vector3d seed_position = position;
    Eigen::Vector3d best_position = position;
    Eigen::Matrix3d best_rotation = rotation;
    double best_cost = cost;
    Outcome best_outcome = outcome;
    const double a = options.restart_angle;
    bool done = false;
    for (int axes = 1; axes <= 3 && !done; ++axes) {
      for (int code = 0; code < 27 && !done; ++code) {
        const int digits[3] = {code % 3 - 1, (code / 3) % 3 - 1, code / 9 - 1};
        if (std::abs(digits[0]) + std::abs(digits[1]) + std::abs(digits[2]) != axes) continue;
        const Eigen::Vector3d rpy =
            start.rpy + a * Eigen::Vector3d(digits[0], digits[1], digits[2]);
        position = seed_position;
        rotation = rotation_from_rpy<double>(rpy);
        if (!inverse_kinematics(model, position, rotation, *cur)) continue;
        *res = cur->lengths - data.target_lengths;
        cost = 0.5 * res->squaredNorm();
        ++s.restarts;
        const Outcome o = attempt();
        if (o == Outcome::kNumericalFailure) continue;
        if (cost < best_cost) {
          best_cost = cost;
          best_position = position;
          best_rotation = rotation;
          best_outcome = o;
        }
        done = o == Outcome::kConverged && res->cwiseAbs().maxCoeff() <= options.max_residual;
      }
    }
    position = best_position;
    rotation = best_rotation;
    outcome = best_outcome;
    inverse_kinematics(model, position, rotation, *cur);
    *res = cur->lengths - data.target_lengths;
    cost = 0.5 * res->squaredNorm();
  }
  if (outcome == Outcome::kConverged) return finish(ForwardKinematicsTermination::kConverged);
  return finish(ForwardKinematicsTermination::kMaxIterations);
}

}  // namespace

ForwardKinematicsSummary forward_kinematics(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& kinematic_lengths,
    const ForwardKinematicsOptions& options, ForwardKinematicsData& data) {
  if (const Status st = check_model_and_data(model, options, data, kinematic_lengths.size());
      !st.ok()) {
    return invalid(st);
  }
  if (!kinematic_lengths.allFinite() || !(kinematic_lengths.minCoeff() > 0.0)) {
    return invalid(Status(ErrorCode::kInvalidArgument,
                          "forward kinematics: cable lengths must be finite and positive"));
  }
  data.target_lengths = kinematic_lengths;
  data.elongations.setZero();
  return solve(model, options, data);
}

ForwardKinematicsSummary forward_kinematics_elastic(
    const RobotModel& model, const Eigen::Ref<const Eigen::VectorXd>& unstretched_lengths,
    const Eigen::Ref<const Eigen::VectorXd>& tensions, const ForwardKinematicsOptions& options,
    ForwardKinematicsData& data) {
  if (const Status st = check_model_and_data(model, options, data, unstretched_lengths.size());
      !st.ok()) {
    return invalid(st);
  }
  const int m = model.num_cables();
  if (tensions.size() != m || static_cast<int>(model.cables.size()) != m) {
    return invalid(Status::error(ErrorCode::kInvalidArgument,
                                 "forward kinematics: %d tensions and %zu cable models for %d "
                                 "cables",
                                 static_cast<int>(tensions.size()), model.cables.size(), m));
  }
  if (!unstretched_lengths.allFinite() || !tensions.allFinite()) {
    return invalid(Status(ErrorCode::kInvalidArgument,
                          "forward kinematics: non-finite cable lengths or tensions"));
  }
  for (int i = 0; i < m; ++i) {
    const CableModel& cable = model.cables[static_cast<std::size_t>(i)];
    const Result<double> loaded = loaded_length_from_unstretched(
        cable, unstretched_lengths(i) + cable.routing_length, tensions(i));
    if (!loaded.ok()) {
      const std::string_view why = loaded.status().message();
      return invalid(Status::error(loaded.status().code(), "forward kinematics, cable %d: %.*s", i,
                                   static_cast<int>(why.size()), why.data()));
    }
    data.target_lengths(i) = *loaded - cable.routing_length;
    data.elongations(i) = data.target_lengths(i) - unstretched_lengths(i);
  }
  if (!(data.target_lengths.minCoeff() > 0.0)) {
    return invalid(
        Status(ErrorCode::kInvalidArgument, "forward kinematics: cable lengths must be positive"));
  }
  return solve(model, options, data);
}

}  // namespace cdpr
