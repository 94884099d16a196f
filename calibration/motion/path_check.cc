#include "cdpr/calibration/path_check.hpp"

#include <algorithm>
#include <cmath>

#include "cdpr/calibration/force_distribution.hpp"

namespace cdpr {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;
// Stand-in for "no limit" on one side when explaining an infeasible pose (finite, as
// distribute_forces requires; far above any cable's strength).
constexpr double kUnbounded = 1e12;
// Beyond this many points a path check is refused (steps too small for the move).
constexpr double kMaxPoints = 1e7;

bool sizes_ok(const RobotModel& model, const KinematicsData& kinematics) {
  const int m = model.num_cables();
  return m >= 1 && m <= kMaxCables && static_cast<int>(model.cables.size()) == m &&
         kinematics.lengths.size() == m;
}

// The band [f_min + margin, f_max - margin]; kInvalidArgument naming the cable when empty.
Status band(const RobotModel& model, double margin, CableVector& lo, CableVector& hi) {
  const int m = model.num_cables();
  lo.resize(m);
  hi.resize(m);
  for (int i = 0; i < m; ++i) {
    const CableModel& c = model.cables[static_cast<std::size_t>(i)];
    lo(i) = c.f_min + margin;
    hi(i) = c.f_max - margin;
    if (!(lo(i) <= hi(i))) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "cable %d: f_min %g N + margin %g N exceeds f_max %g N - margin", i + 1,
                           c.f_min, margin, c.f_max);
    }
  }
  return Status::success();
}

// " - margin 10 N" when there is a margin.
void margin_text(double margin, const char* sign, char* buf, std::size_t n) {
  if (margin > 0.0) {
    std::snprintf(buf, n, " %s margin %g N", sign, margin);
  } else if (n > 0) {
    buf[0] = '\0';
  }
}

// Why no tensions in the band balance the platform at the pose in `kinematics`: relax the upper
// limits (the distribution with the least tensions that keeps every cable above its lower limit);
// if one then exceeds its upper limit, name it. Else keeping every cable taut is impossible: relax
// the lower limits and name the cable that falls furthest below its lower limit.
Status explain_infeasible(const RobotModel& model, const KinematicsData& kinematics,
                          double reference, double margin) {
  const int m = model.num_cables();
  CableVector lo, hi;
  if (Status s = band(model, margin, lo, hi); !s.ok()) return s;
  const Wrench6 w = gravity_wrench(model, kinematics.rotation);
  ForceDistributionOptions options;
  char extra[64];

  CableVector relaxed = CableVector::Constant(m, kUnbounded);
  options.reference_tension = lo.minCoeff();
  ForceDistributionResult r =
      distribute_forces(kinematics.structure_matrix, w, lo, relaxed, options);
  if (r.feasible()) {
    int worst = -1;
    double excess = 0.0;
    for (int i = 0; i < m; ++i) {
      if (r.tensions(i) - hi(i) > excess) {
        excess = r.tensions(i) - hi(i);
        worst = i;
      }
    }
    if (worst >= 0) {
      margin_text(margin, "-", extra, sizeof extra);
      return Status::error(ErrorCode::kOutOfRange, "cable %d would need %.1f N > f_max %g N%s",
                           worst + 1, r.tensions(worst),
                           model.cables[static_cast<std::size_t>(worst)].f_max, extra);
    }
  }
  relaxed.setConstant(m, -kUnbounded);
  options.reference_tension = reference;
  r = distribute_forces(kinematics.structure_matrix, w, relaxed, hi, options);
  if (r.feasible()) {
    int worst = -1;
    double shortfall = 0.0;
    for (int i = 0; i < m; ++i) {
      if (lo(i) - r.tensions(i) > shortfall) {
        shortfall = lo(i) - r.tensions(i);
        worst = i;
      }
    }
    if (worst >= 0) {
      margin_text(margin, "+", extra, sizeof extra);
      return Status::error(ErrorCode::kOutOfRange, "cable %d would need %.1f N < f_min %g N%s",
                           worst + 1, r.tensions(worst),
                           model.cables[static_cast<std::size_t>(worst)].f_min, extra);
    }
  }
  return Status(ErrorCode::kOutOfRange,
                "no cable tensions within the limits balance the platform's weight");
}

