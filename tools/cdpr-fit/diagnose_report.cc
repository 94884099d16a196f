#include "diagnose_report.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "cdpr/calibration/kinematics.hpp"
#include "common.hpp"

namespace cdpr::fit {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string printf_string(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}

// "12.3" style with a fixed number of significant digits, "-" for NaN.
std::string num(double v, int digits = 4) {
  if (!std::isfinite(v)) return "-";
  return fmt(v, digits);
}

std::string mm(double metres) {
  return std::isfinite(metres) ? fmt(metres * 1e3, 4) : "-";
}

// The channel value shown to people: mm for lengths, N for forces, as is otherwise.
std::string shown(double v, const std::string& unit) {
  if (unit == "m") return mm(v) + " mm";
  return num(v) + (unit.empty() || unit == "-" ? "" : " " + unit);
}

std::string pose_text(const Pose& p) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "x %.4f y %.4f z %.4f m, roll %.4f pitch %.4f yaw %.4f rad",
                p.position.x(), p.position.y(), p.position.z(), p.rpy.x(), p.rpy.y(), p.rpy.z());
  return buf;
}

double rms_of(const std::vector<double>& v) {
  double s = 0.0;
  int n = 0;
  for (double x : v) {
    if (!std::isfinite(x)) continue;
    s += x * x;
    ++n;
  }
  return n == 0 ? kNaN : std::sqrt(s / n);
}

// The family of a candidate id, from the refitted candidates or the screen.
std::string family_of(const Diagnosis& d, const std::string& id) {
  for (const EffectFit& e : d.candidates) {
    if (e.id == id) return e.family;
  }
  if (const CandidateScreen* c = d.screen.find(id)) return c->family;
  return "";
}

nlohmann::json effect_json(const EffectFit& e) {
  nlohmann::json params = nlohmann::json::array();
  for (const EffectParameter& p : e.parameters) {
    params.push_back({{"name", p.name},
                      {"unit", p.unit},
                      {"value", number_or_null(p.value)},
                      {"std_dev", number_or_null(p.std_dev)},
                      {"text", p.text}});
  }
  return {{"id", e.id},
          {"name", e.name},
          {"family", e.family},
          {"inclusion_probability", number_or_null(e.inclusion_probability)},
          {"family_inclusion_probability", number_or_null(e.family_inclusion_probability)},
          {"extra_parameters", e.extra_parameters},
          {"chi2_before", number_or_null(e.chi2_before)},
          {"chi2_after", number_or_null(e.chi2_after)},
          {"lrt_statistic", number_or_null(e.lrt_statistic)},
          {"lrt_p_value", number_or_null(e.lrt_p_value)},
          {"bic_delta", number_or_null(e.bic_delta)},
          {"cv_rms_before_m", number_or_null(e.cv_rms_before)},
          {"cv_rms_after_m", number_or_null(e.cv_rms_after)},
          {"deviance_before", number_or_null(e.deviance_before)},
          {"deviance_after", number_or_null(e.deviance_after)},
          {"cv_normalized_before", number_or_null(e.cv_normalized_before)},
          {"cv_normalized_after", number_or_null(e.cv_normalized_after)},
          {"accepted", e.accepted},
          {"modelled_in_config", e.modelled_in_config},
          {"parameters", params}};
}

nlohmann::json misfit_json(const MisfitGroup& g) {
  return {{"name", g.name},
          {"count", g.count},
          {"rms_si", number_or_null(g.rms_si)},
          {"unit", g.unit},
          {"rms_normalized", number_or_null(g.rms_normalized)},
          {"chi2", number_or_null(g.chi2)},
          {"expected_chi2", number_or_null(g.expected_chi2)},
          {"ratio", number_or_null(g.ratio)},
          {"p_value", number_or_null(g.p_value)},
          {"flagged", g.flagged}};
}

nlohmann::json report_json(const IdentificationReport& r) {
  return {{"converged", r.converged},
          {"termination", r.termination},
          {"chi2", number_or_null(r.chi2)},
          {"dof", r.dof},
          {"residual_count", r.num_residuals},
          {"parameter_count", r.num_parameters},
          {"rms",
           {{"length_m", number_or_null(r.rms_length_m)},
            {"laser_m", number_or_null(r.rms_laser_m)},
            {"wrench_n", number_or_null(r.rms_wrench_n)}}},
          {"warnings", r.warnings}};
}

nlohmann::json vector_json(const std::vector<double>& v) {
  nlohmann::json a = nlohmann::json::array();
  for (double x : v) a.push_back(number_or_null(x));
  return a;
}

// ---- SVG ------------------------------------------------------------------------------------

struct Range {
  double lo = 0.0, hi = 1.0;
};

Range range_of(const std::vector<const std::vector<double>*>& values) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto* v : values) {
    for (double x : *v) {
      if (!std::isfinite(x)) continue;
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
  }
  if (!(lo <= hi)) return {0.0, 1.0};
  if (hi - lo < 1e-12 * std::max(1.0, std::abs(hi))) {
    const double pad = hi == 0.0 ? 0.5 : std::abs(hi) * 0.05;
    return {lo - pad, hi + pad};
  }
  const double pad = 0.04 * (hi - lo);
  return {lo - pad, hi + pad};
}

