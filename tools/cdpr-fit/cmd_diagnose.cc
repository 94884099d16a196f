// cdpr-fit diagnose: the mismatch locator's front end (diagnosis.hpp). Loads the config and the
// recording(s) as calibrate does, refuses recordings that do not fit the config (counts, units and
// ranges: recording::check_plausible),
// runs cdpr::diagnose and writes the JSON and HTML reports and the calibrated config.
#include <cmath>
#include <sstream>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/report/report.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "recording_options.hpp"

namespace cdpr::fit {

namespace {

struct Loaded {
  recording::Recording recording;
  MeasurementSet set;
};

// Reads a recording and makes the identification's view of it, refusing what does not fit.
Result<Loaded> load_recording(const std::string& file, const DiagnoseArgs& args,
                              const RobotModel& nominal, std::vector<std::string>* warnings) {
  auto rec = recording::read_recording(file);
  if (!rec.ok()) return rec.status();  // names the file, line and column
  if (Status s = recording::check_against_model(*rec, nominal); !s.ok()) {
    return with_context(s, file + " vs " + args.config);
  }
  // Units (a file in mm under "# units: SI") and ranges, naming the line and column.
  CDPR_RETURN_IF_ERROR(recording::check_plausible(*rec, nominal, file));
  const std::string recorded_robot = rec->metadata.get(recording::key::kRobot);
  if (!recorded_robot.empty() && recorded_robot != nominal.name) {
    warnings->push_back(file + " is a recording of robot '" + recorded_robot + "' but " +
                        args.config + " is '" + nominal.name + "'");
  }
  auto set = recording::to_measurement_set(*rec);
  if (!set.ok()) return with_context(set.status(), file);
  apply_noise_overrides(args.noise, *rec, file, &*set, warnings);
  if (Status s = validate(*set, nominal); !s.ok()) return with_context(s, file);
  return Loaded{std::move(*rec), std::move(*set)};
}

int exit_status_of(Diagnosis::Verdict v) {
  switch (v) {
    case Diagnosis::Verdict::kNoMismatch:
      return kExitNoMismatch;
    case Diagnosis::Verdict::kMismatchNamed:
    case Diagnosis::Verdict::kMismatchUnexplained:
      return kExitMismatch;
    case Diagnosis::Verdict::kInconclusive:
      return kExitInconclusive;
  }
  return kExitMismatch;
}

}  // namespace

Result<Output> diagnose(const DiagnoseArgs& args) {
  if (args.bootstrap < 1) {
    return Status::error(ErrorCode::kInvalidArgument, "--bootstrap %d: must be at least 1",
                         args.bootstrap);
  }
  if (args.folds < 2 && args.folds != 0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "--folds %d: must be at least 2, or 0 (leave one pose out)", args.folds);
  }
  auto nominal = load_config(args.config);
  if (!nominal.ok()) return nominal.status();
  std::vector<std::string> warnings;
  auto primary = load_recording(args.recording, args, *nominal, &warnings);
  if (!primary.ok()) return primary.status();
  std::optional<Loaded> validation;
  if (!args.validate.empty()) {
    auto v = load_recording(args.validate, args, *nominal, &warnings);
    if (!v.ok()) return v.status();
    validation = std::move(*v);
  }

  IdentificationOptions identification;
  CDPR_RETURN_IF_ERROR(apply_estimate(args.estimate, nominal->num_cables(), &identification));
  adapt_to_channels(primary->set, args.estimate, &identification);
  CDPR_RETURN_IF_ERROR(apply_gauge(args.gauge, args.home_pose, primary->set, *nominal,
                                   args.recording, &identification));
  DiagnosisOptions options;
  options.seed = args.seed;
  options.bootstrap_samples = args.bootstrap;
  options.cv_folds = args.folds;
  options.progress = console().progress;