enum class Failure { kNone, kBox, kDegenerate, kLength, kInterference, kWrench, kInput };

// What a failure means for a pose ("is ...") and along a path ("... at").
const char* pose_failure_text(Failure f) {
  switch (f) {
    case Failure::kBox:
      return "is outside the workspace box";
    case Failure::kDegenerate:
      return "is not reachable";
    case Failure::kLength:
      return "is outside the cable length limits";
    case Failure::kInterference:
      return "has touching cables";
    case Failure::kWrench:
      return "is outside the wrench-feasible workspace";
    default:
      return "cannot be checked";
  }
}
const char* path_failure_text(Failure f) {
  switch (f) {
    case Failure::kBox:
      return "leaves the workspace box";
    case Failure::kDegenerate:
      return "meets a degenerate pose";
    case Failure::kLength:
      return "leaves the cable length limits";
    case Failure::kInterference:
      return "makes cables touch";
    case Failure::kWrench:
      return "leaves the wrench-feasible workspace";
    default:
      return "cannot be checked";
  }
}

// Cable lengths within the limits and no two spans closer than the cable diameter.
Status check_cables(const RobotModel& model, const KinematicsData& k,
                    const PathCheckOptions& options, Failure& failure) {
  const int m = model.num_cables();
  for (int i = 0; i < m; ++i) {
    const double L = k.lengths(i);
    const auto u = static_cast<std::size_t>(i);
    const double lo =
        options.min_cable_lengths.empty() ? options.min_cable_length : options.min_cable_lengths[u];
    const double hi =
        options.max_cable_lengths.empty() ? options.max_cable_length : options.max_cable_lengths[u];
    if (L < lo || L > hi) {
      failure = Failure::kLength;
      const bool above = L > hi;
      return Status::error(ErrorCode::kOutOfRange, "cable %d is %.4f m long %s %.4f m", i + 1, L,
                           above ? ">" : "<", above ? hi : lo);
    }
  }
  const double d = options.cable_diameter;
  if (!(d > 0.0)) return Status::success();
  for (int i = 0; i < m; ++i) {
    for (int j = i + 1; j < m; ++j) {
      const auto ai = model.frame_anchors.col(i), aj = model.frame_anchors.col(j);
      const auto bi = k.platform_points.col(i), bj = k.platform_points.col(j);
      if ((ai - aj).norm() < d || (bi - bj).norm() < d) continue;  // they meet by design
      const double dist = segment_distance(ai, bi, aj, bj);
      if (dist < d) {
        failure = Failure::kInterference;
        return Status::error(ErrorCode::kOutOfRange,
                             "cables %d and %d pass %.4f m apart < cable diameter %.4f m", i + 1,
                             j + 1, dist, d);
      }
    }
  }
  return Status::success();
}

struct Verdict {
  Failure failure = Failure::kNone;
  Status reason;
};

