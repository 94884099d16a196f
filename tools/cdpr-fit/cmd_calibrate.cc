// cdpr-fit calibrate: identify the robot from a recording, write the calibrated config and report.
#include <cmath>
#include <sstream>

#include "cdpr/calibration/calibration_verdict.hpp"
#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/paper_method.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/report/report.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "recording_options.hpp"

namespace cdpr::fit {

const std::vector<std::string>& estimate_names() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> v;
    for (const EstimateItem& item : estimate_items()) v.emplace_back(item.word);
    return v;
  }();
  return names;
}

void adapt_to_channels(const MeasurementSet& set, const std::vector<std::string>& names,
                       IdentificationOptions* o) {
  if (!names.empty()) return;
  bool laser = false, swivel = false, incl = false, yaw = false;
  for (const PoseMeasurement& p : set.poses) {
    laser = laser || (p.laser_distances.size() > 0 && !p.laser_distances.array().isNaN().all());
    swivel = swivel || (p.swivel_angles.size() > 0 && !p.swivel_angles.array().isNaN().all());
    incl = incl || !std::isnan(p.inclination(0));
    yaw = yaw || !std::isnan(p.imu_yaw);
  }
  if (!laser) o->estimate_laser_plane = false;
  o->estimate_swivel_zeros = swivel;
  o->estimate_inclinometer_mounting = incl || yaw;
  o->estimate_imu_yaw_zero = yaw;
}

Status apply_estimate(const std::vector<std::string>& names, int num_cables,
                      IdentificationOptions* o) {
  Status s = set_estimate(names, num_cables, *o);
  return s.ok() ? s : s.prepend("--estimate: ");
}

std::vector<std::string> estimated_items(const IdentificationOptions& o) {
  std::vector<std::string> v;
  for (const EstimateItem& item : estimate_items()) {
    if (item.word == "paper-anchors" || !item.is_set(o)) continue;  // listed as masked anchors
    if (item.word == "anchors" && o.frame_anchor_mask.size()) {
      v.push_back("anchors (masked)");
    } else {
      v.emplace_back(item.word);
    }
  }
  return v;
}

