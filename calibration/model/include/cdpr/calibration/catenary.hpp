// Sagging cables: Irvine's elastic catenary and its small-sag approximation.
//
// One cable in its vertical plane: end A at the origin, end B at (span, height) (span >= 0
// horizontal, height > 0 when B is above A), unstretched length L0, weight per unit unstretched
// length w = mass_per_length * g (N/m), axial stiffness EA (N). H > 0 is the (constant)
// horizontal component of the tension and V the vertical component at B, so the tension at B is
// (H, V) along the cable tangent from A towards B and the cable pulls B with -(H, V); at A the
// tangent force is (H, V - w L0) and the cable pulls A with +(H, V - w L0). Irvine (1981):
//
//   span   = H L0 / EA + (H / w) [asinh(V / H) - asinh((V - w L0) / H)]
//   height = V L0 / EA - w L0^2 / (2 EA) + (1 / w) [T_B - T_A]
//
// with T_B = sqrt(H^2 + V^2), T_A = sqrt(H^2 + (V - w L0)^2). The stretched (arc) length is
// L0 + (1 / (2 w EA)) [V T_B - (V - w L0) T_A + H^2 (asinh(V / H) - asinh((V - w L0) / H))].
//
// Small-sag approximation (a parabola on the chord, inextensible): arc - chord ~ w^2 span^2 c /
// (24 T^2), c the chord length and T the mean tension.
#pragma once

#include <Eigen/Core>
#include <cmath>

#include "cdpr/status.hpp"

namespace cdpr {

// asinh for double and ceres::Jet (Ceres 2.1 has no Jet asinh): odd, through log1p, so it keeps
// full relative precision for small arguments.
template <typename T>
T catenary_asinh(const T& x) {
  using std::log1p;
  using std::sqrt;
  const T a = x < T(0) ? T(-x) : x;
  const T y = log1p(a + a * a / (T(1) + sqrt(T(1) + a * a)));
  return x < T(0) ? T(-y) : y;
}

// End point B = (span, height) for given end forces (H, V). Template: double or ceres::Jet.
// Precondition: H > 0, w > 0, EA > 0.
template <typename T>
Eigen::Matrix<T, 2, 1> elastic_catenary_end_point(const T& horizontal_force,
                                                  const T& vertical_force_b,
                                                  const T& unstretched_length,
                                                  const T& weight_per_length, const T& ea) {
  using std::sqrt;
  const T& h = horizontal_force;
  const T& v = vertical_force_b;
  const T va = v - weight_per_length * unstretched_length;
  const T tb = sqrt(h * h + v * v);
  const T ta = sqrt(h * h + va * va);
  Eigen::Matrix<T, 2, 1> p;
  p(0) = h * unstretched_length / ea +
         (h / weight_per_length) * (catenary_asinh<T>(v / h) - catenary_asinh<T>(va / h));
  p(1) = v * unstretched_length / ea -
         weight_per_length * unstretched_length * unstretched_length / (T(2) * ea) +
         (tb - ta) / weight_per_length;
  return p;
}

struct CatenaryOptions {
  int max_iterations = 100;
  double tolerance = 1e-12;  // on |end point error|, m
};

struct CatenarySolution {
  double horizontal_force = 0.0;  // H, N
  double vertical_force_b = 0.0;  // V at B, N
  double vertical_force_a = 0.0;  // V - w L0 at A, N
  double tension_a = 0.0;         // N
  double tension_b = 0.0;         // N
  double stretched_length = 0.0;  // arc length under load, m
  double chord = 0.0;             // straight distance A-B, m
  int iterations = 0;
};

// Solves the two catenary equations for (H, V) by damped Newton with the analytic Jacobian,
// started from the larger of Peyrot & Goulois' sag guess and the straight elastic cable. w == 0
// gives the straight elastic cable. Errors: kInvalidArgument (span <= 0, L0 <= 0, w < 0, EA <= 0,
// non-finite input; or w == 0 with a slack cable), kNumericalFailure (no convergence).
Result<CatenarySolution> solve_elastic_catenary(double span, double height,
                                                double unstretched_length, double weight_per_length,
                                                double ea, const CatenaryOptions& options = {});

// Small-sag approximation of arc length minus chord, m: w^2 span^2 chord / (24 tension^2).
inline double sag_arc_minus_chord(double weight_per_length, double span, double chord,
                                  double tension) {
  return weight_per_length * weight_per_length * span * span * chord / (24.0 * tension * tension);
}

// Mid-span sag (perpendicular to the chord, parabola): w span c / (8 T), m.
inline double sag_midspan(double weight_per_length, double span, double chord, double tension) {
  return weight_per_length * span * chord / (8.0 * tension);
}

}  // namespace cdpr
