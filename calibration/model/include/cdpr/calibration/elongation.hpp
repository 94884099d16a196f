// Cable elongation models behind one interface (CableModel::elongation), and the least-squares fit
// of the paper's polynomial surface dL = f(L, F) (Jin et al. 2018, Eq. 2) with the order chosen by
// K-fold cross-validation.
//
// Lengths in this file (one cable, SI units):
// - kinematic length L_k: from the frame anchor D to the platform anchor (kinematics.hpp; includes
//   the arc wrapped on a swivel pulley). It is a loaded (stretched) length: the geometry.
// - loaded length L = routing_length + L_k: the whole loaded cable between the winch drum and the
//   platform. Every model below takes L, because the whole loaded cable stretches.
// - unstretched length L0 = L - dL: the same material with no load; what the winch pays out.
// - elongation dL = L - L0 = cable_elongation(cable, L, F) >= 0 for F >= 0.
//
// Models, all written in terms of the loaded length L and the tension F:
// - kRigid:      dL = 0.
// - kHooke:      L = L0 (1 + F / EA)  =>  dL = F L / (EA + F). (Equivalently dL = F L0 / EA.)
// - kPolynomial: dL = sum_{i+j<=n} c_ij s^i t^j with s = (L - length_center) / length_scale,
//                t = (F - tension_center) / tension_scale (PolynomialSurface, robot_model.hpp).
//                Valid inside the fitted (L, F) range only; outside it is an extrapolation.
// F is used as given (no clamping, so the functions stay differentiable); callers pass F >= 0.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cassert>
#include <cstdint>
#include <span>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Largest polynomial order the evaluators accept (fixed-size scratch, no allocation).
inline constexpr int kMaxPolynomialOrder = 8;

// Number of coefficients of a full 2-D polynomial of total degree `order`.
constexpr int polynomial_surface_size(int order) {
  return (order + 1) * (order + 2) / 2;
}

// dL of a PolynomialSurface at loaded length L and tension F (template: double or ceres::Jet).
// Precondition: surface.order in [0, kMaxPolynomialOrder], coefficients sized to match, scales > 0
// (validate_polynomial_surface checks it).
template <typename T>
T polynomial_surface_value(const PolynomialSurface& surface, const T& loaded_length,
                           const T& tension) {
  assert(surface.order >= 0 && surface.order <= kMaxPolynomialOrder);
  assert(static_cast<int>(surface.coefficients.size()) == polynomial_surface_size(surface.order));
  const int n = surface.order;
  const T s = (loaded_length - surface.length_center) / surface.length_scale;
  const T t = (tension - surface.tension_center) / surface.tension_scale;
  std::array<T, kMaxPolynomialOrder + 1> sp;
  std::array<T, kMaxPolynomialOrder + 1> tp;
  sp[0] = T(1);
  tp[0] = T(1);
  for (int k = 1; k <= n; ++k) {
    sp[static_cast<std::size_t>(k)] = sp[static_cast<std::size_t>(k - 1)] * s;
    tp[static_cast<std::size_t>(k)] = tp[static_cast<std::size_t>(k - 1)] * t;
  }
  T value = T(0);
  std::size_t c = 0;
  for (int degree = 0; degree <= n; ++degree) {
    for (int j = 0; j <= degree; ++j, ++c) {
      value += surface.coefficients[c] * sp[static_cast<std::size_t>(degree - j)] *
               tp[static_cast<std::size_t>(j)];
    }
  }
  return value;
}

// The loaded length L (m) whose stretch the elongation model describes: the whole cable between
// the winch drum and the platform, routing_length + the kinematic length L_k. The one definition
// (the identification, the statics, the mismatch locator and the daemon use it).
template <typename T>
T loaded_length(const CableModel& cable, const T& kinematic_length) {
  return kinematic_length + T(cable.routing_length);
}