namespace {

// Above this many poses calibrate warns before it starts (100,000 poses: minutes, gigabytes).
constexpr int kManyPoses = 20000;

// Writes the calibrated config (with a comment header) and the JSON report together: both or,
// when one cannot be written, neither (io::AtomicFileSet).
Status write_outputs(const CalibrateArgs& args, const RobotModel& calibrated,
                     const nlohmann::json& j, const std::string& verdict_line = "") {
  io::AtomicFileSet outputs;
  if (!args.out.empty()) {
    const std::string yaml = "# Calibrated by cdpr-fit calibrate --method " + args.method +
                             " from " + args.config + " and " + args.recording + " (" +
                             recording::utc_timestamp() + ").\n" + verdict_line +
                             "# Winch length_offset and drum size include the identified encoder "
                             "offsets and scales.\n" +
                             config::save_robot_config(calibrated);
    CDPR_RETURN_IF_ERROR(outputs.stage(args.out, yaml));
  }
  if (!args.report.empty())
    CDPR_RETURN_IF_ERROR(outputs.stage(args.report, report::json_text(j) + "\n"));
  return outputs.commit();
}

Result<std::optional<RobotModel>> load_truth(const CalibrateArgs& args, const RobotModel& nominal) {
  if (args.truth.empty()) return std::optional<RobotModel>();
  auto t = load_config(args.truth);
  if (!t.ok()) return t.status();
  if (t->num_cables() != nominal.num_cables()) {
    return Status::error(ErrorCode::kInvalidArgument, "--truth %s has %d cables, %s has %d",
                         args.truth.c_str(), t->num_cables(), args.config.c_str(),
                         nominal.num_cables());
  }
  return std::optional<RobotModel>(std::move(*t));
}

// The report's context from the command line.
report::ReportContext context_of(const CalibrateArgs& args, const recording::Recording& rec,
                                 const std::vector<std::string>& warnings) {
  report::ReportContext c;
  c.title = "cdpr-fit calibrate";
  c.config = args.config;
  c.config_hash = hash_or_unknown(args.config);
  c.recording = args.recording;
  c.recording_hash = hash_or_unknown(args.recording);
  for (const recording::RecordedPose& p : rec.poses) c.pose_indices.push_back(p.index);
  c.method = args.method;
  c.gauge = args.gauge;
  c.loss = args.loss;
  c.home_pose_row = args.home_pose;
  c.max_iterations = args.max_iterations;
  c.calibrated_config = args.out;
  c.truth = args.truth;
  c.warnings = warnings;
  return c;
}

// "wrote ..." lines after the report's text.
std::string wrote_text(const CalibrateArgs& args) {
  std::string h;
  if (!args.out.empty()) h += "\nwrote " + args.out + "\n";
  if (!args.report.empty()) h += "wrote " + args.report + "\n";
  return h;
}

// The verdict as the exit status says it (docs/cdpr-fit.md): 0 passed, 3 fit test failed,
// 4 not trustworthy.
int exit_status_of(const CalibrationVerdict& v) {
  switch (v.kind) {
    case CalibrationVerdict::Kind::kPassed:
      return 0;
    case CalibrationVerdict::Kind::kFitRejected:
      return 3;
    case CalibrationVerdict::Kind::kNotTrustworthy:
      return 4;
  }
  return 4;
}

std::string diagnose_command(const CalibrateArgs& args) {
  return "cdpr-fit diagnose --config " + args.config + " --recording " + args.recording;
}

// The next step for a calibration that did not pass.
std::string next_step(const CalibrationVerdict& v, const CalibrateArgs& args) {
  if (v.kind == CalibrationVerdict::Kind::kFitRejected) {
    return diagnose_command(args) +
           "  (finds which effect the model misses; its --out writes a model that carries it)";
  }
  if (!v.at_bound.empty()) {
    return diagnose_command(args) +
           "  (a parameter ran to its physical limit: a missing effect or a bad recording; "
           "estimate fewer parameters with --estimate if the data cannot determine it)";
  }
  if (!v.converged) {
    return "check the recording and the starting config; " + diagnose_command(args);
  }
  return "measure more or better-spread poses (cdpr-fit design-poses), or estimate fewer "
         "parameters; " +
         diagnose_command(args);
}

// What the standard deviations of the report mean, in words ("" when the fit passed).
std::string uncertainty_words(double scale, const CalibrationVerdict& v) {
  if (!(scale > 1.0)) return "";
  char buf[480];
  std::snprintf(buf, sizeof(buf),
                "\nuncertainty: the fit failed its chi-square test (chi2/dof %.3g), so the noise "
                "the recording states does not explain the residuals; every standard deviation "
                "above is scaled by sqrt(chi2/dof) = %.3g (the misfit taken as noise). The model "
                "misses something: the estimates may be biased by more than that, and on another "
                "campaign they may move by several of these standard deviations.\n",
                v.dof > 0 ? v.chi2 / v.dof : 0.0, scale);
  return buf;
}

// The verdict's word: the library's, or worse_than_nominal for the held-out gate (exit 5).
std::string verdict_key(const CalibrationVerdict& v, int status) {
  return status == kExitWorseThanNominal ? "worse_than_nominal" : to_string(v.kind);
}

nlohmann::json verdict_json(const CalibrationVerdict& v, const std::string& next, int status) {
  nlohmann::json j;
  j["verdict"] = to_string(v.kind);
  j["passed"] = v.passed();
  j["exit_status"] = status;
  j["chi2"] = v.chi2;
  j["dof"] = v.dof;
  j["p_value"] = v.p_value;
  j["alpha"] = v.alpha;
  j["converged"] = v.converged;
  j["at_bound"] = v.at_bound;
  j["reasons"] = v.reasons;
  j["next_step"] = v.passed() ? nlohmann::json(nullptr) : nlohmann::json(next);
  return j;
}

std::string verdict_text(const CalibrationVerdict& v, const std::string& next, int status) {
  std::ostringstream h;
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "\nfit test: chi-square %.1f for %d degrees of freedom (chi2/dof %.2f), p = %.3g "
                "(the fit is rejected below %.3g)\n",
                v.chi2, v.dof, v.dof > 0 ? v.chi2 / v.dof : 0.0, v.p_value, v.alpha);
  h << buf;
  if (status == 0) {
    h << "verdict: PASSED (exit status 0)\n";
    return h.str();
  }
  h << "verdict: "
    << (status == kExitWorseThanNominal                    ? "WORSE THAN NOMINAL"
        : v.kind == CalibrationVerdict::Kind::kFitRejected ? "FIT REJECTED"
                                                           : "NOT TRUSTWORTHY")
    << " (exit status " << status << "): the calibrated model did not pass\n";
  for (const std::string& r : v.reasons) h << "  - " << r << "\n";
  h << "next step: " << next << "\n";
  return h.str();
}

