// The residuals of the identification problem (not installed): the cable constants, the tension
// and elongation helpers, the equilibrium residual and the autodiff cost functors of the other
// channels (length, laser, reference, swivel, inclinometer, IMU yaw). problem_build.cc builds the
// problem with them; equilibrium_cost.cc differentiates the equilibrium residual.
#pragma once

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <span>
#include <vector>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "identification_internal.hpp"

namespace cdpr::ident_detail {

template <typename T>
void pose_from_block(const T* pose, Vec3<T>& r, Mat3<T>& R) {
  r = Vec3<T>(pose[0], pose[1], pose[2]);
  R = rotation_from_rpy<T>(pose[3], pose[4], pose[5]);
}

// Everything a cable's residuals need that is not estimated.
struct CableConstants {
  Eigen::Matrix3d pulley_frame = Eigen::Matrix3d::Identity();
  double pulley_radius = 0.0;
  CableModel cable;
  double sensor_gain = 1.0;    // nominal force sensor gain (raw = gain F + offset)
  double sensor_offset = 0.0;  // nominal offset
  bool estimated_stiffness = false;
};

// True tension from a reading made with the nominal sensor calibration, with the sensor
// corrections g (relative gain) and c (offset, raw units) being estimated.
template <typename T>
T true_tension(const CableConstants& k, double reading, const T& g, const T& c) {
  const double raw = k.sensor_gain * reading + k.sensor_offset;
  return (T(raw) - T(k.sensor_offset) - c) / (T(k.sensor_gain) * (T(1) + g));
}

// Elongation dL of a cable with kinematic length `length` under the tension from `tension_reading`
// (estimated sensor corrections g, c and stiffness scale e), and in *compliance d(dL)/dF.
template <typename T>
T elongation_at(const CableConstants& k, const T& length, double tension_reading, const T& e,
                const T& g, const T& c, T* force, T* compliance) {
  const T F = true_tension(k, tension_reading, g, c);
  if (force) *force = F;
  const T loaded = ident_detail::loaded_length<T>(k.cable, length);
  if (k.estimated_stiffness) {
    const T ea = T(k.cable.ea) * (T(1) + e);
    if (compliance) *compliance = loaded * ea / ((ea + F) * (ea + F));
    return F * loaded / (ea + F);
  }
  if (compliance) {
    *compliance = T(0);
    if (k.cable.elongation != ElongationKind::kRigid) {
      const double h = 1e-3 * std::max(1.0, std::abs(tension_reading));
      *compliance = (cable_elongation<T>(k.cable, loaded, F + T(h)) -
                     cable_elongation<T>(k.cable, loaded, F - T(h))) /
                    T(2.0 * h);
    }
  }
  return cable_elongation<T>(k.cable, loaded, F);
}

// Static equilibrium (6 residuals). Blocks: pose, a_1..a_m, b_1..b_m, g_1..g_m, c_1..c_m,
// o_1..o_m, s_1..s_m, then e (one block when the stiffness is shared, else e_1..e_m), then the
// platform mass (1) and centre of mass (3, platform frame): the weight's force and moment.
//
// The residual w = A^T F + w_gravity carries the force noise linearly: cov(w) = sigma_F^2 A^T A.
// The same tension readings also enter the cable length residuals of the pose, through the
// elongation: r_l,i = U_i(F_i) - reading model, with noise -c_i eps_i + encoder noise
// (c_i = d(dL)/dF). So w is whitened CONDITIONALLY on the length residuals of its pose (the lengths
// are whitened by themselves, LengthCost; together this is the Cholesky factor of the joint
// covariance with the lengths first):
//   w|l   = w + sum_i c_i sigma_F^2 a_i r_l,i / S_i,       S_i = sigma_L^2 + c_i^2 sigma_F^2
//   cov   = sigma_F^2 sum_i a_i a_i^T (sigma_L^2 / S_i)     (a_i = [u_i; R b_i x u_i])
// (cables without a length row: no correction, weight 1). Everything is evaluated at the CURRENT
// pose and geometry (not frozen at the start): the objective is then one fixed function of the
// parameters, the profile likelihood of the errors-in-variables problem with the true tensions as
// nuisance parameters. Frozen at the start, the estimate depended on the starting model and the
// anchors were biased (about 1.7 standard errors of the mean at 1 N on MINI); without the
// conditioning chi^2/dof was about 1.12 at 1 N on MINI.
struct EquilibriumCost {
  std::span<const CableConstants> k;  // Built::constants (shared, not a copy per pose)
  Eigen::VectorXd tensions;
  double sigma_force = 1.0;
  double sigma_length = 1.0;
  std::vector<double> readings;          // cable length readings; NaN: the cable has no length row
  std::vector<double> extra_compliance;  // PoseMeasurement::extra_compliance (empty: none)
  bool shared_stiffness = false;
  int mass_block = 0;  // index of the mass block in the parameter blocks (the centre of mass next)
  double gravity = 9.81;
  Eigen::Matrix<double, 6, 1> external = Eigen::Matrix<double, 6, 1>::Zero();  // world, N, N m
  // Suspended robots with m < 6 cables (issue 18): cov is singular (rank m), so w|l is split into
  // the m tension errors eps = (A^T A)^-1 A^T (w|l) (A = the cable wrench columns a_i), each
  // whitened by its own sigma_F sqrt(sigma_L^2 / S_i), and the 6 - m components of w that no
  // tension can balance, N^T (w - A eps), which carry no sensor noise: the equilibrium condition
  // on the pose, divided by sigma_null (a small model sigma). N is the orthonormal basis of the
  // complement of the current cable wrenches nearest (Cholesky) to 6 - m fixed unit wrench axes
  // E (`null_basis`, chosen once at the initial pose: the axes the cables balance least), so that
  // the rows are one smooth function of the parameters. Empty: the Cholesky whitening below
  // (m >= 6).
  Eigen::MatrixXd null_basis;
  double sigma_null = 1e-3;  // N

