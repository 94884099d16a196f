// Helpers shared by the benchmark programs (bench/*.cc). Not installed, not a library.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/status.hpp"

namespace cdpr::bench {

// The value of `r`, or the reason on stderr and exit status 1: a benchmark cannot go on without it.
template <typename T>
T must(Result<T> r, const char* what) {
  if (!r.ok()) {
    std::fprintf(stderr, "%s failed: %s\n", what, r.status().to_string().c_str());
    std::exit(1);
  }
  return std::move(r).value();
}

// The sensor noise of the MINI benchmarks: laser 1 mm, encoder 0.1 mm, force 1 N.
inline SensorNoise mini_noise() {
  SensorNoise n;
  n.sigma_laser = 1e-3;
  n.sigma_length = 1e-4;
  n.sigma_force = 1.0;
  return n;
}

// RMS over the frame anchor coordinates (ParameterKind::kFrameAnchor) of the Cramer-Rao std of
// the Fisher information `gi`: its pseudo-inverse, taken on the information scaled to a unit
// diagonal.
inline double anchor_crb_rms(const GeometryInformation& gi) {
  const Eigen::VectorXd d = gi.information.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
  const Eigen::MatrixXd In = d.asDiagonal() * gi.information * d.asDiagonal();
  const Eigen::MatrixXd cov =
      d.asDiagonal() * In.completeOrthogonalDecomposition().pseudoInverse() * d.asDiagonal();
  double sum = 0.0;
  int count = 0;
  for (std::size_t q = 0; q < gi.ids.size(); ++q) {
    if (gi.ids[q].kind != ParameterKind::kFrameAnchor) continue;
    sum += cov(static_cast<Eigen::Index>(q), static_cast<Eigen::Index>(q));
    ++count;
  }
  return count ? std::sqrt(sum / count) : 0.0;
}

// The anchor Cramer-Rao RMS at the truth: noise-free readings of `commands` simulated on `truth`
// (the channels `simulation` sets) and the Fisher information of `identification` there.
// `summary` (optional) receives the identifiability analysis in words.
inline double crb_at_truth(const CalibratedModel& truth, const std::vector<Pose>& commands,
                           const SensorNoise& noise, const SimulationOptions& simulation,
                           const IdentificationOptions& identification, std::string* summary) {
  const SimulatedMeasurements sim =
      must(simulate_measurements(truth, commands, noise, 0, simulation), "simulate");
  const GeometryInformation gi =
      must(geometry_information(truth, sim.set, sim.true_poses, identification), "info");
  if (summary) {
    auto ir = analyze_identifiability(truth, sim.set, identification);
    *summary = ir.ok() ? ir->summary() : std::string(ir.status().message());
  }
  return anchor_crb_rms(gi);
}

// The errors of the estimated frame anchor coordinates against the true anchors, accumulated over
// the runs of a Monte Carlo: RMS error, RMS reported std, coverage of the 95 % intervals and the
// bias (RMS over the coordinates of the mean error; its noise floor is about rms / sqrt(runs)).
class AnchorErrors {
 public:
  explicit AnchorErrors(const Eigen::Matrix3Xd& truth)
      : truth_(truth),
        sum_err_(Eigen::Matrix3Xd::Zero(3, truth.cols())),
        count_(Eigen::Array<int, 3, Eigen::Dynamic>::Zero(3, truth.cols())) {}

  void add(const IdentificationReport& rep) {
    for (const ParameterEstimate& p : rep.parameters) {
      if (p.id.kind != ParameterKind::kFrameAnchor) continue;
      const int cable = p.id.index, axis = p.id.component;
      const double e = p.value - truth_(axis, cable);
      sum_sq_ += e * e;
      sum_err_(axis, cable) += e;
      count_(axis, cable) += 1;
      sum_std2_ += p.std_dev * p.std_dev;
      covered_ += std::abs(e) <= 1.96 * p.std_dev ? 1 : 0;
      ++total_;
    }
  }

