#include "cdpr/calibration/mismatch.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numeric>
#include <optional>
#include <utility>

#include "cdpr/calibration/catenary.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "text_format.hpp"

namespace cdpr {
namespace {

// A pose's effect on the net wrench, `delta` (SI), into column `col` of the candidate: whitened
// with the equilibrium rows' covariance `cov` in X, as is in si, rows kw..kw+5. False when the
// covariance is not positive definite.
// `si_delta` (optional): what goes into si instead of `delta` (an effect whose correction of the
// data differs from its effect on the residual, e.g. pulley friction, whose length-row correction
// also removes the equilibrium rows' conditional correction).
bool put_wrench_effect(Eigen::Matrix<double, 6, 6> cov, const Eigen::Matrix<double, 6, 1>& delta,
                       int kw, int col, CandidateColumns& c,
                       const Eigen::Matrix<double, 6, 1>* si_delta = nullptr) {
  cov.diagonal().array() += 1e-12 * cov.trace();
  const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(cov);
  if (llt.info() != Eigen::Success) return false;
  const Eigen::Matrix<double, 6, 1> w = llt.matrixL().solve(delta);
  for (int q = 0; q < 6; ++q) {
    c.X(kw + q, col) = w(q);
    c.si(kw + q, col) = si_delta != nullptr ? (*si_delta)(q) : delta(q);
  }
  return true;
}

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kCreepTimeConstant = 10.0;  // s, the creep candidate's tau

// ------------------------------------------------------------------------------------------
// Distributions (Numerical Recipes style: series and Lentz continued fractions).
// ------------------------------------------------------------------------------------------

double gamma_p_series(double a, double x) {
  double sum = 1.0 / a;
  double del = sum;
  double ap = a;
  for (int n = 0; n < 1000; ++n) {
    ap += 1.0;
    del *= x / ap;
    sum += del;
    if (std::abs(del) < std::abs(sum) * 1e-16) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

double gamma_q_fraction(double a, double x) {
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a;
  double c = 1.0 / kTiny;
  double d = 1.0 / b;
  double h = d;
  for (int i = 1; i < 1000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < 1e-16) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

// Regularised upper incomplete gamma Q(a, x).
double gamma_q(double a, double x) {
  if (!(x > 0.0)) return 1.0;
  if (x < a + 1.0) return std::max(0.0, 1.0 - gamma_p_series(a, x));
  return gamma_q_fraction(a, x);
}

double beta_fraction(double a, double b, double x) {
  constexpr double kTiny = 1e-300;
  const double qab = a + b, qap = a + 1.0, qam = a - 1.0;
  double c = 1.0;
  double d = 1.0 - qab * x / qap;
  if (std::abs(d) < kTiny) d = kTiny;
  d = 1.0 / d;
  double h = d;
  for (int m = 1; m < 1000; ++m) {
    const int m2 = 2 * m;
    double aa = m * (b - m) * x / ((qam + m2) * (a + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    h *= d * c;
    aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < 1e-16) break;
  }
  return h;
}

// Regularised incomplete beta I_x(a, b).
double beta_i(double a, double b, double x) {
  if (x <= 0.0) return 0.0;
  if (x >= 1.0) return 1.0;
  const double bt = std::exp(std::lgamma(a + b) - std::lgamma(a) - std::lgamma(b) +
                             a * std::log(x) + b * std::log1p(-x));
  if (x < (a + 1.0) / (a + b + 2.0)) return bt * beta_fraction(a, b, x) / a;
  return 1.0 - bt * beta_fraction(b, a, 1.0 - x) / b;
}

using mismatch_detail::format;

// ------------------------------------------------------------------------------------------
// Residual layout (mirrors identification.cc's row order per pose: lengths, lasers, wrench,
// reference).
// ------------------------------------------------------------------------------------------

using RowKind = ResidualKind;

struct Row {
  RowKind kind;
  int pose;
  int index;  // cable, laser or wrench/reference component
};

// Orthonormal basis of the column space of X (columns scaled to unit norm first), with the
// singular-value threshold `tol` relative to 1.
Eigen::MatrixXd column_basis(const Eigen::MatrixXd& X, double tol) {
  if (X.cols() == 0) return Eigen::MatrixXd(X.rows(), 0);
  Eigen::MatrixXd Xs = X;
  for (Eigen::Index c = 0; c < Xs.cols(); ++c) {
    const double n = Xs.col(c).norm();
    if (n > 0) Xs.col(c) /= n;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(Xs, Eigen::ComputeThinU);
  int r = 0;
  const Eigen::VectorXd& s = svd.singularValues();
  for (Eigen::Index k = 0; k < s.size(); ++k) {
    if (s(k) > tol) ++r;
  }
  return svd.matrixU().leftCols(r);
}

using Candidate = CandidateColumns;

MisfitGroup make_group(std::string name, const std::vector<int>& rows, const Eigen::VectorXd& r,
                       const Eigen::VectorXd& leverage, const std::vector<double>& si,
                       std::string unit, double alpha) {
  MisfitGroup g;
  g.name = std::move(name);
  g.unit = std::move(unit);
  g.count = static_cast<int>(rows.size());
  double s2 = 0.0;
  bool si_ok = !g.unit.empty();
  for (int k : rows) {
    const auto uk = static_cast<std::size_t>(k);
    g.chi2 += r(k) * r(k);
    g.expected_chi2 += 1.0 - leverage(k);
    if (si_ok && std::isfinite(si[uk])) s2 += si[uk] * si[uk];
  }
  if (g.count == 0) return g;
  g.rms_normalized = std::sqrt(g.chi2 / g.count);
  g.rms_si = si_ok ? std::sqrt(s2 / g.count) : kNaN;
  g.ratio = g.expected_chi2 > 0 ? std::sqrt(g.chi2 / g.expected_chi2) : kNaN;
  g.p_value = g.expected_chi2 > 1e-9 ? chi2_upper_tail(g.chi2, g.expected_chi2) : 1.0;
  g.flagged = g.p_value < alpha;
  return g;
}

// Regression of y on [1, X]: F-test of the slopes.
StructureTest regress(const std::string& variable, int cable, const Eigen::VectorXd& y,
                      const Eigen::MatrixXd& X) {
  StructureTest t;
  t.variable = variable;
  t.cable = cable;
  t.samples = static_cast<int>(y.size());
  if (t.samples < 3 || X.cols() == 0) return t;
  Eigen::MatrixXd Xc = X.rowwise() - X.colwise().mean();
  const Eigen::VectorXd yc = y.array() - y.mean();
  // Drop constant regressors (relative to their magnitude).
  for (Eigen::Index c = 0; c < Xc.cols(); ++c) {
    const double scale = std::max(X.col(c).cwiseAbs().maxCoeff(), 1e-300);
    if (Xc.col(c).norm() < 1e-9 * scale * std::sqrt(static_cast<double>(Xc.rows()))) {
      Xc.col(c).setZero();
    }
  }
  const Eigen::MatrixXd Q = column_basis(Xc, 1e-8);
  t.slopes = static_cast<int>(Q.cols());
  const double tss = yc.squaredNorm();
  if (t.slopes == 0 || tss <= 0 || t.samples - t.slopes - 1 <= 0) return t;
  const double ess = (Q.transpose() * yc).squaredNorm();
  t.explained_fraction = ess / tss;
  const double d2 = t.samples - t.slopes - 1;
  const double rss = std::max(tss - ess, 1e-300);
  t.f_statistic = (ess / t.slopes) / (rss / d2);
  t.p_value = f_upper_tail(t.f_statistic, t.slopes, d2);
  return t;
}

// Everything the screen needs, in residual space.
struct DesignData {
  std::vector<Row> rows;
  std::vector<double> si;  // SI residual per row (NaN where mixed or unknown)
  std::vector<std::vector<int>> length_row;
  std::vector<int> pose_start;
  Eigen::VectorXd r, sigma_len;
  Eigen::VectorXd tension, kin_len, loaded, reading, time, tilt, horizontal;
  Eigen::MatrixXd direction;
  GeometryInformation base;
  std::vector<Candidate> lib;
  // Per (pose, cable), poses x cables: the direction of the last move and the measured variables
  // of the structure scan (NaN where unknown).
  Eigen::MatrixXd move, pc_length, pc_tension, pc_time, pc_tilt, pc_temperature;
  // Per pose (its rows x cables): the whitened residual change for a 1 N error of each cable's
  // tension reading (equilibrium rows and, through the elongation, the cable's length row), and
  // the SI correction of the equilibrium rows that removes it (see put_wrench_effect).
  std::vector<Eigen::MatrixXd> tension_white, tension_si;
  // The same for a 1 m length error of each cable (the true length longer than the reading).
  std::vector<Eigen::MatrixXd> length_white;
};

Result<DesignData> build_design(const CalibratedModel& model, const MeasurementSet& set,
                                const std::vector<Pose>& poses,
                                const std::vector<PoseResiduals>* residuals,
                                const IdentificationOptions& options, const MismatchOptions& mopt) {
  const RobotModel& robot = model.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  const int np = set.num_poses();
  if ((residuals != nullptr && static_cast<int>(residuals->size()) != np) ||
      static_cast<int>(poses.size()) != np) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "mismatch: %d residual sets and %d poses for a measurement set of %d "
                         "poses",
                         residuals != nullptr ? static_cast<int>(residuals->size()) : np,
                         static_cast<int>(poses.size()), np);
  }
  CDPR_RETURN_IF_ERROR(validate(set, robot));

  // --- Jacobians at the estimate: the identification's, and one with every candidate parameter
  // switched on (its extra columns are candidate effects).
  auto base = geometry_information(model, set, poses, options, true);
  if (!base) return base.status();
  IdentificationOptions ext_opt = options;
  ext_opt.estimate_length_scales = true;
  ext_opt.estimate_platform_anchors = true;
  ext_opt.platform_anchor_mask = AnchorMask();
  ext_opt.estimate_force_gains = mopt.force_sensor_candidates || options.estimate_force_gains;
  ext_opt.estimate_force_offsets = mopt.force_sensor_candidates || options.estimate_force_offsets;
  ext_opt.estimate_platform_mass = mopt.force_sensor_candidates || options.estimate_platform_mass;
  ext_opt.estimate_platform_com = mopt.force_sensor_candidates || options.estimate_platform_com;
  ext_opt.estimate_laser_origin = nl > 0 || options.estimate_laser_origin;
  ext_opt.estimate_laser_direction = nl > 0 || options.estimate_laser_direction;
  ext_opt.estimate_laser_plane = nl > 0 || options.estimate_laser_plane;
  auto ext = geometry_information(model, set, poses, ext_opt, true);
  if (!ext) return ext.status();

  // --- Row layout, residual vector, row sigmas.
  std::vector<Row> rows;
  std::vector<double> si;  // SI residual per row (NaN where mixed)
  std::vector<std::vector<int>> length_row(static_cast<std::size_t>(np),
                                           std::vector<int>(static_cast<std::size_t>(m), -1));
  std::vector<int> pose_start(static_cast<std::size_t>(np) + 1, 0);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    const bool have_t = pm.tensions.size() == m;
    pose_start[uj] = static_cast<int>(rows.size());
    if (options.use_lengths) {
      for (int i = 0; i < m; ++i) {
        if (std::isnan(pm.cable_lengths(i))) continue;
        if (have_t && !std::isnan(pm.tensions(i)) &&
            pm.tensions(i) < slack_threshold(options, set.noise)) {
          continue;
        }
        length_row[uj][static_cast<std::size_t>(i)] = static_cast<int>(rows.size());
        rows.push_back({RowKind::kLength, j, i});
        si.push_back(residuals ? (*residuals)[uj].length_m(i) : kNaN);
      }
    }
    if (options.use_laser) {
      for (int l = 0; l < std::min<int>(nl, static_cast<int>(pm.laser_distances.size())); ++l) {
        if (std::isnan(pm.laser_distances(l))) continue;
        rows.push_back({RowKind::kLaser, j, l});
        si.push_back(residuals ? (*residuals)[uj].laser_m(l) : kNaN);
      }
    }
    if (options.use_equilibrium && have_t && pm.tensions.allFinite()) {
      for (int q = 0; q < 6; ++q) {
        rows.push_back({RowKind::kWrench, j, q});
        si.push_back(q < 3 && residuals ? (*residuals)[uj].wrench_si(q) : kNaN);
      }
    }
    // The issue 18 channels come after the reference rows (identification.cc's order).
    int extra = 0;
    if (options.use_swivel && pm.swivel_angles.size() == m) {
      extra += static_cast<int>((pm.swivel_angles.array() == pm.swivel_angles.array()).count());
    }
    if (options.use_inclinometer && !std::isnan(pm.inclination(0)) &&
        !std::isnan(pm.inclination(1))) {
      extra += 2;
    }
    if (options.use_imu_yaw && !std::isnan(pm.imu_yaw)) extra += 1;
    const int have = static_cast<int>(rows.size()) - pose_start[uj];
    const int jac_rows = static_cast<int>(base->jacobian_geometry[uj].rows());
    if (jac_rows == have + 6 + extra && options.use_reference && pm.reference) {
      for (int q = 0; q < 6; ++q) {
        rows.push_back({RowKind::kReference, j, q});
        si.push_back(kNaN);
      }
    } else if (jac_rows != have + extra) {
      return Status::error(ErrorCode::kInternal,
                           "mismatch: pose %d has %d Jacobian rows, the residual layout %d", j,
                           jac_rows, have);
    }
    if (options.use_swivel && pm.swivel_angles.size() == m) {
      for (int i = 0; i < m; ++i) {
        if (std::isnan(pm.swivel_angles(i))) continue;
        rows.push_back({RowKind::kSwivel, j, i});
        si.push_back(residuals ? (*residuals)[uj].swivel_rad(i) : kNaN);
      }
    }
    if (options.use_inclinometer && !std::isnan(pm.inclination(0)) &&
        !std::isnan(pm.inclination(1))) {
      for (int q = 0; q < 2; ++q) {
        rows.push_back({RowKind::kInclination, j, q});
        si.push_back(residuals ? (*residuals)[uj].inclination_rad(q) : kNaN);
      }
    }
    if (options.use_imu_yaw && !std::isnan(pm.imu_yaw)) {
      rows.push_back({RowKind::kImuYaw, j, 0});
      si.push_back(residuals ? (*residuals)[uj].imu_yaw_rad : kNaN);
    }
    if (ext->jacobian_geometry[uj].rows() != jac_rows) {
      return Status::error(ErrorCode::kInternal,
                           "mismatch: pose %d: the extended Jacobian has a different row count", j);
    }
  }
  pose_start[static_cast<std::size_t>(np)] = static_cast<int>(rows.size());
  const int n = static_cast<int>(rows.size());
  Eigen::VectorXd r = Eigen::VectorXd::Zero(n);
  Eigen::VectorXd sigma_len = Eigen::VectorXd::Constant(n, kNaN);
  for (int k = 0; k < n; ++k) {
    const Row& row = rows[static_cast<std::size_t>(k)];
    if (residuals == nullptr) {
      if (row.kind == RowKind::kLength) sigma_len(k) = set.noise.sigma_length;
      continue;
    }
    const PoseResiduals& pr = (*residuals)[static_cast<std::size_t>(row.pose)];
    switch (row.kind) {
      case RowKind::kLength: {
        r(k) = pr.length_normalized(row.index);
        const double rm = pr.length_m(row.index);
        if (std::isfinite(rm) && std::abs(r(k)) > 1e-300) {
          sigma_len(k) = rm / r(k);
        } else {
          sigma_len(k) = set.noise.sigma_length;
        }
        if (!(sigma_len(k) > 0)) sigma_len(k) = set.noise.sigma_length;
        break;
      }
      case RowKind::kLaser:
        r(k) = pr.laser_normalized(row.index);
        break;
      case RowKind::kWrench:
        r(k) = pr.wrench_normalized(row.index);
        break;
      case RowKind::kReference:
        r(k) = pr.reference_normalized(row.index);
        break;
      case RowKind::kSwivel:
        r(k) = pr.swivel_normalized(row.index);
        break;
      case RowKind::kInclination:
        r(k) = pr.inclination_normalized(row.index);
        break;
      case RowKind::kImuYaw:
        r(k) = pr.imu_yaw_normalized;
        break;
    }
    if (!std::isfinite(r(k))) {
      return Status::error(
          ErrorCode::kInternal,
          "mismatch: pose %d: a residual the Jacobian has is missing in the report", row.pose);
    }
  }

  // --- Explanatory variables per length row.
  KinematicsData kin(robot);
  const Eigen::VectorXd nan_n = Eigen::VectorXd::Constant(n, kNaN);
  Eigen::VectorXd tension = nan_n, kin_len = nan_n, loaded = nan_n, reading = nan_n, time = nan_n,
                  tilt = nan_n, horizontal = nan_n;
  Eigen::MatrixXd direction = Eigen::MatrixXd::Constant(n, 3, kNaN);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    if (!inverse_kinematics(robot, poses[uj], kin)) {
      return Status::error(ErrorCode::kNumericalFailure,
                           "mismatch: pose %d: cable %d is degenerate at the estimated pose", j,
                           kin.invalid_cable + 1);
    }
    for (int i = 0; i < m; ++i) {
      const int k = length_row[uj][static_cast<std::size_t>(i)];
      if (k < 0) continue;
      const auto ui = static_cast<std::size_t>(i);
      // Tension readings are in N through the nominal sensor calibration; the estimate's sensor
      // correction is second order for a regressor.
      if (pm.tensions.size() == m) tension(k) = pm.tensions(i);
      kin_len(k) = kin.lengths(i);
      loaded(k) = loaded_length(robot.cables[ui], kin.lengths(i));
      reading(k) = pm.cable_lengths(i);
      time(k) = pm.time;
      tilt(k) = std::acos(std::clamp(kin.rotation(2, 2), -1.0, 1.0));
      const Eigen::Vector3d u = kin.unit_vectors.col(i);
      direction.row(k) = (robot.pulleys[ui].frame.transpose() * (-u)).transpose();
      horizontal(k) = kin.free_lengths(i) * std::hypot(u.x(), u.y());
    }
  }
  // --- Per (pose, cable): direction of the last move, the structure scan's variables, and the
  // effect of a tension-reading error on the residual rows.
  const Eigen::MatrixXd move = last_move_directions(set);
  Eigen::MatrixXd pc_length = Eigen::MatrixXd::Constant(np, m, kNaN), pc_tension = pc_length,
                  pc_time = pc_length, pc_tilt = pc_length, pc_temperature = pc_length;
  std::vector<Eigen::MatrixXd> tension_white(static_cast<std::size_t>(np)),
      tension_si(static_cast<std::size_t>(np)), length_white(static_cast<std::size_t>(np));
  {
    const double sf2 = set.noise.sigma_force * set.noise.sigma_force;
    const double sl2 = set.noise.sigma_length * set.noise.sigma_length;
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const PoseMeasurement& pm = set.poses[uj];
      const int r0 = pose_start[uj], nr = pose_start[uj + 1] - r0;
      tension_white[uj] = Eigen::MatrixXd::Zero(nr, m);
      tension_si[uj] = Eigen::MatrixXd::Zero(nr, m);
      length_white[uj] = Eigen::MatrixXd::Zero(nr, m);
      if (!inverse_kinematics(robot, poses[uj], kin)) continue;  // refused above
      const double tilt_j = std::acos(std::clamp(kin.rotation(2, 2), -1.0, 1.0));
      int kw = -1;
      for (int k = r0; k < r0 + nr; ++k) {
        if (rows[static_cast<std::size_t>(k)].kind == RowKind::kWrench) {
          kw = k;
          break;
        }
      }
      Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, Eigen::Dynamic> a(6, m), aw(6, m), leak(6, m);
      for (int i = 0; i < m; ++i) {
        const auto ui = static_cast<std::size_t>(i);
        pc_length(j, i) = kin.lengths(i);
        if (pm.tensions.size() == m) pc_tension(j, i) = pm.tensions(i);
        pc_time(j, i) = pm.time;
        pc_tilt(j, i) = tilt_j;
        pc_temperature(j, i) = pm.temperature;
        const Eigen::Vector3d u = kin.unit_vectors.col(i);
        const Eigen::Vector3d rb = kin.rotation * robot.platform_anchors.col(i);
        a.col(i) << u, rb.cross(u);
        // The length row's sigma holds the cable compliance c (sigma^2 = sl2 + c^2 sf2); the
        // equilibrium rows are whitened conditionally on it (weight sl2 / sigma^2), as identify()
        // does, so a tension-reading error e moves them by weight * e * a and the length row by
        // -c e / sigma.
        const int kl = length_row[uj][ui];
        // A length error (the true length longer than the reading) moves the length row by
        // 1 / sigma and, through that conditioning, the equilibrium rows by c sf2 / sigma^2 a.
        double weight = 1.0;
        leak.col(i).setZero();
        if (kl >= 0) {
          const double s2 = sigma_len(kl) * sigma_len(kl);
          weight = sl2 / s2;
          const double c = std::sqrt(std::max(s2 - sl2, 0.0) / sf2);
          tension_white[uj](kl - r0, i) = -c / sigma_len(kl);
          length_white[uj](kl - r0, i) = 1.0 / sigma_len(kl);
          leak.col(i) = (c * sf2 / s2) * a.col(i);
        }
        aw.col(i) = weight * a.col(i);
        cov += sf2 * weight * a.col(i) * a.col(i).transpose();
      }
      if (kw < 0) continue;
      cov.diagonal().array() += 1e-12 * cov.trace();
      const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(cov);
      if (llt.info() != Eigen::Success) continue;
      tension_white[uj].middleRows(kw - r0, 6) = llt.matrixL().solve(aw);
      length_white[uj].middleRows(kw - r0, 6) = llt.matrixL().solve(leak);
      tension_si[uj].middleRows(kw - r0, 6) = a;
    }
  }

  // --- NAME: the candidate library.
  // The ids, names and families are the effect library's (effect_library.hpp); the columns are
  // built here, in the library's order.
  std::vector<Candidate> lib;
  auto candidate = [](const char* id, Eigen::MatrixXd X, Eigen::MatrixXd x_si) {
    const EffectDescriptor* e = find_effect(id);
    return Candidate{
        id, std::string(e->name), std::string(e->family), std::move(X), std::move(x_si), {}, {}};
  };
  // `slope`: the value's derivative by the row's tension reading (CandidateColumns::dtension;
  // `none` for a value that does not follow it).
  auto none = [](int) { return 0.0; };
  auto per_length_row = [&](const char* id, bool per_cable, auto value, auto slope) {
    Candidate c = candidate(id, Eigen::MatrixXd::Zero(n, per_cable ? m : 1), {});
    c.dtension = Eigen::MatrixXd::Zero(n, per_cable ? m : 1);
    bool any = false, follows = false;
    for (int k = 0; k < n; ++k) {
      const Row& row = rows[static_cast<std::size_t>(k)];
      if (row.kind != RowKind::kLength) continue;
      const double v = value(k);
      if (!std::isfinite(v)) continue;
      c.X(k, per_cable ? row.index : 0) = v / sigma_len(k);
      any = any || v != 0.0;
      const double s = slope(k);
      if (!std::isfinite(s)) continue;
      c.dtension(k, per_cable ? row.index : 0) = s / sigma_len(k);
      follows = follows || s != 0.0;
    }
    if (!follows) c.dtension.resize(0, 0);
    if (any) lib.push_back(std::move(c));
  };
  const bool have_time = time.array().isFinite().count() > 0;
  auto fl = [&](int k) { return tension(k) * loaded(k); };
  auto load_len = [&](int k) { return loaded(k); };
  auto f = [&](int k) { return tension(k); };
  auto one = [](int) { return 1.0; };
  per_length_row("hooke_shared", false, fl, load_len);
  per_length_row("hooke_per_cable", true, fl, load_len);
  per_length_row("compliance_shared", false, f, one);
  per_length_row("compliance_per_cable", true, f, one);
  per_length_row("encoder_offset_per_cable", true, one, none);
  if (have_time) {
    per_length_row(
        "encoder_drift_per_cable", true, [&](int k) { return time(k); }, none);
    // Creep of a polymer cable under load, time-hardening logarithmic law: the compliance grows
    // by c ln(1 + t / tau) with t the time since the recording (and the load) started. Once t is
    // several tau the shape is ln(t) whatever tau is, and a constant part is elasticity's, so one
    // tau (typical of primary creep of polymer fibre ropes) serves as the regressor.
    auto log_time = [&](int k) { return std::log1p(std::max(time(k), 0.0) / kCreepTimeConstant); };
    per_length_row(
        "creep_shared", false, [&](int k) { return fl(k) * log_time(k); },
        [&](int k) { return loaded(k) * log_time(k); });
    per_length_row(
        "transmission_drift_shared", false, [&](int k) { return time(k) * reading(k); }, none);
  }
  // Sag of a heavy cable (mass per length mu), to first order in the sag. The encoder pays out
  // the arc, longer than the chord by (mu g)^2 Lh^2 L / (24 F^2) (column 0; its coefficient in
  // the residual model - reading is -(mu g)^2 / 24 <= 0). And the platform carries part of each
  // cable's weight W = mu g L off the chord: with the tension T read at the frame end, the cable
  // pulls the platform with T u - (W / 2)(e_z + (e_z . u) u), so the modelled net wrench is off by
  // sum_i (W_i / 2)(e_z + (e_z . u_i) u_i) and its moment (column 1, coefficient mu), whitened
  // with the equilibrium rows' covariance (conditional on the length rows, as identify() has it).
  {
    Candidate c = candidate("sag_shared", Eigen::MatrixXd::Zero(n, 2), Eigen::MatrixXd::Zero(n, 2));
    bool any = false;
    for (int k = 0; k < n; ++k) {
      if (rows[static_cast<std::size_t>(k)].kind != RowKind::kLength) continue;
      const double v = horizontal(k) * horizontal(k) * kin_len(k) / (tension(k) * tension(k));
      if (!std::isfinite(v)) continue;
      c.X(k, 0) = v / sigma_len(k);
      c.si(k, 0) = v;
      any = any || v != 0.0;
    }
    const double sf2 = set.noise.sigma_force * set.noise.sigma_force;
    const double sl2 = set.noise.sigma_length * set.noise.sigma_length;
    const Eigen::Vector3d ez = Eigen::Vector3d::UnitZ();
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      int kw = -1;
      for (int k = pose_start[uj]; k < pose_start[uj + 1]; ++k) {
        if (rows[static_cast<std::size_t>(k)].kind == RowKind::kWrench) {
          kw = k;
          break;
        }
      }
      if (kw < 0 || !inverse_kinematics(robot, poses[uj], kin)) continue;
      Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      for (int i = 0; i < m; ++i) {
        const Eigen::Vector3d u = kin.unit_vectors.col(i);
        const Eigen::Vector3d rb = kin.rotation * robot.platform_anchors.col(i);
        Eigen::Matrix<double, 6, 1> a;
        a << u, rb.cross(u);
        const int kl = length_row[uj][static_cast<std::size_t>(i)];
        const double s2 = kl >= 0 ? sigma_len(kl) * sigma_len(kl) : sl2;
        cov += sf2 * (sl2 / s2) * a * a.transpose();
        const Eigen::Vector3d v = 0.5 * robot.gravity * kin.lengths(i) * (ez + ez.dot(u) * u);
        delta.head<3>() += v;
        delta.tail<3>() += rb.cross(v);
      }
      if (!put_wrench_effect(cov, delta, kw, 1, c)) continue;
      any = true;
    }
    if (any) lib.push_back(std::move(c));
  }
  // Nonlinear elongation (a F + k2 F^2) L: a refinement of elasticity (selection_group), so its
  // linear part moves with the curvature instead of being a second effect.
  {
    Candidate c = candidate("nonlinear_elasticity_shared", Eigen::MatrixXd::Zero(n, 2), {});
    c.dtension = Eigen::MatrixXd::Zero(n, 2);
    bool any = false;
    for (int k = 0; k < n; ++k) {
      if (rows[static_cast<std::size_t>(k)].kind != RowKind::kLength) continue;
      if (!std::isfinite(fl(k))) continue;
      c.X(k, 0) = fl(k) / sigma_len(k);
      c.X(k, 1) = tension(k) * fl(k) / sigma_len(k);
      c.dtension(k, 0) = loaded(k) / sigma_len(k);
      c.dtension(k, 1) = 2.0 * fl(k) / sigma_len(k);
      any = any || fl(k) != 0.0;
    }
    if (any) lib.push_back(std::move(c));
  }

