#include "cdpr/calibration/model_check.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <limits>
#include <string>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/suspended_statics.hpp"

namespace cdpr {
namespace {

bool finite(double v) {
  return std::isfinite(v);
}
template <typename Derived>
bool finite(const Eigen::MatrixBase<Derived>& m) {
  return m.allFinite();
}

Status not_finite(const char* prefix, const char* field) {
  return Status::error(ErrorCode::kInvalidArgument, "%s%s: expected finite numbers, got NaN or inf",
                       prefix, field);
}

Status check_positive(const char* prefix, const char* field, double v, const char* unit) {
  if (!finite(v)) return not_finite(prefix, field);
  if (!(v > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s%s: expected a positive number (%s), got %g", prefix, field, unit, v);
  }
  return Status::success();
}

Status check_non_negative(const char* prefix, const char* field, double v, const char* unit) {
  if (!finite(v)) return not_finite(prefix, field);
  if (!(v >= 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s%s: expected a non-negative number (%s), got %g", prefix, field, unit,
                         v);
  }
  return Status::success();
}

Status check_unit(const char* prefix, const char* field, const Eigen::Vector3d& v, double tol) {
  if (!finite(v)) return not_finite(prefix, field);
  const double n = v.norm();
  if (std::abs(n - 1.0) > tol) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s%s: expected a unit vector, got [%g, %g, %g] of length %g", prefix,
                         field, v.x(), v.y(), v.z(), n);
  }
  return Status::success();
}

Status check_cable(const RobotModel& model, int i, const ModelCheckOptions& options) {
  const auto k = static_cast<std::size_t>(i);
  char p[40];
  std::snprintf(p, sizeof(p), "cables[%d].", i);
  if (!finite(model.frame_anchors.col(i))) return not_finite(p, "frame_anchor");
  if (!finite(model.platform_anchors.col(i))) return not_finite(p, "platform_anchor");

  const PulleyModel& pulley = model.pulleys[k];
  CDPR_RETURN_IF_ERROR(check_non_negative(p, "pulley.radius", pulley.radius, "m"));
  if (!finite(pulley.frame)) return not_finite(p, "pulley");
  const Eigen::Matrix3d gram = pulley.frame.transpose() * pulley.frame;
  const double orthonormality = (gram - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthonormality > options.unit_tolerance || pulley.frame.determinant() < 0.0) {
    return Status::error(
        ErrorCode::kInvalidArgument,
        "%spulley: the pulley frame (columns reference, axis x reference, axis) is "
        "not a right-handed orthonormal frame (|R^T R - I| = %g, det = %g)",
        p, orthonormality, pulley.frame.determinant());
  }

  const WinchModel& w = model.winches[k];
  CDPR_RETURN_IF_ERROR(check_positive(p, "winch.drum_diameter", w.drum_diameter, "m"));
  CDPR_RETURN_IF_ERROR(check_non_negative(p, "winch.drum_pitch", w.drum_pitch, "m"));
  CDPR_RETURN_IF_ERROR(
      check_positive(p, "winch.gear_ratio", w.gear_ratio, "motor rev per drum rev"));
  CDPR_RETURN_IF_ERROR(check_positive(p, "winch.counts_per_rev", w.counts_per_rev, "counts"));
  if (!finite(w.length_offset)) return not_finite(p, "winch.length_offset");
  if (w.direction != 1 && w.direction != -1) {
    return Status::error(ErrorCode::kInvalidArgument, "%swinch.direction: expected 1 or -1, got %d",
                         p, w.direction);
  }

  const CableModel& c = model.cables[k];
  CDPR_RETURN_IF_ERROR(check_positive(p, "ea", c.ea, "N"));
  CDPR_RETURN_IF_ERROR(check_non_negative(p, "mass_per_length", c.mass_per_length, "kg/m"));
  CDPR_RETURN_IF_ERROR(check_non_negative(p, "routing_length", c.routing_length, "m"));
  CDPR_RETURN_IF_ERROR(check_non_negative(p, "f_min", c.f_min, "N"));
  CDPR_RETURN_IF_ERROR(check_positive(p, "f_max", c.f_max, "N"));
  if (c.f_min > c.f_max) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%sf_min: the minimum tension %g N is above the maximum f_max = %g N", p,
                         c.f_min, c.f_max);
  }
  if (c.elongation == ElongationKind::kPolynomial) {
    const int n = c.polynomial.order;
    if (n < 0) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%selongation.order: expected a non-negative order, got %d", p, n);
    }
    const std::size_t expected = static_cast<std::size_t>((n + 1) * (n + 2) / 2);
    if (c.polynomial.coefficients.size() != expected) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%selongation.coefficients: order %d needs %zu coefficients, got %zu", p,
                           n, expected, c.polynomial.coefficients.size());
    }
    for (double v : c.polynomial.coefficients) {
      if (!finite(v)) return not_finite(p, "elongation.coefficients");
    }
    if (!finite(c.polynomial.length_center)) return not_finite(p, "elongation.length_center");
    if (!finite(c.polynomial.tension_center)) return not_finite(p, "elongation.tension_center");
    CDPR_RETURN_IF_ERROR(
        check_positive(p, "elongation.length_scale", c.polynomial.length_scale, "m"));
    CDPR_RETURN_IF_ERROR(
        check_positive(p, "elongation.tension_scale", c.polynomial.tension_scale, "N"));
  }

  const ForceSensorModel& s = model.force_sensors[k];
  if (!finite(s.gain)) return not_finite(p, "force_sensor.gain");
  if (s.gain == 0.0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%sforce_sensor.gain: expected a non-zero number, got 0", p);
  }
  if (!finite(s.offset)) return not_finite(p, "force_sensor.offset");
  return Status::success();
}

