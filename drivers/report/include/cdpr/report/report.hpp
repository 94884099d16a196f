// The calibration report: what an identification (and optionally a diagnosis of the same
// recording) found, rendered as a JSON document for scripts, text for a terminal and one
// self-contained HTML page with inline SVG plots (no script, no external file, no network).
// `cdpr-fit calibrate` and `cdpr-fit diagnose` print and write these documents; the daemon writes
// the same report for a calibration run.
//
//   report::CalibrationReportInput in;
//   in.before = &nominal;                    // the model identified from
//   in.after = &identification.estimate;     // the calibrated model
//   in.identification = &identification;     // identify()'s report
//   in.set = &set;                           // the MeasurementSet it was identified from
//   in.diagnosis = &diagnosis;               // optional: diagnose() on the same recording
//   in.context.title = "cdprd calibrate";
//   in.context.config = "mini.yaml";  in.context.config_hash = "fnv1a64:...";  // names, hashes
//   const report::Rendered r = report::render_calibration_report(in);
//   // r.json, r.text, r.html (write them with cdpr/io/atomic_file.hpp)
//
// The JSON of the identification is cdpr-fit calibrate's document, the JSON of a diagnosis is
// cdpr-fit diagnose's (docs/cdpr-fit.md describes both); the combined report is the
// identification's document with the diagnosis's under "diagnosis". The HTML page is laid out for
// the decision to accept the calibration (docs/cdpr-fit.md, "HTML report"): on the first screen
// the verdict and the next step, the named effects (value +- std, share of the misfit), the
// largest anchor change with its uncertainty, the position accuracy over the ISO 9283 box
// before/after (with context.identification) and chi^2/dof with its p-value; then residual heat
// maps per cable and pose, the residuals against the variable each named effect follows, the
// anchor changes on a top and a side view with uncertainty ellipses and the measured poses; then
// the tables, with what does not bear on the verdict folded. No physics is computed here: the
// explaining variables and the accuracy figures come from calibration/ (residual_explanation.hpp,
// predicted_accuracy.hpp).
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/paper_method.hpp"
#include "cdpr/calibration/robot_model.hpp"

namespace cdpr::report {

// What the reports say about the run besides the results: names, hashes, options.
struct ReportContext {
  std::string title;  // first words of the text, e.g. "cdpr-fit calibrate"
  std::string config, config_hash;
  std::string recording, recording_hash;
  std::string validation, validation_hash;  // second recording of a diagnosis; empty: none
  std::vector<int> pose_indices;            // the recording's pose number per row; empty: the row
  // The identification's options as the user gave them.
  std::string method = "ours";
  std::vector<std::string> estimated;  // the estimated items ("anchors", "offsets", ...)
  std::string gauge = "home", loss = "none";
  int home_pose_row = 0, max_iterations = 100;
  // The diagnosis's options.
  unsigned seed = 1;
  int bootstrap = 0, folds = 0;
  std::string calibrated_config;  // the config written from this run, "" when none
  std::string truth;              // the true robot's config (simulation studies), "" when none
  std::vector<std::string> warnings;
  // The parameters the identification estimated: with them the HTML page shows the predicted
  // position accuracy over the ISO 9283 box (AccuracyBox's cube about the nominal home pose):
  // before = the nominal model's error if the calibrated model is right
  // (measure_position_accuracy), after = the Cramer-Rao bound of the recorded pose set
  // (predict_accuracy, as the daemon's gate). Unset: not computed.
  std::optional<IdentificationOptions> identification;
};

struct CalibrationReportInput {
  // Required.
  const CalibratedModel* before = nullptr;               // the model identified from
  const CalibratedModel* after = nullptr;                // the calibrated model
  const IdentificationReport* identification = nullptr;  // identify()'s report
  const MeasurementSet* set = nullptr;                   // what it was identified from
  // Optional.
  const IdentifiabilityReport* identifiability = nullptr;
  std::string identifiability_error;  // why there is no identifiability report
  const Diagnosis* diagnosis = nullptr;
  const RobotModel* truth = nullptr;  // anchor errors against it (context.truth names it)
  ReportContext context;
};

struct Rendered {
  nlohmann::json json;
  std::string text;
  std::string html;
};

// The identification, and the diagnosis when given, in the three renderings.
Rendered render_calibration_report(const CalibrationReportInput& in);

// The renderings of the identification alone (cdpr-fit calibrate's documents).
nlohmann::json identification_json(const CalibrationReportInput& in);
std::string identification_text(const CalibrationReportInput& in);

// The paper's method (cdpr-fit calibrate --method paper): frame anchors only, no standard
// deviations; JSON and text.
struct PaperReportInput {
  const CalibratedModel* before = nullptr;   // required: the model identified from
  const PaperMethodReport* paper = nullptr;  // required
  const MeasurementSet* set = nullptr;       // required
  const RobotModel* truth = nullptr;         // optional
  std::string estimate = "paper-anchors";    // or "anchors"
  double lambda = 0.0;                       // the damping used
  ReportContext context;
};
nlohmann::json paper_method_json(const PaperReportInput& in);
std::string paper_method_text(const PaperReportInput& in);

// The renderings of a diagnosis (cdpr-fit diagnose's documents). `nominal` is the model diagnosed
// against, `set` the recording.
nlohmann::json diagnosis_json(const Diagnosis& d, const RobotModel& nominal,
                              const MeasurementSet& set, const ReportContext& c);
std::string diagnosis_text(const Diagnosis& d, const RobotModel& nominal, const MeasurementSet& set,
                           const ReportContext& c);
std::string diagnosis_html(const Diagnosis& d, const RobotModel& nominal, const MeasurementSet& set,
                           const ReportContext& c);

// "no_mismatch", "mismatch_named", "mismatch_unexplained", "inconclusive".
std::string verdict_key(Diagnosis::Verdict v);

}  // namespace cdpr::report
