#include "cdpr/calibration/monitoring.hpp"

#include <Eigen/Cholesky>
#include <cmath>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/force_distribution.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "monitoring_effects.hpp"

namespace cdpr {
namespace {

// The variance of a row without a usable reading (m^2 or N^2): its information is nil.
constexpr double kNoReading = 1e12;

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d s;
  s << 0.0, -v(2), v(1), v(2), 0.0, -v(0), -v(1), v(0), 0.0;
  return s;
}

}  // namespace

MonitorNoise monitor_noise(const SensorNoise& noise, const PredictedAccuracy* accuracy) {
  MonitorNoise n;
  n.sigma_length = noise.sigma_length;
  n.sigma_force = noise.sigma_force;
  n.sigma_laser = noise.sigma_laser;
  if (accuracy != nullptr) n.model_length = accuracy->anchor_rms_std_m;
  return n;
}

Monitor::Monitor(const CalibratedModel& model, const MonitorOptions& options, double threshold)
    : model_(model),
      options_(options),
      m_(model.robot.num_cables()),
      lasers_(static_cast<int>(model.robot.lasers.size())),
      n_(m_ + 6 + lasers_),
      p_(monitoring::total_columns(m_)),
      threshold_(threshold),
      kinematics_(model.robot) {
  resize_linearisation(lin_);
  projected_precision_.resize(n_, n_);
  weighted_signature_.resize(n_, p_);
  gram_.resize(p_, p_);
  contribution_.resize(p_, p_);
  moment_.resize(p_);
  blocks_.resize(static_cast<std::size_t>(options.history_blocks));
  for (Block& b : blocks_) {
    b.gram.resize(p_, p_);
    b.moment.resize(p_);
  }
  mean_sigma_.resize(n_);
  const char* axes[] = {"fx", "fy", "fz", "mx", "my", "mz"};
  for (int i = 0; i < m_; ++i) names_.push_back("length " + std::to_string(i + 1));
  for (const char* a : axes) names_.push_back(std::string("equilibrium ") + a);
  for (int k = 0; k < lasers_; ++k) names_.push_back("laser " + std::to_string(k + 1));
  for (int r = 0; r < n_; ++r) {
    detectors_[static_cast<std::size_t>(r)] = Cusum(options.allowance, threshold);
  }
  reset();
}

Result<Monitor> Monitor::create(const CalibratedModel& model, const MonitorOptions& options) {
  const int m = model.robot.num_cables();
  const int lasers = static_cast<int>(model.robot.lasers.size());
  if (m < 6 || m > kMonitorMaxCables || lasers > kMonitorMaxLasers) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "monitor: %d cables and %d lasers (6..%d cables and up to %d lasers)", m,
                         lasers, kMonitorMaxCables, kMonitorMaxLasers);
  }
  const MonitorNoise& nz = options.noise;
  if (!(nz.sigma_length > 0.0) || !(nz.sigma_force > 0.0) || !(nz.sigma_laser > 0.0) ||
      !(nz.model_length >= 0.0) || !(nz.model_force >= 0.0) || !(options.window_s > 0.0) ||
      options.samples_per_pose < 1 || options.full_sequence_poses < 1 ||
      options.block_samples < 1 || options.history_blocks < 1 ||
      !(options.gate_alpha > 0.0 && options.gate_alpha < 1.0)) {
    return Status(ErrorCode::kInvalidArgument,
                  "monitor: noise sigmas, window, samples per pose, full sequence poses, block "
                  "samples and history blocks must be positive and the gate in (0, 1)");
  }
  CDPR_ASSIGN_OR_RETURN(const double h,
                        cusum_threshold(options.false_alarms_per_hour, options.samples_per_hour,
                                        m + 6 + lasers, options.allowance));
  return Monitor(model, options, h);
}

void Monitor::reset() {
  gram_.setZero();
  moment_.setZero();
  for (Block& b : blocks_) {
    b.gram.setZero();
    b.moment.setZero();
    b.samples = 0;
  }
  block_ = 0;
  mean_sigma_.setZero();
  chi2_ = 0.0;
  weight_ = 0.0;
  samples_ = 0;
  alarms_ = 0;
  last_time_s_ = std::numeric_limits<double>::quiet_NaN();
  first_alarm_time_s_ = std::numeric_limits<double>::quiet_NaN();
  first_alarm_row_ = -1;
  for (Cusum& c : detectors_) c.reset();
  row_alarms_.fill(0);
}