  // Candidates from parameters the identification did not estimate (exact Jacobian columns).
  {
    std::map<std::string, int> base_cols;
    for (int q = 0; q < static_cast<int>(base->names.size()); ++q)
      base_cols[base->names[static_cast<std::size_t>(q)]] = q;
    Eigen::MatrixXd Jx = Eigen::MatrixXd::Zero(n, static_cast<Eigen::Index>(ext->names.size()));
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      Jx.middleRows(pose_start[uj], pose_start[uj + 1] - pose_start[uj]) =
          ext->jacobian_geometry[uj];
    }
    // The descriptor's parameter kinds (EffectDescriptor::parameters) that the standard
    // identification left fixed.
    auto group = [&](const char* id) {
      const std::vector<ParameterKind>& kinds = find_effect(id)->parameters;
      std::vector<int> picked;
      for (int q = 0; q < static_cast<int>(ext->names.size()); ++q) {
        const std::string& nm = ext->names[static_cast<std::size_t>(q)];
        const ParameterKind kind = ext->ids[static_cast<std::size_t>(q)].kind;
        if (base_cols.count(nm) || std::find(kinds.begin(), kinds.end(), kind) == kinds.end()) {
          continue;
        }
        picked.push_back(q);
      }
      if (picked.empty()) return;
      Candidate c = candidate(id, Eigen::MatrixXd(n, static_cast<Eigen::Index>(picked.size())), {});
      for (std::size_t q = 0; q < picked.size(); ++q) {
        c.X.col(static_cast<Eigen::Index>(q)) = Jx.col(picked[q]);
      }
      if (c.X.norm() > 0) lib.push_back(std::move(c));
    };
    for (const char* id :
         {"drum_scale_per_cable", "platform_anchors", "force_gain_per_cable",
          "force_offset_per_cable", "laser_mounting", "laser_direction", "laser_plane"}) {
      group(id);
    }
    // The shared drum scale: the sum of the per-cable columns.
    for (const Candidate& c : lib) {
      if (c.id == "drum_scale_per_cable") {
        Candidate s = candidate("drum_scale_shared", c.X.rowwise().sum(), {});
        lib.push_back(std::move(s));
        break;
      }
    }
  }

