// What cdprd makes of one calibration: the proposed model, the acceptance gates and the report
// a person reads before accepting (JSON for scripts, one self-contained HTML page with plots: the
// decision on top of the calibration report that cdpr-fit also writes, cdpr/report/report.hpp).
//
// Gates (DaemonConfig::acceptance): the chi-square p-value of the final fit (its degrees of
// freedom accounted for), the largest frame-anchor change against the active model, the
// predicted RMS position error over the ISO 9283 box (Cramer-Rao bound of the recorded pose
// set), and no unresolved mismatch (the mismatch locator's verdict is "no mismatch" or
// "mismatch named").
//
// The section "ISO 9283 (position and path)" (calibration_report_iso9283.cc) gives an AP-like
// figure PREDICTED at ISO 9283's five points about home, nominal vs calibrated
// (predict_iso9283_position), the command that MEASURES AP, RP, AT and RT on the virtual robot
// (iso9283_bench: the daemon cannot see the true pose of a real robot) with the paper's figures
// beside, and the measured table when the daemon config names the bench's file
// (report.iso9283_measured).
#pragma once

#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/controller/daemon_config.hpp"
#include "cdpr/report/iso9283.hpp"

namespace cdpr::controller {

struct Gate {
  std::string name;  // "fit", "anchor_change", "predicted_accuracy", "mismatch"
  bool passed = false;
  double value = 0.0;  // the figure judged (p-value, m, m, 0/1)
  double limit = 0.0;
  std::string text;  // "chi2 171.2 on 166 dof, p = 0.37 >= 0.001"
};

struct CalibrationOutcome {
  RobotModel before;                               // the active model the sequence measured with
  RobotModel model;                                // the proposed model (named effects carried)
  const IdentificationReport* fit = nullptr;       // the final fit (with the named effects)
  const IdentificationReport* standard = nullptr;  // the standard identification
  const Diagnosis* diagnosis = nullptr;            // nullptr when the locator did not run
  std::string verdict;                             // one sentence
  std::string verdict_key;  // no_mismatch, mismatch_named, mismatch_unexplained, ...
  std::vector<std::string> named_effects;
  std::vector<Gate> gates;
  bool gates_passed = false;
  std::string failed_gates;  // "fit, mismatch"
  double predicted_position_rms_m = 0.0;
  // What the in-service monitor takes from this calibration once accepted (monitoring_figures;
  // docs/monitoring.md "In the daemon"); NaN where the calibration gives none.
  double model_length_m = std::numeric_limits<double>::quiet_NaN();
  double model_force_n = std::numeric_limits<double>::quiet_NaN();
  // AP-like figure predicted at ISO 9283's points of the box about home; when it could not be
  // computed, why (iso9283_predicted.points == 0).
  PredictedIsoPosition iso9283_predicted;
  std::string iso9283_predicted_problem;
  int poses = 0;
};

// A pose measured again because the mismatch locator found a gross reading in it: its first row
// stays in the recording and is left out of the identification.
struct RemeasuredPose {
  int row = 0;          // 0-based row of the recording left out
  int again = 0;        // 0-based row that measured the pose again
  std::string reading;  // the gross reading(s), in words (describe(GrossReading))
};

struct CalibrationReportContext {
  int calibration = 0;
  std::string daemon;
  int geometry_version = 0;
  std::string recording, robot_config, canopen_config, laser_config, daemon_config;
  std::string started;
  double measuring_s = 0.0;
  std::vector<RemeasuredPose> remeasured;
  // ISO 9283 figures measured on the virtual robot (load_iso9283_measured): the file ("": none
  // configured), its figures, or why they could not be read.
  std::string iso9283_file;
  std::optional<report::Iso9283Measured> iso9283_measured;
  std::string iso9283_problem;
};

// The command that measures the figures on the virtual robot and writes the file.
inline constexpr const char* kIso9283Command = "build/ci/bench/iso9283_bench --out iso9283.json";

// Reads `path` into c.iso9283_*; never fails: a missing, unreadable or malformed file becomes
// c.iso9283_problem (naming the file and the field) and the report says so.
void load_iso9283_measured(const std::string& path, CalibrationReportContext& c);

// The section "ISO 9283 (position and path)": HTML (in calibration_html), text (appended to
// report.txt) and JSON ("iso9283" in calibration_json).
std::string iso9283_html(const CalibrationOutcome& o, const CalibrationReportContext& c);
std::string iso9283_text(const CalibrationOutcome& o, const CalibrationReportContext& c);
nlohmann::json iso9283_json(const CalibrationOutcome& o, const CalibrationReportContext& c);

// cdprd's pose design for `model` when no pose list is given: measuring.poses, max_angle,
// design_angle_steps and design_emphasis_weight, candidates kept max(design_tension_margin,
// motion.tension_margin) inside [f_min, f_max], the candidate box fitted to the robot
// (fit_design_box_to_robot).
PoseDesignOptions measuring_design_options(const DaemonConfig& c, const RobotModel& model);

// One round of extra poses that the mismatch locator asks for: the separating poses of each
// confounded pair, then a suspect's follow-up poses, and how the next diagnosis runs. After a
// suspect's follow-up poses beside named effects it is confirmatory: it screens only
// confirm_groups (follow_up_groups) and names a suspect held back for weak evidence only with
// strong evidence (DiagnosisOptions::confirm_suspect). No poses: the sequence is done.
struct ExtraPoseRound {
  std::vector<Pose> poses;
  std::vector<double> pretensions;          // N, planned pretension at each pose
  std::vector<std::string> confirm_groups;  // MismatchOptions::only_groups of the next diagnosis
  std::string confirm_suspect;              // DiagnosisOptions::confirm_suspect of the next one
};
ExtraPoseRound extra_pose_round(const Diagnosis& d);

// The gates and the proposed model. `diagnosis` may be nullptr. The referenced reports must
// outlive the outcome.
CalibrationOutcome evaluate_calibration(const RobotModel& before, const MeasurementSet& set,
                                        const IdentificationReport& standard,
                                        const Diagnosis* diagnosis, const AcceptanceGates& gates,
                                        const IdentificationOptions& options);

nlohmann::json calibration_json(const CalibrationOutcome& o, const CalibrationReportContext& c);
// The figures the in-service monitor needs of this calibration, kept in the accepted geometry's
// metadata ("monitoring" in geometry/NNNNNN.json and in report.json; null where not given):
//  - predicted_position_rms_m: the predicted RMS position error over the ISO 9283 box (the
//    predicted_accuracy gate), the "at acceptance" figure;
//  - model_length_m: the model's length uncertainty, RMS of the final fit's standard deviations
//    of the frame-anchor coordinates and encoder zeros it estimated (the monitor's prior on
//    exactly those parameters);
//  - model_force_n: the model's force uncertainty, the final fit's RMS equilibrium residual per
//    force axis at the measured poses.
nlohmann::json monitoring_figures(const CalibrationOutcome& o);
// The page a person reads before accepting: the verdict, the gates and the next step, inserted at
// the top of `report_page` (the calibration report of cdpr/report/report.hpp).
std::string calibration_html(const CalibrationOutcome& o, const CalibrationReportContext& c,
                             const std::string& report_page);

}  // namespace cdpr::controller
