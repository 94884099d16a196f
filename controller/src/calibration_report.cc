#include "cdpr/controller/calibration_report.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

#include "cdpr/calibration/calibration_verdict.hpp"
#include "cdpr/calibration/mismatch.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/report/format.hpp"
#include "cdpr/report/report.hpp"

namespace cdpr::controller {
using json = nlohmann::json;

namespace {

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

json finite_or_null(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}

// Standard deviation of frame anchor coordinate a_<cable>.<axis> in the fit, NaN when not
// estimated.
double anchor_std(const IdentificationReport* fit, int cable, char axis) {
  if (fit == nullptr) return std::numeric_limits<double>::quiet_NaN();
  const ParameterId id{ParameterKind::kFrameAnchor, cable, axis - 'x'};
  for (const ParameterEstimate& p : fit->parameters) {
    if (p.id == id) return p.std_dev;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

namespace {

// Fit: the chi-square test every front end uses (calibration_verdict.hpp).
Gate fit_gate(const IdentificationReport& fit, const AcceptanceGates& gates) {
  Gate g;
  g.name = "fit";
  const FitTest test = chi_square_fit_test(fit.chi2, fit.dof, gates.min_fit_p_value);
  g.value = test.p_value;
  g.limit = gates.min_fit_p_value;
  g.passed = fit.converged && test.passed;
  g.text = fmt("chi2 %.1f", fit.chi2) + " on " + std::to_string(fit.dof) +
           " dof, p = " + fmt("%.3g", g.value) + (g.passed ? " >= " : " < ") +
           fmt("%.3g", g.limit) + (fit.converged ? "" : " (the solver did not converge)");
  return g;
}

// Largest frame-anchor change.
Gate anchor_change_gate(const RobotModel& before, const RobotModel& after,
                        const AcceptanceGates& gates) {
  Gate g;
  g.name = "anchor_change";
  for (std::size_t i = 0; i < before.cables.size() && i < after.cables.size(); ++i) {
    g.value = std::max(g.value, (after.frame_anchors.col(static_cast<Eigen::Index>(i)) -
                                 before.frame_anchors.col(static_cast<Eigen::Index>(i)))
                                    .norm());
  }
  g.limit = gates.max_anchor_change_m;
  g.passed = g.value <= g.limit;
  g.text = "largest frame-anchor change " + fmt("%.2f", g.value * 1e3) + " mm" +
           (g.passed ? " <= " : " > ") + fmt("%.1f", g.limit * 1e3) + " mm";
  return g;
}

// `m` with its encoder zeros and drum scale (relative to `reference`'s drums) as readings: the
// robot `reference` commands in counts reaches the lengths `m` gives those counts (winch.hpp).
CalibratedModel counting(const RobotModel& m, const RobotModel& reference) {
  CalibratedModel c = CalibratedModel::from_robot(m);
  for (int i = 0; i < m.num_cables() && i < reference.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    c.readings.length_offsets(i) = m.winches[k].length_offset;
    c.readings.length_scales(i) =
        m.winches[k].drum_diameter / reference.winches[k].drum_diameter - 1.0;
  }
  return c;
}

// Predicted position accuracy over the ISO 9283 box (Cramer-Rao bound of this pose set), and
// the AP-like figure at ISO 9283's points from the same bound.
Gate predicted_accuracy_gate(const RobotModel& before, const RobotModel& after,
                             const MeasurementSet& set, const IdentificationOptions& options,
                             const AcceptanceGates& gates, CalibrationOutcome& o) {
  Gate g;
  g.name = "predicted_accuracy";
  std::vector<Pose> poses;
  for (const PoseMeasurement& p : set.poses) poses.push_back(p.commanded);
  PredictedAccuracyOptions pa;
  pa.identification = options;
  pa.box.center = after.home.position;
  // The pose set was planned feasible for the model it was measured with; the bound hardly
  // depends on the geometry's few millimetres of change.
  const CalibratedModel nominal = CalibratedModel::from_robot(before);
  const CalibratedModel calibrated = CalibratedModel::from_robot(after);
  auto acc = predict_accuracy(nominal, poses, set.noise, pa);
  if (!acc.ok()) acc = predict_accuracy(calibrated, poses, set.noise, pa);
  g.limit = gates.max_predicted_position_error_m;
  if (acc.ok()) {
    g.value = acc->position_rms_m;
    o.predicted_position_rms_m = g.value;
    g.passed = g.value <= g.limit;
    g.text = "predicted RMS position error " + fmt("%.3f", g.value * 1e3) + " mm over " +
             std::to_string(acc->grid_points) + " box points" + (g.passed ? " <= " : " > ") +
             fmt("%.3f", g.limit * 1e3) + " mm";
    auto iso = predict_iso9283_position(counting(before, before), counting(after, before), *acc,
                                        set.noise, pa);
    if (iso.ok()) {
      o.iso9283_predicted = *iso;
    } else {
      o.iso9283_predicted_problem = iso.status().to_string();
    }
  } else {
    g.value = std::numeric_limits<double>::quiet_NaN();
    g.passed = false;
    g.text = "predicted accuracy unavailable: " + acc.status().to_string();
    o.iso9283_predicted_problem = g.text;
  }
  return g;
}

// No unresolved mismatch (unless the config allows it).
Gate mismatch_gate(const Diagnosis* diagnosis, const std::string& verdict_key,
                   const AcceptanceGates& gates) {
  Gate g;
  g.name = "mismatch";
  const bool unresolved =
      diagnosis != nullptr && (diagnosis->verdict == Diagnosis::Verdict::kMismatchUnexplained ||
                               diagnosis->verdict == Diagnosis::Verdict::kInconclusive);
  g.value = unresolved ? 1.0 : 0.0;
  g.limit = 0.0;
  g.passed = !unresolved || gates.allow_unresolved_mismatch;
  g.text = std::string("mismatch locator: ") + verdict_key +
           (unresolved && gates.allow_unresolved_mismatch ? " (allowed by the config)" : "");
  return g;
}

// RMS of the fit's standard deviations of the parameters the monitor's length prior covers
// (frame-anchor coordinates, encoder zeros); NaN when it estimated none with a finite one.
double length_uncertainty(const IdentificationReport& fit) {
  double sum = 0.0;
  int n = 0;
  for (const ParameterEstimate& p : fit.parameters) {
    if ((p.id.kind == ParameterKind::kFrameAnchor || p.id.kind == ParameterKind::kLengthOffset) &&
        std::isfinite(p.std_dev)) {
      sum += p.std_dev * p.std_dev;
      ++n;
    }
  }
  return n > 0 ? std::sqrt(sum / n) : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

CalibrationOutcome evaluate_calibration(const RobotModel& before, const MeasurementSet& set,
                                        const IdentificationReport& standard,
                                        const Diagnosis* diagnosis, const AcceptanceGates& gates,
                                        const IdentificationOptions& options) {
  CalibrationOutcome o;
  o.before = before;
  o.standard = &standard;
  o.diagnosis = diagnosis;
  o.poses = set.num_poses();
  o.fit = &standard;
  o.model = standard.estimate.robot;
  if (diagnosis != nullptr) {
    o.model = diagnosis->model_after.robot;
    if (diagnosis->after) o.fit = &*diagnosis->after;
    o.verdict = diagnosis->headline;
    o.verdict_key = report::verdict_key(diagnosis->verdict);
    for (const EffectFit& e : diagnosis->accepted) {
      o.named_effects.push_back(e.name + (e.modelled_in_config ? "" : " (not carried)"));
    }
  } else {
    o.verdict = "identification only (the mismatch locator is off)";
    o.verdict_key = "not_diagnosed";
  }
  o.model_length_m = length_uncertainty(*o.fit);
  if (o.fit->rms_wrench_n > 0.0) o.model_force_n = o.fit->rms_wrench_n;
  o.gates.push_back(fit_gate(*o.fit, gates));
  o.gates.push_back(anchor_change_gate(before, o.model, gates));
  o.gates.push_back(predicted_accuracy_gate(before, o.model, set, options, gates, o));
  o.gates.push_back(mismatch_gate(diagnosis, o.verdict_key, gates));
  o.gates_passed = true;
  for (const Gate& g : o.gates) {
    if (!g.passed) {
      o.gates_passed = false;
      o.failed_gates += (o.failed_gates.empty() ? "" : ", ") + g.name;
    }
  }
  return o;
}

json calibration_json(const CalibrationOutcome& o, const CalibrationReportContext& c) {
  json anchors = json::array();
  for (std::size_t i = 0; i < o.model.cables.size(); ++i) {
    const Eigen::Vector3d& b = o.before.frame_anchors.col(static_cast<Eigen::Index>(i));
    const Eigen::Vector3d& a = o.model.frame_anchors.col(static_cast<Eigen::Index>(i));
    const int ci = static_cast<int>(i);
    anchors.push_back(
        {{"cable", ci + 1},
         {"before_m", {b.x(), b.y(), b.z()}},
         {"after_m", {a.x(), a.y(), a.z()}},
         {"std_m",
          {finite_or_null(anchor_std(o.fit, ci, 'x')), finite_or_null(anchor_std(o.fit, ci, 'y')),
           finite_or_null(anchor_std(o.fit, ci, 'z'))}},
         {"change_m", (a - b).norm()}});
  }
  json gates = json::array();
  for (const Gate& g : o.gates) {
    gates.push_back({{"name", g.name},
                     {"passed", g.passed},
                     {"value", finite_or_null(g.value)},
                     {"limit", g.limit},
                     {"text", g.text}});
  }
  json effects = json::array();
  if (o.diagnosis != nullptr) {
    for (const EffectFit& e : o.diagnosis->accepted) {
      json params = json::array();
      for (const EffectParameter& p : e.parameters) params.push_back(p.text);
      effects.push_back({{"id", e.id},
                         {"name", e.name},
                         {"parameters", params},
                         {"carried_in_model", e.modelled_in_config},
                         {"held_out_rms_before_m", e.cv_rms_before},
                         {"held_out_rms_after_m", e.cv_rms_after}});
    }
  }
  json residuals = json::array();  // per pose, normalised length residuals of the final fit
  for (const PoseResiduals& r : o.fit->residuals) {
    json row = json::array();
    for (int i = 0; i < r.length_normalized.size(); ++i)
      row.push_back(finite_or_null(r.length_normalized(i)));
    residuals.push_back(row);
  }
  json remeasured = json::array();
  for (const RemeasuredPose& r : c.remeasured) {
    remeasured.push_back(
        {{"pose", r.row + 1}, {"measured_again_as", r.again + 1}, {"reading", r.reading}});
  }
  return {{"calibration", c.calibration},
          {"daemon", c.daemon},
          {"geometry_version_before", c.geometry_version},
          {"started", c.started},
          {"measuring_and_identification_s", c.measuring_s},
          {"files",
           {{"recording", c.recording},
            {"robot", c.robot_config},
            {"canopen", c.canopen_config},
            {"laser", c.laser_config},
            {"daemon", c.daemon_config}}},
          {"poses", o.poses},
          {"poses_measured_again", remeasured},
          {"verdict", o.verdict},
          {"verdict_key", o.verdict_key},
          {"named_effects", effects},
          {"gates", gates},
          {"gates_passed", o.gates_passed},
          {"predicted_position_rms_m", o.predicted_position_rms_m},
          {"monitoring", monitoring_figures(o)},
          {"iso9283", iso9283_json(o, c)},
          {"fit",
           {{"chi2", o.fit->chi2},
            {"dof", o.fit->dof},
            {"converged", o.fit->converged},
            {"rms_length_m", o.fit->rms_length_m},
            {"rms_laser_m", o.fit->rms_laser_m},
            {"rms_wrench_n", o.fit->rms_wrench_n}}},
          {"standard_fit", {{"chi2", o.standard->chi2}, {"dof", o.standard->dof}}},
          {"frame_anchors", anchors},
          {"length_residuals_normalized", residuals}};
}

json monitoring_figures(const CalibrationOutcome& o) {
  // (predicted_position_rms_m stays 0 when the prediction failed: the gate says why)
  const double position =
      o.predicted_position_rms_m > 0.0 ? o.predicted_position_rms_m : std::nan("");
  return {{"predicted_position_rms_m", finite_or_null(position)},
          {"model_length_m", finite_or_null(o.model_length_m)},
          {"model_force_n", finite_or_null(o.model_force_n)}};
}

std::string calibration_html(const CalibrationOutcome& o, const CalibrationReportContext& c,
                             const std::string& report_page) {
  // The decision first: verdict, gates, next step; then the calibration report the library
  // renders (cdpr-fit's page: anchors before/after with their standard deviations, residuals per
  // cable and pose, the named effects and the residuals against what would explain them).
  std::ostringstream h;
  h << "<section id=\"cdprd-decision\">\n<h1>cdprd calibration " << c.calibration << " of "
    << report::html_escape(o.model.name) << "</h1>\n";
  h << "<p><strong style=\"color:" << (o.gates_passed ? "#060" : "#a00") << "\">"
    << (o.gates_passed ? "Every gate passed"
                       : "Gates failed: " + report::html_escape(o.failed_gates))
    << "</strong>. " << report::html_escape(o.verdict) << "</p>\n";
  h << "<p>Next step: "
    << (o.gates_passed
            ? "<code>cdprctl accept</code> to run on the proposed geometry (every gate passed; "
              "the summary below says what changed), or <code>cdprctl reject</code>."
            : "<code>cdprctl reject</code>, or <code>cdprctl accept</code> only if the failed "
              "gates are understood (the summary and the plots below show why they failed).")
    << "</p>\n";
  h << "<table><tr><th>gate</th><th>result</th><th>detail</th></tr>\n";
  for (const Gate& g : o.gates) {
    h << "<tr><td>" << g.name << "</td><td>" << (g.passed ? "pass" : "<strong>fail</strong>")
      << "</td><td>" << report::html_escape(g.text) << "</td></tr>\n";
  }
  h << "</table>\n<p>" << report::html_escape(c.daemon)
    << "; geometry version before: " << c.geometry_version << "; recording <code>"
    << report::html_escape(std::filesystem::path(c.recording).filename().string()) << "</code>; "
    << o.poses << " poses; started " << report::html_escape(c.started) << ".</p>\n";
  for (const RemeasuredPose& r : c.remeasured) {
    h << "<p>Pose " << r.row + 1 << " was measured again as pose " << r.again + 1 << ": "
      << report::html_escape(r.reading)
      << ". Its first row stays in the recording and is left out of the identification.</p>\n";
  }
  h << "</section>\n" << iso9283_html(o, c);
  std::string page = report_page;
  const std::size_t body = page.find("<body>");
  if (body == std::string::npos)
    return "<!DOCTYPE html>\n<html><body>\n" + h.str() + "</body></html>\n";
  page.insert(body + 6, "\n" + h.str());
  return page;
}

PoseDesignOptions measuring_design_options(const DaemonConfig& c, const RobotModel& model) {
  PoseDesignOptions o;
  o.num_poses = c.measuring.poses;
  o.max_angle = c.measuring.max_angle;
  o.angle_steps = c.measuring.design_angle_steps;
  o.emphasis_weight = c.measuring.design_emphasis_weight;
  // Candidates keep the design margin, at least the planning margin so that no designed pose is
  // dropped below for it.
  o.tension_margin = std::max(c.measuring.design_tension_margin, c.motion.tension_margin);
  fit_design_box_to_robot(model, o);
  return o;
}

ExtraPoseRound extra_pose_round(const Diagnosis& d) {
  ExtraPoseRound r;
  for (const ConfoundedFinding& cf : d.confounded) {
    r.poses.insert(r.poses.end(), cf.separating_poses.begin(), cf.separating_poses.end());
    r.pretensions.insert(r.pretensions.end(), cf.separating_pretensions.begin(),
                         cf.separating_pretensions.end());
  }
  if (d.follow_up) {
    r.poses.insert(r.poses.end(), d.follow_up->poses.begin(), d.follow_up->poses.end());
    r.pretensions.insert(r.pretensions.end(), d.follow_up->pretensions.begin(),
                         d.follow_up->pretensions.end());
    r.confirm_groups = follow_up_groups(d);
    if (d.follow_up->held_back) r.confirm_suspect = d.follow_up->suspect;
  }
  return r;
}

}  // namespace cdpr::controller