  // Direction-dependent effects (d = +-1: the cable was last paid out / reeled in). Hysteresis:
  // the true length is longer by h_i d (length rows). Pulley friction: the tension reading is off
  // by f_i d (the tension effect above, per pose).
  if (mopt.direction_candidates && move.cwiseAbs().sum() > 0) {
    // The length rows and, through their conditioning, the equilibrium rows; the data are
    // corrected on the length rows only (the equilibrium rows follow), so si is 0 there.
    Candidate h =
        candidate("hysteresis_per_cable", Eigen::MatrixXd::Zero(n, m), Eigen::MatrixXd::Zero(n, m));
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const int r0 = pose_start[uj], nr = pose_start[uj + 1] - r0;
      for (int i = 0; i < m; ++i) h.X.block(r0, i, nr, 1) = move(j, i) * length_white[uj].col(i);
    }
    if (h.X.norm() > 0) lib.push_back(std::move(h));
    Candidate c = candidate("pulley_friction_per_cable", Eigen::MatrixXd::Zero(n, m),
                            Eigen::MatrixXd::Zero(n, m));
    c.tension_readings = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(np) * m, m);
    for (int j = 0; j < np; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      const int r0 = pose_start[uj], nr = pose_start[uj + 1] - r0;
      for (int i = 0; i < m; ++i) {
        c.X.block(r0, i, nr, 1) = move(j, i) * tension_white[uj].col(i);
        c.si.block(r0, i, nr, 1) = move(j, i) * tension_si[uj].col(i);
        c.tension_readings(static_cast<Eigen::Index>(j) * m + i, i) = move(j, i);
      }
    }
    if (c.X.norm() > 0) lib.push_back(std::move(c));
  }

  // A confirmatory screen (MismatchOptions::only_groups): the listed selection groups only.
  if (!mopt.only_groups.empty()) {
    std::erase_if(lib, [&](const Candidate& c) {
      return std::find(mopt.only_groups.begin(), mopt.only_groups.end(),
                       selection_group(c.family)) == mopt.only_groups.end();
    });
  }

  DesignData D;
  D.rows = std::move(rows);
  D.si = std::move(si);
  D.length_row = std::move(length_row);
  D.pose_start = std::move(pose_start);
  D.r = std::move(r);
  D.sigma_len = std::move(sigma_len);
  D.tension = std::move(tension);
  D.kin_len = std::move(kin_len);
  D.loaded = std::move(loaded);
  D.reading = std::move(reading);
  D.time = std::move(time);
  D.tilt = std::move(tilt);
  D.horizontal = std::move(horizontal);
  D.direction = std::move(direction);
  D.base = std::move(*base);
  D.lib = std::move(lib);
  D.move = move;
  D.pc_length = std::move(pc_length);
  D.pc_tension = std::move(pc_tension);
  D.pc_time = std::move(pc_time);
  D.pc_tilt = std::move(pc_tilt);
  D.pc_temperature = std::move(pc_temperature);
  D.tension_white = std::move(tension_white);
  D.tension_si = std::move(tension_si);
  D.length_white = std::move(length_white);
  return D;
}

