// The renderings of an identification (cdpr-fit calibrate's documents) and the combined
// calibration report.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "cdpr/report/format.hpp"
#include "cdpr/report/report.hpp"
#include "report_internal.hpp"
#include "svg.hpp"

namespace cdpr::report {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

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
  // What fixes the world frame (the gauge) and what each channel makes observable, as the text
  // report's summary() states them (issue 18).
  nlohmann::json channels = nlohmann::json::array();
  for (const ChannelContribution& c : r.channels) {
    nlohmann::json made = nlohmann::json::array();
    nlohmann::json sharper = nlohmann::json::array();
    for (const auto& [name, ratio] : c.gains) {
      if (std::isinf(ratio)) {
        made.push_back(name);
      } else {
        sharper.push_back({{"parameter", name}, {"std_ratio", ratio}});
      }
    }
    channels.push_back({{"channel", c.channel},
                        {"rows", c.rows},
                        {"rank_without", c.rank_without},
                        {"makes_identifiable", made},
                        {"sharpens", sharper},
                        {"description", c.description}});
  }
  nlohmann::json unobserved = nlohmann::json::array();
  for (int q : r.unobserved) unobserved.push_back(r.parameter_names[static_cast<std::size_t>(q)]);
  return {{"identifiable", r.identifiable()},
          {"gauge", r.notes},
          {"channels", channels},
          {"not_observed", unobserved},
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

int pose_number(const ReportContext& c, std::size_t row) {
  return row < c.pose_indices.size() ? c.pose_indices[row] : static_cast<int>(row);
}

nlohmann::json inputs_json(const ReportContext& c, const RobotModel& nominal,
                           const MeasurementSet& set) {
  return {{"config", c.config},
          {"config_hash", c.config_hash},
          {"recording", c.recording},
          {"recording_hash", c.recording_hash},
          {"poses", set.num_poses()},
          {"cables", nominal.num_cables()},
          {"lasers", static_cast<int>(nominal.lasers.size())}};
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

std::string truth_comparison(const ReportContext& c, const RobotModel& nominal,
                             const RobotModel& calibrated, const RobotModel& truth,
                             nlohmann::json* j) {
  const Eigen::VectorXd before = anchor_errors(nominal, truth);
  const Eigen::VectorXd after = anchor_errors(calibrated, truth);
  (*j)["anchor_error_vs_truth"] = {{"truth", c.truth},
                                   {"nominal_m", to_json(before)},
                                   {"calibrated_m", to_json(after)},
                                   {"nominal_rms_m", rms(before)},
                                   {"calibrated_rms_m", rms(after)},
                                   {"nominal_max_m", before.maxCoeff()},
                                   {"calibrated_max_m", after.maxCoeff()}};
  std::ostringstream t;
  t << "\nFrame anchor error vs " << c.truth << " (m):\n  cable    nominal  calibrated\n";
  for (Eigen::Index i = 0; i < before.size(); ++i) {
    char line[96];
    std::snprintf(line, sizeof line, "  %5ld  %9.3e   %9.3e\n", static_cast<long>(i + 1), before(i),
                  after(i));
    t << line;
  }
  t << "  RMS    " << fmt(rms(before), 4) << " -> " << fmt(rms(after), 4) << " m\n";
  return t.str();
}

std::string warnings_text(const std::vector<std::string>& warnings) {
  std::ostringstream h;
  if (!warnings.empty()) {
    h << "\nWarnings:\n";
    for (const std::string& w : warnings) h << "  - " << w << "\n";
  }
  return h.str();
}

}  // namespace

nlohmann::json identification_json(const CalibrationReportInput& in) {
  const ReportContext& c = in.context;
  const IdentificationReport& r = *in.identification;
  const RobotModel& nominal = in.before->robot;
  const RobotModel& calibrated = in.after->robot;
  const MeasurementSet& set = *in.set;
  nlohmann::json params = nlohmann::json::array();
  for (const ParameterEstimate& p : r.parameters) {
    params.push_back({{"name", p.name},
                      {"unit", p.unit},
                      {"initial", p.initial},
                      {"value", p.value},
                      {"std_dev", number_or_null(p.std_dev)},
                      {"lower", number_or_null(p.lower)},
                      {"upper", number_or_null(p.upper)},
                      {"at_bound", p.at_bound}});
  }
  nlohmann::json residuals = nlohmann::json::array();
  for (std::size_t j = 0; j < r.residuals.size(); ++j) {
    const PoseResiduals& pr = r.residuals[j];
    residuals.push_back(
        {{"row", j},
         {"pose", pose_number(c, j)},
         {"length_m", to_json(pr.length_m)},
         {"length_normalized", to_json(pr.length_normalized)},
         {"laser_m", to_json(pr.laser_m)},
         {"laser_normalized", to_json(pr.laser_normalized)},
         {"wrench_si", to_json(Eigen::VectorXd(pr.wrench_si))},
         {"wrench_normalized", to_json(Eigen::VectorXd(pr.wrench_normalized))},
         {"reference_normalized", to_json(Eigen::VectorXd(pr.reference_normalized))}});
    // Issue 18 channels, only when the recording has them (reports without them are unchanged).
    nlohmann::json& row = residuals.back();
    if (pr.swivel_normalized.size() > 0 && !pr.swivel_normalized.array().isNaN().all()) {
      row["swivel_rad"] = to_json(pr.swivel_rad);
      row["swivel_normalized"] = to_json(pr.swivel_normalized);
    }
    if (!pr.inclination_normalized.array().isNaN().all()) {
      row["inclination_rad"] = to_json(Eigen::VectorXd(pr.inclination_rad));
      row["inclination_normalized"] = to_json(Eigen::VectorXd(pr.inclination_normalized));
    }
    if (!std::isnan(pr.imu_yaw_normalized)) {
      row["imu_yaw_rad"] = pr.imu_yaw_rad;
      row["imu_yaw_normalized"] = pr.imu_yaw_normalized;
    }
  }
  nlohmann::json poses = nlohmann::json::array();
  for (std::size_t j = 0; j < r.poses.size(); ++j) {
    poses.push_back({{"pose", pose_number(c, j)},
                     {"estimate", to_json(Eigen::VectorXd(r.poses[j].vector()))},
                     {"std_dev", j < r.pose_std.size() ? to_json(Eigen::VectorXd(r.pose_std[j]))
                                                       : nlohmann::json(nullptr)}});
  }
  nlohmann::json j = {
      {"command", "calibrate"},
      {"method", c.method},
      {"inputs", inputs_json(c, nominal, set)},
      {"options",
       {{"estimate", c.estimated},
        {"gauge", c.gauge},
        {"loss", c.loss},
        {"home_pose_row", c.home_pose_row},
        {"max_iterations", c.max_iterations}}},
      {"noise",
       {{"length_m", set.noise.sigma_length},
        {"laser_m", set.noise.sigma_laser},
        {"force_n", set.noise.sigma_force}}},
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
       {{"nominal", to_json(nominal.frame_anchors)},
        {"calibrated", to_json(calibrated.frame_anchors)}}},
      {"length_offsets_m", to_json(in.after->readings.length_offsets)},
      {"length_scales", to_json(in.after->readings.length_scales)},
      {"poses", poses},
      {"residuals", residuals},
      {"warnings", c.warnings},
      {"trustworthy", r.converged && c.warnings.empty()},
  };
  if (in.identifiability != nullptr) {
    j["identifiability"] = identifiability_json(*in.identifiability);
  } else {
    j["identifiability"] = {{"error", in.identifiability_error}};
  }
  if (in.truth != nullptr) truth_comparison(c, nominal, calibrated, *in.truth, &j);
  if (!c.calibrated_config.empty()) j["calibrated_config"] = c.calibrated_config;
  return j;
}

std::string identification_text(const CalibrationReportInput& in) {
  const ReportContext& c = in.context;
  const RobotModel& nominal = in.before->robot;
  std::ostringstream h;
  h << c.title << ": " << c.config << " + " << c.recording << " (" << in.set->num_poses()
    << " poses, " << nominal.num_cables() << " cables, " << nominal.lasers.size() << " laser"
    << (nominal.lasers.size() == 1 ? "" : "s") << ")\n";
  h << "estimating:";
  for (const std::string& e : c.estimated) h << " " << e;
  h << "\n\n" << in.identification->full_report();
  if (in.identifiability != nullptr) {
    h << "\nIdentifiability:\n" << in.identifiability->summary() << "\n";
  }
  h << anchor_table(nominal, in.after->robot);
  if (in.truth != nullptr) {
    nlohmann::json unused;
    h << truth_comparison(c, nominal, in.after->robot, *in.truth, &unused);
  }
  // The solver's own warnings are in full_report() above; the rest are about the inputs.
  std::vector<std::string> others;
  for (const std::string& w : c.warnings) {
    const auto& own = in.identification->warnings;
    if (std::find(own.begin(), own.end(), w) == own.end()) others.push_back(w);
  }
  h << warnings_text(others);
  return h.str();
}

nlohmann::json paper_method_json(const PaperReportInput& in) {
  const ReportContext& c = in.context;
  const PaperMethodReport& r = *in.paper;
  const RobotModel& nominal = in.before->robot;
  nlohmann::json poses = nlohmann::json::array();
  for (std::size_t j = 0; j < r.poses.size(); ++j) {
    poses.push_back(
        {{"pose", pose_number(c, j)}, {"estimate", to_json(Eigen::VectorXd(r.poses[j].vector()))}});
  }
  nlohmann::json j = {
      {"command", "calibrate"},
      {"method", "paper"},
      {"inputs", inputs_json(c, nominal, *in.set)},
      {"options",
       {{"estimate", in.estimate},
        {"home_pose_row", c.home_pose_row},
        {"max_iterations", c.max_iterations},
        {"lambda", in.lambda}}},
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
        {"calibrated", to_json(r.estimate.robot.frame_anchors)}}},
      {"poses", poses},
      {"warnings", c.warnings},
      {"trustworthy", r.converged && c.warnings.empty()},
  };
  if (in.truth != nullptr) truth_comparison(c, nominal, r.estimate.robot, *in.truth, &j);
  if (!c.calibrated_config.empty()) j["calibrated_config"] = c.calibrated_config;
  return j;
}