// One point of a path (or a single pose): box, inverse kinematics, tension plan. On failure the
// reason without the point (the caller names it).
Verdict check_point(const RobotModel& model, const Eigen::Vector3d& position,
                    const Eigen::Matrix3d& rotation, double reference,
                    const PathCheckOptions& options, KinematicsData& kinematics, TensionPlan& plan,
                    PathCheckSummary* summary, double s) {
  Verdict v;
  if (options.workspace_box && !options.workspace_box->contains(position)) {
    static constexpr char kAxis[3] = {'x', 'y', 'z'};
    const Eigen::AlignedBox3d& box = *options.workspace_box;
    for (int k = 0; k < 3; ++k) {
      if (position(k) < box.min()(k) || position(k) > box.max()(k)) {
        const bool above = position(k) > box.max()(k);
        v.failure = Failure::kBox;
        v.reason =
            Status::error(ErrorCode::kOutOfRange, "%c = %.4f m %s %.4f m", kAxis[k], position(k),
                          above ? ">" : "<", above ? box.max()(k) : box.min()(k));
        return v;
      }
    }
  }
  if (!inverse_kinematics(model, position, rotation, kinematics)) {
    v.failure = Failure::kDegenerate;
    v.reason =
        Status::error(ErrorCode::kNumericalFailure,
                      "cable %d is degenerate (its platform anchor is on its frame anchor or "
                      "inside its pulley circle)",
                      kinematics.invalid_cable + 1);
    return v;
  }
  if (Status c = check_cables(model, kinematics, options, v.failure); !c.ok()) {
    v.reason = c;
    return v;
  }
  const Status planned = plan_tensions(model, kinematics, reference, options.tension_margin, plan);
  if (!planned.ok()) {
    if (planned.code() == ErrorCode::kOutOfRange) {
      v.failure = Failure::kWrench;
      v.reason = explain_infeasible(model, kinematics, reference, options.tension_margin);
    } else {
      v.failure =
          planned.code() == ErrorCode::kNumericalFailure ? Failure::kDegenerate : Failure::kInput;
      v.reason = planned;
    }
    return v;
  }
  if (summary != nullptr) {
    ++summary->points;
    for (int i = 0; i < model.num_cables(); ++i) {
      const CableModel& c = model.cables[static_cast<std::size_t>(i)];
      const double slack = std::min(plan.tensions(i) - c.f_min, c.f_max - plan.tensions(i));
      if (slack < summary->min_tension_slack) {
        summary->min_tension_slack = slack;
        summary->min_slack_s = s;
        summary->min_slack_cable = i + 1;
      }
    }
  }
  return v;
}

Status validate_options(const RobotModel& model, const PathCheckOptions& options,
                        double* reference) {
  const int m = model.num_cables();
  if (m < 1 || m > kMaxCables || static_cast<int>(model.cables.size()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: the model has %d cables and %d cable descriptions (1 to %d "
                         "cables supported)",
                         m, static_cast<int>(model.cables.size()), kMaxCables);
  }
  if (!(std::isfinite(options.max_linear_step) && options.max_linear_step > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: max_linear_step must be finite and > 0 (got %g)",
                         options.max_linear_step);
  }
  if (!(std::isfinite(options.max_angular_step) && options.max_angular_step > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: max_angular_step must be finite and > 0 (got %g)",
                         options.max_angular_step);
  }
  if (!(std::isfinite(options.tension_margin) && options.tension_margin >= 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: tension_margin must be finite and >= 0 (got %g)",
                         options.tension_margin);
  }
  *reference = std::isnan(options.reference_tension) ? default_reference_tension(model)
                                                     : options.reference_tension;
  if (!(std::isfinite(*reference) && *reference > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: reference_tension must be finite and > 0 (got %g)",
                         *reference);
  }
  if (!(options.min_cable_length >= 0.0 && options.max_cable_length > options.min_cable_length) ||
      !(std::isfinite(options.cable_diameter) && options.cable_diameter >= 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: need 0 <= min_cable_length < max_cable_length (got %g, %g) "
                         "and a finite cable_diameter >= 0 (got %g)",
                         options.min_cable_length, options.max_cable_length,
                         options.cable_diameter);
  }
  for (const std::vector<double>* v : {&options.min_cable_lengths, &options.max_cable_lengths}) {
    if (!v->empty() && v->size() != static_cast<std::size_t>(m)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "path check: %zu per-cable length limits for %d cables", v->size(), m);
    }
  }
  for (std::size_t i = 0;
       i < options.min_cable_lengths.size() && !options.max_cable_lengths.empty(); ++i) {
    if (!(options.min_cable_lengths[i] >= 0.0 &&
          options.max_cable_lengths[i] > options.min_cable_lengths[i])) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "path check: cable %zu: need 0 <= min < max length (got %g, %g)", i + 1,
                           options.min_cable_lengths[i], options.max_cable_lengths[i]);
    }
  }
  if (options.workspace_box &&
      (!options.workspace_box->min().allFinite() || !options.workspace_box->max().allFinite() ||
       options.workspace_box->isEmpty())) {
    return Status(ErrorCode::kInvalidArgument,
                  "path check: workspace_box must be finite with min <= max on every axis");
  }
  CableVector lo, hi;
  if (Status s = band(model, options.tension_margin, lo, hi); !s.ok()) {
    return s.prepend("path check: ");
  }
  return Status::success();
}