void Monitor::resize_linearisation(Linearisation& out) const {
  out.residual.resize(n_);
  out.covariance.resize(n_, n_);
  out.nuisance.resize(n_, 6);
  out.signature.resize(n_, p_);
}

bool Monitor::linearise(const MonitorSample& s, Linearisation& out) {
  const RobotModel& robot = model_.robot;
  for (int i = 0; i < m_; ++i) {
    if (!std::isfinite(s.lengths[static_cast<std::size_t>(i)]) ||
        !std::isfinite(s.tensions[static_cast<std::size_t>(i)])) {
      return false;
    }
  }
  if (!s.pose.position.allFinite() || !s.pose.rpy.allFinite()) return false;
  if (!inverse_kinematics(robot, s.pose, kinematics_)) return false;
  const KinematicsData& k = kinematics_;
  const MonitorNoise& nz = options_.noise;
  std::array<double, kMonitorMaxCables> compliance{};
  resize_linearisation(out);  // fixed capacity: no allocation
  out.residual.setZero();
  out.covariance.setZero();
  out.nuisance.setZero();
  out.signature.setZero();
  for (int i = 0; i < m_; ++i) {
    const auto u = static_cast<std::size_t>(i);
    const CableModel& c = robot.cables[u];
    const double f = s.tensions[u];
    const ElongationDerivatives d =
        cable_elongation_derivatives(c, loaded_length(c, k.lengths(i)), f);
    compliance[u] = d.d_tension;
    out.residual(i) = s.lengths[u] - cable_length_command<double>(c, k.lengths(i), f);
    out.covariance(i, i) = nz.sigma_length * nz.sigma_length + nz.model_length * nz.model_length;
    // A slack cable's length says nothing of the geometry: its row carries nothing.
    if (f < 0.5 * c.f_min) out.covariance(i, i) = kNoReading;
    out.nuisance.row(i) = -k.structure_matrix.col(i).transpose();
  }
  // Force noise: into length row i through the compliance, into the wrench through A.
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMonitorMaxRows, kMonitorMaxCables> map(
      n_, m_);
  map.setZero();
  for (int i = 0; i < m_; ++i) {
    map(i, i) = compliance[static_cast<std::size_t>(i)];
    map.block<6, 1>(m_, i) = k.structure_matrix.col(i);
  }
  out.covariance.noalias() += nz.sigma_force * nz.sigma_force * (map * map.transpose());
  Eigen::Matrix<double, 6, 1> wrench = gravity_wrench(robot, k.rotation);
  for (int i = 0; i < m_; ++i)
    wrench += k.structure_matrix.col(i) * s.tensions[static_cast<std::size_t>(i)];
  out.residual.segment<6>(m_) = wrench;
  // The pose error also turns the cables at fixed tensions: the true wrench A(x + dx) F + w is
  // zero, so the residual moves by -d(A F)/dx dx.
  for (int i = 0; i < m_; ++i) {
    const double f = s.tensions[static_cast<std::size_t>(i)];
    const Eigen::Vector3d u = k.unit_vectors.col(i);
    const Eigen::Vector3d rb = k.rotation * robot.platform_anchors.col(i);
    Eigen::Matrix<double, 3, 6> dp;  // platform anchor motion per (dr, dtheta)
    dp << Eigen::Matrix3d::Identity(), -skew(rb);
    const Eigen::Matrix<double, 3, 6> du =
        -(Eigen::Matrix3d::Identity() - u * u.transpose()) / k.free_lengths(i) * dp;
    out.nuisance.block<3, 6>(m_, 0) -= f * du;
    out.nuisance.block<3, 6>(m_ + 3, 0) -= f * (skew(rb) * du);
    out.nuisance.block<3, 3>(m_ + 3, 3) -= f * (skew(u) * skew(rb));
  }
  const double rho = robot.platform_radius();
  for (int a = 0; a < 6; ++a) {
    const double scale = a < 3 ? 1.0 : rho;
    out.covariance(m_ + a, m_ + a) += nz.model_force * nz.model_force * scale * scale;
  }
  // Lasers: distance along the beam to the target plane; its pose derivative is the nuisance.
  for (int l = 0; l < lasers_; ++l) {
    const int row = m_ + 6 + l;
    const LaserModel& lm = robot.lasers[static_cast<std::size_t>(l)];
    const double reading = s.lasers[static_cast<std::size_t>(l)];
    const Eigen::Vector3d ro = k.rotation * lm.origin;
    const Eigen::Vector3d dir = k.rotation * lm.direction;
    const double nd = lm.plane_normal.dot(dir);
    out.covariance(row, row) = nz.sigma_laser * nz.sigma_laser;
    if (!std::isfinite(reading) || std::abs(nd) < 1e-6) {
      out.covariance(row, row) = kNoReading;
      continue;
    }
    const double dist = lm.plane_normal.dot(lm.plane_point - s.pose.position - ro) / nd;
    out.residual(row) = reading - dist;
    out.nuisance.block<1, 3>(row, 0) = -lm.plane_normal.transpose() / nd;
    out.nuisance.block<1, 3>(row, 3) =
        -(ro.cross(lm.plane_normal) + dist * dir.cross(lm.plane_normal)).transpose() / nd;
  }
  monitoring::SampleGeometry g{
      m_, &k, &robot, s.lengths.data(), s.tensions.data(), compliance.data()};
  for (const monitoring::EffectEntry& e : monitoring::effect_table()) {
    if (!e.per_cable) {
      e.fill(g, -1, out.signature, monitoring::first_column(e, -1, m_));
      continue;
    }
    for (int i = 0; i < m_; ++i) e.fill(g, i, out.signature, monitoring::first_column(e, i, m_));
  }
  return true;
}