// The paper's method (paper_method.hpp): anchors only, no covariance.
Result<Output> calibrate_paper(const CalibrateArgs& args, const RobotModel& nominal,
                               const recording::Recording& rec, const MeasurementSet& set,
                               std::vector<std::string> warnings) {
  PaperMethodOptions options;
  options.home_pose_index = args.home_pose;
  options.max_iterations = args.max_iterations;
  for (const std::string& e : args.estimate) {
    if (e == "anchors") {
      options.parameters = AnchorMask::Constant(3, nominal.num_cables(), true);
    } else if (e != "paper-anchors") {
      return Status::error(ErrorCode::kInvalidArgument,
                           "--method paper estimates frame anchors only (--estimate anchors or "
                           "paper-anchors), not '%s'",
                           e.c_str());
    }
  }
  if (options.parameters.size() == 0 && nominal.num_cables() != 8) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "--method paper: the paper's parameter set is for 8 cables; this config "
                         "has %d (use --estimate anchors)",
                         nominal.num_cables());
  }
  if (args.home_pose < 0 || args.home_pose >= set.num_poses()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "--home-pose %d: the recording has rows 0..%d", args.home_pose,
                         set.num_poses() - 1);
  }
  auto truth = load_truth(args, nominal);
  if (!truth.ok()) return truth.status();
  const CalibratedModel initial = CalibratedModel::from_robot(nominal);
  auto result = paper_method(initial, set, options);
  if (!result.ok()) {
    return with_context(result.status(), "calibrating " + args.config + " from " + args.recording);
  }
  const PaperMethodReport& r = *result;
  if (!r.converged) warnings.push_back("the paper's iteration did not converge: " + r.termination);
  // identify() and paper_method() already fold the identified reading model into the winches
  // (IdentificationReport::estimate); folding it again would double the offsets.
  report::PaperReportInput in;
  in.before = &initial;
  in.paper = &r;
  in.set = &set;
  in.truth = truth->has_value() ? &**truth : nullptr;
  in.estimate = options.parameters.size() == 0 ? "paper-anchors" : "anchors";
  in.lambda = options.lambda;
  in.context = context_of(args, rec, warnings);
  nlohmann::json j = report::paper_method_json(in);
  CDPR_RETURN_IF_ERROR(write_outputs(args, r.estimate.robot, j));
  Output out;
  out.json = std::move(j);
  out.human = report::paper_method_text(in) + wrote_text(args);
  if (!r.converged) {
    // No covariance and no chi-square here: only convergence can be judged.
    out.exit_status = 4;
    out.json["exit_status"] = 4;
    out.notice = "cdpr-fit calibrate: the paper's iteration did not converge (exit status 4): " +
                 r.termination + "\n";
  }
  return out;
}

// The held-out gate of --validate: the calibrated model must predict the other recording better
// than the nominal one, both with the poses re-fitted (model_validation.hpp). Without --validate:
// passed, nothing said.
struct HeldOutGate {
  bool better = true;
  std::string why, text;
  nlohmann::json json;
};

