// In-service monitoring (docs/monitoring.md): while the robot works, are its readings still
// consistent with the model the last calibration gave, and if not, which change do they look like?
//
// Per sample (MonitorSample: a pose and what the sensors read there, fixed-size arrays the RT
// cycle can fill), Monitor::add forms the consistency residuals of the calibrated model
//   length i:     l_i - (L_k,i(pose) - dL_i(F_i))   encoder length vs the model at the measured
//                                                    tension (ik_compensation.hpp)
//   equilibrium:  A(pose) F + w_gravity              the measured tensions balance the weight
//   laser k:      d_k - distance_k(pose)             where a laser reading is present
// with their covariance from the calibration's noise (the force noise enters the length rows
// through the cable compliance and the equilibrium rows through A) plus the model uncertainty.
// The pose error of the platform (the commanded pose is not where an imperfect model puts it) is a
// nuisance: projected out per sample by generalised least squares, so each residual keeps only
// what no pose can explain. Each projected residual, divided by its standard deviation, feeds a
// two-sided CUSUM (change_detector.hpp) whose threshold follows from the stated false-alarm rate.
// The same projected information accumulates the normal equations of every candidate change
// (MonitorEffect, one table in monitoring_effects.cc) over the window since the calibration, and
// per block of samples for the change-point fits.
// Monitor::add allocates nothing, locks nothing, throws nothing (monitoring_test.cc counts).
//
// Monitor::assess (the supervisor, allocates): which candidate explains the accumulated residuals
// best (least squares on its signature columns over the window or from a block boundary on, BIC;
// a gate at a family-wise 1e-3), its size, the predicted position error over the ISO 9283 box now
// vs at acceptance (the change propagated
// through the same sensitivity as predicted_accuracy.hpp: dx = -pinv(dL/dx) dL), and a proposal:
// the parameters to re-identify, the poses that tell them apart and a stopping rule, or the full
// sequence when that is cheaper.
#pragma once

#include <Eigen/Core>
#include <array>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/change_detector.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

inline constexpr int kMonitorMaxCables = 12;
inline constexpr int kMonitorMaxLasers = 2;
inline constexpr int kMonitorMaxRows = kMonitorMaxCables + 6 + kMonitorMaxLasers;
inline constexpr int kMonitorMaxColumns = 5 * kMonitorMaxCables + 2;

// What the RT cycle samples at a hold or during a (slow, quasi-static) move. Plain data.
struct MonitorSample {
  static constexpr double kMissing = std::numeric_limits<double>::quiet_NaN();
  double time_s = kMissing;  // s since the calibration was accepted
  Pose pose;                 // the commanded pose (or a pose solved from the readings)
  // m: the encoder counts through the calibrated winch and reading model (unstretched,
  // D-referenced)
  std::array<double, kMonitorMaxCables> lengths{};
  // N: the force sensors through the calibrated sensor model
  std::array<double, kMonitorMaxCables> tensions{};
  // m; kMissing: no reading this sample
  std::array<double, kMonitorMaxLasers> lasers = missing_lasers();

  static constexpr std::array<double, kMonitorMaxLasers> missing_lasers() {
    std::array<double, kMonitorMaxLasers> a{};
    for (double& x : a) x = kMissing;
    return a;
  }
};

// The noise and model uncertainty the last calibration reported, one standard deviation.
struct MonitorNoise {
  double sigma_length = 1.0e-5;  // m, an encoder length reading
  double sigma_force = 1.0;      // N, a tension reading
  double sigma_laser = 1.0e-3;   // m
  double model_length = 0.0;     // m, uncertainty of a model length (e.g. the anchors' CRB)
  double model_force = 0.0;      // N, uncertainty of the equilibrium (e.g. of the weight)
};
// From the calibration's sensor noise and its predicted accuracy (anchor_rms_std_m as the length
// uncertainty; `accuracy` may be null).
MonitorNoise monitor_noise(const SensorNoise& noise, const PredictedAccuracy* accuracy);

