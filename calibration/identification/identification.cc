// The identification: the problem (identification_problem.hpp) solved, the estimate extracted,
// the residuals per pose and channel, the covariance of the geometry and the poses, the warnings,
// and the report's text.
#include "cdpr/calibration/identification.hpp"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <set>
#include <sstream>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "identification_problem.hpp"

namespace cdpr {

double slack_threshold(const IdentificationOptions& options, const SensorNoise& noise) {
  return std::max(options.slack_tension_threshold,
                  options.slack_tension_sigmas * noise.sigma_force);
}

AnchorMask paper_anchor_mask() {
  AnchorMask mask = AnchorMask::Constant(3, 8, false);
  for (int c = 1; c <= 6; ++c) {  // x2..x7, y2..y7 (0-based 1..6)
    mask(0, c) = true;
    mask(1, c) = true;
  }
  for (int c = 4; c <= 7; ++c) mask(2, c) = true;  // z5..z8
  return mask;
}

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

using ident_detail::Built;
using ident_detail::CableConstants;
using ident_detail::Channel;
using ident_detail::elongation_at;
using ident_detail::LaserBlocks;
using ident_detail::RowInfo;
using ident_detail::true_tension;

CalibratedModel extract(const Built& B, const CalibratedModel& initial) {
  CalibratedModel out = initial;
  const int m = B.m;
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    for (int q = 0; q < 3; ++q) {
      out.robot.frame_anchors(q, i) = B.a[ui][static_cast<std::size_t>(q)];
      out.robot.platform_anchors(q, i) = B.b[ui][static_cast<std::size_t>(q)];
    }
    out.readings.length_offsets(i) = B.o[ui];
    out.readings.length_scales(i) = B.s[ui];
    WinchModel& w = out.robot.winches[ui];
    const double k = 1.0 + B.s[ui] - initial.readings.length_scales(i);
    w.length_offset = k * w.length_offset + (B.o[ui] - initial.readings.length_offsets(i));
    w.drum_diameter *= k;
    w.drum_pitch *= k;
    out.robot.force_sensors[ui].gain = initial.robot.force_sensors[ui].gain * (1.0 + B.g[ui]);
    out.robot.force_sensors[ui].offset = initial.robot.force_sensors[ui].offset + B.c[ui];
  }
  // Stiffness: only when it was estimated (a shared value lives in e[0]).
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    const bool shared_used = B.constants[ui].estimated_stiffness;
    if (!shared_used) continue;
    const double e = B.shared_stiffness ? B.e[0] : B.e[ui];
    out.robot.cables[ui].ea = initial.robot.cables[ui].ea * (1.0 + e);
    out.robot.cables[ui].elongation = ElongationKind::kHooke;
  }
  if (B.swivel_zero_free) {
    out.robot.swivel_encoders.resize(static_cast<std::size_t>(m));
    for (int i = 0; i < m; ++i) {
      const auto ui = static_cast<std::size_t>(i);
      out.robot.swivel_encoders[ui].direction = initial.robot.swivel_encoder(i).direction;
      out.robot.swivel_encoders[ui].zero = B.swivel_zero[ui];
    }
  }
  if (B.incl_mount_free) {
    out.robot.inclinometer.mounting_rpy = rpy_from_rotation(
        B.incl_mount0 * rotation_from_rpy<double>(B.incl_mount[0], B.incl_mount[1], 0.0));
  }
  if (B.imu_yaw_zero_free) out.robot.inclinometer.yaw_zero = B.imu_yaw_zero;
  out.robot.platform.mass = B.mass;
  out.robot.platform.center_of_mass = Eigen::Vector3d(B.com[0], B.com[1], B.com[2]);
  if (B.home_tilt_free) {
    // A suspended robot's home is where the calibrated model hangs at the home position and
    // heading (the estimated tilt, made an exact equilibrium so that the model check accepts it).
    for (std::size_t j = 0; j < B.poses.size(); ++j) {
      if (B.pose_free[j]) continue;
      const Pose estimated =
          Pose::from_vector(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(B.poses[j].data()));
      const Pose target = B.hang_home_at ? *B.hang_home_at : estimated;
      const Result<SuspendedState> hang = suspended_equilibrium_pose(out.robot, target);
      out.robot.home = hang.ok() ? hang->pose : target;
    }
  } else if (out.robot.suspended && m < 6) {
    // No pose held the home (--gauge none): it keeps its position and heading and hangs as the
    // calibrated model makes it, as a suspended robot's home must (the config loader checks it).
    const Result<SuspendedState> hang = suspended_equilibrium_pose(out.robot, out.robot.home);
    if (hang.ok()) out.robot.home = hang->pose;
  }
  for (std::size_t l = 0; l < B.lasers.size(); ++l) {
    const LaserBlocks& L = B.lasers[l];
    LaserModel& lm = out.robot.lasers[l];
    lm.origin = Eigen::Vector3d(L.origin[0], L.origin[1], L.origin[2]);
    lm.direction = (L.d0 + L.de1 * L.direction[0] + L.de2 * L.direction[1]).normalized();
    lm.plane_normal = (L.n0 + L.ne1 * L.normal[0] + L.ne2 * L.normal[1]).normalized();
    lm.plane_point = L.c * lm.plane_normal;
  }
  return out;
}