namespace monitoring {

bool projected_precision(const Monitor::Linearisation& lin, Monitor::RowMatrix& w) {
  const Eigen::LLT<Monitor::RowMatrix> llt(lin.covariance);
  if (llt.info() != Eigen::Success) return false;
  const Monitor::Nuisance sb = llt.solve(lin.nuisance);  // S^-1 B
  Eigen::Matrix<double, 6, 6> info = lin.nuisance.transpose() * sb;
  info.diagonal().array() += 1e-12 * info.diagonal().maxCoeff();
  const Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(info);
  const auto n = lin.covariance.rows();
  w.noalias() = llt.solve(Monitor::RowMatrix::Identity(n, n));
  w.noalias() -= sb * ldlt.solve(sb.transpose());
  return true;
}

}  // namespace monitoring

bool Monitor::add(const MonitorSample& s) {
  if (!std::isfinite(s.time_s) || !linearise(s, lin_)) return false;
  if (!monitoring::projected_precision(lin_, projected_precision_)) return false;
  // The projected residual e = S W r.
  const RowVector wr = projected_precision_ * lin_.residual;
  // Cov(e) = S W S, e = S W r: each channel normalised by its own standard deviation.
  const RowVector e = lin_.covariance * wr;
  const RowMatrix cov_e = lin_.covariance * projected_precision_ * lin_.covariance;

  const double decay = std::isfinite(last_time_s_) && std::isfinite(options_.window_s)
                           ? std::exp(-std::max(0.0, s.time_s - last_time_s_) / options_.window_s)
                           : 1.0;
  last_time_s_ = s.time_s;
  weighted_signature_.noalias() = projected_precision_ * lin_.signature;
  contribution_.noalias() = lin_.signature.transpose() * weighted_signature_;
  const ColumnVector moment = lin_.signature.transpose() * wr;
  gram_ *= decay;
  gram_ += contribution_;
  moment_ *= decay;
  moment_ += moment;
  Block* block = &blocks_[static_cast<std::size_t>(block_)];
  if (block->samples >= options_.block_samples) {
    block_ = (block_ + 1) % options_.history_blocks;
    block = &blocks_[static_cast<std::size_t>(block_)];
    block->gram.setZero();
    block->moment.setZero();
    block->samples = 0;
  }
  if (block->samples == 0) block->start_s = s.time_s;
  block->gram += contribution_;
  block->moment += moment;
  ++block->samples;
  chi2_ = decay * chi2_ + lin_.residual.dot(wr);
  weight_ = decay * weight_ + 1.0;
  mean_sigma_ *= decay;
  ++samples_;

  bool alarm = false;
  for (int r = 0; r < n_; ++r) {
    const double var = cov_e(r, r);
    const double z = var > 1e-30 * lin_.covariance(r, r) ? e(r) / std::sqrt(var) : 0.0;
    mean_sigma_(r) += z;
    const auto u = static_cast<std::size_t>(r);
    if (detectors_[u].update(z)) {
      ++row_alarms_[u];
      if (alarms_ == 0) {
        first_alarm_time_s_ = s.time_s;
        first_alarm_row_ = r;
      }
      ++alarms_;
      alarm = true;
    }
  }
  return alarm;
}

}  // namespace cdpr
