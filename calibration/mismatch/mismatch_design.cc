// The screen's design (mismatch_internal.hpp): the residual layout of an identification at given
// poses, its normalised residuals, the variables that may explain them, and the columns of every
// candidate effect of the library (effect_library.hpp), in the library's order.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <utility>

#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/mismatch.hpp"
#include "mismatch_internal.hpp"

namespace cdpr {
namespace mismatch_detail {

bool put_wrench_effect(Eigen::Matrix<double, 6, 6> cov, const Eigen::Matrix<double, 6, 1>& delta,
                       int kw, int col, CandidateColumns& c,
                       const Eigen::Matrix<double, 6, 1>* si_delta) {
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

namespace {

constexpr double kCreepTimeConstant = 10.0;  // s, the creep candidate's tau

// The identification options with every candidate parameter switched on: the extra columns of
// their Jacobian are candidate effects.
IdentificationOptions extended_options(const IdentificationOptions& options,
                                       const MismatchOptions& mopt, int nl) {
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
  return ext_opt;
}

// The rows of pose j in the identification's order (D.rows, D.si, D.length_row), checked
// against the Jacobians' row counts.
Status layout_pose_rows(DesignData& D, int j, const RobotModel& robot, const MeasurementSet& set,
                        const std::vector<PoseResiduals>* residuals,
                        const IdentificationOptions& options, const GeometryInformation& ext) {
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  std::vector<Row>& rows = D.rows;
  std::vector<double>& si = D.si;
  const auto uj = static_cast<std::size_t>(j);
  const PoseMeasurement& pm = set.poses[uj];
  const bool have_t = pm.tensions.size() == m;
  D.pose_start[uj] = static_cast<int>(rows.size());
  if (options.use_lengths) {
    for (int i = 0; i < m; ++i) {
      if (std::isnan(pm.cable_lengths(i))) continue;
      if (have_t && !std::isnan(pm.tensions(i)) &&
          pm.tensions(i) < slack_threshold(options, set.noise)) {
        continue;
      }
      D.length_row[uj][static_cast<std::size_t>(i)] = static_cast<int>(rows.size());
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
  // The orientation sensors' rows come after the reference rows (the identification's order).
  const bool swivel = options.use_swivel && pm.swivel_angles.size() == m;
  const bool inclination =
      options.use_inclinometer && !std::isnan(pm.inclination(0)) && !std::isnan(pm.inclination(1));
  const bool imu_yaw = options.use_imu_yaw && !std::isnan(pm.imu_yaw);
  int extra = 0;
  if (swivel) {
    extra += static_cast<int>((pm.swivel_angles.array() == pm.swivel_angles.array()).count());
  }
  if (inclination) extra += 2;
  if (imu_yaw) extra += 1;
  const int have = static_cast<int>(rows.size()) - D.pose_start[uj];
  const int jac_rows = static_cast<int>(D.base.jacobian_geometry[uj].rows());
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
  if (swivel) {
    for (int i = 0; i < m; ++i) {
      if (std::isnan(pm.swivel_angles(i))) continue;
      rows.push_back({RowKind::kSwivel, j, i});
      si.push_back(residuals ? (*residuals)[uj].swivel_rad(i) : kNaN);
    }
  }
  if (inclination) {
    for (int q = 0; q < 2; ++q) {
      rows.push_back({RowKind::kInclination, j, q});
      si.push_back(residuals ? (*residuals)[uj].inclination_rad(q) : kNaN);
    }
  }
  if (imu_yaw) {
    rows.push_back({RowKind::kImuYaw, j, 0});
    si.push_back(residuals ? (*residuals)[uj].imu_yaw_rad : kNaN);
  }
  if (ext.jacobian_geometry[uj].rows() != jac_rows) {
    return Status::error(ErrorCode::kInternal,
                         "mismatch: pose %d: the extended Jacobian has a different row count", j);
  }
  return Status::success();
}

// The normalised residual of each row and the SI sigma of each length row (the encoder noise
// without residuals).
Status fill_residuals(DesignData& D, const MeasurementSet& set,
                      const std::vector<PoseResiduals>* residuals) {
  const int n = static_cast<int>(D.rows.size());
  D.r = Eigen::VectorXd::Zero(n);
  D.sigma_len = Eigen::VectorXd::Constant(n, kNaN);
  Eigen::VectorXd& r = D.r;
  Eigen::VectorXd& sigma_len = D.sigma_len;
  for (int k = 0; k < n; ++k) {
    const Row& row = D.rows[static_cast<std::size_t>(k)];
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
  return Status::success();
}

// The explanatory variables of each length row (NaN on the other rows).
Status fill_length_row_variables(DesignData& D, const RobotModel& robot, const MeasurementSet& set,
                                 const std::vector<Pose>& poses) {
  const int m = robot.num_cables();
  const int np = set.num_poses();
  const int n = static_cast<int>(D.rows.size());
  KinematicsData kin(robot);
  const Eigen::VectorXd nan_n = Eigen::VectorXd::Constant(n, kNaN);
  D.tension = nan_n;
  D.kin_len = nan_n;
  D.loaded = nan_n;
  D.reading = nan_n;
  D.time = nan_n;
  D.tilt = nan_n;
  D.horizontal = nan_n;
  D.direction = Eigen::MatrixXd::Constant(n, 3, kNaN);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    if (!inverse_kinematics(robot, poses[uj], kin)) {
      return Status::error(ErrorCode::kNumericalFailure,
                           "mismatch: pose %d: cable %d is degenerate at the estimated pose", j,
                           kin.invalid_cable + 1);
    }
    for (int i = 0; i < m; ++i) {
      const int k = D.length_row[uj][static_cast<std::size_t>(i)];
      if (k < 0) continue;
      const auto ui = static_cast<std::size_t>(i);
      // Tension readings are in N through the nominal sensor calibration; the estimate's sensor
      // correction is second order for a regressor.
      if (pm.tensions.size() == m) D.tension(k) = pm.tensions(i);
      D.kin_len(k) = kin.lengths(i);
      D.loaded(k) = loaded_length(robot.cables[ui], kin.lengths(i));
      D.reading(k) = pm.cable_lengths(i);
      D.time(k) = pm.time;
      D.tilt(k) = std::acos(std::clamp(kin.rotation(2, 2), -1.0, 1.0));
      const Eigen::Vector3d u = kin.unit_vectors.col(i);
      D.direction.row(k) = (robot.pulleys[ui].frame.transpose() * (-u)).transpose();
      D.horizontal(k) = kin.free_lengths(i) * std::hypot(u.x(), u.y());
    }
  }
  return Status::success();
}

// The first equilibrium row of pose j, -1 when it has none.
int wrench_row(const DesignData& D, std::size_t uj) {
  for (int k = D.pose_start[uj]; k < D.pose_start[uj + 1]; ++k) {
    if (D.rows[static_cast<std::size_t>(k)].kind == RowKind::kWrench) return k;
  }
  return -1;
}

// Per (pose, cable): the direction of the last move, the structure scan's variables, and the
// effect of a tension-reading or length error on the residual rows.
void fill_pose_cable_variables(DesignData& D, const RobotModel& robot, const MeasurementSet& set,
                               const std::vector<Pose>& poses) {
  const int m = robot.num_cables();
  const int np = set.num_poses();
  KinematicsData kin(robot);
  D.move = last_move_directions(set);
  D.pc_length = Eigen::MatrixXd::Constant(np, m, kNaN);
  D.pc_tension = D.pc_length;
  D.pc_time = D.pc_length;
  D.pc_tilt = D.pc_length;
  D.pc_temperature = D.pc_length;
  D.tension_white.assign(static_cast<std::size_t>(np), Eigen::MatrixXd());
  D.tension_si.assign(static_cast<std::size_t>(np), Eigen::MatrixXd());
  D.length_white.assign(static_cast<std::size_t>(np), Eigen::MatrixXd());
  const double sf2 = set.noise.sigma_force * set.noise.sigma_force;
  const double sl2 = set.noise.sigma_length * set.noise.sigma_length;
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
    D.tension_white[uj] = Eigen::MatrixXd::Zero(nr, m);
    D.tension_si[uj] = Eigen::MatrixXd::Zero(nr, m);
    D.length_white[uj] = Eigen::MatrixXd::Zero(nr, m);
    if (!inverse_kinematics(robot, poses[uj], kin)) continue;  // refused before
    const double tilt_j = std::acos(std::clamp(kin.rotation(2, 2), -1.0, 1.0));
    const int kw = wrench_row(D, uj);
    Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, Eigen::Dynamic> a(6, m), aw(6, m), leak(6, m);
    for (int i = 0; i < m; ++i) {
      const auto ui = static_cast<std::size_t>(i);
      D.pc_length(j, i) = kin.lengths(i);
      if (pm.tensions.size() == m) D.pc_tension(j, i) = pm.tensions(i);
      D.pc_time(j, i) = pm.time;
      D.pc_tilt(j, i) = tilt_j;
      D.pc_temperature(j, i) = pm.temperature;
      const Eigen::Vector3d u = kin.unit_vectors.col(i);
      const Eigen::Vector3d rb = kin.rotation * robot.platform_anchors.col(i);
      a.col(i) << u, rb.cross(u);
      // The length row's sigma holds the cable compliance c (sigma^2 = sl2 + c^2 sf2); the
      // equilibrium rows are whitened conditionally on it (weight sl2 / sigma^2), as identify()
      // does, so a tension-reading error e moves them by weight * e * a and the length row by
      // -c e / sigma.
      const int kl = D.length_row[uj][ui];
      // A length error (the true length longer than the reading) moves the length row by
      // 1 / sigma and, through that conditioning, the equilibrium rows by c sf2 / sigma^2 a.
      double weight = 1.0;
      leak.col(i).setZero();
      if (kl >= 0) {
        const double s2 = D.sigma_len(kl) * D.sigma_len(kl);
        weight = sl2 / s2;
        const double c = std::sqrt(std::max(s2 - sl2, 0.0) / sf2);
        D.tension_white[uj](kl - r0, i) = -c / D.sigma_len(kl);
        D.length_white[uj](kl - r0, i) = 1.0 / D.sigma_len(kl);
        leak.col(i) = (c * sf2 / s2) * a.col(i);
      }
      aw.col(i) = weight * a.col(i);
      cov += sf2 * weight * a.col(i) * a.col(i).transpose();
    }
    if (kw < 0) continue;
    cov.diagonal().array() += 1e-12 * cov.trace();
    const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(cov);
    if (llt.info() != Eigen::Success) continue;
    D.tension_white[uj].middleRows(kw - r0, 6) = llt.matrixL().solve(aw);
    D.length_white[uj].middleRows(kw - r0, 6) = llt.matrixL().solve(leak);
    D.tension_si[uj].middleRows(kw - r0, 6) = a;
  }
}

// A candidate of the library with its columns (its words from its descriptor).
Candidate candidate(const char* id, Eigen::MatrixXd X, Eigen::MatrixXd x_si) {
  const EffectDescriptor* e = find_effect(id);
  return Candidate{
      id, std::string(e->name), std::string(e->family), std::move(X), std::move(x_si), {}, {}};
}

// A candidate whose columns are a value on the length rows (one column, or one per cable), with
// `slope` the value's derivative by the row's tension reading (CandidateColumns::dtension; `none`
// for a value that does not follow it). Not added when the value is zero everywhere.
void add_per_length_row(std::vector<Candidate>& lib, const DesignData& D, int m, const char* id,
                        bool per_cable, auto value, auto slope) {
  const int n = static_cast<int>(D.rows.size());
  Candidate c = candidate(id, Eigen::MatrixXd::Zero(n, per_cable ? m : 1), {});
  c.dtension = Eigen::MatrixXd::Zero(n, per_cable ? m : 1);
  bool any = false, follows = false;
  for (int k = 0; k < n; ++k) {
    const Row& row = D.rows[static_cast<std::size_t>(k)];
    if (row.kind != RowKind::kLength) continue;
    const double v = value(k);
    if (!std::isfinite(v)) continue;
    c.X(k, per_cable ? row.index : 0) = v / D.sigma_len(k);
    any = any || v != 0.0;
    const double s = slope(k);
    if (!std::isfinite(s)) continue;
    c.dtension(k, per_cable ? row.index : 0) = s / D.sigma_len(k);
    follows = follows || s != 0.0;
  }
  if (!follows) c.dtension.resize(0, 0);
  if (any) lib.push_back(std::move(c));
}

// The candidates whose columns are a regressor on the length rows: elasticity, compliance, the
// encoder offsets and, with time stamps, encoder drift, creep and transmission drift.
void add_length_row_candidates(std::vector<Candidate>& lib, const DesignData& D, int m) {
  auto none = [](int) { return 0.0; };
  const bool have_time = D.time.array().isFinite().count() > 0;
  auto fl = [&](int k) { return D.tension(k) * D.loaded(k); };
  auto load_len = [&](int k) { return D.loaded(k); };
  auto f = [&](int k) { return D.tension(k); };
  auto one = [](int) { return 1.0; };
  add_per_length_row(lib, D, m, "hooke_shared", false, fl, load_len);
  add_per_length_row(lib, D, m, "hooke_per_cable", true, fl, load_len);
  add_per_length_row(lib, D, m, "compliance_shared", false, f, one);
  add_per_length_row(lib, D, m, "compliance_per_cable", true, f, one);
  add_per_length_row(lib, D, m, "encoder_offset_per_cable", true, one, none);
  if (!have_time) return;
  add_per_length_row(
      lib, D, m, "encoder_drift_per_cable", true, [&](int k) { return D.time(k); }, none);
  // Creep of a polymer cable under load, time-hardening logarithmic law: the compliance grows by
  // c ln(1 + t / tau) with t the time since the recording (and the load) started. Once t is
  // several tau the shape is ln(t) whatever tau is, and a constant part is elasticity's, so one
  // tau (typical of primary creep of polymer fibre ropes) serves as the regressor.
  auto log_time = [&](int k) { return std::log1p(std::max(D.time(k), 0.0) / kCreepTimeConstant); };
  add_per_length_row(
      lib, D, m, "creep_shared", false, [&](int k) { return fl(k) * log_time(k); },
      [&](int k) { return D.loaded(k) * log_time(k); });
  add_per_length_row(
      lib, D, m, "transmission_drift_shared", false,
      [&](int k) { return D.time(k) * D.reading(k); }, none);
}

// Sag of a heavy cable (mass per length mu), to first order in the sag. The encoder pays out the
// arc, longer than the chord by (mu g)^2 Lh^2 L / (24 F^2) (column 0; its coefficient in the
// residual model - reading is -(mu g)^2 / 24 <= 0). And the platform carries part of each cable's
// weight W = mu g L off the chord: with the tension T read at the frame end, the cable pulls the
// platform with T u - (W / 2)(e_z + (e_z . u) u), so the modelled net wrench is off by
// sum_i (W_i / 2)(e_z + (e_z . u_i) u_i) and its moment (column 1, coefficient mu), whitened with
// the equilibrium rows' covariance (conditional on the length rows, as identify() has it).
void add_sag_candidate(std::vector<Candidate>& lib, const DesignData& D, const RobotModel& robot,
                       const MeasurementSet& set, const std::vector<Pose>& poses) {
  const int m = robot.num_cables();
  const int np = set.num_poses();
  const int n = static_cast<int>(D.rows.size());
  KinematicsData kin(robot);
  Candidate c = candidate("sag_shared", Eigen::MatrixXd::Zero(n, 2), Eigen::MatrixXd::Zero(n, 2));
  bool any = false;
  for (int k = 0; k < n; ++k) {
    if (D.rows[static_cast<std::size_t>(k)].kind != RowKind::kLength) continue;
    const double v =
        D.horizontal(k) * D.horizontal(k) * D.kin_len(k) / (D.tension(k) * D.tension(k));
    if (!std::isfinite(v)) continue;
    c.X(k, 0) = v / D.sigma_len(k);
    c.si(k, 0) = v;
    any = any || v != 0.0;
  }
  const double sf2 = set.noise.sigma_force * set.noise.sigma_force;
  const double sl2 = set.noise.sigma_length * set.noise.sigma_length;
  const Eigen::Vector3d ez = Eigen::Vector3d::UnitZ();
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int kw = wrench_row(D, uj);
    if (kw < 0 || !inverse_kinematics(robot, poses[uj], kin)) continue;
    Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
    for (int i = 0; i < m; ++i) {
      const Eigen::Vector3d u = kin.unit_vectors.col(i);
      const Eigen::Vector3d rb = kin.rotation * robot.platform_anchors.col(i);
      Eigen::Matrix<double, 6, 1> a;
      a << u, rb.cross(u);
      const int kl = D.length_row[uj][static_cast<std::size_t>(i)];
      const double s2 = kl >= 0 ? D.sigma_len(kl) * D.sigma_len(kl) : sl2;
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
void add_nonlinear_elasticity_candidate(std::vector<Candidate>& lib, const DesignData& D) {
  const int n = static_cast<int>(D.rows.size());
  auto fl = [&](int k) { return D.tension(k) * D.loaded(k); };
  Candidate c = candidate("nonlinear_elasticity_shared", Eigen::MatrixXd::Zero(n, 2), {});
  c.dtension = Eigen::MatrixXd::Zero(n, 2);
  bool any = false;
  for (int k = 0; k < n; ++k) {
    if (D.rows[static_cast<std::size_t>(k)].kind != RowKind::kLength) continue;
    if (!std::isfinite(fl(k))) continue;
    c.X(k, 0) = fl(k) / D.sigma_len(k);
    c.X(k, 1) = D.tension(k) * fl(k) / D.sigma_len(k);
    c.dtension(k, 0) = D.loaded(k) / D.sigma_len(k);
    c.dtension(k, 1) = 2.0 * fl(k) / D.sigma_len(k);
    any = any || fl(k) != 0.0;
  }
  if (any) lib.push_back(std::move(c));
}

// Candidates from parameters the identification did not estimate (exact Jacobian columns of the
// extended identification `ext`): the descriptor's parameter kinds (EffectDescriptor::parameters)
// that the standard identification left fixed; the shared drum scale is the sum of the per-cable
// columns.
void add_jacobian_candidates(std::vector<Candidate>& lib, const DesignData& D,
                             const GeometryInformation& ext) {
  const GeometryInformation& base = D.base;
  const int n = static_cast<int>(D.rows.size());
  const int np = static_cast<int>(D.pose_start.size()) - 1;
  std::map<std::string, int> base_cols;
  for (int q = 0; q < static_cast<int>(base.names.size()); ++q)
    base_cols[base.names[static_cast<std::size_t>(q)]] = q;
  Eigen::MatrixXd Jx = Eigen::MatrixXd::Zero(n, static_cast<Eigen::Index>(ext.names.size()));
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    Jx.middleRows(D.pose_start[uj], D.pose_start[uj + 1] - D.pose_start[uj]) =
        ext.jacobian_geometry[uj];
  }
  auto group = [&](const EffectDescriptor& e) {
    const std::vector<ParameterKind>& kinds = e.parameters;
    const std::string id(e.id);
    std::vector<int> picked;
    for (int q = 0; q < static_cast<int>(ext.names.size()); ++q) {
      const std::string& nm = ext.names[static_cast<std::size_t>(q)];
      const ParameterKind kind = ext.ids[static_cast<std::size_t>(q)].kind;
      if (base_cols.count(nm) || std::find(kinds.begin(), kinds.end(), kind) == kinds.end()) {
        continue;
      }
      picked.push_back(q);
    }
    if (picked.empty()) return;
    Candidate c =
        candidate(id.c_str(), Eigen::MatrixXd(n, static_cast<Eigen::Index>(picked.size())), {});
    for (std::size_t q = 0; q < picked.size(); ++q) {
      c.X.col(static_cast<Eigen::Index>(q)) = Jx.col(picked[q]);
    }
    if (c.X.norm() > 0) lib.push_back(std::move(c));
  };
  for (const EffectDescriptor& e : effect_library()) {
    if (e.columns == EffectColumns::kUnestimatedParameters) group(e);
  }
  for (const Candidate& c : lib) {
    if (c.id == "drum_scale_per_cable") {
      Candidate s = candidate("drum_scale_shared", c.X.rowwise().sum(), {});
      lib.push_back(std::move(s));
      break;
    }
  }
}

// Direction-dependent effects (d = +-1: the cable was last paid out / reeled in). Hysteresis: the
// true length is longer by h_i d (length rows and, through their conditioning, the equilibrium
// rows; the data are corrected on the length rows only, the equilibrium rows follow, so si is 0
// there). Pulley friction: the tension reading is off by f_i d (the tension effect, per pose).
void add_direction_candidates(std::vector<Candidate>& lib, const DesignData& D, int m) {
  const int n = static_cast<int>(D.rows.size());
  const int np = static_cast<int>(D.pose_start.size()) - 1;
  const Eigen::MatrixXd& move = D.move;
  Candidate h =
      candidate("hysteresis_per_cable", Eigen::MatrixXd::Zero(n, m), Eigen::MatrixXd::Zero(n, m));
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
    for (int i = 0; i < m; ++i) h.X.block(r0, i, nr, 1) = move(j, i) * D.length_white[uj].col(i);
  }
  if (h.X.norm() > 0) lib.push_back(std::move(h));
  Candidate c = candidate("pulley_friction_per_cable", Eigen::MatrixXd::Zero(n, m),
                          Eigen::MatrixXd::Zero(n, m));
  c.tension_readings = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(np) * m, m);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const int r0 = D.pose_start[uj], nr = D.pose_start[uj + 1] - r0;
    for (int i = 0; i < m; ++i) {
      c.X.block(r0, i, nr, 1) = move(j, i) * D.tension_white[uj].col(i);
      c.si.block(r0, i, nr, 1) = move(j, i) * D.tension_si[uj].col(i);
      c.tension_readings(static_cast<Eigen::Index>(j) * m + i, i) = move(j, i);
    }
  }
  if (c.X.norm() > 0) lib.push_back(std::move(c));
}

// The candidate library's columns, in the library's order (effect_library.hpp).
std::vector<Candidate> candidate_library(const DesignData& D, const RobotModel& robot,
                                         const MeasurementSet& set, const std::vector<Pose>& poses,
                                         const GeometryInformation& ext,
                                         const MismatchOptions& mopt) {
  const int m = robot.num_cables();
  std::vector<Candidate> lib;
  add_length_row_candidates(lib, D, m);
  add_sag_candidate(lib, D, robot, set, poses);
  add_nonlinear_elasticity_candidate(lib, D);
  add_jacobian_candidates(lib, D, ext);
  if (mopt.direction_candidates && D.move.cwiseAbs().sum() > 0) add_direction_candidates(lib, D, m);
  // A confirmatory screen (MismatchOptions::only_groups): the listed selection groups only.
  if (!mopt.only_groups.empty()) {
    std::erase_if(lib, [&](const Candidate& c) {
      return std::find(mopt.only_groups.begin(), mopt.only_groups.end(),
                       selection_group(c.family)) == mopt.only_groups.end();
    });
  }
  return lib;
}

}  // namespace

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
  // Jacobians at the estimate: the identification's, and one with every candidate parameter
  // switched on (its extra columns are candidate effects).
  auto base = geometry_information(model, set, poses, options, true);
  if (!base) return base.status();
  auto ext = geometry_information(model, set, poses, extended_options(options, mopt, nl), true);
  if (!ext) return ext.status();
  DesignData D;
  D.base = std::move(*base);
  D.length_row.assign(static_cast<std::size_t>(np),
                      std::vector<int>(static_cast<std::size_t>(m), -1));
  D.pose_start.assign(static_cast<std::size_t>(np) + 1, 0);
  for (int j = 0; j < np; ++j) {
    CDPR_RETURN_IF_ERROR(layout_pose_rows(D, j, robot, set, residuals, options, *ext));
  }
  D.pose_start[static_cast<std::size_t>(np)] = static_cast<int>(D.rows.size());
  CDPR_RETURN_IF_ERROR(fill_residuals(D, set, residuals));
  CDPR_RETURN_IF_ERROR(fill_length_row_variables(D, robot, set, poses));
  fill_pose_cable_variables(D, robot, set, poses);
  D.lib = candidate_library(D, robot, set, poses, *ext, mopt);
  return D;
}

}  // namespace mismatch_detail

