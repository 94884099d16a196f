// Inverse kinematics of a cable robot with point anchors or swivel pulleys.
//
// Two tiers, in the Pinocchio style:
// - Scalar templates (`rotation_from_rpy<T>`, `cable_geometry<T>`) that work for double and for
//   ceres::Jet, so the identification gets exact Jacobians by automatic differentiation.
// - `inverse_kinematics(model, pose, data)`: all m cables at once into a preallocated
//   KinematicsData (lengths, unit vectors, structure matrix). It allocates nothing: the RT loop
//   calls it every cycle.
//
// Swivel pulley model (conventions in robot_model.hpp): with the platform anchor P written in the
// pulley frame as (v_x, v_y, v_z) relative to D = a_i, the swivel angle is gamma = atan2(v_y, v_x),
// the cable plane holds the axis ez and e_gamma = cos(gamma) ex + sin(gamma) ey. In that plane,
// with rho = sqrt(v_x^2 + v_y^2) and h = v_z, the pulley centre is M = (r, 0) and
//   BM  = sqrt((rho - r)^2 + h^2)              (centre to platform anchor)
//   l_f = sqrt(BM^2 - r^2)                     (free length, tangent point to platform anchor)
//   beta = acos(l_f / BM) + acos(h / BM)       (wrap angle)
//   L   = r * beta + l_f                        (length from D to the platform anchor)
// and the tangent (exit) point is T = D + r (1 - cos beta) e_gamma + r sin(beta) ez.
// Worked case (tested): r = 0.1, P = D + (0.2, 0, -0.1) gives BM = 0.1 sqrt(2), l_f = 0.1,
// beta = pi/4 + 3 pi/4 = pi, exit point D + (0.2, 0, 0), L = 0.1 pi + 0.1 (half a turn, then down).
// A property used below: dL/dP = -(T - P) / l_f, i.e. the length changes as for a point anchor
// placed at the exit point, so the structure matrix keeps its usual form with u_i = (T - P)/l_f.
//
// Evaluation (same values as the formulas above, fewer transcendental calls, better derivatives
// near acos(+-1)): with a = |rho - r|, cos(beta) = (l_f h - r a) / BM^2, sin(beta) =
// (r h + l_f a) / BM^2, beta = atan2(sin, cos) taken in [0, 2 pi); e_gamma = (v_x, v_y) / rho.
//
// Which way the cable enters: it travels along +ez at D. With h > 0 the platform lies ahead
// (wrap below pi/2 when rho > r); with h < 0 it lies behind and the cable wraps past pi/2.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <numbers>

#include "cdpr/calibration/robot_model.hpp"

