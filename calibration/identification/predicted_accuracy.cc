#include "cdpr/calibration/predicted_accuracy.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"

namespace cdpr {

std::vector<Pose> AccuracyBox::grid() const {
  std::vector<Pose> out;
  const int n = std::max(1, points_per_axis);
  for (int ix = 0; ix < n; ++ix) {
    for (int iy = 0; iy < n; ++iy) {
      for (int iz = 0; iz < n; ++iz) {
        auto t = [&](int k) { return n == 1 ? 0.0 : -1.0 + 2.0 * k / (n - 1); };
        Pose p;
        p.position = center + half_extent.cwiseProduct(Eigen::Vector3d(t(ix), t(iy), t(iz)));
        out.push_back(p);
      }
    }
  }
  return out;
}

std::vector<Eigen::Vector3d> iso9283_points(const AccuracyBox& box) {
  const Eigen::Vector3d& h = box.half_extent;
  const Eigen::Vector3d corners[4] = {{-h.x(), -h.y(), -h.z()},
                                      {-h.x(), h.y(), -h.z()},
                                      {h.x(), h.y(), h.z()},
                                      {h.x(), -h.y(), h.z()}};
  std::vector<Eigen::Vector3d> out = {box.center};
  for (const Eigen::Vector3d& c : corners) out.push_back(box.center + 0.8 * c);
  return out;
}

namespace {

Eigen::MatrixXd normalized_pinv(const Eigen::MatrixXd& S, double tol, int* rank) {
  const int P = static_cast<int>(S.rows());
  if (rank) *rank = 0;
  if (P == 0) return Eigen::MatrixXd(0, 0);  // nothing estimated: no parameter to be uncertain
  Eigen::VectorXd d(P);
  for (int q = 0; q < P; ++q) d(q) = S(q, q) > 0 ? std::sqrt(S(q, q)) : 1.0;
  const Eigen::MatrixXd N = d.cwiseInverse().asDiagonal() * S * d.cwiseInverse().asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(N);
  const double lmax = es.eigenvalues().maxCoeff();
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(P);
  int r = 0;
  for (int q = 0; q < P; ++q) {
    if (lmax > 0 && es.eigenvalues()(q) > 0 && std::sqrt(es.eigenvalues()(q) / lmax) > tol) {
      inv(q) = 1.0 / es.eigenvalues()(q);
      ++r;
    }
  }
  if (rank) *rank = r;
  return d.cwiseInverse().asDiagonal() *
         (es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose()) *
         d.cwiseInverse().asDiagonal();
}

}  // namespace

void fit_estimates_to_channels(const SensorChannels& channels, IdentificationOptions* options) {
  if (!channels.laser) {
    options->estimate_laser_origin = false;
    options->estimate_laser_direction = false;
    options->estimate_laser_plane = false;
  }
  options->estimate_swivel_zeros = channels.swivel;
  options->estimate_inclinometer_mounting = channels.inclinometer || channels.imu_yaw;
  options->estimate_imu_yaw_zero = channels.imu_yaw;
}

Status check_estimates_for_channels(const RobotModel& robot, const SensorChannels& channels,
                                    const IdentificationOptions& identification) {
  if (!channels.laser && !robot.lasers.empty() &&
      (identification.estimate_laser_origin || identification.estimate_laser_direction ||
       identification.estimate_laser_plane)) {
    return Status(ErrorCode::kInvalidArgument,
                  "the laser's parameters are estimated but the laser channel is not recorded "
                  "(they would stay unobserved); estimate them only with the laser "
                  "(fit_estimates_to_channels)");
  }
  return Status::success();
}

Result<std::vector<Eigen::MatrixXd>> pose_sensitivities(const CalibratedModel& model,
                                                        const AccuracyBox& box, double f_ref,
                                                        const SensorNoise& noise,
                                                        const IdentificationOptions& identification,
                                                        const std::vector<ParameterId>& ids,
                                                        int* skipped_points) {
  const int m = model.robot.num_cables();
  // An under-actuated suspended robot cannot hold a level pose: each target is evaluated where
  // the platform hangs at its position and yaw.
  const bool suspended = model.robot.suspended && m < 6;
  std::vector<Pose> grid;
  int skipped = 0;
  for (const Pose& target : box.grid()) {
    Pose p = target;
    if (suspended) {
      const Result<SuspendedState> hang = suspended_equilibrium_pose(model.robot, target);
      if (!hang) {
        ++skipped;
        continue;
      }
      p = hang->pose;
    }
    if (simple_tension_distribution(model.robot, p, f_ref)) {
      grid.push_back(p);
    } else {
      ++skipped;
    }
  }
  if (skipped_points) *skipped_points = skipped;
  std::vector<Eigen::MatrixXd> out;
  if (grid.empty()) return out;
  SimulationOptions so;
  so.add_noise = false;
  so.reference_tension = f_ref;
  auto gsim = simulate_measurements(model, grid, noise, 0, so);
  if (!gsim) return gsim.status();
  // Lengths only, and no pose held by the gauge: every grid pose is free. The mounting
  // parameters of the issue 18 channels do not enter the lengths (their columns of G are zero);
  // the grid records none of those channels, so they are not free there and are mapped by id.
  IdentificationOptions go = identification;
  go.use_laser = false;
  // A suspended robot's pose also obeys the 6 - m equilibrium conditions no tension can balance:
  // the equilibrium rows are kept, and only the lengths and those conditions fix the pose below.
  go.use_equilibrium = suspended;
  go.use_reference = false;
  go.estimate_swivel_zeros = false;
  go.estimate_inclinometer_mounting = false;
  go.estimate_imu_yaw_zero = false;
  if (go.gauge == Gauge::kHomePose) go.gauge = Gauge::kNone;
  if (go.gauge == Gauge::kHomePoseAndLaserPlane) go.gauge = Gauge::kLaserPlane;
  auto gg = geometry_information(model, gsim->set, grid, go, /*keep_jacobians=*/true);
  if (!gg) return gg.status();
  // Column of each of the grid's parameters in `ids`.
  std::vector<Eigen::Index> column(gg->ids.size());
  for (std::size_t q = 0; q < gg->ids.size(); ++q) {
    const auto it = std::find(ids.begin(), ids.end(), gg->ids[q]);
    if (it == ids.end()) {
      return Status::error(ErrorCode::kInternal,
                           "pose sensitivities: parameter %s is not in the list",
                           gg->names[q].c_str());
    }
    column[q] = static_cast<Eigen::Index>(it - ids.begin());
  }
  const auto P = static_cast<Eigen::Index>(ids.size());
  for (std::size_t k = 0; k < grid.size(); ++k) {
    Eigen::MatrixXd Jp = gg->jacobian_pose[k];
    Eigen::MatrixXd Jg = gg->jacobian_geometry[k];
    if (suspended) {
      // Rows of a pose: m lengths, then the equilibrium's m tension errors (the tensions follow
      // the platform: not a constraint) and its 6 - m conditions. Keep the lengths and the
      // conditions: a square system (its row scaling does not change G).
      if (Jp.rows() != m + 6) {
        return Status::error(ErrorCode::kInternal,
                             "pose sensitivities: grid point %zu has %d rows, expected %d "
                             "(lengths and equilibrium)",
                             k + 1, static_cast<int>(Jp.rows()), m + 6);
      }
      Eigen::MatrixXd p(6, 6), g(6, Jg.cols());
      p << Jp.topRows(m), Jp.bottomRows(6 - m);
      g << Jg.topRows(m), Jg.bottomRows(6 - m);
      Jp = std::move(p);
      Jg = std::move(g);
    }
    const Eigen::MatrixXd Gk = -Jp.completeOrthogonalDecomposition().pseudoInverse() * Jg;
    Eigen::MatrixXd G = Eigen::MatrixXd::Zero(Gk.rows(), P);
    for (std::size_t q = 0; q < column.size(); ++q) {
      G.col(column[q]) = Gk.col(static_cast<Eigen::Index>(q));
    }
    out.push_back(std::move(G));
  }
  return out;
}

Result<PredictedAccuracy> predict_accuracy(const CalibratedModel& model,
                                           const std::vector<Pose>& poses, const SensorNoise& noise,
                                           const PredictedAccuracyOptions& options) {
  CDPR_RETURN_IF_ERROR(
      check_estimates_for_channels(model.robot, options.channels, options.identification));
  SimulationOptions so;
  so.add_noise = false;
  so.reference_tension = options.reference_tension;
  so.use_channels(options.channels);
  auto sim = simulate_measurements(model, poses, noise, 0, so);
  if (!sim) return sim.status();
  auto gi = geometry_information(model, sim->set, poses, options.identification);
  if (!gi) return gi.status();
  PredictedAccuracy out;
  out.ids = gi->ids;
  out.names = gi->names;
  out.covariance = normalized_pinv(gi->information, options.rank_tolerance, &out.rank);
  out.crb_std = out.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  double sum = 0.0;
  int count = 0;
  for (std::size_t q = 0; q < out.ids.size(); ++q) {
    if (out.ids[q].kind == ParameterKind::kFrameAnchor) {
      sum += out.covariance(static_cast<int>(q), static_cast<int>(q));
      ++count;
    }
  }
  out.anchor_rms_std_m = count ? std::sqrt(sum / count) : 0.0;

  // Sensitivity of the commanded lengths at the grid.
  const double f_ref = std::isnan(options.reference_tension)
                           ? default_reference_tension(model.robot)
                           : options.reference_tension;
  auto sens = pose_sensitivities(model, options.box, f_ref, noise, options.identification, gi->ids,
                                 &out.skipped_points);
  if (!sens) return sens.status();
  if (sens->empty()) return out;
  double total = 0.0;
  for (const Eigen::MatrixXd& G : *sens) {
    const Eigen::MatrixXd cx = G * out.covariance * G.transpose();
    const double v = cx.topLeftCorner<3, 3>().trace();
    total += v;
    out.position_max_m = std::max(out.position_max_m, std::sqrt(std::max(0.0, v)));
  }
  out.grid_points = static_cast<int>(sens->size());
  out.position_rms_m = std::sqrt(total / static_cast<double>(sens->size()));
  return out;
}

Result<RealizedAccuracy> measure_position_accuracy(const CalibratedModel& truth,
                                                   const CalibratedModel& controller,
                                                   const AccuracyBox& box,
                                                   double reference_tension) {
  const double f_ref = std::isnan(reference_tension) ? default_reference_tension(controller.robot)
                                                     : reference_tension;
  RealizedAccuracy out;
  double sp = 0.0, so = 0.0;
  for (const Pose& target : box.grid()) {
    auto f = simple_tension_distribution(controller.robot, target, f_ref);
    if (!f) {
      ++out.failed_points;
      continue;
    }
    auto u = unstretched_lengths(controller.robot, target, *f);
    if (!u) {
      ++out.failed_points;
      continue;
    }
    const Eigen::VectorXd reading = ((u->array() - controller.readings.length_offsets.array()) /
                                     (1.0 + controller.readings.length_scales.array()))
                                        .matrix();
    const Eigen::VectorXd u_true = ((1.0 + truth.readings.length_scales.array()) * reading.array() +
                                    truth.readings.length_offsets.array())
                                       .matrix();
    auto reached = settle_platform(truth.robot, u_true, target);
    if (!reached) {
      ++out.failed_points;
      continue;
    }
    const double e = (reached->position - target.position).norm();
    sp += e * e;
    so += (reached->rpy - target.rpy).squaredNorm();
    out.position_max_m = std::max(out.position_max_m, e);
    ++out.grid_points;
  }
  if (out.grid_points == 0) {
    return Status(ErrorCode::kNumericalFailure, "accuracy: no grid point could be reached");
  }
  out.position_rms_m = std::sqrt(sp / out.grid_points);
  out.orientation_rms_rad = std::sqrt(so / out.grid_points);
  return out;
}

Result<PredictedIsoPosition> predict_iso9283_position(const CalibratedModel& nominal,
                                                      const CalibratedModel& calibrated,
                                                      const PredictedAccuracy& crb,
                                                      const SensorNoise& noise,
                                                      const PredictedAccuracyOptions& options) {
  const double f_ref = std::isnan(options.reference_tension)
                           ? default_reference_tension(nominal.robot)
                           : options.reference_tension;
  PredictedIsoPosition out;
  out.nominal_m = 0.0;
  out.calibrated_m = 0.0;
  for (const Eigen::Vector3d& p : iso9283_points(options.box)) {
    AccuracyBox at;
    at.center = p;
    at.half_extent.setZero();
    at.points_per_axis = 1;
    const auto reached = measure_position_accuracy(calibrated, nominal, at, f_ref);
    const auto sens =
        pose_sensitivities(nominal, at, f_ref, noise, options.identification, crb.ids, nullptr);
    if (!reached.ok() || !sens.ok() || sens->size() != 1) continue;
    const Eigen::MatrixXd& G = sens->front();
    const double v = (G * crb.covariance * G.transpose()).topLeftCorner<3, 3>().trace();
    out.nominal_m = std::max(out.nominal_m, reached->position_max_m);
    out.calibrated_m = std::max(out.calibrated_m, std::sqrt(std::max(0.0, v)));
    ++out.points;
  }
  if (out.points == 0) {
    return Status(
        ErrorCode::kNumericalFailure,
        "ISO 9283 points: none is feasible for both the nominal and the calibrated model");
  }
  return out;
}

}  // namespace cdpr