Status check_sizes(const RobotModel& model) {
  const std::size_t m = static_cast<std::size_t>(model.num_cables());
  auto mismatch = [&](const char* field, std::size_t n) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s: expected one entry per cable (%zu, the number of frame anchors), got "
                         "%zu",
                         field, m, n);
  };
  if (static_cast<std::size_t>(model.platform_anchors.cols()) != m) {
    return mismatch("platform_anchors", static_cast<std::size_t>(model.platform_anchors.cols()));
  }
  if (model.pulleys.size() != m) return mismatch("pulleys", model.pulleys.size());
  if (model.winches.size() != m) return mismatch("winches", model.winches.size());
  if (model.cables.size() != m) return mismatch("cables", model.cables.size());
  if (model.force_sensors.size() != m) return mismatch("force_sensors", model.force_sensors.size());
  if (!model.swivel_encoders.empty() && model.swivel_encoders.size() != m) {
    return mismatch("swivel_encoders", model.swivel_encoders.size());
  }
  for (std::size_t k = 0; k < model.swivel_encoders.size(); ++k) {
    const SwivelEncoderModel& e = model.swivel_encoders[k];
    if (!std::isfinite(e.zero)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "cables[%zu].swivel_encoder.zero: expected a finite number (rad)", k);
    }
    if (e.direction != 1 && e.direction != -1) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "cables[%zu].swivel_encoder.direction: expected 1 or -1, got %d", k,
                           e.direction);
    }
  }
  if (!model.inclinometer.mounting_rpy.allFinite() || !std::isfinite(model.inclinometer.yaw_zero)) {
    return Status(ErrorCode::kInvalidArgument,
                  "inclinometer: mounting_rpy and yaw_zero must be finite (rad)");
  }
  return Status::success();
}

Status check_platform(const PlatformModel& p) {
  CDPR_RETURN_IF_ERROR(check_positive("", "platform.mass", p.mass, "kg"));
  if (!finite(p.center_of_mass)) return not_finite("", "platform.center_of_mass");
  if (!finite(p.inertia)) return not_finite("", "platform.inertia");
  const double asym = (p.inertia - p.inertia.transpose()).cwiseAbs().maxCoeff();
  if (asym > 1e-12 * (1.0 + p.inertia.cwiseAbs().maxCoeff())) {
    return Status(ErrorCode::kInvalidArgument,
                  "platform.inertia: expected a symmetric matrix (kg m^2)");
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(p.inertia, Eigen::EigenvaluesOnly);
  if (!(eig.eigenvalues()(0) > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "platform.inertia: expected a positive definite matrix (kg m^2), smallest "
                         "eigenvalue %g",
                         eig.eigenvalues()(0));
  }
  return Status::success();
}

Status check_laser(const LaserModel& l, int j, double tol) {
  char p[40];
  std::snprintf(p, sizeof(p), "lasers[%d].", j);
  if (!finite(l.origin)) return not_finite(p, "origin");
  if (!finite(l.plane_point)) return not_finite(p, "plane_point");
  if (!finite(l.direction) || l.direction.norm() == 0.0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%sdirection: expected a unit vector, got a zero or non-finite vector", p);
  }
  CDPR_RETURN_IF_ERROR(check_unit(p, "direction", l.direction, tol));
  CDPR_RETURN_IF_ERROR(check_unit(p, "plane_normal", l.plane_normal, tol));
  CDPR_RETURN_IF_ERROR(check_non_negative(p, "range", l.range_min, "m"));
  if (!finite(l.range_max) || !(l.range_max > l.range_min)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%srange: expected [min, max] with 0 <= min < max (m), got [%g, %g]", p,
                         l.range_min, l.range_max);
  }
  return Status::success();
}

