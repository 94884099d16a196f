// cdpr-fit calibrate: identify the robot from a recording, write the calibrated config and report.
#include <cmath>
#include <sstream>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/paper_method.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/recording/recording.hpp"
#include "commands.hpp"
#include "common.hpp"

namespace cdpr::fit {

const std::vector<std::string>& estimate_names() {
  static const std::vector<std::string> names = {
      "anchors",       "paper-anchors", "platform-anchors",    "offsets",
      "scales",        "stiffness",     "stiffness-per-cable", "force-gains",
      "force-offsets", "laser-origin",  "laser-direction",     "laser-plane"};
  return names;
}

Status apply_estimate(const std::vector<std::string>& names, int num_cables,
                      IdentificationOptions* o) {
  if (names.empty()) return Status::Ok();  // the defaults of IdentificationOptions
  o->estimate_frame_anchors = false;
  o->estimate_platform_anchors = false;
  o->estimate_length_offsets = false;
  o->estimate_length_scales = false;
  o->estimate_stiffness = StiffnessEstimate::kFixed;
  o->estimate_force_gains = false;
  o->estimate_force_offsets = false;
  o->estimate_laser_origin = false;
  o->estimate_laser_direction = false;
  o->estimate_laser_plane = false;
  for (const std::string& n : names) {
    if (n == "anchors") {
      o->estimate_frame_anchors = true;
    } else if (n == "paper-anchors") {
      if (num_cables != 8) {
        return Status::Error(ErrorCode::kInvalidArgument,
                             "--estimate paper-anchors is the paper's 16-coordinate subset of an "
                             "8-cable robot; this config has %d cables",
                             num_cables);
      }
      o->estimate_frame_anchors = true;
      o->frame_anchor_mask = paper_anchor_mask();
    } else if (n == "platform-anchors") {
      o->estimate_platform_anchors = true;
    } else if (n == "offsets") {
      o->estimate_length_offsets = true;
    } else if (n == "scales") {
      o->estimate_length_scales = true;
    } else if (n == "stiffness") {
      o->estimate_stiffness = StiffnessEstimate::kShared;
    } else if (n == "stiffness-per-cable") {
      o->estimate_stiffness = StiffnessEstimate::kPerCable;
    } else if (n == "force-gains") {
      o->estimate_force_gains = true;
    } else if (n == "force-offsets") {
      o->estimate_force_offsets = true;
    } else if (n == "laser-origin") {
      o->estimate_laser_origin = true;
    } else if (n == "laser-direction") {
      o->estimate_laser_direction = true;
    } else if (n == "laser-plane") {
      o->estimate_laser_plane = true;
    } else {
      std::string all;
      for (const std::string& k : estimate_names()) all += (all.empty() ? "" : ", ") + k;
      return Status::Error(ErrorCode::kInvalidArgument, "--estimate: unknown item '%s' (one of %s)",
                           n.c_str(), all.c_str());
    }
  }
  return Status::Ok();
}

std::vector<std::string> estimated_items(const IdentificationOptions& o) {
  std::vector<std::string> v;
  if (o.estimate_frame_anchors)
    v.push_back(o.frame_anchor_mask.size() ? "anchors (masked)" : "anchors");
  if (o.estimate_platform_anchors) v.push_back("platform-anchors");
  if (o.estimate_length_offsets) v.push_back("offsets");
  if (o.estimate_length_scales) v.push_back("scales");
  if (o.estimate_stiffness == StiffnessEstimate::kShared) v.push_back("stiffness");
  if (o.estimate_stiffness == StiffnessEstimate::kPerCable) v.push_back("stiffness-per-cable");
  if (o.estimate_force_gains) v.push_back("force-gains");
  if (o.estimate_force_offsets) v.push_back("force-offsets");
  if (o.estimate_laser_origin) v.push_back("laser-origin");
  if (o.estimate_laser_direction) v.push_back("laser-direction");
  if (o.estimate_laser_plane) v.push_back("laser-plane");
  return v;
}

namespace {

// Per cable ||a_i - a_true,i|| (m).
Eigen::VectorXd anchor_errors(const RobotModel& model, const RobotModel& truth) {
  return (model.frame_anchors - truth.frame_anchors).colwise().norm().transpose();
}

double rms(const Eigen::VectorXd& v) {
  return v.size() == 0 ? 0.0 : std::sqrt(v.squaredNorm() / static_cast<double>(v.size()));
}

nlohmann::json identifiability_json(const IdentifiabilityReport& r) {
  nlohmann::json dirs = nlohmann::json::array();
  for (const ParameterDirection& d : r.directions) {
    nlohmann::json comps = nlohmann::json::array();
    for (const DirectionComponent& c : d.components) {
      comps.push_back({{"description", c.description}, {"weight", c.weight}});
    }
    dirs.push_back({{"singular_value", d.singular_value},
                    {"null", d.null},
                    {"gauge", d.gauge},
                    {"description", d.description},
                    {"components", comps}});
  }
  return {{"identifiable", r.identifiable()},
          {"rank", r.rank},
          {"parameters", r.num_parameters},
          {"residuals", r.num_residuals},
          {"condition_number", number_or_null(r.condition_number)},
          {"singular_values", to_json(r.singular_values)},
          {"normalized_singular_values", to_json(r.normalized_singular_values)},
          {"o1", r.o1},
          {"o2", r.o2},
          {"o3", r.o3},
          {"o4", r.o4},
          {"o5", r.o5},
          {"weak_or_null_directions", dirs}};
}

// Writes the calibrated config (with a comment header) and the JSON report together: both or,
// when one cannot be written, neither (io::AtomicFileSet). Records the config in the JSON.
Status write_outputs(const CalibrateArgs& args, const RobotModel& calibrated, nlohmann::json* j) {
  io::AtomicFileSet outputs;
  if (!args.out.empty()) {
    const std::string yaml = "# Calibrated by cdpr-fit calibrate --method " + args.method +
                             " from " + args.config + " and " + args.recording + " (" +
                             recording::utc_timestamp() + ").\n" +
                             "# Winch length_offset and drum size include the identified encoder "
                             "offsets and scales.\n" +
                             config::save_robot_config(calibrated);
    CDPR_RETURN_IF_ERROR(outputs.stage(args.out, yaml));
    (*j)["calibrated_config"] = args.out;
  }
  if (!args.report.empty()) CDPR_RETURN_IF_ERROR(outputs.stage(args.report, j->dump(2) + "\n"));
  return outputs.commit();
}

Result<std::optional<RobotModel>> load_truth(const CalibrateArgs& args, const RobotModel& nominal) {
  if (args.truth.empty()) return std::optional<RobotModel>();
  auto t = load_config(args.truth);
  if (!t.ok()) return t.status();
  if (t->num_cables() != nominal.num_cables()) {
    return Status::Error(ErrorCode::kInvalidArgument, "--truth %s has %d cables, %s has %d",
                         args.truth.c_str(), t->num_cables(), args.config.c_str(),
                         nominal.num_cables());
  }
  return std::optional<RobotModel>(std::move(*t));
}

// Anchor errors vs the truth into the JSON and a text table.
std::string truth_comparison(const CalibrateArgs& args, const RobotModel& nominal,
                             const RobotModel& calibrated, const RobotModel& truth,
                             nlohmann::json* j) {
  const Eigen::VectorXd before = anchor_errors(nominal, truth);
  const Eigen::VectorXd after = anchor_errors(calibrated, truth);
  (*j)["anchor_error_vs_truth"] = {{"truth", args.truth},
                                   {"nominal_m", to_json(before)},
                                   {"calibrated_m", to_json(after)},
                                   {"nominal_rms_m", rms(before)},
                                   {"calibrated_rms_m", rms(after)},
                                   {"nominal_max_m", before.maxCoeff()},
                                   {"calibrated_max_m", after.maxCoeff()}};
  std::ostringstream t;
  t << "\nFrame anchor error vs " << args.truth << " (m):\n  cable    nominal  calibrated\n";
  for (Eigen::Index i = 0; i < before.size(); ++i) {
    char line[96];
    std::snprintf(line, sizeof line, "  %5ld  %9.3e   %9.3e\n", static_cast<long>(i + 1), before(i),
                  after(i));
    t << line;
  }
  t << "  RMS    " << fmt(rms(before), 4) << " -> " << fmt(rms(after), 4) << " m\n";
  return t.str();
}

std::string anchor_table(const RobotModel& nominal, const RobotModel& calibrated) {
  std::ostringstream h;
  h << "\nFrame anchors (m):\n  cable   nominal                         calibrated\n";
  for (int i = 0; i < nominal.num_cables(); ++i) {
    char line[160];
    const auto a = nominal.frame_anchors.col(i);
    const auto b = calibrated.frame_anchors.col(i);
    std::snprintf(line, sizeof line, "  %5d   [%8.5f, %8.5f, %8.5f]   [%8.5f, %8.5f, %8.5f]\n",
                  i + 1, a.x(), a.y(), a.z(), b.x(), b.y(), b.z());
    h << line;
  }
  return h.str();
}

std::string tail_text(const CalibrateArgs& args, const std::vector<std::string>& warnings) {
  std::ostringstream h;
  if (!warnings.empty()) {
    h << "\nWarnings:\n";
    for (const std::string& w : warnings) h << "  - " << w << "\n";
  }
  if (!args.out.empty()) h << "\nwrote " << args.out << "\n";
  if (!args.report.empty()) h << "wrote " << args.report << "\n";
  return h.str();
}

nlohmann::json inputs_json(const CalibrateArgs& args, const RobotModel& nominal,
                           const MeasurementSet& set) {
  return {{"config", args.config},
          {"config_hash", hash_or_unknown(args.config)},
          {"recording", args.recording},
          {"recording_hash", hash_or_unknown(args.recording)},
          {"poses", set.num_poses()},
          {"cables", nominal.num_cables()},
          {"lasers", static_cast<int>(nominal.lasers.size())}};
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
      return Status::Error(ErrorCode::kInvalidArgument,
                           "--method paper estimates frame anchors only (--estimate anchors or "
                           "paper-anchors), not '%s'",
                           e.c_str());
    }
  }
  if (options.parameters.size() == 0 && nominal.num_cables() != 8) {
    return Status::Error(ErrorCode::kInvalidArgument,
                         "--method paper: the paper's parameter set is for 8 cables; this config "
                         "has %d (use --estimate anchors)",
                         nominal.num_cables());
  }
  if (args.home_pose < 0 || args.home_pose >= set.num_poses()) {
    return Status::Error(ErrorCode::kInvalidArgument,
                         "--home-pose %d: the recording has rows 0..%d", args.home_pose,
                         set.num_poses() - 1);
  }
  auto truth = load_truth(args, nominal);
  if (!truth.ok()) return truth.status();
  const CalibratedModel initial = CalibratedModel::FromRobot(nominal);
  auto report = paper_method(initial, set, options);
  if (!report.ok()) {
    return with_context(report.status(), "calibrating " + args.config + " from " + args.recording);
  }
  const PaperMethodReport& r = *report;
  if (!r.converged) warnings.push_back("the paper's iteration did not converge: " + r.termination);
  // identify() and paper_method() already fold the identified reading model into the winches
  // (IdentificationReport::estimate); folding it again would double the offsets.
  const RobotModel& calibrated = r.estimate.robot;
  nlohmann::json poses = nlohmann::json::array();
  for (std::size_t j = 0; j < r.poses.size(); ++j) {
    poses.push_back({{"pose", rec.poses[j].index},
                     {"estimate", to_json(Eigen::VectorXd(r.poses[j].vector()))}});
  }
  nlohmann::json j = {
      {"command", "calibrate"},
      {"method", "paper"},
      {"inputs", inputs_json(args, nominal, set)},
      {"options",
       {{"estimate", options.parameters.size() == 0 ? "paper-anchors" : "anchors"},
        {"home_pose_row", args.home_pose},
        {"max_iterations", args.max_iterations},
        {"lambda", options.lambda}}},
      {"converged", r.converged},
      {"termination", r.termination},
      {"iterations", r.iterations},
      {"fk_solves", r.fk_solves},
      {"error_norm_m", {{"initial", r.initial_error_norm}, {"final", r.final_error_norm}}},
      {"error_history_m", r.error_history},
      {"time_s", r.time_s},
      {"std_devs", nullptr},
      {"frame_anchors",
       {{"nominal", to_json(nominal.frame_anchors)},
        {"calibrated", to_json(calibrated.frame_anchors)}}},
      {"poses", poses},
      {"warnings", warnings},
      {"trustworthy", r.converged && warnings.empty()},
  };
  const std::string truth_text =
      truth->has_value() ? truth_comparison(args, nominal, calibrated, **truth, &j) : "";
  CDPR_RETURN_IF_ERROR(write_outputs(args, calibrated, &j));
  std::ostringstream h;
  h << "cdpr-fit calibrate --method paper: " << args.config << " + " << args.recording << " ("
    << set.num_poses() << " poses)\n\n"
    << r.Summary() << "\n(the paper's method gives no standard deviations)\n"
    << anchor_table(nominal, calibrated) << truth_text << tail_text(args, warnings);
  Output out;
  out.json = std::move(j);
  out.human = h.str();
  return out;
}

}  // namespace