  // The parameter blocks of cable i among the functor's (o, s and e are read only when the cable
  // has a length row).
  template <typename T>
  struct CableBlocks {
    const T *a, *b, *g, *c, *o, *s, *e;
  };
  template <typename T>
  CableBlocks<T> cable_blocks(T const* const* p, int i) const {
    const int m = static_cast<int>(k.size());
    return {p[1 + i],
            p[1 + m + i],
            p[1 + 2 * m + i],
            p[1 + 3 * m + i],
            p[1 + 4 * m + i],
            p[1 + 5 * m + i],
            p[1 + 6 * m + (shared_stiffness ? 0 : i)]};
  }

  // The start of the net wrench: the weight's force and moment at the platform orientation R, and
  // the external wrench.
  template <typename T>
  void weight_wrench(const Mat3<T>& R, const T* mass, const T* com,
                     Eigen::Matrix<T, 6, 1>& w) const {
    const Vec3<T> weight(T(0), T(0), -mass[0] * T(gravity));
    w.template head<3>() = weight;
    w.template tail<3>() = (R * Vec3<T>(com[0], com[1], com[2])).cross(weight);
    w += external.cast<T>();
  }

  // Cable i's terms at the pose (r, R): its wrench column a_i, true tension F, weight
  // sigma_L^2 / S_i and, with a length row, the factor of a_i in the correction. False when the
  // cable is degenerate at the pose.
  template <typename T>
  struct CableTerms {
    Eigen::Matrix<T, 6, 1> col;
    T force;
    T weight = T(1);
    bool has_length = false;
    T correction = T(0);  // compliance sigma_F^2 r_l / S_i (with a length row)
  };
  template <typename T>
  bool cable_terms(int i, const Vec3<T>& r, const Mat3<T>& R, const CableBlocks<T>& q,
                   CableTerms<T>& out) const {
    const auto ui = static_cast<std::size_t>(i);
    const T *a = q.a, *b = q.b, *g = q.g, *c = q.c;
    const double sf2 = sigma_force * sigma_force;
    const double sl2 = sigma_length * sigma_length;
    const Vec3<T> rb = R * Vec3<T>(b[0], b[1], b[2]);
    const CableGeometry<T> geom = cable_geometry<T>(Vec3<T>(a[0], a[1], a[2]), k[ui].pulley_frame,
                                                    T(k[ui].pulley_radius), r + rb);
    if (!geom.valid) return false;
    out.force = true_tension(k[ui], tensions(i), g[0], c[0]);
    out.col.template head<3>() = geom.unit;
    out.col.template tail<3>() = rb.cross(geom.unit);
    out.has_length = !readings.empty() && !std::isnan(readings[ui]);
    if (out.has_length) {
      T compliance;
      const T U = geom.length - elongation_at<T>(k[ui], geom.length, tensions(i), q.e[0], g[0],
                                                 c[0], nullptr, &compliance);
      const T rl = U - ((T(1) + q.s[0]) * T(readings[ui]) + q.o[0]);
      if (!extra_compliance.empty()) compliance += T(extra_compliance[ui]);
      const T S = T(sl2) + compliance * compliance * T(sf2);
      out.weight = T(sl2) / S;
      out.correction = compliance * T(sf2) * rl / S;
    }
    return true;
  }