std::string paper_method_text(const PaperReportInput& in) {
  const ReportContext& c = in.context;
  const RobotModel& nominal = in.before->robot;
  std::ostringstream h;
  h << c.title << " --method paper: " << c.config << " + " << c.recording << " ("
    << in.set->num_poses() << " poses)\n\n"
    << in.paper->summary() << "\n(the paper's method gives no standard deviations)\n"
    << anchor_table(nominal, in.paper->estimate.robot);
  if (in.truth != nullptr) {
    nlohmann::json unused;
    h << truth_comparison(c, nominal, in.paper->estimate.robot, *in.truth, &unused);
  }
  h << warnings_text(c.warnings);
  return h.str();
}

Rendered render_calibration_report(const CalibrationReportInput& in) {
  Rendered out;
  out.json = identification_json(in);
  out.text = identification_text(in);
  if (in.diagnosis != nullptr) {
    out.json["diagnosis"] = diagnosis_json(*in.diagnosis, in.before->robot, *in.set, in.context);
    out.text += "\n" + diagnosis_text(*in.diagnosis, in.before->robot, *in.set, in.context);
  }
  PageInput page;
  page.before = &in.before->robot;
  page.after = in.after;
  page.standard = in.identification;
  page.fit =
      in.diagnosis != nullptr && in.diagnosis->after ? &*in.diagnosis->after : in.identification;
  page.diagnosis = in.diagnosis;
  page.set = in.set;
  page.context = &in.context;
  out.html = html_page(page);
  return out;
}

}  // namespace cdpr::report