  const CalibratedModel initial = CalibratedModel::from_robot(*nominal);
  auto result = cdpr::diagnose(initial, primary->set, validation ? &validation->set : nullptr,
                               identification, options);
  if (!result.ok()) {
    return with_context(result.status(), "diagnosing " + args.recording);
  }
  const Diagnosis& d = *result;

  report::ReportContext c;
  c.title = "cdpr-fit diagnose";
  c.config = args.config;
  c.config_hash = hash_or_unknown(args.config);
  c.recording = args.recording;
  c.recording_hash = hash_or_unknown(args.recording);
  if (!args.validate.empty()) {
    c.validation = args.validate;
    c.validation_hash = hash_or_unknown(args.validate);
  }
  c.estimated = estimated_items(identification);
  c.identification = identification;  // the HTML page's position accuracy
  c.seed = args.seed;
  c.bootstrap = args.bootstrap;
  c.folds = args.folds;
  // Without the standard identification (too few poses) there is nothing calibrated to write;
  // with a gross reading the identification is dragged by it: nothing to write either.
  const bool calibrated = !d.before.residuals.empty() && d.gross_readings.empty();
  if (!args.out.empty() && !calibrated) {
    warnings.push_back("--out " + args.out + " not written: " +
                       (d.gross_readings.empty()
                            ? std::string("no identification was run on this recording")
                            : std::string("the recording holds a gross reading (above)")));
  }
  c.calibrated_config = calibrated ? args.out : std::string();
  c.warnings = warnings;
  for (const std::string& w : d.before.warnings) c.warnings.push_back("identification: " + w);

  Output out;
  out.exit_status = exit_status_of(d.verdict);
  out.json = report::diagnosis_json(d, *nominal, primary->set, c);
  out.json["exit_status"] = out.exit_status;
  out.json["json_report"] =
      args.json_report.empty() ? nlohmann::json(nullptr) : nlohmann::json(args.json_report);
  out.json["html_report"] = args.html.empty() ? nlohmann::json(nullptr) : nlohmann::json(args.html);

  // The calibrated config and the reports are written together, or none of them.
  io::AtomicFileSet outputs;
  if (!c.calibrated_config.empty()) {
    std::string effects;
    for (const EffectFit& e : d.accepted) {
      effects +=
          (effects.empty() ? "" : ", ") + e.id + (e.modelled_in_config ? "" : " (not carried)");
    }
    const std::string yaml =
        "# Calibrated by cdpr-fit diagnose from " + args.config + " and " + args.recording + " (" +
        recording::utc_timestamp() + "); verdict " + report::verdict_key(d.verdict) + ".\n" +
        "# Named effects: " + (effects.empty() ? std::string("none") : effects) + ".\n" +
        "# Winch length_offset and drum size include the identified encoder offsets and scales.\n" +
        config::save_robot_config(d.model_after.robot);
    CDPR_RETURN_IF_ERROR(outputs.stage(args.out, yaml));
  }
  if (!args.html.empty()) {
    CDPR_RETURN_IF_ERROR(
        outputs.stage(args.html, report::diagnosis_html(d, *nominal, primary->set, c)));
  }
  if (!args.json_report.empty()) {
    nlohmann::json file = out.json;
    file["ok"] = true;
    CDPR_RETURN_IF_ERROR(outputs.stage(args.json_report, report::json_text(file) + "\n"));
  }
  CDPR_RETURN_IF_ERROR(outputs.commit());

  std::ostringstream h;
  h << report::diagnosis_text(d, *nominal, primary->set, c) << "\n";
  if (!c.calibrated_config.empty()) h << "wrote " << args.out << "\n";
  if (!args.json_report.empty()) h << "wrote " << args.json_report << "\n";
  if (!args.html.empty()) h << "wrote " << args.html << "\n";
  h << "exit status " << out.exit_status << " (" << report::verdict_key(d.verdict) << ")\n";
  out.human = h.str();
  return out;
}

}  // namespace cdpr::fit