// Tick positions at 1, 2 or 5 times a power of ten, about five of them.
std::vector<double> ticks(const Range& r) {
  const double span = r.hi - r.lo;
  const double raw = span / 5.0;
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  double step = p;
  for (double f : {1.0, 2.0, 5.0, 10.0}) {
    step = f * p;
    if (span / step <= 6.0) break;
  }
  std::vector<double> t;
  for (double v = std::ceil(r.lo / step) * step; v <= r.hi + 1e-9 * step; v += step) {
    t.push_back(std::abs(v) < 1e-12 * step ? 0.0 : v);
  }
  return t;
}

struct Frame {
  double left = 64, right = 16, top = 46, bottom = 48;
  double width = 640, height = 340;
  Range x, y;
  double px(double v) const { return left + (v - x.lo) / (x.hi - x.lo) * (width - left - right); }
  double py(double v) const { return top + (y.hi - v) / (y.hi - y.lo) * (height - top - bottom); }
};

std::string coord(double v) {
  return printf_string("%.1f", v);
}

// Axes, grid, tick labels, axis titles and the plot title.
std::string axes(const Frame& f, const std::string& title, const std::string& xlabel,
                 const std::string& ylabel, bool x_ticks = true) {
  std::ostringstream s;
  // About 80 characters fit beside nothing else at this width; longer titles are shortened.
  const std::string shown_title = title.size() > 84 ? title.substr(0, 81) + "..." : title;
  s << "<text x=\"" << coord(f.left) << "\" y=\"18\" class=\"t\">" << html_escape(shown_title)
    << "</text>\n";
  for (double t : ticks(f.y)) {
    s << "<line x1=\"" << coord(f.left) << "\" x2=\"" << coord(f.width - f.right) << "\" y1=\""
      << coord(f.py(t)) << "\" y2=\"" << coord(f.py(t)) << "\" class=\"g\"/>"
      << "<text x=\"" << coord(f.left - 6) << "\" y=\"" << coord(f.py(t) + 4)
      << "\" text-anchor=\"end\">" << html_escape(fmt(t, 4)) << "</text>\n";
  }
  if (x_ticks) {
    for (double t : ticks(f.x)) {
      s << "<line x1=\"" << coord(f.px(t)) << "\" x2=\"" << coord(f.px(t)) << "\" y1=\""
        << coord(f.top) << "\" y2=\"" << coord(f.height - f.bottom) << "\" class=\"g\"/>"
        << "<text x=\"" << coord(f.px(t)) << "\" y=\"" << coord(f.height - f.bottom + 16)
        << "\" text-anchor=\"middle\">" << html_escape(fmt(t, 4)) << "</text>\n";
    }
  }
  s << "<rect x=\"" << coord(f.left) << "\" y=\"" << coord(f.top) << "\" width=\""
    << coord(f.width - f.left - f.right) << "\" height=\"" << coord(f.height - f.top - f.bottom)
    << "\" class=\"a\"/>\n";
  s << "<text x=\"" << coord((f.left + f.width - f.right) / 2) << "\" y=\"" << coord(f.height - 10)
    << "\" text-anchor=\"middle\">" << html_escape(xlabel) << "</text>\n";
  const double cy = (f.top + f.height - f.bottom) / 2;
  s << "<text x=\"14\" y=\"" << coord(cy) << "\" text-anchor=\"middle\" transform=\"rotate(-90 14 "
    << coord(cy) << ")\">" << html_escape(ylabel) << "</text>\n";
  return s.str();
}

std::string horizontal_line(const Frame& f, double y, const std::string& cls) {
  if (y < f.y.lo || y > f.y.hi) return "";
  return "<line x1=\"" + coord(f.left) + "\" x2=\"" + coord(f.width - f.right) + "\" y1=\"" +
         coord(f.py(y)) + "\" y2=\"" + coord(f.py(y)) + "\" class=\"" + cls + "\"/>\n";
}

std::string legend(const Frame& f, const std::vector<std::pair<std::string, std::string>>& items) {
  std::ostringstream s;
  double x = f.width - f.right - 8;
  for (auto it = items.rbegin(); it != items.rend(); ++it) {
    const double w = 14.0 + 7.0 * static_cast<double>(it->first.size());
    x -= w;
    s << "<rect x=\"" << coord(x) << "\" y=\"26\" width=\"10\" height=\"10\" class=\"" << it->second
      << "\"/><text x=\"" << coord(x + 13) << "\" y=\"35\">" << html_escape(it->first)
      << "</text>\n";
  }
  return s.str();
}