// Suspended robot with m < 6 cables: the platform must hang at home.
Status check_suspended_home(const RobotModel& model, const ModelCheckOptions& options) {
  const int m = model.num_cables();
  if (!(model.gravity > 0.0)) {
    return Status(ErrorCode::kInvalidArgument,
                  "gravity: a suspended robot needs gravity > 0 (only the weight keeps its "
                  "cables taut)");
  }
  Result<SuspendedState> s = suspended_tensions(model, model.home);
  if (!s.ok()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables: at the home pose a cable is degenerate (%s)",
                         std::string(s.status().message()).c_str());
  }
  const double weight = model.platform.mass * model.gravity;
  if (s->wrench_residual > options.equilibrium_tolerance * weight) {
    // Where it would hang instead, for the message.
    std::string hint;
    SuspendedOptions so;
    so.min_tension = -std::numeric_limits<double>::infinity();
    if (const Result<SuspendedState> eq = suspended_equilibrium_pose(model, model.home, so);
        eq.ok()) {
      char buf[160];
      std::snprintf(buf, sizeof(buf), "; at this position it would hang at rpy [%.6g, %.6g, %.6g]",
                    eq->pose.rpy.x(), eq->pose.rpy.y(), eq->pose.rpy.z());
      hint = buf;
    }
    return Status::error(ErrorCode::kInvalidArgument,
                         "home.rpy: a suspended robot with %d cables must be in static "
                         "equilibrium at home, but there its cables cannot balance the weight "
                         "(%.3g N of %.3g N left over)%s",
                         m, s->wrench_residual, weight, hint.c_str());
  }
  for (int i = 0; i < m; ++i) {
    const CableModel& c = model.cables[static_cast<std::size_t>(i)];
    const double f = s->tensions(i);
    if (!(f > 0.0)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "cables[%d]: at the home pose this cable would have to push (%.3g N) "
                           "to hold the platform: a suspended platform cannot hang there",
                           i, f);
    }
    // Below f_min is accepted: the platform hangs there on its own (a calibrated geometry may put
    // a cable a little below the planner's floor at home; the planner keeps f_min elsewhere). A
    // cable that cannot hold its share is refused.
    if (f > c.f_max) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "cables[%d]: hanging at home needs %.4g N, outside [f_min, f_max] = "
                           "[%g, %g] N: more than the cable may carry",
                           i, f, c.f_min, c.f_max);
    }
  }
  return Status::success();
}

}  // namespace

StructureConditioning structure_conditioning(const RobotModel& model, const Pose& pose,
                                             double rank_tolerance) {
  StructureConditioning out;
  KinematicsData data(model);
  if (!inverse_kinematics(model, pose, data)) {
    out.invalid_cable = data.invalid_cable;
    return out;
  }
  out.valid = true;
  Eigen::MatrixXd a = data.structure_matrix;
  a.bottomRows<3>() /= model.platform_radius();
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a);
  const Eigen::VectorXd& sv = svd.singularValues();
  const int n = static_cast<int>(sv.size());
  for (int k = 0; k < 6; ++k) out.singular_values(k) = k < n ? sv(k) : 0.0;
  const double smax = out.singular_values(0);
  out.rank = 0;
  for (int k = 0; k < 6; ++k) {
    if (out.singular_values(k) > rank_tolerance * smax && smax > 0.0) ++out.rank;
  }
  out.condition_number =
      out.rank == 6 ? smax / out.singular_values(5) : std::numeric_limits<double>::infinity();
  return out;
}

Status check_model(const RobotModel& model, const ModelCheckOptions& options) {
  const int m = model.num_cables();
  const bool underactuated = model.suspended && m < 6;
  if (underactuated && m < 3) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables: a suspended robot needs at least 3 cables, got %d (with fewer "
                         "the platform is free to turn about the cable line)",
                         m);
  }
  if (!underactuated && m < options.min_cables) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables: a spatial robot needs at least %d cables, got %d (a platform "
                         "that hangs from fewer cables: declare `suspended: true`)",
                         options.min_cables, m);
  }
  CDPR_RETURN_IF_ERROR(check_sizes(model));
  for (int i = 0; i < m; ++i) CDPR_RETURN_IF_ERROR(check_cable(model, i, options));
  CDPR_RETURN_IF_ERROR(check_platform(model.platform));
  if (!finite(model.gravity) || model.gravity < 0.0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "gravity: expected a non-negative number (m/s^2), got %g", model.gravity);
  }
  for (std::size_t j = 0; j < model.lasers.size(); ++j) {
    CDPR_RETURN_IF_ERROR(check_laser(model.lasers[j], static_cast<int>(j), options.unit_tolerance));
  }
  if (!finite(model.home.position)) return not_finite("", "home.position");
  if (!finite(model.home.rpy)) return not_finite("", "home.rpy");

  // Platform anchors that coincide (e.g. all at the origin) are legal; the structure matrix
  // below tells whether the geometry can hold the platform.
  const StructureConditioning sc =
      structure_conditioning(model, model.home, options.rank_tolerance);
  if (!sc.valid) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables[%d].frame_anchor: at the home pose the platform anchor lies on "
                         "the frame anchor or inside its pulley (degenerate cable)",
                         sc.invalid_cable);
  }
  if (underactuated) return check_suspended_home(model, options);
  if (sc.rank < 6) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables: the structure matrix at the home pose has rank %d < 6 (the "
                         "anchors cannot hold the platform in all six directions)",
                         sc.rank);
  }
  if (sc.condition_number > options.max_condition_number) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cables: the structure matrix at the home pose is badly conditioned "
                         "(condition number %.3g > %.3g)",
                         sc.condition_number, options.max_condition_number);
  }
  return Status::success();
}

}  // namespace cdpr