// "2", "2 and 5", "1, 3 and 5" from 0-based indices (+ `base`).
std::string index_list(const std::vector<int>& v, int base) {
  std::string out;
  for (std::size_t q = 0; q < v.size(); ++q) {
    if (q > 0) out += q + 1 == v.size() ? " and " : ", ";
    out += std::to_string(v[q] + base);
  }
  return out;
}

// The DESCRIBE step of locate_mismatch (mismatch.hpp): structure of the residual `D.r` that no
// candidate explains. `Q1` is the basis of the identification's Jacobian, `bases` the screened
// candidates' projected column bases (the library's order).
std::vector<UnexplainedStructure> describe_structure(const DesignData& D, const Eigen::MatrixXd& Q1,
                                                     const std::vector<Eigen::MatrixXd>& bases,
                                                     const MismatchSummary& summary,
                                                     const MismatchOptions& mopt) {
  std::vector<UnexplainedStructure> out;
  const Eigen::VectorXd& r = D.r;
  const int n = static_cast<int>(r.size());
  const int np = static_cast<int>(D.pose_start.size()) - 1;
  const int m = static_cast<int>(D.move.cols());
  const double rss = r.squaredNorm();
  const int d2 = summary.dof - 2;
  if (n == 0 || d2 <= 0 || rss <= 0) return out;
  struct Variable {
    const char* name;
    const Eigen::MatrixXd* values;
    const char* unit;
  };
  const Variable vars[] = {
      {"direction of the last move", &D.move, ""}, {"tension", &D.pc_tension, "N"},
      {"cable length", &D.pc_length, "m"},         {"time", &D.pc_time, "s"},
      {"platform orientation", &D.pc_tilt, "rad"}, {"temperature", &D.pc_temperature, "K"}};
  const char* channels[] = {"cable lengths", "cable tensions"};
  const char* channel_unit[] = {"m", "N"};
  struct Test {
    int channel = 0, cable = 0, var = 0;
    double t = 0.0, p = 1.0, slope = 0.0;
    Eigen::VectorXd z;
    Eigen::VectorXd constant;  // the cable's constant on the channel (the nuisance), projected
  };
  std::vector<Test> tests;
  for (int ch = 0; ch < 2; ++ch) {
    for (int i = 0; i < m; ++i) {
      for (int v = 0; v < static_cast<int>(std::size(vars)); ++v) {
        const Eigen::MatrixXd& val = *vars[v].values;
        Eigen::VectorXd x0 = Eigen::VectorXd::Zero(n), x = Eigen::VectorXd::Zero(n);
        int count = 0;
        for (int j = 0; j < np; ++j) {
          const auto uj = static_cast<std::size_t>(j);
          const double value = val(j, i);
          if (!std::isfinite(value)) continue;
          if (ch == 0 && D.length_row[uj][static_cast<std::size_t>(i)] < 0) continue;
          const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
          const Eigen::VectorXd col =
              ch == 0 ? D.length_white[uj].col(i) : D.tension_white[uj].col(i);
          if (col.squaredNorm() == 0.0) continue;
          x0.segment(r0, nr) += col;
          x.segment(r0, nr) += value * col;
          ++count;
        }
        if (count < 4) continue;
        const Eigen::VectorXd x0p = x0 - Q1 * (Q1.transpose() * x0);
        const Eigen::VectorXd xp = x - Q1 * (Q1.transpose() * x);
        Eigen::VectorXd z = xp;
        if (x0p.squaredNorm() > 1e-18 * x0.squaredNorm()) {
          z -= x0p * (x0p.dot(xp) / x0p.squaredNorm());
        }
        // A constant variable (given the constant per cable) or one the identification models.
        if (!(z.norm() > 1e-6 * x.norm())) continue;
        Test t;
        t.channel = ch;
        t.cable = i;
        t.var = v;
        t.slope = z.dot(r) / z.squaredNorm();
        t.t = z.dot(r) * t.slope;
        const double rest = std::max(rss - t.t, 1e-300);
        t.p = f_upper_tail(t.t / (rest / d2), 1.0, d2);
        t.z = std::move(z);
        t.constant = x0p;
        tests.push_back(std::move(t));
      }
    }
  }
  const double K = static_cast<double>(tests.size());
  // Forward selection over every test (channel x cable x variable): the test with the largest
  // statistic given the ones already selected (their columns projected out of its column and of
  // the residual), while that conditional test is significant (Bonferroni over all tests). A
  // reading error on two cables shows, weaker, on the columns of the other cables (the pose is
  // estimated from all of them, and the equilibrium rows mix every cable's tension): the
  // conditional test leaves those shadows out. Each selected test is then unexplained when no
  // candidate reproduces its column.
  struct Pick {
    const Test* test = nullptr;
    double p = 1.0;  // Bonferroni-adjusted, given the picks before it
    std::string closest;
    double rho = 0.0;
  };
  std::vector<Pick> picks;
  {
    Eigen::MatrixXd U(n, 0);  // orthonormal basis of the selected columns
    std::vector<bool> used(tests.size(), false);
    for (std::size_t step = 0; step < tests.size() && step < static_cast<std::size_t>(2 * m);
         ++step) {
      const Eigen::VectorXd rp = r - U * (U.transpose() * r);
      const double dof_p = d2 - static_cast<double>(U.cols());
      if (dof_p <= 0) break;
      std::size_t best = tests.size();
      double best_t = 0.0;
      for (std::size_t q = 0; q < tests.size(); ++q) {
        if (used[q]) continue;
        const Eigen::VectorXd zp = tests[q].z - U * (U.transpose() * tests[q].z);
        if (!(zp.squaredNorm() > 1e-12 * tests[q].z.squaredNorm())) continue;
        const double tq = std::pow(zp.dot(rp), 2) / zp.squaredNorm();
        if (tq > best_t) {
          best_t = tq;
          best = q;
        }
      }
      if (best == tests.size()) break;
      const double rest = std::max(rp.squaredNorm() - best_t, 1e-300);
      const double p = std::min(1.0, K * f_upper_tail(best_t / (rest / dof_p), 1.0, dof_p));
      if (!(p < mopt.alpha)) break;
      used[best] = true;
      const Eigen::VectorXd q = tests[best].z - U * (U.transpose() * tests[best].z);
      U.conservativeResize(Eigen::NoChange, U.cols() + 1);
      U.col(U.cols() - 1) = q.normalized();
      Pick pk;
      pk.test = &tests[best];
      pk.p = p;
      picks.push_back(std::move(pk));
    }
  }
  // Explained by a candidate when, with that candidate's columns added, the structure is no
  // longer significant (a partial test); else unexplained. Two partial tests, either suffices:
  // - a candidate whose columns come close to the structure's (canonical correlation above
  //   structure_coverage), tested against the residual it leaves;
  // - any candidate, tested against the noise left once it and every selected structure are
  //   fitted. One law for all cables (cable creep) shows most on the cables where it is largest,
  //   so "the readings of cable 2 follow the tension" is significant on its residual though the
  //   creep column is far from that cable's (canonical correlation 0.3-0.8); fitted, creep leaves
  //   it insignificant. (With the first test alone such shadows were reported as physics outside
  //   the library, and creep, a shared EA and the force gains counted as their proxies: MINI
  //   creep + drum scale + laser tilt named winch compliance per winch for the creep.) The noise
  //   estimate excludes the other structures: left in, a second one (pulley friction in the
  //   tensions beside hysteresis in the lengths) inflates it, and a candidate that takes a little
  //   of the first would seem to explain it.
  {
    Eigen::MatrixXd Z(n, static_cast<Eigen::Index>(picks.size()));
    for (std::size_t q = 0; q < picks.size(); ++q)
      Z.col(static_cast<Eigen::Index>(q)) = picks[q].test->z;
    // Per candidate (computed once, for the first structure that needs it): the residual sum of
    // squares and degrees of freedom once it and every selected structure are fitted.
    std::vector<std::optional<std::pair<double, double>>> noise_left(bases.size());
    auto noise_with = [&](std::size_t c) {
      if (!noise_left[c]) {
        Eigen::MatrixXd W(n, bases[c].cols() + Z.cols());
        W << bases[c], Z;
        const Eigen::MatrixXd full = column_basis(W, mopt.rank_tolerance);
        noise_left[c] = std::make_pair((r - full * (full.transpose() * r)).squaredNorm(),
                                       d2 - static_cast<double>(full.cols()));
      }
      return *noise_left[c];
    };
    std::vector<Pick> kept;
    for (Pick& pk : picks) {
      const Eigen::VectorXd& z = pk.test->z;
      bool explained = false;
      for (std::size_t c = 0; c < bases.size() && !explained; ++c) {
        const Eigen::MatrixXd& B = bases[c];
        if (B.cols() == 0) continue;
        const double rho = (B.transpose() * z.normalized()).norm();
        if (rho > pk.rho) {
          pk.rho = rho;
          pk.closest = D.lib[c].name;
        }
        const Eigen::VectorXd zp = z - B * (B.transpose() * z);
        const double k = static_cast<double>(B.cols());
        // Inside the candidate's span (to rounding): the candidate has the structure's shape.
        if (!(zp.squaredNorm() > 1e-12 * z.squaredNorm())) {
          explained = true;
          continue;
        }
        // No degrees of freedom left: a close candidate may be it; nothing can be tested.
        if (d2 - k <= 0) {
          explained = rho > mopt.structure_coverage;
          continue;
        }
        const Eigen::VectorXd rp = r - B * (B.transpose() * r);
        const double tp = std::pow(zp.dot(rp), 2) / zp.squaredNorm();
        auto insignificant = [&](double rest, double dof_p) {
          const double pp = f_upper_tail(tp / (std::max(rest, 1e-300) / dof_p), 1.0, dof_p);
          return !(std::min(1.0, K * pp) < mopt.alpha);
        };
        if (rho > mopt.structure_coverage && insignificant(rp.squaredNorm() - tp, d2 - k)) {
          explained = true;
          continue;
        }
        const auto [rss_left, dof_left] = noise_with(c);
        explained = dof_left > 0 && insignificant(rss_left, dof_left);
      }
      if (!explained) kept.push_back(std::move(pk));
    }
    picks = std::move(kept);
  }
  // The slopes fitted jointly (the selected structures together), in cable order for the words.
  std::vector<double> joint_slope(picks.size(), 0.0);
  if (!picks.empty()) {
    Eigen::MatrixXd Z(n, static_cast<Eigen::Index>(picks.size()));
    for (std::size_t q = 0; q < picks.size(); ++q)
      Z.col(static_cast<Eigen::Index>(q)) = picks[q].test->z;
    const Eigen::VectorXd b = Z.colPivHouseholderQr().solve(r);
    for (std::size_t q = 0; q < picks.size(); ++q) joint_slope[q] = b(static_cast<Eigen::Index>(q));
  }
  std::vector<std::size_t> pick_order(picks.size());
  for (std::size_t q = 0; q < picks.size(); ++q) pick_order[q] = q;
  std::stable_sort(pick_order.begin(), pick_order.end(), [&](std::size_t a, std::size_t b) {
    return picks[a].test->cable < picks[b].test->cable;
  });
  // Grouped by channel and variable.
  for (int ch = 0; ch < 2; ++ch) {
    for (int v = 0; v < static_cast<int>(std::size(vars)); ++v) {
      UnexplainedStructure u;
      u.channel = channels[ch];
      u.variable = vars[v].name;
      u.unit = vars[v].unit[0] == '\0' ? std::string(channel_unit[ch])
                                       : std::string(channel_unit[ch]) + "/" + vars[v].unit;
      Eigen::VectorXd per_pose = Eigen::VectorXd::Zero(np);
      for (std::size_t q : pick_order) {
        const Pick& pk = picks[q];
        const Test& t = *pk.test;
        if (t.channel != ch || t.var != v) continue;
        u.cables.push_back(t.cable);
        u.slopes.push_back(joint_slope[q]);
        u.p_values.push_back(pk.p);
        u.columns.conservativeResize(n, u.columns.cols() + 1);
        u.columns.col(u.columns.cols() - 1) = t.z;
        u.constants.conservativeResize(n, u.constants.cols() + 1);
        u.constants.col(u.constants.cols() - 1) = t.constant;
        if (pk.rho > u.closest_correlation) {
          u.closest_correlation = pk.rho;
          u.closest_candidate = pk.closest;
        }
        for (int j = 0; j < np; ++j) {
          const auto uj = static_cast<std::size_t>(j);
          const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
          per_pose(j) += joint_slope[q] * t.z.segment(r0, nr).dot(r.segment(r0, nr));
        }
      }
      if (u.cables.empty()) continue;
      std::vector<int> order(static_cast<std::size_t>(np));
      for (int j = 0; j < np; ++j) order[static_cast<std::size_t>(j)] = j;
      std::stable_sort(order.begin(), order.end(),
                       [&](int a, int b) { return per_pose(a) > per_pose(b); });
      const double top = np > 0 ? per_pose(order[0]) : 0.0;
      for (int j : order) {
        if (u.poses.size() >= 10 || !(per_pose(j) > 0.25 * top)) break;
        u.poses.push_back(j);
      }
      std::sort(u.poses.begin(), u.poses.end());
      std::string detail;
      for (std::size_t q = 0; q < u.cables.size(); ++q) {
        if (q > 0) detail += "; ";
        const double b = u.slopes[q];
        const bool len = ch == 0;
        const std::string cable = "cable " + std::to_string(u.cables[q] + 1);
        if (v == 0) {
          detail += len ? format("%s: %+.2f mm after paying out, %+.2f mm after reeling in",
                                 cable.c_str(), 1e3 * b, -1e3 * b)
                        : format("%s: %+.2f N after paying out, %+.2f N after reeling in",
                                 cable.c_str(), b, -b);
        } else {
          detail += format("%s: %.3g %s", cable.c_str(), b, u.unit.c_str());
        }
        detail += format(" (p = %.2g)", u.p_values[q]);
      }
      u.description = format(
          "Unexplained structure in the %s: the %s of cable%s %s follow the %s (%s), most at "
          "pose%s %s. No candidate effect of the library has this shape (closest: %s, canonical "
          "correlation %.2f).",
          u.channel.c_str(), ch == 0 ? "length readings" : "tension readings",
          u.cables.size() > 1 ? "s" : "", index_list(u.cables, 1).c_str(), u.variable.c_str(),
          detail.c_str(), u.poses.size() > 1 ? "s" : "", index_list(u.poses, 0).c_str(),
          u.closest_candidate.empty() ? "none" : u.closest_candidate.c_str(),
          u.closest_correlation);
      out.push_back(std::move(u));
    }
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const UnexplainedStructure& a, const UnexplainedStructure& b) {
                     return *std::min_element(a.p_values.begin(), a.p_values.end()) <
                            *std::min_element(b.p_values.begin(), b.p_values.end());
                   });
  return out;
}