std::vector<Pose> initial_poses(const MeasurementSet& set) {
  std::vector<Pose> p;
  p.reserve(set.poses.size());
  for (const PoseMeasurement& pm : set.poses) p.push_back(start_of(pm));
  return p;
}

// Pseudo-inverse of a symmetric PSD matrix after column normalisation; `null` receives the
// normalised null-space basis.
Eigen::MatrixXd pseudo_inverse_normalized(const Eigen::MatrixXd& S, double rel_tol, int* rank,
                                          double* condition, Eigen::MatrixXd* null_basis) {
  const int P = static_cast<int>(S.rows());
  if (P == 0) {  // nothing estimated (a fixed model: only the poses are fitted)
    if (rank) *rank = 0;
    if (condition) *condition = 0.0;
    if (null_basis) *null_basis = Eigen::MatrixXd();
    return Eigen::MatrixXd();
  }
  Eigen::VectorXd d(P);
  for (int q = 0; q < P; ++q) d(q) = S(q, q) > 0 ? std::sqrt(S(q, q)) : 1.0;
  const Eigen::MatrixXd N = d.cwiseInverse().asDiagonal() * S * d.cwiseInverse().asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(N);
  const Eigen::VectorXd lam = es.eigenvalues().cwiseMax(0.0);
  const double lmax = lam.size() ? lam.maxCoeff() : 0.0;
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(P);
  int r = 0;
  double smin = lmax;
  std::vector<int> null_idx;
  for (int q = 0; q < P; ++q) {
    // Singular values are sqrt(lambda): compare sigma ratios with rel_tol.
    if (lmax > 0 && std::sqrt(lam(q) / lmax) > rel_tol) {
      inv(q) = 1.0 / lam(q);
      ++r;
      smin = std::min(smin, lam(q));
    } else {
      null_idx.push_back(q);
    }
  }
  if (rank) *rank = r;
  if (condition) {
    *condition =
        (r == P && smin > 0) ? std::sqrt(lmax / smin) : std::numeric_limits<double>::infinity();
  }
  if (null_basis) {
    null_basis->resize(P, static_cast<int>(null_idx.size()));
    for (std::size_t k = 0; k < null_idx.size(); ++k) {
      null_basis->col(static_cast<int>(k)) = es.eigenvectors().col(null_idx[k]);
    }
  }
  const Eigen::MatrixXd Ninv = es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
  return d.cwiseInverse().asDiagonal() * Ninv * d.cwiseInverse().asDiagonal();
}

// Identifiability at the initial guess (nothing to check for a fixed model, P == 0).
Status check_identifiable(Built& B, const CalibratedModel& initial,
                          const IdentificationOptions& options) {
  if (B.num_geometry == 0) return Status::success();
  auto info0 = ident_detail::information(B, false);
  if (!info0) return info0.status();
  IdentifiabilityOptions io;
  io.rank_tolerance = options.rank_tolerance;
  const IdentifiabilityReport ir =
      analyze_identifiability(ident_detail::to_public(B, *info0, initial), io);
  if (options.refuse_unidentifiable) {
    CDPR_RETURN_IF_ERROR(require_identifiable(ir));
  }
  return Status::success();
}