  // Net wrench, the whitening covariance of w|l and the correction term at the parameters.
  // `columns` and `weights` (optional) receive the a_i and sigma_L^2 / S_i.
  template <typename T>
  bool wrench(T const* const* p, Eigen::Matrix<T, 6, 1>& w, Eigen::Matrix<T, 6, 6>& cov,
              Eigen::Matrix<T, 6, 1>* correction = nullptr,
              Eigen::Matrix<T, 6, Eigen::Dynamic>* columns = nullptr,
              Eigen::Matrix<T, Eigen::Dynamic, 1>* weights = nullptr) const {
    const int m = static_cast<int>(k.size());
    Vec3<T> r;
    Mat3<T> R;
    pose_from_block(p[0], r, R);
    weight_wrench<T>(R, p[mass_block], p[mass_block + 1], w);
    cov.setZero();
    if (correction) correction->setZero();
    if (columns) columns->resize(6, m);
    if (weights) weights->resize(m);
    const double sf2 = sigma_force * sigma_force;
    for (int i = 0; i < m; ++i) {
      CableTerms<T> t;
      if (!cable_terms<T>(i, r, R, cable_blocks(p, i), t)) return false;
      w += t.col * t.force;
      if (t.has_length && correction) *correction += t.col * t.correction;
      cov += (T(sf2) * t.weight) * (t.col * t.col.transpose());
      if (columns) columns->col(i) = t.col;
      if (weights) (*weights)(i) = t.weight;
    }
    return true;
  }

  // The suspended (m < 6) whitening of the file comment above.
  template <typename T>
  bool suspended_residual(T const* const* p, T* residual) const {
    using std::sqrt;
    const int m = static_cast<int>(k.size());
    Eigen::Matrix<T, 6, 1> w;
    Eigen::Matrix<T, 6, 6> cov;
    Eigen::Matrix<T, 6, 1> correction;
    Eigen::Matrix<T, 6, Eigen::Dynamic> A;
    Eigen::Matrix<T, Eigen::Dynamic, 1> weight;
    if (!wrench(p, w, cov, &correction, &A, &weight)) return false;
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> AtA = A.transpose() * A;
    const Eigen::LLT<Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>> llt(AtA);
    if (llt.info() != Eigen::Success) return false;
    const Eigen::Matrix<T, 6, 1> wl = w + correction;
    const Eigen::Matrix<T, Eigen::Dynamic, 1> eps =
        llt.solve(Eigen::Matrix<T, Eigen::Dynamic, 1>(A.transpose() * wl));
    for (int i = 0; i < m; ++i) residual[i] = eps(i) / (T(sigma_force) * sqrt(weight(i)));
    const Eigen::Matrix<T, 6, 1> rest = wl - A * eps;
    // Coordinates of `rest` in the orthonormal basis N = P E (E^T P E)^-1/2 (Cholesky) of the
    // current complement, P = I - A (A^T A)^-1 A^T: N^T rest = L^-1 E^T rest, L L^T = E^T P E.
    const int nn = 6 - m;
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> E = null_basis.cast<T>();
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> AtE = A.transpose() * E;
    const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> S =
        E.transpose() * E - AtE.transpose() * llt.solve(AtE);
    const Eigen::LLT<Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>> lls(S);
    if (lls.info() != Eigen::Success) return false;
    const Eigen::Matrix<T, Eigen::Dynamic, 1> c =
        lls.matrixL().solve(Eigen::Matrix<T, Eigen::Dynamic, 1>(E.transpose() * rest));
    for (int q = 0; q < nn; ++q) residual[m + q] = c(q) / T(sigma_null);
    return true;
  }

  template <typename T>
  bool operator()(T const* const* p, T* residual) const {
    if (null_basis.cols() > 0) return suspended_residual(p, residual);
    Eigen::Matrix<T, 6, 1> w;
    Eigen::Matrix<T, 6, 6> cov;
    Eigen::Matrix<T, 6, 1> correction;
    if (!wrench(p, w, cov, &correction)) return false;
    Eigen::Matrix<T, 6, 1> out;
    if (!whiten<T>(cov, Eigen::Matrix<T, 6, 1>(w + correction), out)) return false;
    for (int q = 0; q < 6; ++q) residual[q] = out(q);
    return true;
  }