// The catenary of a free span (platform anchor at the origin, exit point at (span, height)) whose
// tension at the exit point is T: its unstretched length by the secant method (the tension falls
// as it grows), started from the straight cable plus the small-sag arc. nullopt: no solution.
struct SpanSolution : CatenarySolution {
  double unstretched_length = 0.0;
};

std::optional<SpanSolution> catenary_for_tension(double span, double height, double chord, double w,
                                                 double ea, double T) {
  auto tension_at = [&](double l0, CatenarySolution* sol) {
    auto r = solve_elastic_catenary(span, height, l0, w, ea);
    if (!r.ok()) return std::numeric_limits<double>::quiet_NaN();
    if (sol != nullptr) *sol = *r;
    return r->tension_b - T;
  };
  const double arc = sag_arc_minus_chord(w, span, chord, T) * ea / (ea + T);
  double x0 = chord * ea / (ea + T) + arc, x1 = x0 + 1e-3 * arc + 1e-12 * x0;
  double f0 = tension_at(x0, nullptr), f1 = tension_at(x1, nullptr);
  SpanSolution out;
  for (int it = 0; it < 40 && std::isfinite(f0) && std::isfinite(f1); ++it) {
    bool done = std::abs(f1) <= 1e-10 * (1.0 + T);
    if (!done) {
      if (f1 == f0) return std::nullopt;
      double x2 = x1 - f1 * (x1 - x0) / (f1 - f0);
      if (!(x2 > 0.0)) x2 = 0.5 * x1;
      // Converged in L0 (a stiff cable: the tension cannot be matched closer in double).
      done = std::abs(x2 - x1) <= 1e-14 * x1;
      x0 = x1;
      f0 = f1;
      x1 = x2;
      f1 = done ? 0.0 : tension_at(x1, nullptr);
    }
    if (done) {
      if (!std::isfinite(tension_at(x1, &out))) return std::nullopt;
      out.unstretched_length = x1;
      return out;
    }
  }
  return std::nullopt;
}

}  // namespace

