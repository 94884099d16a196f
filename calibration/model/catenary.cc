#include "cdpr/calibration/catenary.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

namespace cdpr {

namespace {

struct CatenaryEval {
  Eigen::Vector2d point;
  Eigen::Matrix2d jacobian;  // d(point) / d(H, V)
};

CatenaryEval evaluate(double h, double v, double l0, double w, double ea) {
  const double va = v - w * l0;
  const double tb = std::sqrt(h * h + v * v);
  const double ta = std::sqrt(h * h + va * va);
  CatenaryEval e;
  e.point = elastic_catenary_end_point<double>(h, v, l0, w, ea);
  e.jacobian(0, 0) =
      l0 / ea + (std::asinh(v / h) - std::asinh(va / h)) / w - (v / tb - va / ta) / w;
  e.jacobian(0, 1) = (h / w) * (1.0 / tb - 1.0 / ta);
  e.jacobian(1, 0) = (h / tb - h / ta) / w;
  e.jacobian(1, 1) = l0 / ea + (v / tb - va / ta) / w;
  return e;
}

CatenarySolution finish(double span, double height, double h, double v, double l0, double w,
                        double ea, int iterations) {
  CatenarySolution s;
  s.horizontal_force = h;
  s.vertical_force_b = v;
  s.vertical_force_a = v - w * l0;
  s.tension_b = std::sqrt(h * h + v * v);
  s.tension_a = std::sqrt(h * h + s.vertical_force_a * s.vertical_force_a);
  s.chord = std::hypot(span, height);
  if (w > 0.0) {
    const double va = s.vertical_force_a;
    s.stretched_length = l0 + (v * s.tension_b - va * s.tension_a +
                               h * h * (std::asinh(v / h) - std::asinh(va / h))) /
                                  (2.0 * w * ea);
  } else {
    s.stretched_length = s.chord;
  }
  s.iterations = iterations;
  return s;
}

}  // namespace

Result<CatenarySolution> solve_elastic_catenary(double span, double height,
                                                double unstretched_length, double weight_per_length,
                                                double ea, const CatenaryOptions& options) {
  const double l0 = unstretched_length;
  const double w = weight_per_length;
  if (!std::isfinite(span) || !std::isfinite(height) || !std::isfinite(l0) || !std::isfinite(w) ||
      !std::isfinite(ea)) {
    return Status(ErrorCode::kInvalidArgument, "elastic catenary: non-finite input");
  }
  if (!(span > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "elastic catenary: horizontal span %g m must be > 0 (a vertical cable "
                         "has no catenary; use the straight elastic cable)",
                         span);
  }
  if (!(l0 > 0.0) || w < 0.0 || !(ea > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "elastic catenary: need L0 > 0, w >= 0, EA > 0 (L0 %g m, w %g N/m, EA "
                         "%g N)",
                         l0, w, ea);
  }
  const double chord = std::hypot(span, height);
  if (w == 0.0) {
    if (!(chord > l0)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "elastic catenary: weightless cable is slack (chord %.6g m <= L0 "
                           "%.6g m)",
                           chord, l0);
    }
    const double t = ea * (chord - l0) / l0;
    return finish(span, height, t * span / chord, t * height / chord, l0, 0.0, ea, 0);
  }
  // Initial guess: Peyrot & Goulois (1979) for sagging cables, the straight elastic cable for
  // taut ones; the larger horizontal force (Newton from the stiff side is well behaved).
  const double lambda = (l0 * l0 <= chord * chord)
                            ? 0.2
                            : std::sqrt(3.0 * ((l0 * l0 - height * height) / (span * span) - 1.0));
  double h = std::abs(w * span / (2.0 * lambda));
  double v = 0.5 * w * (height / std::tanh(lambda) + l0);
  if (chord > l0) {
    const double t = ea * (chord - l0) / l0;
    const double h_taut = t * span / chord;
    if (h_taut > h) {
      h = h_taut;
      v = t * height / chord + 0.5 * w * l0;
    }
  }
  const Eigen::Vector2d goal(span, height);
  CatenaryEval e = evaluate(h, v, l0, w, ea);
  Eigen::Vector2d f = e.point - goal;
  for (int it = 0; it < options.max_iterations; ++it) {
    if (f.norm() <= options.tolerance) return finish(span, height, h, v, l0, w, ea, it);
    const Eigen::Vector2d step = e.jacobian.partialPivLu().solve(-f);
    if (!step.allFinite()) break;
    // Damped: keep H > 0 and require the error to drop.
    double alpha = 1.0;
    bool accepted = false;
    for (int k = 0; k < 40; ++k, alpha *= 0.5) {
      const double h_new = h + alpha * step(0);
      const double v_new = v + alpha * step(1);
      if (!(h_new > 0.0)) continue;
      const CatenaryEval e_new = evaluate(h_new, v_new, l0, w, ea);
      const Eigen::Vector2d f_new = e_new.point - goal;
      if (f_new.allFinite() && f_new.norm() < f.norm()) {
        h = h_new;
        v = v_new;
        e = e_new;
        f = f_new;
        accepted = true;
        break;
      }
    }
    if (!accepted) {
      if (f.norm() <= 1e3 * options.tolerance) return finish(span, height, h, v, l0, w, ea, it);
      break;
    }
  }
  return Status::error(ErrorCode::kNumericalFailure,
                       "elastic catenary: no solution for span %.6g m, height %.6g m, L0 %.6g m "
                       "(end point error %.3g m)",
                       span, height, l0, f.norm());
}

}  // namespace cdpr