// Each plot carries its style, so that it also reads correctly when saved on its own.
constexpr const char* kSvgStyle =
    "<style>text{font-family:sans-serif;font-size:11px;fill:#222}.t{font-size:13px;"
    "font-weight:bold}.g{stroke:#eee}.a{fill:none;stroke:#888}.z{stroke:#444}"
    ".d{stroke:#999;stroke-dasharray:4 3}.b{fill:#1f77b4;fill-opacity:.45;stroke:#1f77b4}"
    ".f{fill:#d62728;fill-opacity:.75;stroke:none}</style>\n";

std::string svg_open(const Frame& f, const std::string& label) {
  return "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + coord(f.width) + "\" height=\"" +
         coord(f.height) + "\" viewBox=\"0 0 " + coord(f.width) + " " + coord(f.height) +
         "\" role=\"img\" aria-label=\"" + html_escape(label) + "\">\n" + kSvgStyle +
         "<rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>\n";
}

std::string scatter_svg(const ResidualPlot& p) {
  Frame f;
  f.x = range_of({&p.x});
  f.y = range_of({&p.before, &p.after});
  f.y.lo = std::min(f.y.lo, -3.0);
  f.y.hi = std::max(f.y.hi, 3.0);
  const std::string xlabel = p.variable + (p.unit.empty() ? "" : " (" + p.unit + ")");
  std::ostringstream s;
  s << svg_open(f, p.title);
  s << axes(f, p.title, xlabel, "length residual / sigma");
  s << horizontal_line(f, 0.0, "z") << horizontal_line(f, 2.0, "d")
    << horizontal_line(f, -2.0, "d");
  auto points = [&](const std::vector<double>& y, const std::string& cls, double r) {
    for (std::size_t k = 0; k < p.x.size() && k < y.size(); ++k) {
      if (!std::isfinite(p.x[k]) || !std::isfinite(y[k])) continue;
      s << "<circle cx=\"" << coord(f.px(p.x[k])) << "\" cy=\"" << coord(f.py(y[k])) << "\" r=\""
        << r << "\" class=\"" << cls << "\"><title>cable " << p.cable[k] + 1 << ": "
        << html_escape(fmt(y[k], 3)) << "</title></circle>\n";
    }
  };
  points(p.before, "b", 3.0);
  points(p.after, "f", 2.2);
  std::vector<std::pair<std::string, std::string>> items = {{"before", "b"}};
  if (!p.after.empty()) items.push_back({"after", "f"});
  s << legend(f, items) << "</svg>\n";
  return s.str();
}

std::string bars_svg(const CableMisfit& m) {
  Frame f;
  f.x = {0.0, static_cast<double>(m.before.size())};
  f.y = range_of({&m.before, &m.after});
  f.y.lo = 0.0;
  f.y.hi = std::max(f.y.hi, 1.5);
  std::ostringstream s;
  const std::string title = "misfit per cable: length residual RMS in sigmas (1 = noise)";
  s << svg_open(f, title) << axes(f, title, "cable", "RMS / sigma", false);
  s << horizontal_line(f, 1.0, "d");
  const double slot = (f.width - f.left - f.right) / std::max<double>(1.0, f.x.hi);
  const bool two = !m.after.empty();
  const double w = slot * (two ? 0.36 : 0.6);
  for (std::size_t i = 0; i < m.before.size(); ++i) {
    const double x0 = f.left + slot * static_cast<double>(i) + slot * (two ? 0.12 : 0.2);
    auto bar = [&](double x, double v, const std::string& cls, const std::string& what) {
      if (!std::isfinite(v)) return;
      s << "<rect x=\"" << coord(x) << "\" y=\"" << coord(f.py(v)) << "\" width=\"" << coord(w)
        << "\" height=\"" << coord(f.py(0.0) - f.py(v)) << "\" class=\"" << cls
        << "\"><title>cable " << i + 1 << " " << what << ": " << html_escape(fmt(v, 3))
        << "</title></rect>\n";
    };
    bar(x0, m.before[i], "b", "before");
    if (two && i < m.after.size()) bar(x0 + w, m.after[i], "f", "after");
    s << "<text x=\"" << coord(f.left + slot * (static_cast<double>(i) + 0.5)) << "\" y=\""
      << coord(f.height - f.bottom + 16) << "\" text-anchor=\"middle\">" << i + 1 << "</text>\n";
  }
  std::vector<std::pair<std::string, std::string>> items = {{"before", "b"}};
  if (two) items.push_back({"after", "f"});
  s << legend(f, items) << "</svg>\n";
  return s.str();
}

// ---- HTML helpers ---------------------------------------------------------------------------

std::string td(const std::string& text, bool numeric = false) {
  return std::string(numeric ? "<td class=\"n\">" : "<td>") + html_escape(text) + "</td>";
}

std::string th(const std::string& text) {
  return "<th>" + html_escape(text) + "</th>";
}