Eigen::MatrixXd last_move_directions(const MeasurementSet& set, double deadband_sigmas) {
  const int np = set.num_poses();
  const int m = np > 0 ? static_cast<int>(set.poses[0].cable_lengths.size()) : 0;
  Eigen::MatrixXd d = Eigen::MatrixXd::Zero(np, m);
  const double deadband = deadband_sigmas * set.noise.sigma_length;
  for (int i = 0; i < m; ++i) {
    double previous = kNaN, direction = 0.0;
    for (int j = 0; j < np; ++j) {
      const Eigen::VectorXd& l = set.poses[static_cast<std::size_t>(j)].cable_lengths;
      const double now = i < l.size() ? l(i) : kNaN;
      if (std::isfinite(now) && std::isfinite(previous) && std::abs(now - previous) > deadband) {
        direction = now > previous ? 1.0 : -1.0;
      }
      if (std::isfinite(now)) previous = now;
      d(j, i) = direction;
    }
  }
  return d;
}

double chi2_upper_tail(double x, double dof) {
  if (!(dof > 0)) return kNaN;
  if (!(x > 0)) return 1.0;
  return gamma_q(0.5 * dof, 0.5 * x);
}

double f_upper_tail(double x, double d1, double d2) {
  if (!(d1 > 0) || !(d2 > 0)) return kNaN;
  if (!(x > 0)) return 1.0;
  return beta_i(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * x));
}

const CandidateScreen* MismatchSummary::best() const {
  if (candidates.empty() || !candidates.front().significant) return nullptr;
  return &candidates.front();
}

const CandidateScreen* MismatchSummary::find(const std::string& id) const {
  for (const auto& c : candidates) {
    if (c.id == id) return &c;
  }
  return nullptr;
}

std::string MismatchSummary::text() const {
  std::string s;
  for (const auto& f : findings) s += "- " + f + "\n";
  s += format("\n%-34s %5s %10s %10s %9s %8s %10s\n", "candidate", "k", "T", "p(F)", "p(Holm)",
              "explains", "dBIC");
  for (const auto& c : candidates) {
    s += format("%-34s %5d %10.2f %10.3g %9.3g %7.1f%% %10.1f%s\n", c.id.c_str(), c.rank,
                c.statistic, c.p_value, c.p_adjusted, 100.0 * c.explained_fraction, c.bic_delta,
                c.modelled ? " (already modelled)" : (c.significant ? " *" : ""));
  }
  s += format("\n%-22s %6s %10s %10s %10s\n", "channel", "n", "RMS/sigma", "ratio", "p");
  for (const auto& g : channels) {
    s += format("%-22s %6d %10.3f %10.3f %10.3g%s\n", g.name.c_str(), g.count, g.rms_normalized,
                g.ratio, g.p_value, g.flagged ? " *" : "");
  }
  for (const auto& g : cables) {
    s += format("%-22s %6d %10.3f %10.3f %10.3g%s\n", g.name.c_str(), g.count, g.rms_normalized,
                g.ratio, g.p_value, g.flagged ? " *" : "");
  }
  return s;
}

Result<MismatchDesign> mismatch_design(const CalibratedModel& model, const MeasurementSet& set,
                                       const std::vector<Pose>& poses,
                                       const std::vector<PoseResiduals>* residuals,
                                       const IdentificationOptions& options,
                                       const MismatchOptions& mismatch) {
  auto dd = build_design(model, set, poses, residuals, options, mismatch);
  if (!dd) return dd.status();
  DesignData& D = *dd;
  MismatchDesign out;
  for (const Row& row : D.rows) {
    out.kind.push_back(row.kind);
    out.pose.push_back(row.pose);
    out.index.push_back(row.index);
  }
  out.pose_start = std::move(D.pose_start);
  out.residuals = std::move(D.r);
  out.sigma_length = std::move(D.sigma_len);
  out.geometry_names = D.base.names;
  out.jacobian_geometry = std::move(D.base.jacobian_geometry);
  out.jacobian_pose = std::move(D.base.jacobian_pose);
  out.candidates = std::move(D.lib);
  return out;
}

Result<CandidateColumns> sag_effect(const CalibratedModel& model, const MeasurementSet& set,
                                    const std::vector<Pose>& poses, const MismatchDesign& d,
                                    const IdentificationOptions& options, double mass_per_length,
                                    Eigen::VectorXd* compliance) {
  const RobotModel& robot = model.robot;
  const int m = robot.num_cables();
  const int np = d.num_poses();
  if (static_cast<int>(poses.size()) != np || set.num_poses() != np ||
      d.sigma_length.size() != d.num_rows()) {
    return Status(ErrorCode::kInvalidArgument, "sag effect: poses, recording and design differ");
  }
  CandidateColumns out;
  out.id = "sag_shared";
  out.family = std::string(find_effect(out.id)->family);
  out.X = Eigen::MatrixXd::Zero(d.num_rows(), 1);
  out.si = Eigen::MatrixXd::Zero(d.num_rows(), 1);
  if (compliance != nullptr) *compliance = Eigen::VectorXd::Zero(d.num_rows());
  if (!(mass_per_length > 0.0)) return out;
  const double w = mass_per_length * robot.gravity;
  const double slack = slack_threshold(options, set.noise);
  const double sf2 = set.noise.sigma_force * set.noise.sigma_force;
  const double sl2 = set.noise.sigma_length * set.noise.sigma_length;
  KinematicsData kin(robot);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    if (pm.tensions.size() != m || !inverse_kinematics(robot, poses[uj], kin)) continue;
    std::vector<int> length_row(static_cast<std::size_t>(m), -1);
    int kw = -1;
    for (int k = d.pose_start[uj]; k < d.pose_start[uj + 1]; ++k) {
      const auto uk = static_cast<std::size_t>(k);
      if (d.kind[uk] == ResidualKind::kLength)
        length_row[static_cast<std::size_t>(d.index[uk])] = k;
      if (d.kind[uk] == ResidualKind::kWrench && kw < 0) kw = k;
    }
    Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
    for (int i = 0; i < m; ++i) {
      const auto ui = static_cast<std::size_t>(i);
      const Eigen::Vector3d u = kin.unit_vectors.col(i);
      const Eigen::Vector3d rb = kin.platform_points.col(i) - poses[uj].position;
      Eigen::Matrix<double, 6, 1> a;
      a << u, rb.cross(u);
      const int kl = length_row[ui];
      const double s2 = kl >= 0 ? d.sigma_length(kl) * d.sigma_length(kl) : sl2;
      cov += sf2 * (sl2 / s2) * a * a.transpose();
      const double T = pm.tensions(i);
      if (!(T >= slack) || !std::isfinite(T)) continue;
      const double free = kin.free_lengths(i);
      const Eigen::Vector3d chord = free * u;  // platform anchor -> exit point
      const double span = std::hypot(chord.x(), chord.y());
      if (!(span > 1e-6) || !(free > 0.0)) continue;
      const CableModel& c = robot.cables[ui];
      // A rigid model cable: stiff enough that the stretch is negligible, not so stiff that the
      // catenary's tension cannot be resolved in double precision.
      const double ea = c.elongation == ElongationKind::kRigid || !(c.ea > 0.0) ? 1e8 : c.ea;
      const double l_straight = free * ea / (ea + T);
      const std::optional<SpanSolution> sol = catenary_for_tension(span, chord.z(), free, w, ea, T);
      if (!sol) continue;
      const double x1 = sol->unstretched_length;
      if (kl >= 0) {
        out.si(kl, 0) = l_straight - x1;
        out.X(kl, 0) = (l_straight - x1) / d.sigma_length(kl);
        if (compliance != nullptr) {
          // d(effect)/dT: how the tension noise reaches the corrected length residual.
          const double dt = 1e-4 * T + 1e-6;
          const std::optional<SpanSolution> up =
              catenary_for_tension(span, chord.z(), free, w, ea, T + dt);
          if (up) {
            const double l2 = free * ea / (ea + T + dt);
            (*compliance)(kl) = ((l2 - up->unstretched_length) - (l_straight - x1)) / dt;
          }
        }
      }
      // The sagging cable pulls the platform with (H e_h, V_a) (catenary.hpp: end A); the model
      // has T u. The residual (model - truth) of the net wrench gets T u - F.
      const Eigen::Vector3d e_h(chord.x() / span, chord.y() / span, 0.0);
      const Eigen::Vector3d f =
          sol->horizontal_force * e_h + sol->vertical_force_a * Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d v = T * u - f;
      delta.head<3>() += v;
      delta.tail<3>() += rb.cross(v);
    }
    if (kw >= 0) put_wrench_effect(cov, delta, kw, 0, out);
  }
  return out;
}