// "(0.300, 0.000, 0.000) m, (0.0, 0.0, 0.0) deg"
void pose_text(const Pose& pose, char* buf, std::size_t n) {
  std::snprintf(buf, n, "(%.3f, %.3f, %.3f) m, (%.1f, %.1f, %.1f) deg", pose.position.x(),
                pose.position.y(), pose.position.z(), pose.rpy.x() * kRadToDeg,
                pose.rpy.y() * kRadToDeg, pose.rpy.z() * kRadToDeg);
}

}  // namespace

namespace {

// The checks of plan_tensions' input and the band; kOk or the error to return.
Status plan_input(const RobotModel& model, const KinematicsData& kinematics,
                  double reference_tension, double margin, CableVector& lo, CableVector& hi) {
  if (!sizes_ok(model, kinematics)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "tension plan: model with %d cables (1 to %d supported) or scratch data "
                         "of another size",
                         model.num_cables(), kMaxCables);
  }
  if (!(std::isfinite(reference_tension) && reference_tension > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "tension plan: reference tension must be finite and > 0 (got %g)",
                         reference_tension);
  }
  if (!(std::isfinite(margin) && margin >= 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "tension plan: margin must be finite and >= 0 (got %g)", margin);
  }
  if (Status s = band(model, margin, lo, hi); !s.ok()) return s.prepend("tension plan: ");
  return Status::success();
}

// One QP nearest to `reference` into `plan`; the error of an outcome that no reference changes
// (degenerate, invalid, infeasible), else success (feasible or not found: see plan.outcome).
Status plan_attempt(const StructureFactor& factor, const Wrench6& w, const CableVector& lo,
                    const CableVector& hi, double reference, TensionPlan& plan) {
  ForceDistributionOptions options;
  options.reference_tension = reference;
  const ForceDistributionResult r = distribute_forces(factor, w, lo, hi, options);
  plan.outcome = r.outcome;
  plan.tensions = r.tensions;
  plan.reference = reference;
  plan.cables_at_limits = r.cables_at_limits;
  switch (r.outcome) {
    case ForceDistributionOutcome::kDegenerate:
      return Status(ErrorCode::kNumericalFailure, r.status.message()).prepend("tension plan: ");
    case ForceDistributionOutcome::kInvalidInput:
      return Status(ErrorCode::kInvalidArgument, r.status.message()).prepend("tension plan: ");
    case ForceDistributionOutcome::kInfeasible:  // the same at any reference
      return Status(ErrorCode::kOutOfRange,
                    "tension plan: no tensions within the cable limits balance the platform "
                    "(outside the wrench-feasible workspace)");
    case ForceDistributionOutcome::kFeasible:
    case ForceDistributionOutcome::kNotFound:
      break;
  }
  return Status::success();
}

Status not_found() {
  return Status(ErrorCode::kOutOfRange,
                "tension plan: the QP found no tensions within the cable limits");
}

}  // namespace

Status plan_tensions(const RobotModel& model, const KinematicsData& kinematics,
                     const StructureFactor& factor, double reference_tension, double margin,
                     TensionPlan& plan) {
  plan.outcome = ForceDistributionOutcome::kInvalidInput;
  CableVector lo, hi;
  CDPR_RETURN_IF_ERROR(plan_input(model, kinematics, reference_tension, margin, lo, hi));
  const Wrench6 w = gravity_wrench(model, kinematics.rotation);
  for (const double scale : {1.0, 2.0, 4.0}) {
    CDPR_RETURN_IF_ERROR(plan_attempt(factor, w, lo, hi, scale * reference_tension, plan));
    if (plan.outcome == ForceDistributionOutcome::kFeasible && plan.cables_at_limits == 0) {
      return Status::success();
    }
  }
  if (plan.outcome == ForceDistributionOutcome::kFeasible) return Status::success();
  return not_found();
}

Status plan_tensions(const RobotModel& model, const KinematicsData& kinematics,
                     double reference_tension, double margin, TensionPlan& plan) {
  StructureFactor factor;
  factor.compute(kinematics.structure_matrix);
  return plan_tensions(model, kinematics, factor, reference_tension, margin, plan);
}