// Solver iterations as progress (IdentificationOptions::progress).
struct IterationProgress final : ceres::IterationCallback {
  const IdentificationOptions* o = nullptr;
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    o->progress("solver iteration", s.iteration, o->max_iterations);
    return ceres::SOLVER_CONTINUE;
  }
};

ceres::Solver::Options solver_options(Built& B, const IdentificationOptions& options,
                                      IterationProgress* progress, bool free_poses) {
  ceres::Solver::Options so;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.gradient_tolerance = options.gradient_tolerance;
  so.parameter_tolerance = options.parameter_tolerance;
  so.num_threads = options.num_threads;
  so.logging_type = ceres::SILENT;
  if (options.progress) so.callbacks.push_back(progress);
  if (free_poses && B.num_geometry > 0) {
    so.linear_solver_type = ceres::DENSE_SCHUR;
    // Poses are eliminated first (group 0). Every other block gets a group of its own, in the
    // order the problem was built: within one group Ceres orders blocks by their address, which
    // would make the last bits of the result depend on where the heap put the parameter vectors.
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    std::vector<double*> all;
    B.problem.GetParameterBlocks(&all);
    std::set<const double*> pose_blocks;
    for (const auto& pose : B.poses) pose_blocks.insert(pose.data());
    int group = 1;
    for (double* p : all) ordering->AddElementToGroup(p, pose_blocks.count(p) ? 0 : group++);
    so.linear_solver_ordering = ordering;
  } else {
    so.linear_solver_type = ceres::DENSE_QR;
  }
  return so;
}

// Sums of squared SI residuals and their counts, per channel (the report's RMS values).
struct ChannelSums {
  double length = 0, laser = 0, wrench = 0, swivel = 0, inclination = 0, imu_yaw = 0;
  int n_length = 0, n_laser = 0, n_wrench = 0, n_swivel = 0, n_inclination = 0, n_imu_yaw = 0;
};

// One row's normalised residual `r` into the pose's residuals, its sigma's share of the log det
// and its SI square into the sums (the length rows' SI values come from length_residuals).
void record_row(const RowInfo& ri, double r, const SensorNoise& noise, PoseResiduals& pr,
                IdentificationReport& rep, ChannelSums& sums) {
  rep.chi2 += r * r;
  // A row of a fixed sigma: its normalised and SI values, the sigma's share of the log det.
  const auto fixed = [&](double& normalized, double& si, double sigma, double& sum, int& n) {
    normalized = r;
    si = r * sigma;
    rep.log_det_covariance += 2.0 * std::log(sigma);
    sum += si * si;
    ++n;
  };
  const Eigen::Index i = ri.index;
  switch (ri.channel) {
    case Channel::kLength:
      pr.length_normalized(i) = r;  // SI value computed by length_residuals
      break;
    case Channel::kLaser:
      fixed(pr.laser_normalized(i), pr.laser_m(i), noise.sigma_laser, sums.laser, sums.n_laser);
      break;
    case Channel::kWrench:
      pr.wrench_normalized(i) = r;
      break;
    case Channel::kReference:
      pr.reference_normalized(i) = r;
      break;
    case Channel::kSwivel:
      fixed(pr.swivel_normalized(i), pr.swivel_rad(i), noise.sigma_swivel, sums.swivel,
            sums.n_swivel);
      break;
    case Channel::kInclination:
      fixed(pr.inclination_normalized(i), pr.inclination_rad(i), noise.sigma_inclination,
            sums.inclination, sums.n_inclination);
      break;
    case Channel::kImuYaw:
      fixed(pr.imu_yaw_normalized, pr.imu_yaw_rad, noise.sigma_imu_yaw, sums.imu_yaw,
            sums.n_imu_yaw);
      break;
  }
}