namespace cdpr {

template <typename T>
using Vec3 = Eigen::Matrix<T, 3, 1>;
template <typename T>
using Mat3 = Eigen::Matrix<T, 3, 3>;

// R = Rz(yaw) * Ry(pitch) * Rx(roll).
template <typename T>
Mat3<T> rotation_from_rpy(const T& roll, const T& pitch, const T& yaw) {
  using std::cos;
  using std::sin;
  const T cr = cos(roll), sr = sin(roll);
  const T cp = cos(pitch), sp = sin(pitch);
  const T cy = cos(yaw), sy = sin(yaw);
  Mat3<T> R;
  R(0, 0) = cy * cp;
  R(0, 1) = cy * sp * sr - sy * cr;
  R(0, 2) = cy * sp * cr + sy * sr;
  R(1, 0) = sy * cp;
  R(1, 1) = sy * sp * sr + cy * cr;
  R(1, 2) = sy * sp * cr - cy * sr;
  R(2, 0) = -sp;
  R(2, 1) = cp * sr;
  R(2, 2) = cp * cr;
  return R;
}

template <typename T>
Mat3<T> rotation_from_rpy(const Vec3<T>& rpy) {
  return rotation_from_rpy<T>(rpy(0), rpy(1), rpy(2));
}

// Inverse of rotation_from_rpy: (roll, pitch, yaw) with pitch in [-pi/2, pi/2], roll and yaw in
// (-pi, pi]. At the singularity |pitch| = pi/2 it returns yaw = 0 and puts the whole rotation
// about the vertical into roll.
inline Eigen::Vector3d rpy_from_rotation(const Eigen::Matrix3d& R) {
  const double cp = std::hypot(R(0, 0), R(1, 0));
  const double pitch = std::atan2(-R(2, 0), cp);
  if (cp < 1e-12) {
    const double sp = -R(2, 0) > 0.0 ? 1.0 : -1.0;
    return {std::atan2(sp * R(0, 1), R(1, 1)), pitch, 0.0};
  }
  return {std::atan2(R(2, 1), R(2, 2)), pitch, std::atan2(R(1, 0), R(0, 0))};
}

// exp([w]x): the rotation by |w| about w / |w| (Rodrigues), exact to rounding for small |w|.
inline Eigen::Matrix3d rotation_exp(const Eigen::Vector3d& w) {
  const double t2 = w.squaredNorm();
  double a, b;  // sin(t) / t, (1 - cos(t)) / t^2
  if (t2 < 1e-8) {
    a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0;
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0;
  } else {
    const double t = std::sqrt(t2);
    a = std::sin(t) / t;
    b = (1.0 - std::cos(t)) / t2;
  }
  Eigen::Matrix3d K;
  K << 0.0, -w(2), w(1), w(2), 0.0, -w(0), -w(1), w(0), 0.0;
  return Eigen::Matrix3d::Identity() + a * K + b * (K * K);
}

// The geometry of one cable between its frame-side point D and platform anchor P (both world).
template <typename T>
struct CableGeometry {
  T length;            // total length from D to P (free length plus wrapped arc), m
  T free_length;       // straight part, exit point to P, m
  T wrap_angle;        // rad, 0 for a point anchor
  T swivel_angle;      // rad, 0 for a point anchor
  Vec3<T> exit_point;  // world; D for a point anchor
  Vec3<T> unit;        // unit vector from P towards the exit point (direction of the cable force)
  bool valid;          // false when P is inside the pulley circle or on the anchor
};

// Point anchor (radius == 0) or swivel pulley. `radius` is a template scalar so that the
// identification can estimate it; the pulley frame is treated as known.
template <typename T>
CableGeometry<T> cable_geometry(const Vec3<T>& d, const Eigen::Matrix3d& pulley_frame,
                                const T& radius, const Vec3<T>& p) {
  using std::acos;
  using std::atan2;
  using std::cos;
  using std::sin;
  using std::sqrt;
  CableGeometry<T> g;
  g.valid = true;
  if (!(radius > T(0))) {
    const Vec3<T> v = d - p;
    g.free_length = sqrt(v.squaredNorm());
    g.length = g.free_length;
    g.wrap_angle = T(0);
    g.swivel_angle = T(0);
    g.exit_point = d;
    if (!(g.free_length > T(0))) {
      g.valid = false;
      g.unit = Vec3<T>::Zero();
      return g;
    }
    g.unit = v / g.free_length;
    return g;
  }
  const Mat3<T> Rp = pulley_frame.cast<T>();
  const Vec3<T> v = Rp.transpose() * (p - d);  // platform anchor in the pulley frame
  const T rho = sqrt(v(0) * v(0) + v(1) * v(1));
  const T h = v(2);
  g.swivel_angle = atan2(v(1), v(0));
  const T e = rho - radius;
  const T bm2 = e * e + h * h;
  const T r2 = radius * radius;
  if (!(bm2 > r2)) {
    g.valid = false;
    g.free_length = T(0);
    g.length = T(0);
    g.wrap_angle = T(0);
    g.exit_point = d;
    g.unit = Vec3<T>::Zero();
    return g;
  }
  g.free_length = sqrt(bm2 - r2);
  // beta = acos(l_f / BM) + acos(h / BM), through its cosine and sine (see the file comment).
  const T a = e < T(0) ? T(-e) : e;
  const T cos_beta = (g.free_length * h - radius * a) / bm2;
  const T sin_beta = (radius * h + g.free_length * a) / bm2;
  g.wrap_angle = atan2(sin_beta, cos_beta);
  if (g.wrap_angle < T(0)) g.wrap_angle += T(2.0 * std::numbers::pi);
  g.length = radius * g.wrap_angle + g.free_length;
  // e_gamma = cos(gamma) ex + sin(gamma) ey; gamma = 0 when P is on the swivel axis.
  Vec3<T> e_gamma = Rp.col(0);
  if (rho > T(0)) e_gamma = (Rp.col(0) * v(0) + Rp.col(1) * v(1)) / rho;
  g.exit_point = d + e_gamma * (radius * (T(1) - cos_beta)) + Rp.col(2) * (radius * sin_beta);
  g.unit = (g.exit_point - p) / g.free_length;
  return g;
}

// Platform anchor i in the world for pose (r, R).
template <typename T>
Vec3<T> platform_anchor_world(const Vec3<T>& r, const Mat3<T>& R, const Vec3<T>& b) {
  return r + R * b;
}

// Scratch data for inverse_kinematics (Pinocchio's "Data"): sized once for a model, reused.
struct KinematicsData {
  explicit KinematicsData(int num_cables)
      : lengths(num_cables),
        free_lengths(num_cables),
        wrap_angles(num_cables),
        swivel_angles(num_cables),
        unit_vectors(3, num_cables),
        platform_points(3, num_cables),
        structure_matrix(6, num_cables) {}
  explicit KinematicsData(const RobotModel& model) : KinematicsData(model.num_cables()) {}