Status plan_tensions_at(const RobotModel& model, const KinematicsData& kinematics,
                        const StructureFactor& factor, double reference_tension, double margin,
                        TensionPlan& plan) {
  plan.outcome = ForceDistributionOutcome::kInvalidInput;
  CableVector lo, hi;
  CDPR_RETURN_IF_ERROR(plan_input(model, kinematics, reference_tension, margin, lo, hi));
  CDPR_RETURN_IF_ERROR(plan_attempt(factor, gravity_wrench(model, kinematics.rotation), lo, hi,
                                    reference_tension, plan));
  if (plan.outcome == ForceDistributionOutcome::kFeasible) return Status::success();
  return not_found();
}

Status plan_tensions_at(const RobotModel& model, const KinematicsData& kinematics,
                        double reference_tension, double margin, TensionPlan& plan) {
  StructureFactor factor;
  factor.compute(kinematics.structure_matrix);
  return plan_tensions_at(model, kinematics, factor, reference_tension, margin, plan);
}

Status check_pose(const RobotModel& model, const Pose& pose, const PathCheckOptions& options,
                  PathCheckSummary* summary) {
  if (summary != nullptr) *summary = PathCheckSummary{};
  double reference = 0.0;
  if (Status s = validate_options(model, options, &reference); !s.ok()) return s;
  if (!pose.vector().allFinite()) {
    return Status(ErrorCode::kInvalidArgument, "pose check: the pose is not finite");
  }
  KinematicsData kinematics(model);
  TensionPlan plan;
  const Verdict v = check_point(model, pose.position, rotation_from_rpy<double>(pose.rpy),
                                reference, options, kinematics, plan, summary, 0.0);
  if (v.failure == Failure::kNone) return Status::success();
  const char* what = pose_failure_text(v.failure);
  char where[160];
  pose_text(pose, where, sizeof where);
  const std::string_view reason = v.reason.message();
  return Status::error(v.reason.code(), "pose %s %s: %.*s", where, what,
                       static_cast<int>(reason.size()), reason.data());
}

Status check_path(const RobotModel& model, const PoseTrajectory& trajectory,
                  const PathCheckOptions& options, PathCheckSummary* summary) {
  if (summary != nullptr) *summary = PathCheckSummary{};
  double reference = 0.0;
  if (Status s = validate_options(model, options, &reference); !s.ok()) return s;
  const double points =
      std::max({1.0, std::ceil(trajectory.linear_distance() / options.max_linear_step),
                std::ceil(trajectory.angular_distance() / options.max_angular_step)});
  if (points > kMaxPoints) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: %.3g points for a move of %g m and %g rad (steps %g m, %g "
                         "rad too small)",
                         points, trajectory.linear_distance(), trajectory.angular_distance(),
                         options.max_linear_step, options.max_angular_step);
  }
  const int n = static_cast<int>(points);
  KinematicsData kinematics(model);
  TensionPlan plan;
  Eigen::Vector3d position;
  Eigen::Matrix3d rotation;
  for (int k = 0; k <= n; ++k) {
    const double s = k == n ? 1.0 : static_cast<double>(k) / n;
    trajectory.path_point(s, position, rotation);
    const Verdict v =
        check_point(model, position, rotation, reference, options, kinematics, plan, summary, s);
    if (v.failure == Failure::kNone) continue;
    const char* what = path_failure_text(v.failure);
    char target[160];
    pose_text(trajectory.to(), target, sizeof target);
    const std::string_view reason = v.reason.message();
    return Status::error(v.reason.code(), "move to %s %s at s = %.3f (%.3f, %.3f, %.3f) m: %.*s",
                         target, what, s, position.x(), position.y(), position.z(),
                         static_cast<int>(reason.size()), reason.data());
  }
  return Status::success();
}