// The SI values of pose j's length residuals (U - reading model, recomputed at the estimate) and
// their variances' share of the log det, as LengthCost has them: encoder noise plus the force
// noise through the compliance d(dL)/dF at the estimate (elongation_at, as in LengthCost).
void length_residuals(const Built& B, const PoseMeasurement& pm, const KinematicsData& kin,
                      const IdentificationOptions& options, const SensorNoise& noise,
                      PoseResiduals& pr, IdentificationReport& rep, ChannelSums& sums) {
  const int m = B.m;
  for (int i = 0; i < m; ++i) {
    if (std::isnan(pr.length_normalized(i))) continue;
    const auto ui = static_cast<std::size_t>(i);
    const double e = options.estimate_stiffness == StiffnessEstimate::kShared ? B.e[0] : B.e[ui];
    double U = kin.lengths(i);
    const double tr = pm.tensions.size() == m ? pm.tensions(i) : kNaN;
    if (!std::isnan(tr)) {
      CableConstants k = B.constants[ui];
      const double F = true_tension(k, tr, B.g[ui], B.c[ui]);
      const double loaded = ident_detail::loaded_length<double>(k.cable, kin.lengths(i));
      if (k.estimated_stiffness) {
        const double ea = k.cable.ea * (1.0 + e);
        U -= F * loaded / (ea + F);
      } else {
        U -= cable_elongation<double>(k.cable, loaded, F);
      }
    }
    double compliance = 0.0;
    if (!std::isnan(tr)) {
      elongation_at<double>(B.constants[ui], kin.lengths(i), tr, e, B.g[ui], B.c[ui], nullptr,
                            &compliance);
      if (pm.extra_compliance.size() == m) compliance += pm.extra_compliance(i);
    }
    rep.log_det_covariance +=
        std::log(noise.sigma_length * noise.sigma_length +
                 compliance * compliance * noise.sigma_force * noise.sigma_force);
    pr.length_m(i) = U - ((1.0 + B.s[ui]) * pm.cable_lengths(i) + B.o[ui]);
    sums.length += pr.length_m(i) * pr.length_m(i);
    ++sums.n_length;
  }
}

// Pose j's wrench residual in SI units and its covariance's share of the log det.
void wrench_residual(const Built& B, std::size_t j, PoseResiduals& pr, IdentificationReport& rep,
                     ChannelSums& sums) {
  if (std::isnan(pr.wrench_normalized(0)) || B.equilibrium[j] == nullptr) return;
  Eigen::Matrix<double, 6, 1> w;
  Eigen::Matrix<double, 6, 6> cov;
  if (B.equilibrium[j]->wrench<double>(B.equilibrium_blocks[j].data(), w, cov)) {
    pr.wrench_si = w;
    const double ridge = 1e-12 * cov.trace();
    for (int q = 0; q < 6; ++q) cov(q, q) += ridge;
    const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(cov);
    if (llt.info() == Eigen::Success) {
      rep.log_det_covariance += 2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
    }
  }
  sums.wrench += pr.wrench_si.head<3>().squaredNorm();
  sums.n_wrench += 3;
}

// The residuals without loss at the estimate: chi2, the log det of their covariance, per pose and
// channel, and the RMS per channel.
void record_residuals(const Built& B, const std::vector<double>& residuals,
                      const CalibratedModel& initial, const MeasurementSet& set,
                      const IdentificationOptions& options, IdentificationReport& rep) {
  const RobotModel& robot = initial.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  const SensorNoise& noise = set.noise;
  KinematicsData kin(robot);
  ChannelSums sums;
  std::size_t row = 0;
  for (std::size_t j = 0; j < B.poses.size(); ++j) {
    PoseResiduals pr;
    pr.length_m = Eigen::VectorXd::Constant(m, kNaN);
    pr.length_normalized = Eigen::VectorXd::Constant(m, kNaN);
    pr.laser_m = Eigen::VectorXd::Constant(nl, kNaN);
    pr.laser_normalized = Eigen::VectorXd::Constant(nl, kNaN);
    pr.swivel_rad = Eigen::VectorXd::Constant(m, kNaN);
    pr.swivel_normalized = Eigen::VectorXd::Constant(m, kNaN);
    for (const RowInfo& ri : B.rows_per_pose[j])
      record_row(ri, residuals[row++], noise, pr, rep, sums);
    inverse_kinematics(rep.estimate.robot, rep.poses[j], kin);
    length_residuals(B, set.poses[j], kin, options, noise_at(noise, set.poses[j]), pr, rep, sums);
    wrench_residual(B, j, pr, rep, sums);
    rep.residuals.push_back(std::move(pr));
  }
  rep.rms_length_m = sums.n_length ? std::sqrt(sums.length / sums.n_length) : 0.0;
  rep.rms_laser_m = sums.n_laser ? std::sqrt(sums.laser / sums.n_laser) : 0.0;
  rep.rms_wrench_n = sums.n_wrench ? std::sqrt(sums.wrench / sums.n_wrench) : 0.0;
  rep.rms_swivel_rad = sums.n_swivel ? std::sqrt(sums.swivel / sums.n_swivel) : 0.0;
  rep.rms_inclination_rad =
      sums.n_inclination ? std::sqrt(sums.inclination / sums.n_inclination) : 0.0;
  rep.rms_imu_yaw_rad = sums.n_imu_yaw ? std::sqrt(sums.imu_yaw / sums.n_imu_yaw) : 0.0;
}