// Extra poses to measure (separating or follow-up) as an HTML table / text lines.
std::string pose_table_html(const std::vector<Pose>& poses,
                            const std::vector<double>& pretensions) {
  std::ostringstream h;
  h << "<table>\n<tr>" << th("x (m)") << th("y (m)") << th("z (m)") << th("roll (rad)")
    << th("pitch (rad)") << th("yaw (rad)") << th("pretension (N)") << "</tr>\n";
  for (std::size_t k = 0; k < poses.size(); ++k) {
    h << "<tr>";
    const auto v = poses[k].vector();
    for (int q = 0; q < 6; ++q) h << td(printf_string("%.4f", v(q)), true);
    h << td(k < pretensions.size() ? num(pretensions[k]) : "-", true) << "</tr>\n";
  }
  h << "</table>\n";
  return h.str();
}

std::string pose_list_text(const std::vector<Pose>& poses, const std::vector<double>& pretensions) {
  std::string out;
  for (std::size_t k = 0; k < poses.size(); ++k) {
    out += "    " + pose_text(poses[k]);
    if (k < pretensions.size()) out += ", pretension " + num(pretensions[k]) + " N";
    out += "\n";
  }
  return out;
}

std::string p_text(double p) {
  return std::isfinite(p) ? fmt(p, 3) : "-";
}