struct MonitorOptions {
  MonitorNoise noise;
  double false_alarms_per_hour = 0.1;  // stated rate of the detectors together
  double samples_per_hour = 3600.0;    // the rate add() is fed at
  double allowance = 0.5;              // CUSUM k, sigmas (tuned for a shift of 2k)
  // Attribution: the window's weight of a sample decays as exp(-age / window_s); infinity: every
  // sample since the calibration weighs alike.
  double window_s = std::numeric_limits<double>::infinity();
  // Change points: the window's normal equations are also kept per block of block_samples
  // samples, for the last history_blocks blocks; a candidate is also fitted as "zero before a
  // block boundary, constant after" (a change that started in the window), each boundary tried.
  int block_samples = 60;
  int history_blocks = 60;
  // Acceptance: the predicted RMS position error over `box` the calibration was accepted with.
  double acceptance_position_rms_m = 0.0;
  AccuracyBox box;
  double reference_tension = std::numeric_limits<double>::quiet_NaN();  // N; NaN: model default
  // Proposal: poses are added until the re-identified change's predicted position error (RMS over
  // the box) is below reidentify_position_m (force offsets: their std below reidentify_force_n),
  // each pose held for samples_per_pose readings; when that takes more than full_sequence_poses,
  // the full sequence is proposed.
  double reidentify_position_m = 2.0e-5;
  double reidentify_force_n = 0.5;
  int samples_per_pose = 10;
  int full_sequence_poses = 25;
  double gate_alpha = 1.0e-3;  // family-wise false attribution probability
};

// The candidate changes, in the mismatch locator's vocabulary (docs/mismatch-locator.md).
enum class MonitorEffect {
  kFrameAnchor,    // pulley moved: frame anchor a_i (3 columns: dx, dy, dz, m)
  kForceOffset,    // force sensor drift on cable i (offset, N)
  kEncoderSlip,    // encoder slip on cable i (length, m)
  kThermalGrowth,  // cable length growth ~ (routing + l) (thermal; relative)
  kCreepGrowth,    // cable length growth ~ F (routing + L) (creep; 1/N)
};

struct EffectEstimate {
  MonitorEffect effect = MonitorEffect::kFrameAnchor;
  int cable = -1;          // 0-based; -1: every cable
  std::string id;          // locator id, e.g. "frame_anchor", "force_offset_per_cable"
  std::string words;       // for people, e.g. "pulley moved (frame anchor 3)"
  Eigen::VectorXd value;   // SI (see MonitorEffect)
  Eigen::VectorXd std;     // SI, of the window's least squares
  double chi2_drop = 0.0;  // of the window's residuals
  double bic_drop = 0.0;   // chi2_drop - columns * ln(samples) (- ln(boundaries tried))
  // Time the change is fitted from (a block boundary), s; NaN: constant over the whole window.
  double since_s = std::numeric_limits<double>::quiet_NaN();
  bool significant = false;  // chi2_drop beyond the gate
};

struct ReidentificationProposal {
  bool needed = false;
  bool full_sequence = false;
  std::vector<std::string> parameters;  // to re-identify
  std::vector<Pose> poses;              // that tell them apart, in order
  double predicted_position_m = 0.0;    // after poses.size() poses (force offsets: N)
  std::string stopping_rule;            // for people
};

struct MonitorRow {
  std::string name;        // "length 3", "equilibrium fz", "laser 1"
  double statistic = 0.0;  // CUSUM statistic now (alarm above threshold)
  double threshold = 0.0;
  double mean_sigma = 0.0;  // mean normalised projected residual over the window
  int alarms = 0;
};

struct MonitorAssessment {
  int samples = 0;
  std::vector<MonitorRow> rows;
  std::vector<EffectEstimate> effects;  // every candidate, best (largest BIC drop) first
  bool changed = false;                 // the best candidate is significant
  double position_rms_acceptance_m = 0.0;
  double position_rms_now_m = 0.0;
  ReidentificationProposal proposal;
};