// Each geometry parameter's estimate, start, range and whether it ended on a bound.
void record_parameters(const Built& B, const std::vector<double>& initial_values,
                       IdentificationReport& rep) {
  const int P = B.num_geometry;
  rep.parameters.resize(static_cast<std::size_t>(P));
  for (int q = 0; q < P; ++q) {
    ParameterEstimate& pe = rep.parameters[static_cast<std::size_t>(q)];
    pe.id = B.ids[static_cast<std::size_t>(q)];
    pe.name = B.names[static_cast<std::size_t>(q)];
    pe.unit = B.units[static_cast<std::size_t>(q)];
    pe.value = *B.value_ptr[static_cast<std::size_t>(q)];
    pe.initial = initial_values[static_cast<std::size_t>(q)];
    pe.std_dev = std::numeric_limits<double>::infinity();
    pe.lower = B.lower[static_cast<std::size_t>(q)];
    pe.upper = B.upper[static_cast<std::size_t>(q)];
    const double tol = 1e-7 * (pe.upper - pe.lower);
    pe.at_bound = pe.value <= pe.lower + tol || pe.value >= pe.upper - tol;
  }
}

// Covariance of the geometry (Schur complement, pseudo-inverse with null-space handling) and of
// the poses.
void record_covariance(const Built& B, const ident_detail::Information& info,
                       const IdentificationOptions& options, IdentificationReport& rep) {
  const int P = B.num_geometry;
  Eigen::MatrixXd null_basis;
  double cond = 0.0;
  const Eigen::MatrixXd cov =
      pseudo_inverse_normalized(info.total, options.rank_tolerance, &rep.rank, &cond, &null_basis);
  rep.condition_number = cond;
  if (!options.compute_covariance) return;
  rep.covariance = cov;
  for (int q = 0; q < P; ++q) {
    const double in_null = null_basis.cols() ? null_basis.row(q).squaredNorm() : 0.0;
    rep.parameters[static_cast<std::size_t>(q)].std_dev =
        in_null > 1e-2 ? std::numeric_limits<double>::infinity()
                       : std::sqrt(std::max(0.0, cov(q, q)));
  }
  for (std::size_t j = 0; j < B.poses.size(); ++j) {
    if (!B.pose_free[j]) continue;
    const Eigen::Matrix<double, 6, 6>& Hinv = info.hpp_inv[j];
    const Eigen::MatrixXd X = Hinv * info.hpg[j];
    const Eigen::Matrix<double, 6, 6> cp = Hinv + X * cov * X.transpose();
    rep.pose_std[j] = cp.diagonal().cwiseMax(0.0).cwiseSqrt();
  }
}