constexpr const char* kStyle = R"(
body{font-family:sans-serif;max-width:1000px;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
.verdict{padding:.6em 1em;border-radius:4px;font-weight:bold}
.v-no_mismatch{background:#e3f4e3}.v-mismatch_named,.v-mismatch_unexplained{background:#fde8d7}
.v-inconclusive{background:#eee}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 8px}
th{background:#f4f4f4}td.n{text-align:right;font-variant-numeric:tabular-nums}
tr.acc td{font-weight:bold}
svg{display:block;margin:.5em 0}
.small{color:#555;font-size:.9em}
)";

}  // namespace

std::string html_escape(const std::string& s) {
  std::string o;
  o.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&':
        o += "&amp;";
        break;
      case '<':
        o += "&lt;";
        break;
      case '>':
        o += "&gt;";
        break;
      case '"':
        o += "&quot;";
        break;
      case '\'':
        o += "&#39;";
        break;
      default:
        o += c;
    }
  }
  return o;
}

std::string verdict_key(Diagnosis::Verdict v) {
  switch (v) {
    case Diagnosis::Verdict::kNoMismatch:
      return "no_mismatch";
    case Diagnosis::Verdict::kMismatchNamed:
      return "mismatch_named";
    case Diagnosis::Verdict::kMismatchUnexplained:
      return "mismatch_unexplained";
    case Diagnosis::Verdict::kInconclusive:
      return "inconclusive";
  }
  return "unknown";
}

ExplainingVariable explaining_variable(const std::string& family) {
  if (family == "elasticity" || family == "nonlinear elasticity") {
    return {"tension x loaded length", "N m"};
  }
  if (family == "compliance" || family == "force sensor gain" || family == "force sensor offset") {
    return {"tension", "N"};
  }
  if (family == "drum scale") return {"loaded length", "m"};
  if (family == "encoder drift" || family == "transmission drift" || family == "creep") {
    return {"time", "s"};
  }
  return {"pose index", ""};
}

std::vector<ResidualPlot> residual_plots(const Diagnosis& d, const MeasurementSet& set) {
  // The effects to plot: accepted ones, else the top refitted candidate, else the top screened.
  std::vector<std::pair<std::string, std::string>> effects;  // id, name
  for (const EffectFit& e : d.accepted) effects.push_back({e.id, e.name});
  if (effects.empty() && !d.candidates.empty()) {
    effects.push_back({d.candidates.front().id, d.candidates.front().name});
  }
  if (effects.empty() && !d.screen.candidates.empty() && !d.screen.candidates.front().modelled) {
    effects.push_back({d.screen.candidates.front().id, d.screen.candidates.front().name});
  }
  if (effects.empty()) effects.push_back({"", "length residuals"});

  const RobotModel& robot = d.before.estimate.robot;
  const int m = robot.num_cables();
  KinematicsData kin(m);
  std::vector<ResidualPlot> plots;
  for (const auto& [id, name] : effects) {
    ResidualPlot p;
    p.effect_id = id;
    p.title = id.empty() ? name : name + " [" + id + "]";
    const ExplainingVariable var = explaining_variable(family_of(d, id));
    p.variable = var.name;
    p.unit = var.unit;
    const bool have_after =
        d.after.has_value() && d.after->residuals.size() == d.before.residuals.size();
    const std::size_t n = std::min(set.poses.size(), d.before.residuals.size());
    for (std::size_t j = 0; j < n; ++j) {
      const PoseMeasurement& meas = set.poses[j];
      const bool ik_ok =
          j < d.before.poses.size() && inverse_kinematics(robot, d.before.poses[j], kin);
      const Eigen::VectorXd& rb = d.before.residuals[j].length_normalized;
      for (int i = 0; i < m && i < rb.size(); ++i) {
        if (!std::isfinite(rb(i))) continue;
        const double tension =
            meas.tensions.size() > i ? meas.tensions(i) : std::numeric_limits<double>::quiet_NaN();
        const double loaded =
            ik_ok ? robot.cables[static_cast<std::size_t>(i)].routing_length + kin.lengths(i)
                  : kNaN;
        double x = static_cast<double>(j);
        if (var.name == "tension x loaded length") {
          x = tension * loaded;
        } else if (var.name == "tension") {
          x = tension;
        } else if (var.name == "loaded length") {
          x = loaded;
        } else if (var.name == "time") {
          x = std::isfinite(meas.time) ? meas.time : kNaN;
        }
        if (!std::isfinite(x)) continue;
        p.x.push_back(x);
        p.cable.push_back(i);
        p.before.push_back(rb(i));
        if (have_after) {
          const Eigen::VectorXd& ra = d.after->residuals[j].length_normalized;
          p.after.push_back(i < ra.size() ? ra(i) : kNaN);
        }
      }
    }
    if (p.x.empty() && var.name != "pose index") {
      // The variable is not available (no tensions, no time): fall back to the pose index.
      ResidualPlot q;
      q.effect_id = p.effect_id;
      q.title = p.title + " (" + var.name + " not recorded)";
      q.variable = "pose index";
      for (std::size_t j = 0; j < n; ++j) {
        const Eigen::VectorXd& rb = d.before.residuals[j].length_normalized;
        for (int i = 0; i < rb.size(); ++i) {
          if (!std::isfinite(rb(i))) continue;
          q.x.push_back(static_cast<double>(j));
          q.cable.push_back(i);
          q.before.push_back(rb(i));
          if (have_after) {
            const Eigen::VectorXd& ra = d.after->residuals[j].length_normalized;
            q.after.push_back(i < ra.size() ? ra(i) : kNaN);
          }
        }
      }
      p = std::move(q);
    }
    plots.push_back(std::move(p));
  }
  return plots;
}

CableMisfit cable_misfit(const Diagnosis& d, int num_cables) {
  auto per_cable = [&](const std::vector<PoseResiduals>& res) {
    std::vector<double> out;
    for (int i = 0; i < num_cables; ++i) {
      std::vector<double> v;
      for (const PoseResiduals& r : res) {
        if (i < r.length_normalized.size()) v.push_back(r.length_normalized(i));
      }
      out.push_back(rms_of(v));
    }
    return out;
  };
  CableMisfit m;
  m.before = per_cable(d.before.residuals);
  if (d.after) m.after = per_cable(d.after->residuals);
  return m;
}

nlohmann::json diagnosis_json(const Diagnosis& d, const DiagnoseContext& c,
                              const CableMisfit& misfit) {
  nlohmann::json candidates = nlohmann::json::array();
  for (const EffectFit& e : d.candidates) candidates.push_back(effect_json(e));
  nlohmann::json accepted = nlohmann::json::array();
  for (const EffectFit& e : d.accepted) accepted.push_back(effect_json(e));
  nlohmann::json confounded = nlohmann::json::array();
  for (const ConfoundedFinding& f : d.confounded) {
    nlohmann::json poses = nlohmann::json::array();
    for (const Pose& p : f.separating_poses) poses.push_back(to_json(Eigen::VectorXd(p.vector())));
    confounded.push_back({{"first", f.first},
                          {"second", f.second},
                          {"correlation", number_or_null(f.correlation)},
                          {"description", f.description},
                          {"first_fit", effect_json(f.first_fit)},
                          {"second_fit", effect_json(f.second_fit)},
                          {"separating_poses", poses},
                          {"separating_pretensions_n", vector_json(f.separating_pretensions)},
                          {"correlation_with_extra", number_or_null(f.correlation_with_extra)}});
  }
  nlohmann::json follow_up = nullptr;
  if (d.follow_up) {
    const FollowUp& f = *d.follow_up;
    nlohmann::json poses = nlohmann::json::array();
    for (const Pose& p : f.poses) poses.push_back(to_json(Eigen::VectorXd(p.vector())));
    follow_up = {{"suspect", f.suspect},
                 {"name", f.name},
                 {"parameters", f.parameters},
                 {"p_value", number_or_null(f.p_value)},
                 {"p_adjusted", number_or_null(f.p_adjusted)},
                 {"poses", poses},
                 {"pretensions_n", vector_json(f.pretensions)},
                 {"log_det_information_before", number_or_null(f.information_before)},
                 {"log_det_information_after", number_or_null(f.information_after)}};
  }
  nlohmann::json channels = nlohmann::json::array();
  for (const ChannelRms& ch : d.channels) {
    channels.push_back({{"channel", ch.channel},
                        {"unit", ch.unit},
                        {"before", number_or_null(ch.before)},
                        {"after", number_or_null(ch.after)}});
  }
  nlohmann::json screen_candidates = nlohmann::json::array();
  for (const CandidateScreen& s : d.screen.candidates) {
    screen_candidates.push_back({{"id", s.id},
                                 {"name", s.name},
                                 {"family", s.family},
                                 {"rank", s.rank},
                                 {"modelled", s.modelled},
                                 {"statistic", number_or_null(s.statistic)},
                                 {"p_value", number_or_null(s.p_value)},
                                 {"p_adjusted", number_or_null(s.p_adjusted)},
                                 {"explained_fraction", number_or_null(s.explained_fraction)},
                                 {"bic_delta", number_or_null(s.bic_delta)},
                                 {"significant", s.significant}});
  }
  nlohmann::json screen_channels = nlohmann::json::array();
  for (const MisfitGroup& g : d.screen.channels) screen_channels.push_back(misfit_json(g));
  nlohmann::json screen_cables = nlohmann::json::array();
  for (const MisfitGroup& g : d.screen.cables) screen_cables.push_back(misfit_json(g));
  nlohmann::json structure = nlohmann::json::array();
  for (const StructureTest& t : d.screen.structure) {
    if (!t.significant) continue;
    structure.push_back(
        {{"variable", t.variable},
         {"cable", t.cable < 0 ? nlohmann::json("all") : nlohmann::json(t.cable + 1)},
         {"f_statistic", number_or_null(t.f_statistic)},
         {"p_value", number_or_null(t.p_value)},
         {"explained_fraction", number_or_null(t.explained_fraction)}});
  }
  nlohmann::json named = nlohmann::json::array();
  for (const EffectFit& e : d.accepted) named.push_back(e.id);
  return {
      {"command", "diagnose"},
      {"inputs",
       {{"config", c.config},
        {"config_hash", c.config_hash},
        {"recording", c.recording},
        {"recording_hash", c.recording_hash},
        {"validation",
         c.validation.empty() ? nlohmann::json(nullptr) : nlohmann::json(c.validation)},
        {"validation_hash",
         c.validation.empty() ? nlohmann::json(nullptr) : nlohmann::json(c.validation_hash)},
        {"poses", c.poses},
        {"cables", c.cables},
        {"lasers", c.lasers}}},
      {"options",
       {{"estimate", c.estimated},
        {"seed", c.seed},
        {"bootstrap", c.bootstrap},
        {"folds", c.folds}}},
      {"verdict", verdict_key(d.verdict)},
      {"mismatch_found", d.mismatch_found()},
      {"headline", d.headline},
      {"findings", d.findings},
      {"named_effects", named},
      {"accepted", accepted},
      {"candidates", candidates},
      {"confounded", confounded},
      {"follow_up", follow_up},
      {"channels", channels},
      {"held_out",
       {{"source", d.held_out_source},
        {"rms_before_m", number_or_null(d.held_out_rms_before)},
        {"rms_after_m", number_or_null(d.held_out_rms_after)}}},
      {"cable_misfit_normalized",
       {{"before", vector_json(misfit.before)}, {"after", vector_json(misfit.after)}}},
      {"before", report_json(d.before)},
      {"after", d.after ? report_json(*d.after) : nlohmann::json(nullptr)},
      {"screen",
       {{"chi2", number_or_null(d.screen.chi2)},
        {"residual_count", d.screen.num_residuals},
        {"jacobian_rank", d.screen.jacobian_rank},
        {"dof", d.screen.dof},
        {"p_value", number_or_null(d.screen.p_value)},
        {"channels", screen_channels},
        {"cables", screen_cables},
        {"significant_structure", structure},
        {"candidates", screen_candidates}}},
      {"calibrated_config",
       c.calibrated_config.empty() ? nlohmann::json(nullptr) : nlohmann::json(c.calibrated_config)},
      {"warnings", c.warnings},
  };
}

std::string diagnosis_text(const Diagnosis& d, const DiagnoseContext& c) {
  std::ostringstream h;
  h << "cdpr-fit diagnose: " << c.config << " + " << c.recording << " (" << c.poses << " poses, "
    << c.cables << " cables, " << c.lasers << " laser" << (c.lasers == 1 ? "" : "s") << ")\n";
  if (!c.validation.empty()) h << "validation recording: " << c.validation << "\n";
  h << "\nverdict: " << verdict_key(d.verdict) << "\n" << d.headline << "\n";
  if (!d.findings.empty()) {
    h << "\nFindings:\n";
    for (const std::string& f : d.findings) h << "  - " << f << "\n";
  }
  if (!d.accepted.empty()) {
    h << "\nNamed effects:\n";
    for (const EffectFit& e : d.accepted) {
      h << "  " << e.name << " [" << e.id << "]" << (e.modelled_in_config ? "" : " (report only)")
        << "\n";
      for (const EffectParameter& p : e.parameters) {
        h << "      " << (p.text.empty() ? p.name + " = " + num(p.value) : p.text) << "\n";
      }
    }
  }
  char line[200];
  if (!d.channels.empty()) {
    h << "\nResidual RMS per channel:\n";
    std::snprintf(line, sizeof line, "  %-24s %14s %14s\n", "channel", "before", "after");
    h << line;
    for (const ChannelRms& ch : d.channels) {
      std::snprintf(line, sizeof line, "  %-24s %14s %14s\n", ch.channel.c_str(),
                    shown(ch.before, ch.unit).c_str(), shown(ch.after, ch.unit).c_str());
      h << line;
    }
  }
  if (!d.held_out_source.empty()) {
    h << "\nHeld-out length RMS (" << d.held_out_source << "): " << mm(d.held_out_rms_before)
      << " mm before, " << mm(d.held_out_rms_after) << " mm after\n";
  }
  if (!d.candidates.empty()) {
    h << "\nCandidates (refitted, best first):\n";
    std::snprintf(line, sizeof line, "  %-30s %6s %10s %9s %12s %12s %4s\n", "id", "P(in)", "LRT p",
                  "dBIC", "CV before mm", "CV after mm", "");
    h << line;
    for (const EffectFit& e : d.candidates) {
      std::snprintf(line, sizeof line, "  %-30s %6.2f %10s %9.1f %12s %12s %4s\n", e.id.c_str(),
                    e.inclusion_probability, p_text(e.lrt_p_value).c_str(), e.bic_delta,
                    mm(e.cv_rms_before).c_str(), mm(e.cv_rms_after).c_str(),
                    e.accepted ? "yes" : "");
      h << line;
    }
  } else if (!d.screen.candidates.empty()) {
    h << "\nCandidates (screen only, best first):\n";
    std::snprintf(line, sizeof line, "  %-30s %10s %9s %10s\n", "id", "p (Holm)", "dBIC",
                  "explained");
    h << line;
    for (const CandidateScreen& s : d.screen.candidates) {
      if (s.modelled) continue;
      std::snprintf(line, sizeof line, "  %-30s %10s %9.1f %9.1f%%\n", s.id.c_str(),
                    p_text(s.p_adjusted).c_str(), s.bic_delta, 100.0 * s.explained_fraction);
      h << line;
    }
  }
  for (const ConfoundedFinding& f : d.confounded) {
    h << "\nConfounded: " << f.first << " / " << f.second << " (correlation "
      << num(f.correlation, 3) << ")\n  " << f.description << "\n";
    if (!f.separating_poses.empty()) {
      h << "  poses that would separate them (correlation " << num(f.correlation_with_extra, 3)
        << " with them):\n";
      h << pose_list_text(f.separating_poses, f.separating_pretensions);
    }
  }
  if (d.follow_up) {
    h << "\nSuspected, not proven: " << d.follow_up->suspect << " (p "
      << num(d.follow_up->p_value, 3) << " alone, " << num(d.follow_up->p_adjusted, 3)
      << " after Holm). Follow-up poses that would decide it:\n"
      << pose_list_text(d.follow_up->poses, d.follow_up->pretensions);
  }
  if (!c.warnings.empty()) {
    h << "\nWarnings:\n";
    for (const std::string& w : c.warnings) h << "  - " << w << "\n";
  }
  return h.str();
}

std::string diagnosis_html(const Diagnosis& d, const DiagnoseContext& c,
                           const std::vector<ResidualPlot>& plots, const CableMisfit& misfit) {
  std::ostringstream h;
  const std::string key = verdict_key(d.verdict);
  h << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
    << "<title>cdpr-fit diagnose: " << html_escape(c.recording) << "</title>\n<style>" << kStyle
    << "</style>\n</head>\n<body>\n";
  h << "<h1>Mismatch diagnosis</h1>\n<p class=\"small\">config " << html_escape(c.config) << " ("
    << html_escape(c.config_hash) << "), recording " << html_escape(c.recording) << " ("
    << html_escape(c.recording_hash) << "), " << c.poses << " poses, " << c.cables << " cables, "
    << c.lasers << (c.lasers == 1 ? " laser" : " lasers");
  if (!c.validation.empty()) h << ", validation " << html_escape(c.validation);
  h << "; estimated:";
  for (const std::string& e : c.estimated) h << " " << html_escape(e);
  h << "; seed " << c.seed << ", bootstrap " << c.bootstrap << ", folds " << c.folds << "</p>\n";
  h << "<p class=\"verdict v-" << key << "\">" << html_escape(key) << ": "
    << html_escape(d.headline) << "</p>\n";

  if (!d.findings.empty()) {
    h << "<h2>Findings</h2>\n<ul>\n";
    for (const std::string& f : d.findings) h << "<li>" << html_escape(f) << "</li>\n";
    h << "</ul>\n";
  }
  if (!d.accepted.empty()) {
    h << "<h2>Named effects</h2>\n<ul>\n";
    for (const EffectFit& e : d.accepted) {
      h << "<li><b>" << html_escape(e.name) << "</b> [" << html_escape(e.id) << "]"
        << (e.modelled_in_config ? "" : " (reported only, the config cannot carry it)");
      if (!e.parameters.empty()) {
        h << "<ul>";
        for (const EffectParameter& p : e.parameters) {
          h << "<li>" << html_escape(p.text.empty() ? p.name + " = " + num(p.value) : p.text)
            << "</li>";
        }
        h << "</ul>";
      }
      h << "</li>\n";
    }
    h << "</ul>\n";
  }

  h << "<h2>Residuals against the explaining variable</h2>\n"
    << "<p class=\"small\">Normalised cable-length residuals (residual / sigma) of the standard "
       "identification (before) and with the accepted effects modelled (after). Dashed: "
       "&plusmn;2 sigma.</p>\n";
  bool any_points = false;
  for (const ResidualPlot& p : plots) {
    if (p.x.empty()) continue;
    h << scatter_svg(p);
    any_points = true;
  }
  if (!any_points) h << "<p>No residuals to plot (the standard identification was not run).</p>\n";
  bool any_misfit = false;
  for (double v : misfit.before) any_misfit = any_misfit || std::isfinite(v);
  if (any_misfit) h << "<h2>Misfit per cable</h2>\n" << bars_svg(misfit);

  if (!d.channels.empty()) {
    h << "<h2>Residual RMS per channel</h2>\n<table>\n<tr>" << th("channel") << th("before")
      << th("after") << "</tr>\n";
    for (const ChannelRms& ch : d.channels) {
      h << "<tr>" << td(ch.channel) << td(shown(ch.before, ch.unit), true)
        << td(shown(ch.after, ch.unit), true) << "</tr>\n";
    }
    h << "</table>\n";
  }
  if (!d.held_out_source.empty()) {
    h << "<p>Held-out length RMS (" << html_escape(d.held_out_source)
      << "): " << html_escape(mm(d.held_out_rms_before)) << " mm before, "
      << html_escape(mm(d.held_out_rms_after)) << " mm after.</p>\n";
  }

  if (!d.candidates.empty()) {
    h << "<h2>Candidates (refitted)</h2>\n<table>\n<tr>" << th("candidate") << th("inclusion")
      << th("LRT p") << th("dBIC") << th("CV RMS before (mm)") << th("CV RMS after (mm)")
      << th("accepted") << "</tr>\n";
    for (const EffectFit& e : d.candidates) {
      h << "<tr" << (e.accepted ? " class=\"acc\"" : "") << ">" << td(e.name + " [" + e.id + "]")
        << td(num(e.inclusion_probability, 3), true) << td(p_text(e.lrt_p_value), true)
        << td(num(e.bic_delta, 4), true) << td(mm(e.cv_rms_before), true)
        << td(mm(e.cv_rms_after), true) << td(e.accepted ? "yes" : "") << "</tr>\n";
    }
    h << "</table>\n";
  }
  if (!d.screen.candidates.empty()) {
    h << "<h2>Screen (added-variable tests)</h2>\n<table>\n<tr>" << th("candidate") << th("rank")
      << th("p (Holm)") << th("explained") << th("dBIC") << "</tr>\n";
    for (const CandidateScreen& s : d.screen.candidates) {
      h << "<tr>" << td(s.name + " [" + s.id + "]") << td(std::to_string(s.rank), true)
        << td(s.modelled ? "modelled" : p_text(s.p_adjusted), true)
        << td(num(100.0 * s.explained_fraction, 3) + " %", true) << td(num(s.bic_delta, 4), true)
        << "</tr>\n";
    }
    h << "</table>\n";
  }
  if (!d.confounded.empty()) {
    h << "<h2>Confounded pairs</h2>\n";
    for (const ConfoundedFinding& f : d.confounded) {
      h << "<p><b>" << html_escape(f.first) << "</b> / <b>" << html_escape(f.second)
        << "</b>, canonical correlation " << html_escape(num(f.correlation, 3)) << ": "
        << html_escape(f.description) << "</p>\n";
      if (!f.separating_poses.empty()) {
        h << "<p>Extra poses that would separate them (correlation "
          << html_escape(num(f.correlation_with_extra, 3)) << " with them added):</p>\n"
          << pose_table_html(f.separating_poses, f.separating_pretensions);
      }
    }
  }
  if (d.follow_up) {
    h << "<h2>Suspected, not proven</h2>\n<p><b>" << html_escape(d.follow_up->name)
      << "</b>: p = " << html_escape(num(d.follow_up->p_value, 3)) << " alone, "
      << html_escape(num(d.follow_up->p_adjusted, 3))
      << " after Holm's correction over the candidates. Measure these poses, append them to the "
         "recording and diagnose again to decide:</p>\n"
      << pose_table_html(d.follow_up->poses, d.follow_up->pretensions);
  }
  if (!c.warnings.empty()) {
    h << "<h2>Warnings</h2>\n<ul>\n";
    for (const std::string& w : c.warnings) h << "<li>" << html_escape(w) << "</li>\n";
    h << "</ul>\n";
  }
  if (!c.calibrated_config.empty()) {
    h << "<p class=\"small\">Calibrated config: " << html_escape(c.calibrated_config) << "</p>\n";
  }
  h << "</body>\n</html>\n";
  return h.str();
}

}  // namespace cdpr::fit