Result<Output> calibrate(const CalibrateArgs& args) {
  if (args.method != "ours" && args.method != "paper") {
    return Status::Error(ErrorCode::kInvalidArgument, "--method %s: expected ours or paper",
                         args.method.c_str());
  }
  auto nominal = load_config(args.config);
  if (!nominal.ok()) return nominal.status();
  auto rec = recording::read_recording(args.recording);
  if (!rec.ok()) return rec.status();
  if (Status s = recording::check_against_model(*rec, *nominal); !s.ok()) {
    return with_context(s, args.recording + " vs " + args.config);
  }
  std::vector<std::string> warnings;
  const std::string recorded_robot = rec->metadata.get(recording::key::kRobot);
  if (!recorded_robot.empty() && recorded_robot != nominal->name) {
    warnings.push_back("the recording is of robot '" + recorded_robot + "' but " + args.config +
                       " is '" + nominal->name + "'");
  }
  for (const char* k :
       {recording::key::kNoiseLength, recording::key::kNoiseLaser, recording::key::kNoiseForce}) {
    if (!rec->metadata.has(k)) {
      warnings.push_back(std::string("the recording states no '") + k +
                         "'; the default sigma is used");
    }
  }
  auto set = recording::to_measurement_set(*rec);
  if (!set.ok()) return with_context(set.status(), args.recording);
  if (Status s = validate(*set, *nominal); !s.ok()) return with_context(s, args.recording);
  if (args.method == "paper") return calibrate_paper(args, *nominal, *rec, *set, warnings);

  IdentificationOptions options;
  CDPR_RETURN_IF_ERROR(apply_estimate(args.estimate, nominal->num_cables(), &options));
  if (args.gauge == "home") {
    options.gauge = Gauge::kHomePose;
  } else if (args.gauge == "laser-plane") {
    options.gauge = Gauge::kLaserPlane;
  } else if (args.gauge == "both") {
    options.gauge = Gauge::kHomePoseAndLaserPlane;
  } else if (args.gauge == "none") {
    options.gauge = Gauge::kNone;
  } else {
    return Status::Error(ErrorCode::kInvalidArgument,
                         "--gauge %s: expected home, laser-plane, both or none",
                         args.gauge.c_str());
  }
  if (args.loss == "none") {
    options.loss = RobustLoss::kNone;
  } else if (args.loss == "huber") {
    options.loss = RobustLoss::kHuber;
  } else if (args.loss == "cauchy") {
    options.loss = RobustLoss::kCauchy;
  } else {
    return Status::Error(ErrorCode::kInvalidArgument, "--loss %s: expected none, huber or cauchy",
                         args.loss.c_str());
  }
  if (args.home_pose < 0 || args.home_pose >= set->num_poses()) {
    return Status::Error(ErrorCode::kInvalidArgument,
                         "--home-pose %d: the recording has rows 0..%d", args.home_pose,
                         set->num_poses() - 1);
  }
  options.home_pose_index = args.home_pose;
  options.max_iterations = args.max_iterations;
  if (options.gauge == Gauge::kHomePose || options.gauge == Gauge::kHomePoseAndLaserPlane) {
    const auto& home = set->poses[static_cast<std::size_t>(args.home_pose)];
    if (!home.reference && (home.commanded.vector() - nominal->home.vector()).norm() > 1e-6) {
      warnings.push_back("row " + std::to_string(args.home_pose) +
                         " (the gauge's home pose) is not commanded at the config's home pose and "
                         "has no reference reading; the frame is fixed at the config's home");
    }
  }
  auto truth = load_truth(args, *nominal);
  if (!truth.ok()) return truth.status();

  const CalibratedModel initial = CalibratedModel::FromRobot(*nominal);
  // Identifiability of the choice at the commanded poses (named directions for the report).
  auto ident = analyze_identifiability(initial, *set, options);
  auto report = identify(initial, *set, options);
  if (!report.ok()) {
    return with_context(report.status(), "calibrating " + args.config + " from " + args.recording);
  }
  const IdentificationReport& r = *report;
  for (const std::string& w : r.warnings) warnings.push_back(w);
  // identify() and paper_method() already fold the identified reading model into the winches
  // (IdentificationReport::estimate); folding it again would double the offsets.
  const RobotModel& calibrated = r.estimate.robot;

  // ---- JSON report ------------------------------------------------------------------------
  nlohmann::json params = nlohmann::json::array();
  for (const ParameterEstimate& p : r.parameters) {
    params.push_back({{"name", p.name},
                      {"unit", p.unit},
                      {"initial", p.initial},
                      {"value", p.value},
                      {"std_dev", number_or_null(p.std_dev)}});
  }
  nlohmann::json residuals = nlohmann::json::array();
  for (std::size_t j = 0; j < r.residuals.size(); ++j) {
    const PoseResiduals& pr = r.residuals[j];
    residuals.push_back(
        {{"row", j},
         {"pose", rec->poses[j].index},
         {"length_m", to_json(pr.length_m)},
         {"length_normalized", to_json(pr.length_normalized)},
         {"laser_m", to_json(pr.laser_m)},
         {"laser_normalized", to_json(pr.laser_normalized)},
         {"wrench_si", to_json(Eigen::VectorXd(pr.wrench_si))},
         {"wrench_normalized", to_json(Eigen::VectorXd(pr.wrench_normalized))},
         {"reference_normalized", to_json(Eigen::VectorXd(pr.reference_normalized))}});
  }
  nlohmann::json poses = nlohmann::json::array();
  for (std::size_t j = 0; j < r.poses.size(); ++j) {
    poses.push_back({{"pose", rec->poses[j].index},
                     {"estimate", to_json(Eigen::VectorXd(r.poses[j].vector()))},
                     {"std_dev", j < r.pose_std.size() ? to_json(Eigen::VectorXd(r.pose_std[j]))
                                                       : nlohmann::json(nullptr)}});
  }
  nlohmann::json j = {
      {"command", "calibrate"},
      {"method", args.method},
      {"inputs", inputs_json(args, *nominal, *set)},
      {"options",
       {{"estimate", estimated_items(options)},
        {"gauge", args.gauge},
        {"loss", args.loss},
        {"home_pose_row", args.home_pose},
        {"max_iterations", args.max_iterations}}},
      {"noise",
       {{"length_m", set->noise.sigma_length},
        {"laser_m", set->noise.sigma_laser},
        {"force_n", set->noise.sigma_force}}},
      {"converged", r.converged},
      {"termination", r.termination},
      {"iterations", r.iterations},
      {"cost", {{"initial", r.initial_cost}, {"final", r.final_cost}}},
      {"chi2", r.chi2},
      {"dof", r.dof},
      {"residual_count", r.num_residuals},
      {"parameter_count", r.num_parameters},
      {"rms",
       {{"length_m", r.rms_length_m}, {"laser_m", r.rms_laser_m}, {"wrench_n", r.rms_wrench_n}}},
      {"rank", r.rank},
      {"condition_number", number_or_null(r.condition_number)},
      {"solve_time_s", r.solve_time_s},
      {"estimate", params},
      {"frame_anchors",
       {{"nominal", to_json(nominal->frame_anchors)},
        {"calibrated", to_json(calibrated.frame_anchors)}}},
      {"length_offsets_m", to_json(r.estimate.readings.length_offsets)},
      {"length_scales", to_json(r.estimate.readings.length_scales)},
      {"poses", poses},
      {"residuals", residuals},
      {"warnings", warnings},
      {"trustworthy", r.converged && warnings.empty()},
  };
  if (ident.ok()) {
    j["identifiability"] = identifiability_json(*ident);
  } else {
    j["identifiability"] = {{"error", std::string(ident.status().message())}};
  }
  const std::string truth_text =
      truth->has_value() ? truth_comparison(args, *nominal, calibrated, **truth, &j) : "";
  CDPR_RETURN_IF_ERROR(write_outputs(args, calibrated, &j));

  // ---- human text ---------------------------------------------------------------------------
  std::ostringstream h;
  h << "cdpr-fit calibrate: " << args.config << " + " << args.recording << " (" << set->num_poses()
    << " poses, " << nominal->num_cables() << " cables, " << nominal->lasers.size() << " laser"
    << (nominal->lasers.size() == 1 ? "" : "s") << ")\n";
  h << "estimating:";
  for (const std::string& e : estimated_items(options)) h << " " << e;
  h << "\n\n" << r.FullReport();
  if (ident.ok()) h << "\nIdentifiability:\n" << ident->Summary() << "\n";
  h << anchor_table(*nominal, calibrated) << truth_text << tail_text(args, warnings);
  Output out;
  out.json = std::move(j);
  out.human = h.str();
  return out;
}

}  // namespace cdpr::fit