// The warnings: the problem's notes, no convergence, parameters on a bound, a chi-square far from
// its degrees of freedom, rank deficiency, a large condition number, huge anchor deviations.
void record_warnings(const Built& B, const std::string& solver_message, const RobotModel& robot,
                     const IdentificationOptions& options, IdentificationReport& rep) {
  const int P = B.num_geometry;
  char buf[512];
  for (const std::string& n : B.notes) rep.warnings.push_back(n);
  if (!rep.converged) {
    rep.warnings.push_back("the solver did not converge: " + solver_message);
  }
  for (const ParameterEstimate& pe : rep.parameters) {
    if (!pe.at_bound) continue;
    std::snprintf(buf, sizeof(buf),
                  "%s = %.6g %s ended on the %s bound of its physical range [%.6g, %.6g]: the data "
                  "push it outside what the robot can be (a missing effect or a bad recording)",
                  pe.name.c_str(), pe.value, pe.unit.c_str(),
                  pe.value <= 0.5 * (pe.lower + pe.upper) ? "lower" : "upper", pe.lower, pe.upper);
    rep.warnings.emplace_back(buf);
  }
  if (rep.dof > 0) {
    const double z = (rep.chi2 - rep.dof) / std::sqrt(2.0 * rep.dof);
    if (std::abs(z) > options.chi2_warning_sigmas) {
      std::snprintf(buf, sizeof(buf),
                    "chi-square %.1f is far from its %d degrees of freedom (%.1f sigma): the noise "
                    "figures or the model are wrong%s",
                    rep.chi2, rep.dof, z, z > 0 ? " (unmodelled effect or optimistic sigmas)" : "");
      rep.warnings.emplace_back(buf);
    }
  }
  if (rep.rank < P) {
    std::snprintf(buf, sizeof(buf), "rank deficient: rank %d of %d parameters", rep.rank, P);
    rep.warnings.emplace_back(buf);
  }
  if (rep.condition_number > options.condition_warning) {
    std::snprintf(buf, sizeof(buf), "condition number %.3g > %.3g: weakly identifiable parameters",
                  rep.condition_number, options.condition_warning);
    rep.warnings.emplace_back(buf);
  }
  const Eigen::Matrix3Xd& anchors = robot.frame_anchors;
  const double frame_size =
      anchors.cols() ? (anchors.rowwise().maxCoeff() - anchors.rowwise().minCoeff()).norm() : 0.0;
  const double huge = std::max(options.huge_std_anchor, options.huge_std_fraction * frame_size);
  for (const ParameterEstimate& pe : rep.parameters) {
    if (options.compute_covariance && pe.unit == "m" && pe.std_dev > huge) {
      std::snprintf(buf, sizeof(buf),
                    "%s has a huge standard deviation (%.3g m, above %.3g m: %.3g %% of the "
                    "%.3g m frame)",
                    pe.name.c_str(), pe.std_dev, huge, 100.0 * options.huge_std_fraction,
                    frame_size);
      rep.warnings.emplace_back(buf);
    }
  }
}

}  // namespace

