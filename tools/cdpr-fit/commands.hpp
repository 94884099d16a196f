// cdpr-fit's subcommands as functions (the library cdpr_fit_app; main() only calls run()).
//
// Each command takes its arguments as a struct, does its work and returns an Output: the JSON
// document (printed with --json) and the human text (printed otherwise), or a Status naming what
// was wrong with the input. Files named in the arguments are read and written by the command.
#pragma once

#include <cstdint>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/model_validation.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"
#include "recording_options.hpp"

namespace cdpr::fit {

struct Output {
  nlohmann::json json;
  std::string human;
  // The process exit status when the command succeeded: 0, or a finding the command reports
  // through it (diagnose: 3 mismatch found, 4 inconclusive; calibrate: 3 fit test failed, 4 not
  // trustworthy). 1 and 2 are kept for errors.
  int exit_status = 0;
  // Printed on stderr whatever the output format (e.g. calibrate's "did not pass" line, so that
  // --json on stdout never hides it). Empty: nothing.
  std::string notice;
};

// ---------------------------------------------------------------------------------------------
// simulate
// ---------------------------------------------------------------------------------------------
struct SimulateArgs {
  std::string config;   // the TRUE robot (YAML)
  std::string nominal;  // optional: the controller's model (force conversion, elastic physics)
  std::string poses;    // pose list CSV, or
  int design = 0;       // > 0: design this many poses (design_poses on the nominal, else truth)
  std::string out;      // recording CSV to write
  SensorNoise noise;
  std::uint64_t seed = 1;
  bool add_noise = true;
  bool elastic = false;              // SimulationOptions::Physics::kElastic (needs nominal)
  std::vector<int> reference_poses;  // poses that also get a reference pose reading
  double reference_tension = std::numeric_limits<double>::quiet_NaN();  // N; NaN = default
  // The channels the robot has (issue 18): any of laser, swivel, inclinometer, imu-yaw.
  std::vector<std::string> channels = {"laser"};
};
Result<Output> simulate(const SimulateArgs& args);

// ---------------------------------------------------------------------------------------------
// calibrate
// ---------------------------------------------------------------------------------------------
struct CalibrateArgs {
  std::string config;     // nominal robot (YAML), the starting point
  std::string recording;  // recording CSV
  std::string method = "ours";
  std::vector<std::string> estimate;  // empty = the defaults of IdentificationOptions
  std::string gauge = "home";         // home | laser-plane | both | none
  std::string loss = "none";          // none | huber | cauchy
  int home_pose = 0;
  int max_iterations = 100;
  std::string out;          // calibrated config YAML to write (optional)
  std::string report;       // JSON report to write (optional)
  std::string truth;        // optional true robot (simulation studies): anchor errors in the report
  double fit_alpha = 0.01;  // significance level of the chi^2 fit test (calibration_verdict.hpp)
  NoiseOverrides noise;     // sensor sigmas replacing the recording's
  // A held-out recording of the same robot (made with `config`): the calibrated model must
  // predict it better than `config` (model_validation.hpp), else exit status 5.
  std::string validate;
};
// Exit status of calibrate when the calibrated model does not beat the nominal one on the
// held-out recording of --validate.
inline constexpr int kExitWorseThanNominal = 5;
// Exit status: 0 the calibration passed; 3 the fit test failed (the residuals are larger than the
// noise explains: a missing effect); 4 not trustworthy (not converged, a parameter on the bound of
// its physical range, or an identification warning). --out and --report are written for 0, 3 and
// 4; for 3 and 4 a notice on stderr says so.
Result<Output> calibrate(const CalibrateArgs& args);

// The names --estimate accepts, in the order of the help text.
const std::vector<std::string>& estimate_names();

// The calibrated config is IdentificationReport::estimate.robot (or the paper method's): the
// identified reading model unstretched = (1 + s_i) reading + o_i is already folded into each
// winch there (length_offset' = (1 + s_i) length_offset + o_i, drum diameter and pitch scaled by
// 1 + s_i), so it must not be folded a second time.

// ---------------------------------------------------------------------------------------------
// design-poses, predict-accuracy
// ---------------------------------------------------------------------------------------------
struct DesignArgs {
  std::string config;
  int count = 25;
  std::string out;                    // pose list CSV to write
  std::vector<std::string> estimate;  // parameters the design is for (as calibrate --estimate)
  // m, half side of the cube of candidate positions around home; NaN: scaled to the frame
  // (fit_design_box_to_robot, 0.4 x the anchors' half extent per axis)
  double half_extent = std::numeric_limits<double>::quiet_NaN();
  std::string criterion = "d-optimal";  // or "position": position accuracy over the test cube
  double test_half_extent = 0.156;      // m, test cube (ISO 9283 style) for position/--compare
  int points_per_axis = 5;
  double max_angle = PoseDesignOptions{}.max_angle;   // rad
  int angle_steps = PoseDesignOptions{}.angle_steps;  // tilts max_angle x j / angle_steps
  // Weight of the laser's beam direction in the design (PoseDesignOptions::emphasis_weight);
  // 0: plain D-optimal on the estimated parameters.
  double emphasis_weight = PoseDesignOptions{}.emphasis_weight;
  // N: every designed pose needs a tension distribution within [f_min + margin, f_max - margin]
  // (PoseDesignOptions::tension_margin; cdprd passes its measuring.design_tension_margin)
  double tension_margin = 0.0;
  SensorNoise noise;
  // The channels the calibration will record besides lengths and tensions (issue 18): laser,
  // swivel, inclinometer, imu-yaw, or {"none"}. Empty: the laser when the config has one.
  std::vector<std::string> channels;
  bool compare = false;  // also compare with random and box-corner sets of the same size
  std::uint64_t seed = 1;
};
Result<Output> design_poses(const DesignArgs& args);

struct PredictArgs {
  std::string config;
  std::string poses;
  std::vector<std::string> estimate;
  SensorNoise noise;
  std::vector<std::string> channels;  // as DesignArgs::channels
  double half_extent = 0.156;         // m, test cube (ISO 9283 style) for the position error
  int points_per_axis = 5;
};
Result<Output> predict_accuracy(const PredictArgs& args);

// ---------------------------------------------------------------------------------------------
// fit-cable, fit-force-sensor
// ---------------------------------------------------------------------------------------------
struct FitCableArgs {
  std::string experiment;
  int min_order = 1;
  int max_order = 5;
  int folds = 5;
  std::uint32_t seed = 1;
  bool minimum_error = false;  // choose the minimum-CV order instead of the one-standard-error rule
};
Result<Output> fit_cable(const FitCableArgs& args);

struct FitForceArgs {
  std::string experiment;
  double gravity = std::numeric_limits<double>::quiet_NaN();  // NaN: metadata or 9.81
};
Result<Output> fit_force_sensor(const FitForceArgs& args);

// ---------------------------------------------------------------------------------------------
// diagnose (the mismatch locator, calibration/mismatch/include/cdpr/calibration/diagnosis.hpp)
// ---------------------------------------------------------------------------------------------
struct DiagnoseArgs {
  std::string config;       // nominal robot (YAML)
  std::string recording;    // recording CSV
  std::string validate;     // optional second recording for held-out prediction
  std::string json_report;  // JSON report file to write (optional)
  std::string html;         // HTML report file to write (optional)
  std::string out;          // calibrated config YAML carrying the named effects (optional)
  std::vector<std::string> estimate;  // as calibrate --estimate; empty = defaults
  NoiseOverrides noise;               // sensor sigmas replacing the recording's noise_* metadata
  std::string gauge = "home";         // as calibrate --gauge
  int home_pose = 0;
  unsigned seed = 1;
  int bootstrap = 100;
  int folds = 0;  // 0: leave one pose out
};
// ---------------------------------------------------------------------------------------------
// validate (model_validation.hpp): models predicting a held-out recording
// ---------------------------------------------------------------------------------------------
struct ValidateArgs {
  std::string config;               // the config the recording was made with (its readings)
  std::string recording;            // the held-out recording
  std::vector<std::string> models;  // configs to compare (nominal, calibrated, diagnosed)
  NoiseOverrides noise;
};
Result<Output> validate_models(const ValidateArgs& args);

// The held-out predictions of `models` on a recording whose readings were made with `made_with`
// (validate and calibrate --validate).
struct HeldOut {
  std::vector<std::string> models;
  std::vector<ModelPrediction> predictions;
};
using NamedModel = std::pair<std::string, RobotModel>;
// Reads and checks a held-out recording as calibrate reads its recording.
Result<MeasurementSet> load_held_out(const RobotModel& made_with, const std::string& config,
                                     const std::string& file, const NoiseOverrides& noise,
                                     std::vector<std::string>* warnings);
Result<HeldOut> held_out_predictions(const RobotModel& made_with, const MeasurementSet& set,
                                     const std::vector<NamedModel>& models);
std::string held_out_table(const HeldOut& h);  // RMS per channel in mm, mrad, N
nlohmann::json held_out_json(const std::string& recording_file, const HeldOut& h);  // SI

// Exit statuses of diagnose (Output::exit_status).
inline constexpr int kExitNoMismatch = 0;
inline constexpr int kExitMismatch = 3;
inline constexpr int kExitInconclusive = 4;
Result<Output> diagnose(const DiagnoseArgs& args);

}  // namespace cdpr::fit
