// The calibration report's section "ISO 9283 (position and path)" (calibration_report.hpp).
#include <cmath>
#include <cstdio>
#include <sstream>

#include "cdpr/controller/calibration_report.hpp"
#include "cdpr/io/bounded_read.hpp"
#include "cdpr/report/format.hpp"

namespace cdpr::controller {
namespace {

using json = nlohmann::json;

constexpr std::size_t kMaxFileBytes = 64 * 1024;

std::string mm(double m, const char* f = "%.3f") {
  if (!std::isfinite(m)) return "-";
  char buf[48];
  std::snprintf(buf, sizeof buf, f, m * 1e3);
  return buf;
}

std::string percent(double gain) {
  if (!std::isfinite(gain)) return "-";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%+.0f %%", 100.0 * gain);
  return buf;
}

// 1 - calibrated / nominal: the paper's "position accuracy increased by 58 %".
double gain(double nominal, double calibrated) {
  return nominal > 0.0 ? 1.0 - calibrated / nominal : std::numeric_limits<double>::quiet_NaN();
}

// One row of the measured table: the figure, nominal, calibrated, the paper (calibrated).
struct Row {
  const char* name;
  double report::Iso9283Figures::*value;
  std::string paper;
};

std::vector<Row> rows() {
  const std::string at = mm(report::kPaperPathAccuracyM) + " (path accuracy)";
  const std::string rt = mm(report::kPaperPathRepeatabilityM, "%.2f") + " (path repeatability)";
  return {{"AP, mm", &report::Iso9283Figures::ap_m,
           percent(report::kPaperPositionAccuracyGain) + " position accuracy"},
          {"RP, mm", &report::Iso9283Figures::rp_m, "-"},
          {"AT line, mm", &report::Iso9283Figures::at_line_m, at},
          {"AT circle, mm", &report::Iso9283Figures::at_circle_m, at},
          {"RT line, mm", &report::Iso9283Figures::rt_line_m, rt},
          {"RT circle, mm", &report::Iso9283Figures::rt_circle_m, rt}};
}

// The cells of one row: nominal, calibrated ("-" when nothing was measured).
std::pair<std::string, std::string> cells(const Row& r, const CalibrationReportContext& c) {
  if (!c.iso9283_measured) return {"-", "-"};
  const report::Iso9283Measured& m = *c.iso9283_measured;
  const double n = m.nominal.*r.value, k = m.calibrated.*r.value;
  std::string calibrated = mm(k, "%.4f");
  if (r.value == &report::Iso9283Figures::ap_m) {
    calibrated += " (" + percent(gain(n, k)) + " position accuracy)";
  }
  return {mm(n, "%.4f"), calibrated};
}

std::string predicted_sentence(const CalibrationOutcome& o) {
  const PredictedIsoPosition& p = o.iso9283_predicted;
  if (p.points == 0) {
    return "Predicted position error at ISO 9283's points: not computed (" +
           o.iso9283_predicted_problem + ").";
  }
  return "Predicted, not measured (this calibration's models and the Cramer-Rao bound of its "
         "pose set): position error at ISO 9283's points of the 312 mm cube about home, largest "
         "of " +
         std::to_string(p.points) + ": nominal model " + mm(p.nominal_m) +
         " mm (where its encoder counts take the robot if the calibration is right) -> "
         "calibrated " +
         mm(p.calibrated_m) + " mm (RMS from the parameters' uncertainty), " +
         percent(gain(p.nominal_m, p.calibrated_m)) +
         " position accuracy predicted; the paper measured " +
         percent(report::kPaperPositionAccuracyGain) + ".";
}

std::string measured_sentence(const CalibrationReportContext& c) {
  const std::string how = std::string(
                              "Measured AP, RP, AT, RT come from the virtual robot's true "
                              "pose (the daemon cannot see a real robot's): ") +
                          kIso9283Command +
                          ", then report.iso9283_measured: iso9283.json in the daemon config.";
  if (c.iso9283_file.empty()) return how + " No measured figures are configured.";
  if (!c.iso9283_measured) {
    return how + " The measured figures could not be read: " + c.iso9283_problem;
  }
  return how + " Measured: " + c.iso9283_file +
         (c.iso9283_measured->setup.empty() ? "" : " (" + c.iso9283_measured->setup + ")") + ".";
}

}  // namespace

void load_iso9283_measured(const std::string& path, CalibrationReportContext& c) {
  c.iso9283_file = path;
  c.iso9283_measured.reset();
  c.iso9283_problem.clear();
  if (path.empty()) return;
  const Result<std::string> text = io::read_regular_file(path, kMaxFileBytes);
  if (!text.ok()) {
    c.iso9283_problem = text.status().to_string();
    return;
  }
  Result<report::Iso9283Measured> m = report::parse_iso9283(*text, path);
  if (!m.ok()) {
    c.iso9283_problem = m.status().to_string();
    return;
  }
  c.iso9283_measured = std::move(*m);
}

std::string iso9283_html(const CalibrationOutcome& o, const CalibrationReportContext& c) {
  std::ostringstream h;
  h << "<section id=\"iso9283\">\n<h2>ISO 9283 (position and path)</h2>\n<p>"
    << report::html_escape(predicted_sentence(o)) << "</p>\n<p>"
    << report::html_escape(measured_sentence(c)) << "</p>\n";
  h << "<table><tr><th>figure</th><th>nominal geometry</th><th>calibrated geometry</th>"
       "<th>paper (calibrated)</th></tr>\n";
  for (const Row& r : rows()) {
    const auto [n, k] = cells(r, c);
    h << "<tr><td>" << r.name << "</td><td class=\"n\">" << n << "</td><td class=\"n\">"
      << report::html_escape(k) << "</td><td>" << report::html_escape(r.paper) << "</td></tr>\n";
  }
  h << "</table>\n</section>\n";
  return h.str();
}

std::string iso9283_text(const CalibrationOutcome& o, const CalibrationReportContext& c) {
  std::ostringstream t;
  t << "ISO 9283 (position and path)\n"
    << predicted_sentence(o) << "\n"
    << measured_sentence(c) << "\n";
  for (const Row& r : rows()) {
    const auto [n, k] = cells(r, c);
    t << "  " << r.name << ": nominal " << n << ", calibrated " << k << "; paper " << r.paper
      << "\n";
  }
  return t.str();
}

json iso9283_json(const CalibrationOutcome& o, const CalibrationReportContext& c) {
  const PredictedIsoPosition& p = o.iso9283_predicted;
  json predicted = {{"points", p.points},
                    {"nominal_m", report::number_or_null(p.nominal_m)},
                    {"calibrated_m", report::number_or_null(p.calibrated_m)}};
  if (p.points == 0) predicted["problem"] = o.iso9283_predicted_problem;
  return {{"predicted", predicted},
          {"paper",
           {{"position_accuracy_gain", report::kPaperPositionAccuracyGain},
            {"path_accuracy_m", report::kPaperPathAccuracyM},
            {"path_repeatability_m", report::kPaperPathRepeatabilityM}}},
          {"command", kIso9283Command},
          {"measured_file", c.iso9283_file},
          {"measured", c.iso9283_measured ? report::iso9283_json(*c.iso9283_measured) : json()},
          {"measured_problem", c.iso9283_problem}};
}

}  // namespace cdpr::controller