  Eigen::VectorXd lengths;           // L_i, m (free length + arc for pulleys)
  Eigen::VectorXd free_lengths;      // m
  Eigen::VectorXd wrap_angles;       // rad
  Eigen::VectorXd swivel_angles;     // rad
  Eigen::Matrix3Xd unit_vectors;     // u_i, world, from platform anchor towards the frame
  Eigen::Matrix3Xd platform_points;  // r + R b_i, world
  // A^T (6 x m): column i is [u_i; (R b_i) x u_i]; wrench balance is A^T f + w = 0, and the
  // length Jacobian with respect to (dr, dtheta) (small rotation in the world) is -A.
  Eigen::Matrix<double, 6, Eigen::Dynamic> structure_matrix;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  int invalid_cable = -1;  // first cable whose geometry is degenerate, -1 if none
};

// All cables at once for a platform at `position` with rotation matrix `rotation` (world).
// Returns false (and sets data.invalid_cable) when a cable is degenerate. Allocates nothing.
inline bool inverse_kinematics(const RobotModel& model, const Eigen::Vector3d& position,
                               const Eigen::Matrix3d& rotation, KinematicsData& data) {
  const int m = model.num_cables();
  data.rotation = rotation;
  data.invalid_cable = -1;
  for (int i = 0; i < m; ++i) {
    const Eigen::Vector3d rb = rotation * model.platform_anchors.col(i);
    const Eigen::Vector3d p = position + rb;
    const PulleyModel& pulley = model.pulleys[static_cast<std::size_t>(i)];
    const Eigen::Vector3d d = model.frame_anchors.col(i);
    const CableGeometry<double> g = cable_geometry<double>(d, pulley.frame, pulley.radius, p);
    if (!g.valid && data.invalid_cable < 0) data.invalid_cable = i;
    data.lengths(i) = g.length;
    data.free_lengths(i) = g.free_length;
    data.wrap_angles(i) = g.wrap_angle;
    data.swivel_angles(i) = g.swivel_angle;
    data.unit_vectors.col(i) = g.unit;
    data.platform_points.col(i) = p;
    data.structure_matrix.col(i).head<3>() = g.unit;
    data.structure_matrix.col(i).tail<3>() = rb.cross(g.unit);
  }
  return data.invalid_cable < 0;
}

// All cables at once. Returns false (and sets data.invalid_cable) when a cable is degenerate.
// Allocates nothing.
inline bool inverse_kinematics(const RobotModel& model, const Pose& pose, KinematicsData& data) {
  return inverse_kinematics(model, pose.position, rotation_from_rpy<double>(pose.rpy), data);
}

}  // namespace cdpr