class Monitor {
 public:
  // kInvalidArgument: more cables or lasers than the fixed capacity, options out of range.
  static Result<Monitor> create(const CalibratedModel& model, const MonitorOptions& options);

  // One sample. True when a detector raised an alarm on it. A sample with a missing length or
  // tension, or at a degenerate pose, is skipped (false). Allocates nothing.
  bool add(const MonitorSample& sample);

  // Forgets the window and the detectors (after a new calibration is accepted).
  void reset();

  int samples() const { return samples_; }
  int rows() const { return n_; }
  const Cusum& detector(int row) const { return detectors_[static_cast<std::size_t>(row)]; }
  int alarms() const { return alarms_; }
  double first_alarm_time_s() const { return first_alarm_time_s_; }  // NaN: none yet
  int first_alarm_row() const { return first_alarm_row_; }           // -1: none yet
  const std::string& row_name(int row) const { return names_[static_cast<std::size_t>(row)]; }
  double threshold() const { return threshold_; }

  // Attribution, accuracy and proposal from the window (the supervisor; allocates).
  Result<MonitorAssessment> assess() const;

  using RowVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMonitorMaxRows, 1>;
  using RowMatrix =
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMonitorMaxRows, kMonitorMaxRows>;
  using Signature =
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMonitorMaxRows, kMonitorMaxColumns>;
  using Nuisance = Eigen::Matrix<double, Eigen::Dynamic, 6, 0, kMonitorMaxRows, 6>;
  using Gram = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMonitorMaxColumns,
                             kMonitorMaxColumns>;
  using ColumnVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, kMonitorMaxColumns, 1>;

  // The residuals, their covariance, the nuisance (pose) columns and the candidates' signature
  // columns at one sample (public for the proposal's pose information and the tests).
  struct Linearisation {
    RowVector residual;
    RowMatrix covariance;
    Nuisance nuisance;
    Signature signature;
  };
  // False at a degenerate pose or a missing reading. Allocates nothing (fixed capacities).
  bool linearise(const MonitorSample& sample, Linearisation& out);
  void resize_linearisation(Linearisation& out) const;

  // One block of samples' normal equations (unweighted), for the change-point fits.
  struct Block {
    Eigen::MatrixXd gram;
    Eigen::VectorXd moment;
    int samples = 0;
    double start_s = 0.0;
  };

  const CalibratedModel& model() const { return model_; }
  const MonitorOptions& options() const { return options_; }
  int columns() const { return p_; }

 private:
  Monitor(const CalibratedModel& model, const MonitorOptions& options, double threshold);

  CalibratedModel model_;
  MonitorOptions options_;
  int m_ = 0;
  int lasers_ = 0;
  int n_ = 0;  // rows: m lengths, 6 equilibrium, lasers
  int p_ = 0;  // signature columns
  double threshold_ = 0.0;
  KinematicsData kinematics_;
  Linearisation lin_;
  RowMatrix projected_precision_;  // W = S^-1 - S^-1 B (B' S^-1 B)^-1 B' S^-1
  Signature weighted_signature_;   // W S
  std::vector<Block> blocks_;      // ring, sized at creation
  int block_ = 0;                  // the block being filled
  Gram contribution_;              // this sample's S' W S
  Gram gram_;                      // sum of weights x S' W S
  ColumnVector moment_;            // sum of weights x S' W r
  double chi2_ = 0.0;              // sum of weights x r' W r
  double weight_ = 0.0;            // sum of weights
  RowVector mean_sigma_;           // window sum of weights x normalised projected residual
  std::array<Cusum, kMonitorMaxRows> detectors_{};
  std::array<int, kMonitorMaxRows> row_alarms_{};
  std::vector<std::string> names_;
  double last_time_s_ = std::numeric_limits<double>::quiet_NaN();
  int samples_ = 0;
  int alarms_ = 0;
  double first_alarm_time_s_ = std::numeric_limits<double>::quiet_NaN();
  int first_alarm_row_ = -1;
};

// The assessment for people (lengths and positions in mm, forces in N).
std::string describe(const MonitorAssessment& assessment);

}  // namespace cdpr