Result<MismatchSummary> locate_mismatch(const IdentificationReport& report,
                                        const MeasurementSet& set,
                                        const IdentificationOptions& options,
                                        const MismatchOptions& mopt) {
  auto dd = build_design(report.estimate, set, report.poses, &report.residuals, options, mopt);
  if (!dd) return dd.status();
  const DesignData& D = *dd;
  const RobotModel& robot = report.estimate.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  const int np = set.num_poses();
  const std::vector<Row>& rows = D.rows;
  const std::vector<double>& si = D.si;
  const std::vector<int>& pose_start = D.pose_start;
  const int n = static_cast<int>(rows.size());
  const Eigen::VectorXd& r = D.r;
  const GeometryInformation* base = &D.base;
  const std::vector<Candidate>& lib = D.lib;
  const Eigen::VectorXd &tension = D.tension, &kin_len = D.kin_len, &time = D.time, &tilt = D.tilt;
  const Eigen::MatrixXd& direction = D.direction;
  const Eigen::VectorXd& loaded = D.loaded;

  // --- Full Jacobian J (geometry + free poses) and its column-space basis.
  const int P = static_cast<int>(base->names.size());
  std::vector<int> pose_col(static_cast<std::size_t>(np), -1);
  int cols = P;
  for (int j = 0; j < np; ++j) {
    if (base->jacobian_pose[static_cast<std::size_t>(j)].norm() > 0) {
      pose_col[static_cast<std::size_t>(j)] = cols;
      cols += 6;
    }
  }
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(n, cols);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int r0 = pose_start[uj];
    const int nr = pose_start[uj + 1] - r0;
    J.block(r0, 0, nr, P) = base->jacobian_geometry[uj];
    if (pose_col[uj] >= 0) J.block(r0, pose_col[uj], nr, 6) = base->jacobian_pose[uj];
  }
  const Eigen::MatrixXd Q1 = column_basis(J, mopt.rank_tolerance);
  const int rankJ = static_cast<int>(Q1.cols());
  const Eigen::VectorXd leverage = Q1.rowwise().squaredNorm();
  auto project = [&](const Eigen::MatrixXd& X) -> Eigen::MatrixXd {
    return X - Q1 * (Q1.transpose() * X);
  };

  MismatchSummary out;
  out.num_residuals = n;
  out.chi2 = r.squaredNorm();
  out.jacobian_rank = rankJ;
  out.dof = n - rankJ;
  if (n == 0 || out.dof <= 0) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "mismatch: %d residuals and %d fitted quantities leave no degrees of "
                         "freedom",
                         n, rankJ);
  }
  out.p_value = chi2_upper_tail(out.chi2, out.dof);
  const double alpha = mopt.alpha;

  // --- LOCATE: misfit per channel, cable and pose.
  {
    std::vector<int> len, wr, ref, swv, inc, yaw;
    std::vector<std::vector<int>> las(static_cast<std::size_t>(nl));
    std::vector<std::vector<int>> cab(static_cast<std::size_t>(m));
    for (int k = 0; k < n; ++k) {
      const Row& row = rows[static_cast<std::size_t>(k)];
      switch (row.kind) {
        case RowKind::kLength:
          len.push_back(k);
          cab[static_cast<std::size_t>(row.index)].push_back(k);
          break;
        case RowKind::kLaser:
          las[static_cast<std::size_t>(row.index)].push_back(k);
          break;
        case RowKind::kWrench:
          wr.push_back(k);
          break;
        case RowKind::kReference:
          ref.push_back(k);
          break;
        case RowKind::kSwivel:
          swv.push_back(k);
          break;
        case RowKind::kInclination:
          inc.push_back(k);
          break;
        case RowKind::kImuYaw:
          yaw.push_back(k);
          break;
      }
    }
    if (!len.empty()) {
      out.channels.push_back(make_group("cable lengths", len, r, leverage, si, "m", alpha));
    }
    for (int l = 0; l < nl; ++l) {
      if (las[static_cast<std::size_t>(l)].empty()) continue;
      out.channels.push_back(make_group("laser " + std::to_string(l + 1),
                                        las[static_cast<std::size_t>(l)], r, leverage, si, "m",
                                        alpha));
    }
    if (!wr.empty()) {
      out.channels.push_back(make_group("equilibrium", wr, r, leverage, si, "", alpha));
    }
    if (!ref.empty()) {
      out.channels.push_back(make_group("reference pose", ref, r, leverage, si, "", alpha));
    }
    if (!swv.empty()) {
      out.channels.push_back(make_group("swivel angles", swv, r, leverage, si, "rad", alpha));
    }
    if (!inc.empty()) {
      out.channels.push_back(make_group("inclinometer", inc, r, leverage, si, "rad", alpha));
    }
    if (!yaw.empty()) {
      out.channels.push_back(make_group("IMU yaw", yaw, r, leverage, si, "rad", alpha));
    }
    for (int i = 0; i < m; ++i) {
      if (cab[static_cast<std::size_t>(i)].empty()) continue;
      out.cables.push_back(make_group("cable " + std::to_string(i + 1),
                                      cab[static_cast<std::size_t>(i)], r, leverage, si, "m",
                                      alpha));
    }
    for (int j = 0; j < np; ++j) {
      std::vector<int> pr;
      for (int k = pose_start[static_cast<std::size_t>(j)];
           k < pose_start[static_cast<std::size_t>(j) + 1]; ++k) {
        pr.push_back(k);
      }
      out.poses.push_back(make_group("pose " + std::to_string(j), pr, r, leverage, si, "", alpha));
    }
  }

  // --- LOCATE: structure tests of the normalised length residuals.
  {
    struct Variable {
      std::string name;
      Eigen::MatrixXd values;  // n x q
    };
    std::vector<Variable> vars;
    vars.push_back({"tension x length", tension.cwiseProduct(loaded)});
    vars.push_back({"tension", tension});
    vars.push_back({"cable length", kin_len});
    vars.push_back({"time", time});
    vars.push_back({"platform tilt", tilt});
    vars.push_back({"cable direction in the pulley frame", direction});
    std::vector<StructureTest> tests;
    for (int i = -1; i < m; ++i) {
      for (const Variable& v : vars) {
        std::vector<int> idx;
        for (int k = 0; k < n; ++k) {
          const Row& row = rows[static_cast<std::size_t>(k)];
          if (row.kind != RowKind::kLength || (i >= 0 && row.index != i)) continue;
          if (!v.values.row(k).allFinite()) continue;
          idx.push_back(k);
        }
        if (static_cast<int>(idx.size()) < 4) continue;
        Eigen::VectorXd y(static_cast<Eigen::Index>(idx.size()));
        Eigen::MatrixXd X(static_cast<Eigen::Index>(idx.size()), v.values.cols());
        for (std::size_t q = 0; q < idx.size(); ++q) {
          y(static_cast<Eigen::Index>(q)) = r(idx[q]);
          X.row(static_cast<Eigen::Index>(q)) = v.values.row(idx[q]);
        }
        StructureTest t = regress(v.name, i, y, X);
        if (t.slopes > 0) tests.push_back(t);
      }
    }
    const double bonferroni = alpha / std::max<double>(1.0, static_cast<double>(tests.size()));
    for (auto& t : tests) t.significant = t.p_value < bonferroni;
    out.structure = std::move(tests);
  }

  // --- Screen every candidate.
  const double rss = out.chi2;
  std::vector<Eigen::MatrixXd> bases(lib.size());
  for (std::size_t c = 0; c < lib.size(); ++c) {
    CandidateScreen s;
    s.id = lib[c].id;
    s.name = lib[c].name;
    s.family = lib[c].family;
    s.columns = static_cast<int>(lib[c].X.cols());
    const Eigen::MatrixXd Xp = project(lib[c].X);
    // Rank relative to the unprojected column norms: a column that loses (almost) all of its
    // length in the projection is already modelled by the identification.
    Eigen::MatrixXd Xs = Xp;
    for (Eigen::Index q = 0; q < Xs.cols(); ++q) {
      const double nx = lib[c].X.col(q).norm();
      Xs.col(q) = nx > 0 ? Eigen::VectorXd(Xs.col(q) / nx) : Eigen::VectorXd::Zero(n);
    }
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(Xs, Eigen::ComputeThinU);
    int rk = 0;
    for (Eigen::Index q = 0; q < svd.singularValues().size(); ++q) {
      if (svd.singularValues()(q) > std::sqrt(mopt.rank_tolerance)) ++rk;
    }
    bases[c] = svd.matrixU().leftCols(rk);
    s.rank = rk;
    s.modelled = rk == 0;
    if (rk > 0 && out.dof - rk > 0) {
      s.statistic = (bases[c].transpose() * r).squaredNorm();
      s.p_score = chi2_upper_tail(s.statistic, rk);
      s.explained_fraction = rss > 0 ? s.statistic / rss : 0.0;
      const double rest = std::max(rss - s.statistic, 1e-300);
      s.f_statistic = (s.statistic / rk) / (rest / (out.dof - rk));
      s.p_value = f_upper_tail(s.f_statistic, rk, out.dof - rk);
      s.bic_delta = n * std::log(rest / rss) + rk * std::log(static_cast<double>(n));
      s.coefficients = Xp.completeOrthogonalDecomposition().solve(r);
    }
    out.candidates.push_back(std::move(s));
  }
  // Holm over the screened candidates.
  {
    std::vector<std::size_t> order;
    for (std::size_t c = 0; c < out.candidates.size(); ++c) {
      if (out.candidates[c].rank > 0) order.push_back(c);
    }
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
      return out.candidates[a].p_value < out.candidates[b].p_value;
    });
    double running = 0.0;
    const double K = static_cast<double>(order.size());
    for (std::size_t q = 0; q < order.size(); ++q) {
      CandidateScreen& s = out.candidates[order[q]];
      running = std::max(running, std::min(1.0, (K - static_cast<double>(q)) * s.p_value));
      s.p_adjusted = running;
      s.significant = s.p_adjusted < alpha;
    }
  }
  // Confounded pairs (different families, both screened).
  for (std::size_t a = 0; a < lib.size(); ++a) {
    for (std::size_t b = a + 1; b < lib.size(); ++b) {
      if (selection_group(lib[a].family) == selection_group(lib[b].family) ||
          bases[a].cols() == 0 || bases[b].cols() == 0) {
        continue;  // refinements of one effect are compared by nested tests, not confounded
      }
      const Eigen::MatrixXd M = bases[a].transpose() * bases[b];
      const Eigen::VectorXd cc = Eigen::JacobiSVD<Eigen::MatrixXd>(M).singularValues();
      const double rho = cc(0);
      if (rho <= mopt.confound_threshold) continue;
      ConfoundedPair p;
      p.first = lib[a].id;
      p.second = lib[b].id;
      p.correlation = rho;
      p.directions = static_cast<int>((cc.array() > mopt.confound_threshold).count());
      p.first_rank = static_cast<int>(bases[a].cols());
      p.second_rank = static_cast<int>(bases[b].cols());
      // One grows with time, the other does not: no pose measured after the recording tells them
      // apart as well as a pose measured again after a long wait (creep has nearly levelled off
      // by the end of a recording, so new poses see it as a constant compliance).
      auto timed = [](const Candidate& c) {
        const EffectDescriptor* e = find_effect(c.id);
        return e != nullptr && e->plotted_against.name == "time";
      };
      const char* hint = (lib[a].family == "elasticity" && lib[b].family == "compliance")
                             ? " (equal tension at very different free lengths)"
                         : timed(lib[a]) != timed(lib[b])
                             ? " (a loaded pose held and measured again after a long wait)"
                             : "";
      p.description = format(
          "%s and %s are confounded on this pose set (canonical correlation %.2f after the "
          "identification is projected out): the data cannot tell them apart; separate them with "
          "poses that excite one without the other%s, or a bench test",
          lib[a].name.c_str(), lib[b].name.c_str(), rho, hint);
      out.confounded.push_back(std::move(p));
    }
  }
  // --- DESCRIBE: structure that no candidate explains.
  if (mopt.describe_structure) out.unexplained = describe_structure(D, Q1, bases, out, mopt);
  // Each candidate's test beyond the unexplained structures.
  {
    Eigen::MatrixXd U(n, 0);
    for (const auto& u : out.unexplained) {
      // The structure with its nuisance: a constant per listed cable (friction on a cable paid
      // out more often than reeled in also shifts its mean reading).
      Eigen::MatrixXd W(n, U.cols() + u.columns.cols() + u.constants.cols());
      W << U, u.columns, u.constants;
      U = W;
    }
    if (U.cols() > 0) U = column_basis(U, mopt.rank_tolerance);
    const Eigen::VectorXd rU = r - U * (U.transpose() * r);
    std::vector<std::size_t> order;
    std::vector<double> p(out.candidates.size(), 1.0);
    for (std::size_t c = 0; c < out.candidates.size(); ++c) {
      if (out.candidates[c].rank == 0) continue;
      order.push_back(c);
      if (U.cols() == 0) {
        p[c] = out.candidates[c].p_value;
        continue;
      }
      // bases[c] is orthonormal: the singular values of its part outside U say how much of each
      // direction is left.
      Eigen::JacobiSVD<Eigen::MatrixXd> svd(bases[c] - U * (U.transpose() * bases[c]),
                                            Eigen::ComputeThinU);
      int rk = 0;
      for (Eigen::Index q = 0; q < svd.singularValues().size(); ++q) {
        if (svd.singularValues()(q) > std::sqrt(mopt.rank_tolerance)) ++rk;
      }
      const Eigen::MatrixXd B = svd.matrixU().leftCols(rk);
      const double dof_c = out.dof - static_cast<double>(U.cols() + B.cols());
      if (B.cols() == 0 || dof_c <= 0) continue;
      const double t = (B.transpose() * rU).squaredNorm();
      const double rest = std::max(rU.squaredNorm() - t, 1e-300);
      p[c] = f_upper_tail((t / static_cast<double>(B.cols())) / (rest / dof_c),
                          static_cast<double>(B.cols()), dof_c);
    }
    std::sort(order.begin(), order.end(),
              [&](std::size_t a, std::size_t b) { return p[a] < p[b]; });
    double running = 0.0;
    const double K = static_cast<double>(order.size());
    for (std::size_t q = 0; q < order.size(); ++q) {
      running = std::max(running, std::min(1.0, (K - static_cast<double>(q)) * p[order[q]]));
      out.candidates[order[q]].p_beyond_structure = running;
    }
  }

  std::stable_sort(out.candidates.begin(), out.candidates.end(),
                   [](const CandidateScreen& a, const CandidateScreen& b) {
                     if ((a.rank == 0) != (b.rank == 0)) return b.rank == 0;
                     return a.bic_delta < b.bic_delta;
                   });
  std::sort(out.confounded.begin(), out.confounded.end(),
            [](const ConfoundedPair& a, const ConfoundedPair& b) {
              return a.correlation > b.correlation;
            });

  // --- Findings in words.
  if (out.p_value < alpha) {
    out.findings.push_back(
        format("The model does not explain the recording: chi^2 = %.1f for %d degrees of freedom "
               "(%.2f times the noise, p = %.3g).",
               out.chi2, out.dof, std::sqrt(out.chi2 / out.dof), out.p_value));
  } else {
    out.findings.push_back(format(
        "The residuals are consistent with the stated sensor noise: chi^2 = %.1f for %d degrees "
        "of freedom (p = %.3g).",
        out.chi2, out.dof, out.p_value));
  }
  for (const auto& g : out.channels) {
    if (!g.flagged) continue;
    out.findings.push_back(
        format("Channel '%s' misfits: %.2f times its expected noise (chi^2 = %.1f against %.1f, "
               "p = %.3g).",
               g.name.c_str(), g.ratio, g.chi2, g.expected_chi2, g.p_value));
  }
  for (const auto& g : out.cables) {
    if (!g.flagged) continue;
    out.findings.push_back(format("Cable %s misfits: %.2f times its expected noise (p = %.3g).",
                                  g.name.c_str() + 6, g.ratio, g.p_value));
  }
  for (const auto& t : out.structure) {
    if (!t.significant) continue;
    out.findings.push_back(
        format("The length residuals of %s follow %s (F = %.1f, p = %.3g, explains %.0f %%).",
               t.cable < 0 ? "all cables" : ("cable " + std::to_string(t.cable + 1)).c_str(),
               t.variable.c_str(), t.f_statistic, t.p_value, 100.0 * t.explained_fraction));
  }
  for (const auto& u : out.unexplained) out.findings.push_back(u.description);
  if (const CandidateScreen* b = out.best()) {
    out.findings.push_back(
        format("Most likely missing physics: %s; it explains %.0f %% of the misfit (p = %.3g after "
               "Holm's correction).",
               b->name.c_str(), 100.0 * b->explained_fraction, b->p_adjusted));
  } else {
    out.findings.push_back(format("No candidate effect is significant at alpha = %.3g.", alpha));
  }
  for (const auto& p : out.confounded) out.findings.push_back(p.description + ".");
  return out;
}

}  // namespace cdpr