Result<IdentificationReport> identify(const CalibratedModel& initial, const MeasurementSet& set,
                                      const IdentificationOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  auto built = ident_detail::build_problem(initial, set, initial_poses(set), options);
  if (!built) return built.status();
  Built& B = **built;
  // P == 0 is a fixed model: only the free poses are fitted (a model checked on a recording,
  // pose_refit.hpp).
  const int P = B.num_geometry;
  // The initial values, before the solver moves them (the problem is built once).
  std::vector<double> initial_values(static_cast<std::size_t>(P));
  for (int q = 0; q < P; ++q) {
    initial_values[static_cast<std::size_t>(q)] = *B.value_ptr[static_cast<std::size_t>(q)];
  }
  int free_pose_params = 0;
  for (bool f : B.pose_free) free_pose_params += f ? 6 : 0;
  const int num_params = P + free_pose_params;
  if (B.num_residuals <= num_params) {
    return Status::error(
        ErrorCode::kFailedPrecondition,
        "identification: too few poses: %d poses give %d residuals for %d unknowns "
        "(%d parameters + %d pose coordinates); measure more poses",
        set.num_poses(), B.num_residuals, num_params, P, free_pose_params);
  }
  CDPR_RETURN_IF_ERROR(check_identifiable(B, initial, options));

  IterationProgress iteration_progress;
  iteration_progress.o = &options;
  const ceres::Solver::Options so =
      solver_options(B, options, &iteration_progress, free_pose_params > 0);
  ceres::Solver::Summary summary;
  const auto ts = std::chrono::steady_clock::now();
  ceres::Solve(so, &B.problem, &summary);
  const auto te = std::chrono::steady_clock::now();

  IdentificationReport rep;
  rep.solve_time_s = std::chrono::duration<double>(te - ts).count();
  rep.initial_cost = summary.initial_cost;
  rep.final_cost = summary.final_cost;
  rep.iterations = static_cast<int>(summary.iterations.size()) - 1;
  rep.converged = summary.termination_type == ceres::CONVERGENCE;
  rep.termination = summary.message;
  rep.num_residuals = B.num_residuals;
  rep.num_parameters = num_params;
  rep.dof = B.num_residuals - num_params;
  if (summary.termination_type == ceres::FAILURE) {
    return Status::error(ErrorCode::kNumericalFailure, "identification: Ceres failed: %s",
                         summary.message.c_str());
  }
  rep.estimate = extract(B, initial);
  for (const auto& p : B.poses) {
    rep.poses.push_back(Pose::from_vector(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(p.data())));
  }
  auto info_noloss = ident_detail::information(B, false);
  if (!info_noloss) return info_noloss.status();
  record_residuals(B, info_noloss->residuals, initial, set, options, rep);
  record_parameters(B, initial_values, rep);
  rep.pose_std.assign(B.poses.size(), Eigen::Matrix<double, 6, 1>::Zero());
  auto info_loss = options.loss == RobustLoss::kNone ? std::move(info_noloss)
                                                     : ident_detail::information(B, true);
  if (!info_loss) return info_loss.status();
  record_covariance(B, *info_loss, options, rep);
  record_warnings(B, summary.message, initial.robot, options, rep);
  rep.total_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

std::vector<std::string> IdentificationReport::parameters_at_bound() const {
  std::vector<std::string> v;
  for (const ParameterEstimate& pe : parameters)
    if (pe.at_bound) v.push_back(pe.name);
  return v;
}

std::string IdentificationReport::brief_report() const {
  char buf[320];
  std::snprintf(buf, sizeof(buf),
                "Identification: %s, %d iterations, cost %.6g -> %.6g, chi2 %.1f / dof %d, "
                "rank %d, cond %.3g, %.1f ms, %zu warnings",
                converged ? "CONVERGED" : "NOT CONVERGED", iterations, initial_cost, final_cost,
                chi2, dof, rank, condition_number, 1e3 * total_time_s, warnings.size());
  return buf;
}

std::string IdentificationReport::full_report() const {
  std::ostringstream os;
  char buf[320];
  os << "cdpr identification report\n";
  os << "--------------------------\n";
  std::snprintf(buf, sizeof(buf), "%-28s %12d\n%-28s %12d\n%-28s %12d\n", "Residuals",
                num_residuals, "Parameters (incl. poses)", num_parameters, "Degrees of freedom",
                dof);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12.6g\n%-28s %12.6g\n%-28s %12.6g\n", "Initial cost",
                initial_cost, "Final cost", final_cost, "Chi-square (no loss)", chi2);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12d\n%-28s %12.3f\n%-28s %12.3f\n", "Iterations",
                iterations, "Solve time (ms)", 1e3 * solve_time_s, "Total time (ms)",
                1e3 * total_time_s);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12d\n%-28s %12.4g\n", "Rank (geometry)", rank,
                "Condition number", condition_number);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12.4g\n%-28s %12.4g\n%-28s %12.4g\n",
                "RMS length residual (m)", rms_length_m, "RMS laser residual (m)", rms_laser_m,
                "RMS wrench residual (N)", rms_wrench_n);
  os << buf;
  if (rms_swivel_rad > 0 || rms_inclination_rad > 0 || rms_imu_yaw_rad > 0) {
    std::snprintf(buf, sizeof(buf), "%-28s %12.4g\n%-28s %12.4g\n%-28s %12.4g\n",
                  "RMS swivel residual (rad)", rms_swivel_rad, "RMS inclin. residual (rad)",
                  rms_inclination_rad, "RMS IMU yaw residual (rad)", rms_imu_yaw_rad);
    os << buf;
  }
  os << "\nParameters:\n";
  std::snprintf(buf, sizeof(buf), "  %-24s %14s %14s %14s %12s  %s\n", "name", "initial",
                "estimate", "change", "std dev", "unit");
  os << buf;
  for (const ParameterEstimate& p : parameters) {
    std::snprintf(buf, sizeof(buf), "  %-24s %14.7g %14.7g %14.4g %12.4g  %s\n", p.name.c_str(),
                  p.initial, p.value, p.value - p.initial, p.std_dev, p.unit.c_str());
    os << buf;
  }
  os << "\nTermination: " << (converged ? "CONVERGENCE" : "NO CONVERGENCE") << " (" << termination
     << ")\n";
  if (warnings.empty()) {
    os << "Solver: no warnings.\n";
  } else {
    os << "Solver warnings:\n";
    for (const std::string& w : warnings) os << "  - " << w << "\n";
  }
  return os.str();
}

}  // namespace cdpr