  double rms() const { return std::sqrt(sum_sq_ / std::max<long>(1, total_)); }
  double reported_std() const { return std::sqrt(sum_std2_ / std::max<long>(1, total_)); }
  double coverage_percent() const {
    return 100.0 * static_cast<double>(covered_) / static_cast<double>(std::max<long>(1, total_));
  }
  double bias() const {
    double bias2 = 0.0;
    int biased = 0;
    for (Eigen::Index q = 0; q < sum_err_.size(); ++q) {
      const int n = count_(q);
      if (n == 0) continue;
      bias2 += (sum_err_(q) / n) * (sum_err_(q) / n);
      ++biased;
    }
    return std::sqrt(bias2 / std::max(1, biased));
  }
  double bias_max() const {  // the largest |mean error| of a coordinate
    double out = 0.0;
    for (Eigen::Index q = 0; q < sum_err_.size(); ++q) {
      if (count_(q) > 0) out = std::max(out, std::abs(sum_err_(q) / count_(q)));
    }
    return out;
  }

 private:
  Eigen::Matrix3Xd truth_;
  double sum_sq_ = 0.0, sum_std2_ = 0.0;
  long covered_ = 0, total_ = 0;
  Eigen::Matrix3Xd sum_err_;                    // per coordinate (axis, cable)
  Eigen::Array<int, 3, Eigen::Dynamic> count_;  // estimates per coordinate
};

// The position error over a test box of one calibrated model (m).
struct BoxError {
  double rms = 0.0, max = 0.0;
  int points = 0;  // box targets evaluated
};

// The BoxError of `model` over `box` on the robot `truth` (measure_position_accuracy).
inline BoxError realized_box_error(const CalibratedModel& truth, const CalibratedModel& model,
                                   const AccuracyBox& box) {
  const RealizedAccuracy acc = must(measure_position_accuracy(truth, model, box), "accuracy");
  return BoxError{acc.position_rms_m, acc.position_max_m, acc.grid_points};
}

// What the Monte Carlo of a configuration gives: the runs that converged, those the identification
// refused, and over the converged runs the anchor errors, the mean chi2/dof and the box error (RMS
// and mean over the runs of each run's RMS, and the largest point error).
struct MonteCarlo {
  explicit MonteCarlo(const Eigen::Matrix3Xd& true_anchors) : anchors(true_anchors) {}
  int ok = 0, refused = 0;
  AnchorErrors anchors;
  double sum_chi2_dof = 0.0, sum_box = 0.0, sum_box2 = 0.0, box_max = 0.0;

  double chi2_dof() const { return sum_chi2_dof / std::max(1, ok); }
  double box_rms() const { return std::sqrt(sum_box2 / std::max(1, ok)); }
  double box_mean() const { return sum_box / std::max(1, ok); }
};

// Seeds 0 .. seeds - 1: `truth` is commanded to `commands` by the simulation `simulation` with
// noise seed 1000 + seed (a recording the simulator fails on is skipped), `nominal` is calibrated
// from it with `identification`, and `box_error(model)` gives the BoxError of the calibrated
// model. Runs that are refused or do not converge are not counted.
template <typename BoxErrorOf>
MonteCarlo monte_carlo(int seeds, const CalibratedModel& truth, const CalibratedModel& nominal,
                       const std::vector<Pose>& commands, const SensorNoise& noise,
                       const SimulationOptions& simulation,
                       const IdentificationOptions& identification, BoxErrorOf box_error) {
  MonteCarlo mc(truth.robot.frame_anchors);
  for (int seed = 0; seed < seeds; ++seed) {
    auto sim = simulate_measurements(truth, commands, noise, 1000 + seed, simulation);
    if (!sim.ok()) continue;
    auto rep = identify(nominal, sim->set, identification);
    if (!rep.ok()) {
      ++mc.refused;
      continue;
    }
    if (!rep->converged) continue;
    ++mc.ok;
    mc.sum_chi2_dof += rep->chi2 / std::max(1, rep->dof);
    const BoxError be = box_error(rep->estimate);
    mc.sum_box += be.rms;
    mc.sum_box2 += be.rms * be.rms;
    mc.box_max = std::max(mc.box_max, be.max);
    mc.anchors.add(*rep);
  }
  return mc;
}

}  // namespace cdpr::bench