Status check_path(const RobotModel& model, const Path& path, const PathCheckOptions& options,
                  PathCheckSummary* summary) {
  if (summary != nullptr) *summary = PathCheckSummary{};
  double reference = 0.0;
  if (Status s = validate_options(model, options, &reference); !s.ok()) return s;
  double total = 0.0;
  for (const PathMotion& m : path.motions()) {
    const double span = m.sigma_end - m.sigma_begin;
    total += 1.0 + std::max({1.0, std::ceil(span * m.max_linear_rate / options.max_linear_step),
                             std::ceil(span * m.max_angular_rate / options.max_angular_step)});
  }
  if (total > kMaxPoints) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "path check: %.3g points for a path of %g m (steps %g m, %g rad too "
                         "small)",
                         total, path.length(), options.max_linear_step, options.max_angular_step);
  }
  KinematicsData kinematics(model);
  TensionPlan plan;
  Eigen::Vector3d position;
  Eigen::Matrix3d rotation;
  auto check = [&](double sigma) -> Status {
    path.path_point(sigma, position, rotation);
    const Verdict v = check_point(model, position, rotation, reference, options, kinematics, plan,
                                  summary, sigma);
    if (v.failure == Failure::kNone) return Status::success();
    const std::string_view reason = v.reason.message();
    return Status::error(
        v.reason.code(), "path line %d %s at sigma = %.3f m (%.3f, %.3f, %.3f) m: %.*s",
        path.line_at(sigma), path_failure_text(v.failure), sigma, position.x(), position.y(),
        position.z(), static_cast<int>(reason.size()), reason.data());
  };
  if (path.motions().empty()) return check(0.0);
  for (const PathMotion& m : path.motions()) {
    const double span = m.sigma_end - m.sigma_begin;
    const int n = static_cast<int>(
        std::max({1.0, std::ceil(span * m.max_linear_rate / options.max_linear_step),
                  std::ceil(span * m.max_angular_rate / options.max_angular_step)}));
    for (int k = 0; k <= n; ++k) {
      const double sigma = k == n ? m.sigma_end : m.sigma_begin + span * k / n;
      if (Status s = check(sigma); !s.ok()) return s;
    }
  }
  return Status::success();
}

double segment_distance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1,
                        const Eigen::Vector3d& q0, const Eigen::Vector3d& q1) {
  // Closest points p0 + s d1, q0 + t d2 with s, t in [0, 1] (clamped, then re-solved).
  const Eigen::Vector3d d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0.0, t = 0.0;
  if (a <= 1e-300 && e <= 1e-300) return r.norm();
  if (a <= 1e-300) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 1e-300) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2), denom = a * e - b * b;
      s = denom > 1e-300 ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0.0) {
        t = 0.0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1.0) {
        t = 1.0;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  return ((p0 + s * d1) - (q0 + t * d2)).norm();
}

Status command_counts(const RobotModel& model, const Pose& pose, double reference_tension,
                      CommandData& data, std::span<const double> margins, int* chosen) {
  *chosen = -1;
  const int m = model.num_cables();
  if (!sizes_ok(model, data.kinematics) || data.cable.counts.size() != m ||
      data.cable.kinematics.lengths.size() != m || static_cast<int>(model.winches.size()) != m ||
      margins.empty()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "command: model with %d cables (1 to %d supported), command data of "
                         "another size or no margin",
                         m, kMaxCables);
  }
  if (!inverse_kinematics(model, pose, data.kinematics)) {
    return Status::error(ErrorCode::kNumericalFailure,
                         "command: cable %d is degenerate at the pose",
                         data.kinematics.invalid_cable + 1);
  }
  data.factor.compute(data.kinematics.structure_matrix);
  Status last;
  for (std::size_t j = 0; j < margins.size(); ++j) {
    last = plan_tensions(model, data.kinematics, data.factor, reference_tension, margins[j],
                         data.plan);
    if (last.ok()) {
      compensate_lengths(model, data.kinematics, data.plan.tensions, data.cable);
      *chosen = static_cast<int>(j);
      return Status::success();
    }
  }
  return last.prepend("command: ");
}

Status command_counts(const RobotModel& model, const Pose& pose, double reference_tension,
                      CommandData& data, double margin) {
  int chosen = -1;
  return command_counts(model, pose, reference_tension, data, std::span<const double>(&margin, 1),
                        &chosen);
}

}  // namespace cdpr