  // out = L^-1 v, L L^T = cov (m >= 6). A tiny ridge keeps the factorisation defined at a
  // (refused elsewhere) singular geometry.
  template <typename T>
  static bool whiten(Eigen::Matrix<T, 6, 6> cov, const Eigen::Matrix<T, 6, 1>& v,
                     Eigen::Matrix<T, 6, 1>& out) {
    const T ridge = T(1e-12) * cov.trace();
    for (int q = 0; q < 6; ++q) cov(q, q) += ridge;
    const Eigen::LLT<Eigen::Matrix<T, 6, 6>> llt(cov);
    if (llt.info() != Eigen::Success) return false;
    out = llt.matrixL().solve(v);
    return true;
  }
};

// The cost function of EquilibriumCost `f` (owned) over parameter blocks of `block_sizes` (the
// functor's layout). Its residuals are the functor's; its Jacobian is that of the automatic
// differentiation over all blocks up to rounding, computed cable by cable (each cable's terms
// depend on 17 coordinates, not on the 90 of all blocks) and chained through the whitening.
// Suspended robots with m < 6 cables are differentiated over all blocks.
ceres::CostFunction* equilibrium_cost_function(EquilibriumCost* f,
                                               const std::vector<int>& block_sizes);

// Unstretched length U = L_k - dL at pose; false when the geometry is degenerate. With
// `compliance` non-null also d(dL)/dF there (m/N; 0 without a tension reading).
template <typename T>
bool unstretched_length(const CableConstants& k, const T* a, const T* b, const T* pose,
                        double tension_reading, const T& e, const T& g, const T& c, T& U,
                        Vec3<T>* unit = nullptr, Vec3<T>* arm = nullptr, T* force = nullptr,
                        T* compliance = nullptr) {
  Vec3<T> r;
  Mat3<T> R;
  pose_from_block(pose, r, R);
  const Vec3<T> rb = R * Vec3<T>(b[0], b[1], b[2]);
  const Vec3<T> P = r + rb;
  const CableGeometry<T> geom =
      cable_geometry<T>(Vec3<T>(a[0], a[1], a[2]), k.pulley_frame, T(k.pulley_radius), P);
  if (!geom.valid) return false;
  U = geom.length;
  if (compliance) *compliance = T(0);
  if (!std::isnan(tension_reading)) {
    U -= elongation_at<T>(k, geom.length, tension_reading, e, g, c, force, compliance);
  } else if (force) {
    *force = T(0);
  }
  if (unit) *unit = geom.unit;
  if (arm) *arm = rb;
  return true;
}

// Cable length residual. Blocks: a(3), b(3), pose(6), o(1), s(1), e(1), g(1), c(1).
// Its sigma combines the encoder noise and the force noise through the cable compliance at the
// CURRENT geometry and tension, sqrt(sigma_length^2 + (d(dL)/dF sigma_force)^2), so that, like the
// equilibrium residual, the objective does not depend on where the solver started.
struct LengthCost {
  const CableConstants* k = nullptr;  // Built::constants (shared: 100,000 poses, 8 cables each)
  double reading = 0.0;
  double tension = std::numeric_limits<double>::quiet_NaN();
  double sigma_length = 1.0;
  double sigma_force = 0.0;       // 0: the force noise is not propagated
  double extra_compliance = 0.0;  // PoseMeasurement::extra_compliance, m/N
  template <typename T>
  bool operator()(const T* a, const T* b, const T* pose, const T* o, const T* s, const T* e,
                  const T* g, const T* c, T* residual) const {
    T U;
    T compliance;
    if (!unstretched_length<T>(*k, a, b, pose, tension, e[0], g[0], c[0], U, nullptr, nullptr,
                               nullptr, &compliance)) {
      return false;
    }
    const T force_part = (compliance + T(extra_compliance)) * T(sigma_force);
    const T sigma = sqrt(T(sigma_length * sigma_length) + force_part * force_part);
    residual[0] = (U - ((T(1) + s[0]) * T(reading) + o[0])) / sigma;
    return true;
  }
};

// Laser residual. Blocks: pose(6), origin(3), direction angles(2), normal angles(2), c(1).
struct LaserCost {
  Eigen::Vector3d d0, de1, de2;  // platform frame
  Eigen::Vector3d n0, ne1, ne2;  // world
  double reading = 0.0;
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* pose, const T* origin, const T* dir, const T* normal, const T* c,
                  T* residual) const {
    Vec3<T> r;
    Mat3<T> R;
    pose_from_block(pose, r, R);
    Vec3<T> d = d0.cast<T>() + de1.cast<T>() * dir[0] + de2.cast<T>() * dir[1];
    d = d / sqrt(d.squaredNorm());
    Vec3<T> n = n0.cast<T>() + ne1.cast<T>() * normal[0] + ne2.cast<T>() * normal[1];
    n = n / sqrt(n.squaredNorm());
    const Vec3<T> p = r + R * Vec3<T>(origin[0], origin[1], origin[2]);
    const Vec3<T> dw = R * d;
    const T den = n.dot(dw);
    if (!(abs(den) > T(1e-9))) return false;
    const T t = (c[0] - n.dot(p)) / den;
    residual[0] = (t - T(reading)) / T(sigma);
    return true;
  }
};