Eigen::MatrixXd last_move_directions(const MeasurementSet& set, double deadband_sigmas) {
  const int np = set.num_poses();
  const int m = np > 0 ? static_cast<int>(set.poses[0].cable_lengths.size()) : 0;
  Eigen::MatrixXd d = Eigen::MatrixXd::Zero(np, m);
  const double deadband = deadband_sigmas * set.noise.sigma_length;
  for (int i = 0; i < m; ++i) {
    double previous = mismatch_detail::kNaN, direction = 0.0;
    for (int j = 0; j < np; ++j) {
      const Eigen::VectorXd& l = set.poses[static_cast<std::size_t>(j)].cable_lengths;
      const double now = i < l.size() ? l(i) : mismatch_detail::kNaN;
      if (std::isfinite(now) && std::isfinite(previous) && std::abs(now - previous) > deadband) {
        direction = now > previous ? 1.0 : -1.0;
      }
      if (std::isfinite(now)) previous = now;
      d(j, i) = direction;
    }
  }
  return d;
}

Result<MismatchDesign> mismatch_design(const CalibratedModel& model, const MeasurementSet& set,
                                       const std::vector<Pose>& poses,
                                       const std::vector<PoseResiduals>* residuals,
                                       const IdentificationOptions& options,
                                       const MismatchOptions& mismatch) {
  auto dd = mismatch_detail::build_design(model, set, poses, residuals, options, mismatch);
  if (!dd) return dd.status();
  mismatch_detail::DesignData& D = *dd;
  MismatchDesign out;
  for (const mismatch_detail::Row& row : D.rows) {
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

}  // namespace cdpr