Result<HeldOutGate> held_out_gate(const CalibrateArgs& args, const RobotModel& nominal,
                                  const RobotModel& calibrated,
                                  std::vector<std::string>* warnings) {
  HeldOutGate g;
  if (args.validate.empty()) return g;
  auto held = load_held_out(nominal, args.config, args.validate, args.noise, warnings);
  if (!held.ok()) return held.status();
  auto h =
      held_out_predictions(nominal, *held, {{args.config, nominal}, {"calibrated", calibrated}});
  if (!h.ok()) return h.status();
  g.better = beats(h->predictions[1], h->predictions[0], &g.why);
  g.json = held_out_json(args.validate, *h);
  g.json["beats_nominal"] = g.better;
  g.json["why"] = g.why;
  g.text = "\nheld-out prediction of " + args.validate + " (poses re-fitted):\n" +
           held_out_table(*h) + "calibrated model " + (g.better ? "beats" : "DOES NOT BEAT") +
           " the nominal one: " + g.why + "\n";
  return g;
}

}  // namespace

Result<Output> calibrate(const CalibrateArgs& args) {
  if (args.method != "ours" && args.method != "paper") {
    return Status::error(ErrorCode::kInvalidArgument, "--method %s: expected ours or paper",
                         args.method.c_str());
  }
  auto nominal = load_config(args.config);
  if (!nominal.ok()) return nominal.status();
  auto rec = recording::read_recording(args.recording);
  if (!rec.ok()) return rec.status();
  if (Status s = recording::check_against_model(*rec, *nominal); !s.ok()) {
    return with_context(s, args.recording + " vs " + args.config);
  }
  // Units (a file in mm under "# units: SI") and ranges, naming the line and column.
  CDPR_RETURN_IF_ERROR(recording::check_plausible(*rec, *nominal, args.recording));
  std::vector<std::string> warnings;
  const std::string recorded_robot = rec->metadata.get(recording::key::kRobot);
  if (!recorded_robot.empty() && recorded_robot != nominal->name) {
    warnings.push_back("the recording is of robot '" + recorded_robot + "' but " + args.config +
                       " is '" + nominal->name + "'");
  }
  auto set = recording::to_measurement_set(*rec);
  if (!set.ok()) return with_context(set.status(), args.recording);
  apply_noise_overrides(args.noise, *rec, args.recording, &*set, &warnings);
  if (Status s = validate(*set, *nominal); !s.ok()) return with_context(s, args.recording);
  if (args.method == "paper") return calibrate_paper(args, *nominal, *rec, *set, warnings);

  IdentificationOptions options;
  CDPR_RETURN_IF_ERROR(apply_estimate(args.estimate, nominal->num_cables(), &options));
  adapt_to_channels(*set, args.estimate, &options);
  CDPR_RETURN_IF_ERROR(
      apply_gauge(args.gauge, args.home_pose, *set, *nominal, args.recording, &options));
  if (args.loss == "none") {
    options.loss = RobustLoss::kNone;
  } else if (args.loss == "huber") {
    options.loss = RobustLoss::kHuber;
  } else if (args.loss == "cauchy") {
    options.loss = RobustLoss::kCauchy;
  } else {
    return Status::error(ErrorCode::kInvalidArgument, "--loss %s: expected none, huber or cauchy",
                         args.loss.c_str());
  }
  options.max_iterations = args.max_iterations;
  options.progress = console().progress;
  if (set->num_poses() > kManyPoses) {
    console().warn(std::to_string(set->num_poses()) +
                   " poses: the identification and its report take minutes and gigabytes");
  }
  auto truth = load_truth(args, *nominal);
  if (!truth.ok()) return truth.status();

  const CalibratedModel initial = CalibratedModel::from_robot(*nominal);
  // Identifiability of the choice at the commanded poses (named directions for the report).
  auto ident = analyze_identifiability(initial, *set, options);
  auto result = identify(initial, *set, options);
  if (!result.ok()) {
    return with_context(result.status(), "calibrating " + args.config + " from " + args.recording);
  }
  IdentificationReport& r = *result;
  for (const std::string& w : r.warnings) warnings.push_back(w);
  // The verdict: fit test, convergence, physical ranges, the identification's own checks.
  CalibrationVerdictOptions vo;
  vo.alpha = args.fit_alpha;
  CalibrationVerdict verdict = judge_calibration(r, vo);
  // A calibration that did not pass: is it a wild reading (a mistyped cell, a glitch)? Then that
  // is the reason to state first, and the next step is the reading, not a missing effect.
  const std::vector<GrossReading> wild = verdict.passed()
                                             ? std::vector<GrossReading>{}
                                             : find_gross_readings(initial, *set, r, options);
  // Honest uncertainty: a fit that failed its test has its standard deviations scaled by
  // sqrt(chi2/dof) before anything reports them (calibration_verdict.hpp).
  const double uncertainty_scale = scale_uncertainty_for_misfit(verdict, &r);
  // identify() and paper_method() already fold the identified reading model into the winches
  // (IdentificationReport::estimate); folding it again would double the offsets.
  const RobotModel& calibrated = r.estimate.robot;

  report::CalibrationReportInput in;
  in.before = &initial;
  in.after = &r.estimate;
  in.identification = &r;
  in.set = &*set;
  if (ident.ok()) {
    in.identifiability = &*ident;
  } else {
    in.identifiability_error = std::string(ident.status().message());
  }
  in.truth = truth->has_value() ? &**truth : nullptr;
  in.context = context_of(args, *rec, warnings);
  in.context.estimated = estimated_items(options);
  nlohmann::json j = report::identification_json(in);
  const std::string uncertainty_note = uncertainty_words(uncertainty_scale, verdict);
  j["uncertainty"] = {{"scaled_for_misfit", uncertainty_scale > 1.0},
                      {"scale", uncertainty_scale},
                      {"note", uncertainty_note}};
  std::vector<std::string> gross;
  for (const GrossReading& g : wild) gross.push_back(describe(g));
  if (!wild.empty()) verdict.reasons.insert(verdict.reasons.begin(), describe(wild));
  int status = exit_status_of(verdict);
  std::string next = gross.empty()
                         ? next_step(verdict, args)
                         : "check " +
                               std::string(gross.size() == 1 ? "that reading" : "those readings") +
                               ", measure the pose again or leave it out, and calibrate again";
  j["fit_test"] = verdict_json(verdict, next, status);
  j["fit_test"]["gross_readings"] = gross;
  auto gate = held_out_gate(args, *nominal, calibrated, &warnings);
  if (!gate.ok()) return gate.status();
  if (!args.validate.empty()) j["validation"] = gate->json;
  if (!gate->better) {
    status = kExitWorseThanNominal;
    verdict.reasons.insert(verdict.reasons.begin(),
                           "the calibrated model predicts the held-out recording " + args.validate +
                               " worse than the nominal model (" + gate->why + ")");
    next =
        "do not use this calibration: diagnose the recording (cdpr-fit diagnose) and compare "
        "the models with cdpr-fit validate";
    j["fit_test"]["verdict"] = verdict_key(verdict, status);
    j["fit_test"]["passed"] = false;
    j["fit_test"]["exit_status"] = status;
    j["fit_test"]["reasons"] = verdict.reasons;
    j["fit_test"]["next_step"] = next;
  }
  j["exit_status"] = status;
  const std::string verdict_line = status == 0
                                       ? std::string("# Verdict: passed.\n")
                                       : "# Verdict: " + verdict_key(verdict, status) +
                                             ": this model DID NOT PASS the calibration checks (" +
                                             verdict.reasons.front() + ").\n";
  CDPR_RETURN_IF_ERROR(write_outputs(args, calibrated, j, verdict_line));
  Output out;
  out.exit_status = status;
  out.json = std::move(j);
  out.human = report::identification_text(in) + uncertainty_note + gate->text +
              verdict_text(verdict, next, status) + wrote_text(args);
  if (status != 0) {
    std::string n = "cdpr-fit calibrate: the calibrated model did not pass (" +
                    verdict_key(verdict, status) + ", exit status " + std::to_string(status) +
                    "): " + verdict.reasons.front() + "\n";
    if (!args.out.empty()) {
      n += "cdpr-fit calibrate: " + args.out +
           " was written anyway, as asked; do not use it on the robot before the cause is "
           "found\n";
    }
    n += "cdpr-fit calibrate: next step: " + next + "\n";
    out.notice = n;
    if (!args.out.empty()) {
      out.human += "NOTE: " + args.out + " holds a model that did not pass (see the verdict)\n";
    }
  }
  return out;
}

}  // namespace cdpr::fit