struct ReferenceCost {
  Eigen::Matrix<double, 6, 1> reference;
  Eigen::Matrix<double, 6, 1> inv_sigma;
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    for (int q = 0; q < 6; ++q) residual[q] = (pose[q] - T(reference(q))) * T(inv_sigma(q));
    return true;
  }
};

// Angle difference wrapped to (-pi, pi]; the derivative is exactly 1 (atan2(sin, cos)).
template <typename T>
T wrap_angle(const T& x) {
  using std::atan2;
  using std::cos;
  using std::sin;
  return atan2(sin(x), cos(x));
}

// Swivel-angle residual (issue 18). Blocks: a(3), b(3), pose(6), zero(1).
//   r = wrap(direction (gamma - zero) - reading) / sigma,  gamma = atan2(v_y, v_x),
//   v = Rp^T (r + R b - a)   (the swivel angle of kinematics.hpp, pulley frame Rp of the model)
struct SwivelCost {
  Eigen::Matrix3d pulley_frame = Eigen::Matrix3d::Identity();
  int direction = 1;
  double reading = 0.0;
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* a, const T* b, const T* pose, const T* zero, T* residual) const {
    Vec3<T> r;
    Mat3<T> R;
    pose_from_block(pose, r, R);
    const Vec3<T> P = r + R * Vec3<T>(b[0], b[1], b[2]);
    const Vec3<T> v = pulley_frame.transpose().cast<T>() * (P - Vec3<T>(a[0], a[1], a[2]));
    // On the swivel axis the angle is undefined.
    if (!(v(0) * v(0) + v(1) * v(1) > T(1e-18))) return false;
    const T gamma = atan2(v(1), v(0));
    residual[0] =
        wrap_angle<T>(T(static_cast<double>(direction)) * (gamma - zero[0]) - T(reading)) /
        T(sigma);
    return true;
  }
};

// Orientation of the inclinometer / IMU frame: R(pose) R_m0 rotation_from_rpy(d0, d1, 0).
template <typename T>
Mat3<T> sensor_rotation(const T* pose, const Eigen::Matrix3d& mount0, const T* d) {
  return rotation_from_rpy<T>(pose[3], pose[4], pose[5]) * mount0.cast<T>() *
         rotation_from_rpy<T>(d[0], d[1], T(0));
}

// Inclinometer residuals (issue 18), 2 per pose. Blocks: pose(6), mounting correction(2).
struct InclinometerCost {
  Eigen::Matrix3d mount0 = Eigen::Matrix3d::Identity();
  Eigen::Vector2d reading = Eigen::Vector2d::Zero();
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* pose, const T* mount, T* residual) const {
    using std::sqrt;
    const Mat3<T> Rs = sensor_rotation<T>(pose, mount0, mount);
    const T c = sqrt(Rs(2, 1) * Rs(2, 1) + Rs(2, 2) * Rs(2, 2));
    if (!(c > T(1e-9))) return false;  // sensor x axis vertical: roll undefined
    const T roll = atan2(Rs(2, 1), Rs(2, 2));
    const T pitch = atan2(-Rs(2, 0), c);
    residual[0] = wrap_angle<T>(roll - T(reading(0))) / T(sigma);
    residual[1] = wrap_angle<T>(pitch - T(reading(1))) / T(sigma);
    return true;
  }
};

// IMU heading residual (issue 18). Blocks: pose(6), mounting correction(2), yaw zero(1).
struct ImuYawCost {
  Eigen::Matrix3d mount0 = Eigen::Matrix3d::Identity();
  double reading = 0.0;
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* pose, const T* mount, const T* yaw_zero, T* residual) const {
    const Mat3<T> Rs = sensor_rotation<T>(pose, mount0, mount);
    if (!(Rs(0, 0) * Rs(0, 0) + Rs(1, 0) * Rs(1, 0) > T(1e-18))) return false;
    const T yaw = atan2(Rs(1, 0), Rs(0, 0));
    residual[0] = wrap_angle<T>(yaw - yaw_zero[0] - T(reading)) / T(sigma);
    return true;
  }
};

}  // namespace cdpr::ident_detail