// Elongation dL (m) of the whole loaded cable of length `loaded_length` (m, routing_length +
// kinematic length) under `tension` (N). Template: double or ceres::Jet. Allocates nothing.
template <typename T>
T cable_elongation(const CableModel& cable, const T& loaded_length, const T& tension) {
  switch (cable.elongation) {
    case ElongationKind::kRigid:
      return T(0);
    case ElongationKind::kHooke:
      return tension * loaded_length / (T(cable.ea) + tension);
    case ElongationKind::kPolynomial:
      return polynomial_surface_value<T>(cable.polynomial, loaded_length, tension);
  }
  return T(0);
}

// The elongation and its partial derivatives (analytic), for Newton solves and stiffness.
struct ElongationDerivatives {
  double elongation = 0.0;  // dL, m
  double d_length = 0.0;    // d(dL)/dL, dimensionless
  double d_tension = 0.0;   // d(dL)/dF, m/N (the cable compliance at this length)
};

ElongationDerivatives cable_elongation_derivatives(const CableModel& cable, double loaded_length,
                                                   double tension);

// The loaded length L whose unstretched length is `unstretched_length`: solves L - dL(L, F) = L0
// (closed form for kRigid and kHooke, Newton for kPolynomial). Allocates nothing. Fails with
// kNumericalFailure when d(L - dL)/dL <= 0 (a surface that shrinks the cable faster than it is
// lengthened: outside its fitted range) or Newton does not converge to 1e-13 m in 50 steps.
Result<double> loaded_length_from_unstretched(const CableModel& cable, double unstretched_length,
                                              double tension);

// Checks order, coefficient count, finite coefficients and positive scales; names the problem.
Status validate_polynomial_surface(const PolynomialSurface& surface);

// ---------------------------------------------------------------------------------------------
// Fitting the polynomial surface from bench measurements.
// ---------------------------------------------------------------------------------------------

// One measurement: the cable loaded to `tension` has loaded length `length` and stretched by
// `elongation` from its unloaded length.
struct ElongationSample {
  double length = 0.0;      // loaded length L, m
  double tension = 0.0;     // F, N
  double elongation = 0.0;  // dL, m
};

struct PolynomialFitOptions {
  int min_order = 1;       // candidate orders min_order..max_order (<= kMaxPolynomialOrder)
  int max_order = 5;       // the paper used 5
  int folds = 5;           // K of K-fold cross-validation, 2 <= K <= number of samples
  std::uint32_t seed = 1;  // shuffles the samples into folds (deterministic for a given seed)
  enum class Selection {
    kMinimumError,      // the order with the lowest mean CV RMSE
    kOneStandardError,  // the lowest order within one standard error of that minimum (default:
                        // the minimum alone over-selects on noisy data)
  };
  Selection selection = Selection::kOneStandardError;
  // An order whose scaled design matrix (or a fold's) has sigma_min / sigma_max below this is
  // treated as not identifiable from the samples (its CV error is reported as infinity).
  double rank_tolerance = 1e-10;
};

struct PolynomialFitSummary {
  PolynomialSurface surface;  // fitted on all samples at the chosen order, scaling stored
  int order = -1;             // chosen order
  // Per candidate order (index k is order min_order + k): mean of the per-fold RMSE on the
  // held-out samples, m, and its standard error over the folds. Infinity: not identifiable.
  std::vector<int> orders;
  std::vector<double> cv_rmse;
  std::vector<double> cv_rmse_stderr;
  double training_rmse = 0.0;     // m, chosen order on all samples
  double condition_number = 0.0;  // of the scaled design matrix at the chosen order
  int num_samples = 0;
};

// Least squares on scaled variables (centre = mid-range, scale = half-range, so s, t in [-1, 1]);
// the scaling is stored in the returned surface. Refuses (kInvalidArgument) non-finite samples,
// fewer samples than the smallest candidate needs, a single length or a single tension (no
// surface is identifiable), bad options; kNumericalFailure when no candidate order is
// identifiable.
Result<PolynomialFitSummary> fit_polynomial_surface(std::span<const ElongationSample> samples,
                                                    const PolynomialFitOptions& options = {});

}  // namespace cdpr
