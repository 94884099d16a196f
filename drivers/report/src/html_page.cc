// The HTML page of the calibration report, designed for the decision "accept this calibration or
// not": the first screen holds the verdict and the next step, the named effects (value +- std,
// share of the misfit explained), the largest anchor change with its uncertainty, the predicted
// position accuracy before/after over the ISO 9283 box and chi^2/dof with its p-value. Then the
// plots (residuals per cable and pose, residuals against what the named effect follows, anchor
// changes on a top and a side view with uncertainty ellipses, the measured poses in the
// workspace), then the tables, with everything that does not bear on the decision folded in
// <details>. No script, nothing fetched; each plot has a text alternative and a table.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>
#include <sstream>
#include <string>

#include "cdpr/calibration/mismatch.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/residual_explanation.hpp"
#include "cdpr/report/format.hpp"
#include "report_internal.hpp"
#include "svg.hpp"

namespace cdpr::report {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string num(double v, int digits = 4) {
  return std::isfinite(v) ? fmt(v, digits) : "-";
}

std::string mm(double metres, int digits = 4) {
  return std::isfinite(metres) ? fmt(metres * 1e3, digits) : "-";
}

std::string p_text(double p) {
  if (!std::isfinite(p)) return "-";
  if (p < 1e-16) return "< 1e-16";
  return fmt(p, 3);
}

std::string shown(double v, const std::string& unit) {
  if (!std::isfinite(v)) return "-";
  if (unit == "m") return mm(v, 3) + " mm";
  return num(v, 3) + (unit.empty() || unit == "-" ? "" : " " + unit);
}

std::string pct(double fraction) {
  return std::isfinite(fraction) ? fmt(100.0 * fraction, 3) + " %" : "-";
}

int pose_number(const ReportContext& c, std::size_t row) {
  return row < c.pose_indices.size() ? c.pose_indices[row] : static_cast<int>(row);
}

// RMS of the cable-length residuals (m) per cable, NaN where a cable has none.
std::vector<double> cable_rms_m(const std::vector<PoseResiduals>& residuals, int num_cables) {
  std::vector<double> out;
  for (int i = 0; i < num_cables; ++i) {
    double sum = 0.0;
    int n = 0;
    for (const PoseResiduals& r : residuals) {
      if (i >= r.length_m.size() || !std::isfinite(r.length_m(i))) continue;
      sum += r.length_m(i) * r.length_m(i);
      ++n;
    }
    out.push_back(n == 0 ? kNaN : std::sqrt(sum / n));
  }
  return out;
}

// The 3 x 3 covariance (m^2) of frame anchor `cable` in `fit`; false when not estimated.
bool anchor_covariance(const IdentificationReport* fit, int cable, Eigen::Matrix3d* cov) {
  if (fit == nullptr) return false;
  int idx[3] = {-1, -1, -1};
  for (std::size_t q = 0; q < fit->parameters.size(); ++q) {
    const ParameterId& id = fit->parameters[q].id;
    if (id.kind != ParameterKind::kFrameAnchor || id.index != cable) continue;
    if (id.component >= 0 && id.component < 3) idx[id.component] = static_cast<int>(q);
  }
  cov->setZero();
  bool any = false;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) {
      if (idx[a] < 0 || idx[b] < 0) continue;
      if (idx[a] >= fit->covariance.rows() || idx[b] >= fit->covariance.cols()) continue;
      (*cov)(a, b) = fit->covariance(idx[a], idx[b]);
      any = true;
    }
  }
  if (!any) {
    // No covariance matrix: the standard deviations alone.
    for (int a = 0; a < 3; ++a) {
      if (idx[a] < 0) continue;
      const double s = fit->parameters[static_cast<std::size_t>(idx[a])].std_dev;
      if (std::isfinite(s)) {
        (*cov)(a, a) = s * s;
        any = true;
      }
    }
  }
  return any;
}

// The predicted position accuracy over the ISO 9283 box.
struct Accuracy {
  bool computed = false;
  std::string why_not;
  double before_rms = kNaN, before_max = kNaN;  // the nominal model, if the calibration is right
  double after_rms = kNaN, after_max = kNaN;    // Cramer-Rao bound of the recorded pose set
  int grid_points = 0;
  AccuracyBox box;
};

Accuracy accuracy_of(const PageInput& in) {
  Accuracy a;
  const ReportContext& c = *in.context;
  if (!c.identification) {
    a.why_not = "not computed (the identification options were not given)";
    return a;
  }
  a.box.center = in.before->home.position;
  const CalibratedModel before = CalibratedModel::from_robot(*in.before);
  PredictedAccuracyOptions po;
  po.identification = *c.identification;
  po.box = a.box;
  std::vector<Pose> poses;
  for (const PoseMeasurement& p : in.set->poses) poses.push_back(p.commanded);
  // As the daemon's gate: the pose set was planned feasible for the model it was measured with.
  auto predicted = predict_accuracy(before, poses, in.set->noise, po);
  if (!predicted.ok()) predicted = predict_accuracy(*in.after, poses, in.set->noise, po);
  auto realised = measure_position_accuracy(*in.after, before, a.box);
  if (!predicted.ok() && !realised.ok()) {
    a.why_not = "unavailable: " + predicted.status().to_string();
    return a;
  }
  a.computed = true;
  if (predicted.ok()) {
    a.after_rms = predicted->position_rms_m;
    a.after_max = predicted->position_max_m;
    a.grid_points = predicted->grid_points;
  }
  if (realised.ok()) {
    a.before_rms = realised->position_rms_m;
    a.before_max = realised->position_max_m;
    a.grid_points = std::max(a.grid_points, realised->grid_points);
  }
  return a;
}

// The largest frame-anchor change and its standard deviation along the change.
struct AnchorChange {
  int cable = -1;
  double change = 0.0;    // m
  double std_dev = kNaN;  // m, along the change
  int moved = 0;          // anchors that moved by more than 2 standard deviations
};

AnchorChange largest_change(const PageInput& in) {
  AnchorChange out;
  const int m = in.before->num_cables();
  for (int i = 0; i < m && i < in.after->robot.num_cables(); ++i) {
    const Eigen::Vector3d d =
        in.after->robot.frame_anchors.col(i) - in.before->frame_anchors.col(i);
    Eigen::Matrix3d cov;
    const bool has = anchor_covariance(in.fit, i, &cov);
    const double n = d.norm();
    const double s = has && n > 0 ? std::sqrt(std::max(0.0, (d / n).dot(cov * (d / n)))) : kNaN;
    if (std::isfinite(s) && n > 2.0 * s) ++out.moved;
    if (n > out.change || out.cable < 0) {
      out.cable = i;
      out.change = n;
      out.std_dev = s;
    }
  }
  return out;
}

// Confounded pairs that bear on the verdict: one of them is named or is the suspect.
bool matters(const ConfoundedFinding& f, const Diagnosis& d) {
  std::set<std::string> ids;
  for (const EffectFit& e : d.accepted) ids.insert(e.id);
  if (d.follow_up) ids.insert(d.follow_up->suspect);
  return ids.count(f.first) > 0 || ids.count(f.second) > 0;
}

// The pairs the diagnosis reports (with both fits and separating poses) and the other pairs the
// screen found confounded, as rows of one kind.
struct PairRow {
  std::string first, second;  // plain language
  double correlation = kNaN;
  std::string fits, extra;  // chi^2 of both fits; extra poses and the correlation with them
  bool matters = false;
  const ConfoundedFinding* finding = nullptr;
};

std::vector<PairRow> pair_rows(const Diagnosis& d) {
  std::set<std::string> ids;
  for (const EffectFit& e : d.accepted) ids.insert(e.id);
  if (d.follow_up) ids.insert(d.follow_up->suspect);
  auto name_of = [&](const std::string& id) {
    const CandidateScreen* s = d.screen.find(id);
    return s != nullptr && !s->name.empty() ? s->name : id;
  };
  std::vector<PairRow> rows;
  std::set<std::pair<std::string, std::string>> seen;
  for (const ConfoundedFinding& f : d.confounded) {
    PairRow r;
    r.first = f.first_fit.name.empty() ? name_of(f.first) : f.first_fit.name;
    r.second = f.second_fit.name.empty() ? name_of(f.second) : f.second_fit.name;
    r.correlation = f.correlation;
    r.fits = num(f.first_fit.chi2_after, 5) + " / " + num(f.second_fit.chi2_after, 5);
    r.extra = f.separating_poses.empty() ? "-"
                                         : std::to_string(f.separating_poses.size()) +
                                               " poses: " + num(f.correlation_with_extra, 4);
    r.matters = matters(f, d);
    r.finding = &f;
    rows.push_back(r);
    seen.insert({f.first, f.second});
    seen.insert({f.second, f.first});
  }
  for (const ConfoundedPair& c : d.screen.confounded) {
    if (seen.count({c.first, c.second}) > 0) continue;
    PairRow r;
    r.first = name_of(c.first);
    r.second = name_of(c.second);
    r.correlation = c.correlation;
    r.fits = "not refitted";
    r.extra = "-";
    r.matters = ids.count(c.first) > 0 || ids.count(c.second) > 0;
    rows.push_back(r);
  }
  return rows;
}

// What to do next, in one or two sentences.
std::string next_step(const PageInput& in, double p) {
  const ReportContext& c = *in.context;
  const Diagnosis* d = in.diagnosis;
  if (in.fit == nullptr) {
    return "Do not accept: no identification was run on this recording. Record more poses "
           "(at least 12) and run it again.";
  }
  if (!in.fit->converged) {
    return "Do not accept: the solver did not converge. Check the recording (see the warnings "
           "below) and run it again.";
  }
  std::string extra;
  if (!c.warnings.empty()) extra = " Read the warnings at the end of the page first.";
  if (d == nullptr) {
    if (p < 1e-3) {
      return "Do not accept yet: the model does not explain the recording within the noise "
             "(p < 0.001). Run cdpr-fit diagnose on this recording to find what is missing." +
             extra;
    }
    return "Accept the calibrated model: the fit is consistent with the sensor noise." + extra;
  }
  int relevant = 0;
  for (const PairRow& r : pair_rows(*d)) relevant += r.matters ? 1 : 0;
  const std::string confounded =
      relevant > 0
          ? " Before relying on the named effect, measure the separating poses of the " +
                std::to_string(relevant) + " confounded pair" + (relevant == 1 ? "" : "s") +
                " below: this pose set cannot tell them apart."
          : "";
  switch (d->verdict) {
    case Diagnosis::Verdict::kNoMismatch: {
      std::string s = "Accept the calibrated model: no missing physics found.";
      if (d->follow_up) {
        s += " Optionally measure the " + std::to_string(d->follow_up->poses.size()) +
             " follow-up poses below to decide the suspect (" + d->follow_up->name + ").";
      }
      return s + extra;
    }
    case Diagnosis::Verdict::kMismatchNamed: {
      std::string not_carried;
      for (const EffectFit& e : d->accepted) {
        if (!e.modelled_in_config) not_carried += (not_carried.empty() ? "" : ", ") + e.name;
      }
      if (!not_carried.empty()) {
        return "Accept with care: the calibrated model carries the named effects except " +
               not_carried + " (the config has no field for it; compensate it elsewhere)." +
               confounded + extra;
      }
      return "Accept the calibrated model: it carries the named effect" +
             std::string(d->accepted.size() == 1 ? "" : "s") + "." + confounded + extra;
    }
    case Diagnosis::Verdict::kMismatchUnexplained:
      return "Do not accept: the model does not explain the recording and no candidate effect "
             "does. Look at the residual heat map for the cables and poses where the misfit sits, "
             "check those sensors and the recording, then measure again." +
             extra;
    case Diagnosis::Verdict::kInconclusive:
      if (d->follow_up) {
        return "Do not decide yet: measure the " + std::to_string(d->follow_up->poses.size()) +
               " follow-up poses below, append them to the recording and diagnose again." + extra;
      }
      return "Do not decide yet: the recording is too small to tell the effects apart. Record "
             "more poses (at least 12) and diagnose again." +
             extra;
  }
  return extra;
}

std::string verdict_html(const PageInput& in, double p) {
  const Diagnosis* d = in.diagnosis;
  std::ostringstream h;
  if (d != nullptr) {
    const std::string key = verdict_key(d->verdict);
    h << "<p class=\"verdict v-" << key << "\" id=\"verdict\">" << html_escape(key) << ": "
      << html_escape(d->headline) << "</p>\n";
  } else {
    const IdentificationReport& r = *in.fit;
    const bool trustworthy = r.converged && in.context->warnings.empty() && !(p < 1e-3);
    h << "<p class=\"verdict " << (trustworthy ? "v-no_mismatch" : "v-mismatch_named")
      << "\" id=\"verdict\">"
      << (!r.converged                    ? "did not converge"
          : !in.context->warnings.empty() ? "converged with warnings"
          : p < 1e-3                      ? "converged, misfit beyond the noise"
                                          : "converged, consistent with the noise")
      << ": chi&sup2;/dof " << html_escape(num(r.chi2 / std::max(1, r.dof), 3))
      << ", p = " << html_escape(p_text(p)) << "</p>\n";
  }
  h << "<p class=\"next\" id=\"next-step\"><b>Next step:</b> " << html_escape(next_step(in, p))
    << "</p>\n";
  return h.str();
}

// The named effects: effect, value +- std per parameter, share of the misfit explained.
std::string effects_table(const PageInput& in) {
  const Diagnosis* d = in.diagnosis;
  std::ostringstream h;
  h << "<table id=\"effects\" class=\"effects\">\n<caption>Named effects</caption>\n<tr>"
    << th("effect") << th("value ± std") << th("misfit explained") << "</tr>\n";
  if (d == nullptr) {
    h << "<tr><td colspan=\"3\">not diagnosed: the identification alone (run cdpr-fit diagnose "
         "to look for missing physics)</td></tr>\n";
  } else if (d->accepted.empty()) {
    h << "<tr><td colspan=\"3\">none";
    if (d->follow_up) {
      h << "; suspected, not proven: " << html_escape(d->follow_up->name) << " (p "
        << html_escape(p_text(d->follow_up->p_value)) << " alone, "
        << html_escape(p_text(d->follow_up->p_adjusted)) << " after Holm)";
    }
    h << "</td></tr>\n";
  } else {
    // The excess chi^2 of the standard identification over its degrees of freedom is the misfit.
    const double excess = d->before.chi2 - static_cast<double>(d->before.dof);
    for (const EffectFit& e : d->accepted) {
      std::string values;
      for (const EffectParameter& p : e.parameters) {
        const std::string v =
            p.text.empty() ? p.name + " = " + num(p.value) + " ± " + num(p.std_dev) + " " + p.unit
                           : p.text;
        values += (values.empty() ? "" : "; ") + v;
      }
      const double share = excess > 0 ? (e.chi2_before - e.chi2_after) / excess : kNaN;
      h << "<tr>" << td(e.name + (e.modelled_in_config ? "" : " (not carried by the config)"))
        << "<td class=\"vals\">" << html_escape(values) << "</td>" << td(pct(share), true)
        << "</tr>\n";
    }
  }
  h << "</table>\n";
  return h.str();
}

std::string key_figures(const PageInput& in, double p, const Accuracy& acc,
                        const AnchorChange& change) {
  std::ostringstream h;
  h << "<table id=\"key-figures\" class=\"keys\">\n<caption>Key figures</caption>\n";
  if (in.fit != nullptr) {
    const IdentificationReport& r = *in.fit;
    h << "<tr><th scope=\"row\">fit</th><td>chi&sup2;/dof "
      << html_escape(num(r.chi2 / std::max(1, r.dof), 4)) << " (chi&sup2; "
      << html_escape(num(r.chi2, 5)) << " on " << r.dof << " dof), p = " << html_escape(p_text(p));
    if (in.standard != nullptr && in.standard != in.fit) {
      h << "; standard identification: chi&sup2;/dof "
        << html_escape(num(in.standard->chi2 / std::max(1, in.standard->dof), 4)) << ", p = "
        << html_escape(p_text(chi2_upper_tail(in.standard->chi2, std::max(1, in.standard->dof))));
    }
    h << "; length RMS " << html_escape(mm(r.rms_length_m, 3)) << " mm</td></tr>\n";
  }
  h << "<tr><th scope=\"row\">anchors changed</th><td>";
  if (change.cable >= 0) {
    h << "largest " << html_escape(mm(change.change, 3)) << " mm (cable " << change.cable + 1
      << ")";
    if (std::isfinite(change.std_dev)) {
      h << " ± " << html_escape(mm(change.std_dev, 2)) << " mm (1&sigma; along the change); "
        << change.moved << " of " << in.before->num_cables()
        << " anchors moved by more than 2&sigma;";
    }
  } else {
    h << "-";
  }
  h << "</td></tr>\n<tr><th scope=\"row\">position accuracy</th><td>";
  if (acc.computed) {
    h << "over the ISO 9283 box (" << html_escape(mm(2 * acc.box.half_extent.x(), 3))
      << " mm cube about home, " << acc.grid_points << " points): nominal model "
      << html_escape(mm(acc.before_rms, 3)) << " mm RMS (max " << html_escape(mm(acc.before_max, 3))
      << ") &rarr; calibrated " << html_escape(mm(acc.after_rms, 3)) << " mm RMS (max "
      << html_escape(mm(acc.after_max, 3)) << "; Cram&eacute;r-Rao bound of this pose set)";
  } else {
    h << html_escape(acc.why_not);
  }
  h << "</td></tr>\n";
  if (in.diagnosis != nullptr && !in.diagnosis->held_out_source.empty()) {
    h << "<tr><th scope=\"row\">held-out length RMS</th><td>"
      << html_escape(mm(in.diagnosis->held_out_rms_before, 3)) << " mm &rarr; "
      << html_escape(mm(in.diagnosis->held_out_rms_after, 3)) << " mm ("
      << html_escape(in.diagnosis->held_out_source) << ")</td></tr>\n";
  }
  h << "</table>\n";
  return h.str();
}

// ---- plots ----------------------------------------------------------------------------------

std::vector<std::vector<double>> residual_matrix(const IdentificationReport& r, int cables) {
  std::vector<std::vector<double>> rows(static_cast<std::size_t>(cables));
  for (const PoseResiduals& p : r.residuals) {
    for (int i = 0; i < cables; ++i) {
      rows[static_cast<std::size_t>(i)].push_back(
          i < p.length_normalized.size() ? p.length_normalized(i) : kNaN);
    }
  }
  return rows;
}

std::string matrix_table(const std::vector<std::vector<double>>& rows, const std::vector<int>& cols,
                         const std::string& caption) {
  std::ostringstream h;
  h << "<details class=\"data\"><summary>Table: " << html_escape(caption)
    << "</summary>\n<div class=\"scroll\"><table>\n<tr>" << th("cable");
  for (int c : cols) h << th(std::to_string(c));
  h << "</tr>\n";
  for (std::size_t i = 0; i < rows.size(); ++i) {
    h << "<tr>" << td(std::to_string(i + 1), true);
    for (double v : rows[i]) h << td(num(v, 3), true);
    h << "</tr>\n";
  }
  h << "</table></div></details>\n";
  return h.str();
}

std::string heatmaps(const PageInput& in) {
  const int m = in.before->num_cables();
  const ReportContext& c = *in.context;
  std::ostringstream h;
  struct Series {
    const IdentificationReport* r;
    std::string what;
  };
  std::vector<Series> series;
  if (in.standard != nullptr && in.fit != nullptr && in.standard != in.fit) {
    series.push_back({in.standard, "before: standard identification"});
    series.push_back({in.fit, "after: with the named effects"});
  } else if (in.fit != nullptr) {
    series.push_back({in.fit, "calibrated model"});
  }
  if (series.empty() || series.front().r->residuals.empty()) return "";
  h << "<h2 id=\"residual-maps\">Length residuals per cable and pose</h2>\n"
    << "<p class=\"small\">Residual / sigma of every cable length at every pose: white is the "
       "noise level, red too long a measured length, blue too short, grey no reading; a column is "
       "a "
       "pose, a row a cable. Structure (a row, a column, a gradient) is what a missing effect "
       "leaves.</p>\n";
  for (const Series& s : series) {
    svg::Heatmap map;
    map.title = "length residual / sigma per cable and pose, " + s.what;
    map.xlabel = "pose";
    map.ylabel = "cable";
    map.values = residual_matrix(*s.r, m);
    for (int i = 0; i < m; ++i) map.row_labels.push_back("cable " + std::to_string(i + 1));
    for (std::size_t j = 0; j < s.r->residuals.size(); ++j) {
      map.column_labels.push_back(pose_number(c, j));
    }
    h << svg::heatmap(map) << matrix_table(map.values, map.column_labels, map.title);
  }
  return h.str();
}

std::string explained_plots(const PageInput& in) {
  if (in.diagnosis == nullptr) return "";
  const std::vector<ExplainedResiduals> plots = explained_residuals(*in.diagnosis, *in.set);
  std::ostringstream h;
  h << "<h2 id=\"explained\">Residuals against the explaining variable</h2>\n"
    << "<p class=\"small\">Normalised cable-length residuals (residual / sigma) of the standard "
       "identification (before) and with the accepted effects modelled (after), against the "
       "variable the effect follows. Dashed: &plusmn;2 sigma.</p>\n";
  bool any = false;
  for (const ExplainedResiduals& p : plots) {
    if (p.x.empty()) continue;
    svg::Scatter plot;
    plot.title = p.title;
    plot.xlabel = p.variable + (p.unit.empty() ? "" : " (" + p.unit + ")");
    plot.ylabel = "length residual / sigma";
    plot.x = p.x;
    plot.cable = p.cable;
    plot.before = p.before;
    plot.after = p.after;
    h << svg::scatter(plot);
    h << "<details class=\"data\"><summary>Table: " << html_escape(p.title)
      << "</summary>\n<div class=\"scroll\"><table>\n<tr>" << th("cable") << th(plot.xlabel)
      << th("before") << th("after") << "</tr>\n";
    for (std::size_t k = 0; k < p.x.size(); ++k) {
      h << "<tr>" << td(k < p.cable.size() ? std::to_string(p.cable[k] + 1) : "-", true)
        << td(num(p.x[k]), true) << td(k < p.before.size() ? num(p.before[k], 3) : "-", true)
        << td(k < p.after.size() ? num(p.after[k], 3) : "-", true) << "</tr>\n";
    }
    h << "</table></div></details>\n";
    any = true;
  }
  if (!any) h << "<p>No residuals to plot (the standard identification was not run).</p>\n";
  return h.str();
}

// A magnification 1, 2 or 5 times a power of ten that makes `largest` about `target` long.
double magnification(double largest, double target) {
  if (!(largest > 0) || !(target > 0)) return 1.0;
  const double raw = target / largest;
  if (raw <= 1.0) return 1.0;
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  double k = p;
  for (double f : {1.0, 2.0, 5.0, 10.0}) {
    if (f * p <= raw) k = f * p;
  }
  return k;
}

// The two plan views of the workspace plots: the top view (x, y) and the side view (x, z).
struct PlanAxes {
  int ax, ay;
  const char* name;
};
constexpr PlanAxes kPlanViews[2] = {{0, 1, "top view (x, y)"}, {0, 2, "side view (x, z)"}};

// An empty plan view on `view`'s axes, titled `title`.
svg::PlanView plan_on(const PlanAxes& view, const std::string& title) {
  static const char* const kLabels[3] = {"x (m)", "y (m)", "z (m)"};
  svg::PlanView p;
  p.title = title;
  p.xlabel = kLabels[view.ax];
  p.ylabel = kLabels[view.ay];
  return p;
}

std::string axis_name(int axis) {
  return std::string(1, static_cast<char>('x' + axis));
}

std::string anchor_views(const PageInput& in) {
  const int m = in.before->num_cables();
  const Eigen::Matrix3Xd& a0 = in.before->frame_anchors;
  const Eigen::Matrix3Xd& a1 = in.after->robot.frame_anchors;
  double extent = 0.0, largest = 0.0;
  std::vector<Eigen::Matrix3d> cov(static_cast<std::size_t>(m), Eigen::Matrix3d::Zero());
  std::vector<bool> has(static_cast<std::size_t>(m), false);
  for (int i = 0; i < m; ++i) {
    extent = std::max(extent, (a0.col(i) - a0.rowwise().mean()).norm());
    Eigen::Matrix3d c;
    has[static_cast<std::size_t>(i)] = anchor_covariance(in.fit, i, &c);
    cov[static_cast<std::size_t>(i)] = c;
    const double s = has[static_cast<std::size_t>(i)] ? std::sqrt(c.trace()) : 0.0;
    largest = std::max(largest, std::max((a1.col(i) - a0.col(i)).norm(), s));
  }
  const double k = magnification(largest, 0.12 * extent);
  std::ostringstream h;
  h << "<h2 id=\"anchors\">Frame anchors: changes and their uncertainty</h2>\n"
    << "<p class=\"small\">Squares: the nominal anchors; arrows: the change to the calibrated "
       "anchors; shaded: the 1-sigma uncertainty ellipse from the fit's covariance. Changes and "
       "ellipses are magnified &times;"
    << html_escape(fmt(k, 3)) << " (positions in m).</p>\n<div class=\"pair\">\n";
  for (const PlanAxes& view : kPlanViews) {
    const int ax = view.ax, ay = view.ay;
    svg::PlanView p =
        plan_on(view, std::string("frame anchors, ") + view.name + ", changes ×" + fmt(k, 3));
    std::string desc;
    for (int i = 0; i < m; ++i) {
      const Eigen::Vector3d d = a1.col(i) - a0.col(i);
      const std::string who = "cable " + std::to_string(i + 1);
      p.points.push_back(
          {a0(ax, i), a0(ay, i), "o",
           who + " nominal (" + fmt(a0(ax, i), 4) + ", " + fmt(a0(ay, i), 4) + ") m"});
      p.arrows.push_back({a0(ax, i), a0(ay, i), a0(ax, i) + k * d(ax), a0(ay, i) + k * d(ay),
                          who + ": moved " + mm(d(ax), 3) + ", " + mm(d(ay), 3) + " mm"});
      if (has[static_cast<std::size_t>(i)]) {
        const Eigen::Matrix3d& c = cov[static_cast<std::size_t>(i)];
        p.ellipses.push_back({a0(ax, i) + k * d(ax), a0(ay, i) + k * d(ay), k * k * c(ax, ax),
                              k * k * c(ax, ay), k * k * c(ay, ay),
                              who + ": 1-sigma " + mm(std::sqrt(c(ax, ax)), 2) + " x " +
                                  mm(std::sqrt(c(ay, ay)), 2) + " mm"});
      }
      desc += (i == 0 ? "" : "; ") + who + " moved " + mm(d(ax), 3) + " mm in " + axis_name(ax) +
              ", " + mm(d(ay), 3) + " mm in " + axis_name(ay);
    }
    p.description = "Frame anchors " + std::string(view.name) + ": " + desc + ".";
    p.legend = {{"nominal", "o"}, {"change ×" + fmt(k, 3), "f"}, {"1σ", "e"}};
    h << svg::plan_view(p);
  }
  h << "</div>\n";
  return h.str();
}

std::string pose_views(const PageInput& in, const Accuracy& acc) {
  const int m = in.before->num_cables();
  const ReportContext& c = *in.context;
  std::vector<Pose> poses;
  if (in.fit != nullptr && !in.fit->poses.empty()) {
    poses = in.fit->poses;
  } else {
    for (const PoseMeasurement& p : in.set->poses) poses.push_back(p.commanded);
  }
  if (poses.empty()) return "";
  AccuracyBox box = acc.box;
  box.center = in.before->home.position;
  std::ostringstream h;
  h << "<h2 id=\"poses\">Measured poses in the workspace</h2>\n"
    << "<p class=\"small\">Dots: the platform positions of the recording ("
    << (in.fit != nullptr && !in.fit->poses.empty() ? "as estimated" : "as commanded")
    << "); squares: the frame anchors; dashed: the ISO 9283 box of the accuracy figures.</p>\n"
    << "<div class=\"pair\">\n";
  for (const PlanAxes& view : kPlanViews) {
    const int ax = view.ax, ay = view.ay;
    svg::PlanView p = plan_on(view, std::string("measured poses, ") + view.name);
    for (int i = 0; i < m; ++i) {
      p.points.push_back({in.before->frame_anchors(ax, i), in.before->frame_anchors(ay, i), "o",
                          "anchor " + std::to_string(i + 1)});
    }
    double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
    for (std::size_t j = 0; j < poses.size(); ++j) {
      const Eigen::Vector3d& x = poses[j].position;
      p.points.push_back({x(ax), x(ay), "p",
                          "pose " + std::to_string(pose_number(c, j)) + ": " + fmt(x(ax), 4) +
                              ", " + fmt(x(ay), 4) + " m"});
      lo[0] = std::min(lo[0], x(ax));
      hi[0] = std::max(hi[0], x(ax));
      lo[1] = std::min(lo[1], x(ay));
      hi[1] = std::max(hi[1], x(ay));
    }
    p.boxes.push_back({box.center(ax) - box.half_extent(ax), box.center(ay) - box.half_extent(ay),
                       box.center(ax) + box.half_extent(ax), box.center(ay) + box.half_extent(ay),
                       "ISO 9283 box"});
    p.description = std::to_string(poses.size()) + " poses spanning " + fmt(lo[0], 3) + " to " +
                    fmt(hi[0], 3) + " m in " + axis_name(ax) + " and " + fmt(lo[1], 3) + " to " +
                    fmt(hi[1], 3) + " m in " + axis_name(ay) + ", among " + std::to_string(m) +
                    " frame anchors.";
    p.legend = {{"anchor", "o"}, {"pose", "p"}, {"ISO box", "bx"}};
    h << svg::plan_view(p);
  }
  h << "</div>\n<details class=\"data\"><summary>Table: the poses</summary>\n"
    << "<div class=\"scroll\"><table>\n<tr>" << th("pose") << th("x (m)") << th("y (m)")
    << th("z (m)") << th("roll (rad)") << th("pitch (rad)") << th("yaw (rad)") << "</tr>\n";
  for (std::size_t j = 0; j < poses.size(); ++j) {
    h << "<tr>" << td(std::to_string(pose_number(c, j)), true);
    const auto v = poses[j].vector();
    for (int q = 0; q < 6; ++q) h << td(fmt(v(q), 5), true);
    h << "</tr>\n";
  }
  h << "</table></div></details>\n";
  return h.str();
}

// ---- tables -----------------------------------------------------------------------------------

std::string anchor_table(const PageInput& in) {
  const int m = in.before->num_cables();
  std::ostringstream h;
  h << "<h2 id=\"anchor-table\">Frame anchors</h2>\n<table>\n<tr>" << th("cable")
    << th("before x (m)") << th("before y (m)") << th("before z (m)") << th("after x (m)")
    << th("after y (m)") << th("after z (m)") << th("change (mm)") << th("std (mm)") << "</tr>\n";
  for (int i = 0; i < m; ++i) {
    const auto b = in.before->frame_anchors.col(i);
    const auto a = in.after->robot.frame_anchors.col(i);
    h << "<tr>" << td(std::to_string(i + 1), true);
    for (int q = 0; q < 3; ++q) h << td(fmt(b(q), 6), true);
    for (int q = 0; q < 3; ++q) h << td(fmt(a(q), 6), true);
    Eigen::Matrix3d cov;
    const bool has = anchor_covariance(in.fit, i, &cov);
    h << td(mm((a - b).norm(), 3), true)
      << td(has ? fmt(1e3 * std::sqrt(cov.trace()), 3) : "-", true) << "</tr>\n";
  }
  h << "</table>\n<p class=\"small\">std: sqrt(var x + var y + var z) of the anchor "
       "position.</p>\n";
  return h.str();
}

// One table: the channels and the cables, RMS before/after and the chi^2 test of the screen.
std::string statistics_table(const PageInput& in) {
  const Diagnosis* d = in.diagnosis;
  std::ostringstream h;
  h << "<h2 id=\"statistics\">Statistics per channel and per cable</h2>\n<table>\n<tr>";
  if (d != nullptr && !d->screen.channels.empty()) {
    h << th("group") << th("residuals") << th("RMS before") << th("RMS after") << th("RMS / sigma")
      << th("chi² / expected") << th("p") << "</tr>\n";
    auto row = [&](const MisfitGroup& g, const ChannelRms* ch) {
      h << "<tr" << (g.flagged ? " class=\"flag\"" : "") << ">" << td(g.name)
        << td(std::to_string(g.count), true)
        << td(ch != nullptr ? shown(ch->before, ch->unit) : shown(g.rms_si, g.unit), true)
        << td(ch != nullptr ? shown(ch->after, ch->unit) : "-", true)
        << td(num(g.rms_normalized, 3), true)
        << td(num(g.chi2, 4) + " / " + num(g.expected_chi2, 4), true)
        << td(p_text(g.p_value) + (g.flagged ? " (beyond the noise)" : ""), true) << "</tr>\n";
    };
    // The diagnosis's channel names may be shorter or longer than the screen's ("laser" and
    // "laser 1"): a channel pairs with the one screen group whose name it begins or ends.
    auto pairs = [](const std::string& a, const std::string& b) {
      return a == b || a.rfind(b, 0) == 0 || b.rfind(a, 0) == 0;
    };
    std::vector<const ChannelRms*> match(d->screen.channels.size(), nullptr);
    std::vector<bool> used(d->channels.size(), false);
    for (std::size_t k = 0; k < d->channels.size(); ++k) {
      int hits = 0;
      std::size_t at = 0;
      for (std::size_t g = 0; g < d->screen.channels.size(); ++g) {
        if (pairs(d->channels[k].channel, d->screen.channels[g].name)) {
          ++hits;
          at = g;
        }
      }
      if (hits == 1 && match[at] == nullptr) {
        match[at] = &d->channels[k];
        used[k] = true;
      }
    }
    for (std::size_t g = 0; g < d->screen.channels.size(); ++g)
      row(d->screen.channels[g], match[g]);
    for (std::size_t k = 0; k < d->channels.size(); ++k) {
      if (used[k]) continue;
      const ChannelRms& c = d->channels[k];
      h << "<tr>" << td(c.channel) << td("-", true) << td(shown(c.before, c.unit), true)
        << td(shown(c.after, c.unit), true) << td("-", true) << td("-", true) << td("-", true)
        << "</tr>\n";
    }
    const std::vector<double> after =
        d->after ? cable_rms_m(d->after->residuals, in.before->num_cables())
                 : std::vector<double>();
    for (std::size_t i = 0; i < d->screen.cables.size(); ++i) {
      const MisfitGroup& g = d->screen.cables[i];
      h << "<tr" << (g.flagged ? " class=\"flag\"" : "") << ">" << td(g.name)
        << td(std::to_string(g.count), true) << td(shown(g.rms_si, g.unit), true)
        << td(i < after.size() ? shown(after[i], "m") : "-", true)
        << td(num(g.rms_normalized, 3), true)
        << td(num(g.chi2, 4) + " / " + num(g.expected_chi2, 4), true)
        << td(p_text(g.p_value) + (g.flagged ? " (beyond the noise)" : ""), true) << "</tr>\n";
    }
  } else if (in.fit != nullptr) {
    // The identification alone: the calibrated model's RMS per channel and per cable.
    const IdentificationReport& r = *in.fit;
    h << th("group") << th("residuals") << th("RMS") << th("RMS / sigma") << "</tr>\n";
    const std::vector<double> si = cable_rms_m(r.residuals, in.before->num_cables());
    const std::vector<double> rms = cable_rms(r.residuals, in.before->num_cables());
    h << "<tr>" << td("cable lengths") << td("-", true) << td(shown(r.rms_length_m, "m"), true)
      << td("-", true) << "</tr>\n<tr>" << td("laser") << td("-", true)
      << td(shown(r.rms_laser_m, "m"), true) << td("-", true) << "</tr>\n<tr>" << td("wrench")
      << td("-", true) << td(shown(r.rms_wrench_n, "N"), true) << td("-", true) << "</tr>\n";
    for (std::size_t i = 0; i < rms.size(); ++i) {
      int n = 0;
      for (const PoseResiduals& p : r.residuals) {
        n += static_cast<Eigen::Index>(i) < p.length_normalized.size() &&
                     std::isfinite(p.length_normalized(static_cast<Eigen::Index>(i)))
                 ? 1
                 : 0;
      }
      h << "<tr>" << td("cable " + std::to_string(i + 1)) << td(std::to_string(n), true)
        << td(shown(si[i], "m"), true) << td(num(rms[i], 3), true) << "</tr>\n";
    }
  } else {
    h << th("group") << "</tr>\n<tr>" << td("no identification was run") << "</tr>\n";
  }
  h << "</table>\n<p class=\"small\">RMS / sigma 1 is the noise level; chi&sup2; / expected "
       "compares a group's sum of squared normalised residuals with its effective degrees of "
       "freedom (p: chi&sup2; upper tail).</p>\n";
  return h.str();
}

std::string pose_table_html(const std::vector<Pose>& poses,
                            const std::vector<double>& pretensions) {
  std::ostringstream h;
  h << "<table>\n<tr>" << th("x (m)") << th("y (m)") << th("z (m)") << th("roll (rad)")
    << th("pitch (rad)") << th("yaw (rad)") << th("pretension (N)") << "</tr>\n";
  for (std::size_t k = 0; k < poses.size(); ++k) {
    h << "<tr>";
    const auto v = poses[k].vector();
    for (int q = 0; q < 6; ++q) {
      char buf[32];
      std::snprintf(buf, sizeof buf, "%.4f", v(q));
      h << td(buf, true);
    }
    h << td(k < pretensions.size() ? num(pretensions[k]) : "-", true) << "</tr>\n";
  }
  h << "</table>\n";
  return h.str();
}

std::string confounded_html(const Diagnosis& d) {
  const std::vector<PairRow> rows = pair_rows(d);
  if (rows.empty()) return "";
  std::vector<const PairRow*> relevant, rest;
  for (const PairRow& r : rows) (r.matters ? relevant : rest).push_back(&r);
  std::ostringstream h;
  h << "<h2 id=\"confounded\">Confounded pairs</h2>\n";
  auto table = [&](const std::vector<const PairRow*>& pairs, const char* id) {
    h << "<table id=\"" << id << "\">\n<tr>" << th("first") << th("second")
      << th("canonical correlation") << th("chi² of the fits") << th("with the extra poses")
      << "</tr>\n";
    for (const PairRow* r : pairs) {
      h << "<tr>" << td(r->first) << td(r->second) << td(num(r->correlation, 4), true)
        << td(r->fits, true) << td(r->extra, true) << "</tr>\n";
    }
    h << "</table>\n";
  };
  if (relevant.empty()) {
    h << "<p>None of the confounded pairs involves a named or suspected effect.</p>\n";
  } else {
    h << "<p>Pairs that involve a named or suspected effect: this pose set cannot tell them "
         "apart.</p>\n";
    table(relevant, "confounded-relevant");
    for (const PairRow* r : relevant) {
      if (r->finding == nullptr || r->finding->separating_poses.empty()) continue;
      const ConfoundedFinding& f = *r->finding;
      h << "<details><summary>Extra poses that would separate " << html_escape(f.first) << " and "
        << html_escape(f.second) << "</summary>\n<p>" << html_escape(f.description) << "</p>\n"
        << pose_table_html(f.separating_poses, f.separating_pretensions) << "</details>\n";
    }
  }
  if (!rest.empty()) {
    h << "<details><summary>" << rest.size() << " other confounded pair"
      << (rest.size() == 1 ? "" : "s") << " (no bearing on the verdict)</summary>\n";
    table(rest, "confounded-other");
    h << "</details>\n";
  }
  return h.str();
}

std::string candidates_html(const Diagnosis& d) {
  std::ostringstream h;
  if (!d.candidates.empty()) {
    h << "<details><summary>Candidates refitted (" << d.candidates.size()
      << ")</summary>\n<table>\n<tr>" << th("candidate") << th("selected itself")
      << th("its family selected") << th("LRT p") << th("dBIC") << th("CV RMS before (mm)")
      << th("CV RMS after (mm)") << th("accepted") << "</tr>\n";
    for (const EffectFit& e : d.candidates) {
      h << "<tr" << (e.accepted ? " class=\"acc\"" : "") << ">" << td(e.name + " [" + e.id + "]")
        << td(num(e.inclusion_probability, 3), true)
        << td(num(e.family_inclusion_probability, 3), true) << td(p_text(e.lrt_p_value), true)
        << td(num(e.bic_delta, 4), true) << td(mm(e.cv_rms_before), true)
        << td(mm(e.cv_rms_after), true) << td(e.accepted ? "yes" : "") << "</tr>\n";
    }
    h << "</table>\n</details>\n";
  }
  if (!d.screen.candidates.empty()) {
    h << "<details><summary>Screen: added-variable tests (" << d.screen.candidates.size()
      << ")</summary>\n<table>\n<tr>" << th("candidate") << th("rank") << th("p (Holm)")
      << th("explained") << th("dBIC") << "</tr>\n";
    for (const CandidateScreen& s : d.screen.candidates) {
      h << "<tr>" << td(s.name + " [" + s.id + "]") << td(std::to_string(s.rank), true)
        << td(s.modelled ? "modelled" : p_text(s.p_adjusted), true)
        << td(pct(s.explained_fraction), true) << td(num(s.bic_delta, 4), true) << "</tr>\n";
    }
    h << "</table>\n</details>\n";
  }
  return h.str();
}

}  // namespace

std::string html_page(const PageInput& in) {
  const ReportContext& c = *in.context;
  const Diagnosis* d = in.diagnosis;
  const int m = in.before->num_cables();
  const int lasers = static_cast<int>(in.before->lasers.size());
  const double p =
      in.fit != nullptr ? chi2_upper_tail(in.fit->chi2, std::max(1, in.fit->dof)) : kNaN;
  const Accuracy acc = accuracy_of(in);
  const AnchorChange change = largest_change(in);
  std::ostringstream h;
  h << page_head(c.title + ": " + c.recording);
  h << "<header>\n<h1>" << html_escape(in.heading) << ": " << html_escape(c.title)
    << "</h1>\n<p class=\"small\" id=\"inputs\">config <code>" << html_escape(c.config)
    << "</code> (" << html_escape(c.config_hash) << "), recording <code>"
    << html_escape(c.recording) << "</code> (" << html_escape(c.recording_hash) << ")";
  if (!c.validation.empty()) {
    h << ", validation <code>" << html_escape(c.validation) << "</code> ("
      << html_escape(c.validation_hash) << ")";
  }
  h << "; " << in.set->num_poses() << " poses, " << m << " cables, " << lasers
    << (lasers == 1 ? " laser" : " lasers");
  if (!c.estimated.empty()) {
    h << "; estimated:";
    for (const std::string& e : c.estimated) h << " " << html_escape(e);
  }
  if (d != nullptr) {
    h << "; seed " << c.seed << ", bootstrap " << c.bootstrap << ", folds "
      << (c.folds == 0 ? std::string("leave one pose out") : std::to_string(c.folds));
  }
  h << "</p>\n</header>\n";

  // First screen: the decision.
  h << "<section id=\"summary\" aria-label=\"decision summary\">\n";
  if (in.fit == nullptr && d != nullptr) {
    const std::string key = verdict_key(d->verdict);
    h << "<p class=\"verdict v-" << key << "\" id=\"verdict\">" << html_escape(key) << ": "
      << html_escape(d->headline) << "</p>\n<p class=\"next\" id=\"next-step\"><b>Next step:</b> "
      << html_escape(next_step(in, p)) << "</p>\n";
  } else {
    h << verdict_html(in, p);
  }
  h << effects_table(in) << key_figures(in, p, acc, change);
  h << "<nav class=\"small\">Below: <a href=\"#residual-maps\">residuals per cable and pose</a>"
    << (d != nullptr ? " &middot; <a href=\"#explained\">residuals against the effect</a>" : "")
    << " &middot; <a href=\"#anchors\">anchor changes</a> &middot; <a href=\"#poses\">poses</a>"
    << " &middot; <a href=\"#statistics\">statistics</a>"
    << (d != nullptr && !d->confounded.empty() ? " &middot; <a href=\"#confounded\">confounded "
                                                 "pairs</a>"
                                               : "")
    << "</nav>\n</section>\n";

  // The plots.
  h << heatmaps(in) << explained_plots(in) << anchor_views(in) << pose_views(in, acc);

  // The tables.
  h << anchor_table(in) << statistics_table(in);
  if (d != nullptr) {
    h << confounded_html(*d);
    if (d->follow_up) {
      h << "<h2 id=\"follow-up\">Suspected, not proven</h2>\n<p><b>"
        << html_escape(d->follow_up->name)
        << "</b>: p = " << html_escape(p_text(d->follow_up->p_value)) << " alone, "
        << html_escape(p_text(d->follow_up->p_adjusted))
        << " after Holm's correction over the candidates. Measure these poses, append them to the "
           "recording and diagnose again to decide:</p>\n"
        << pose_table_html(d->follow_up->poses, d->follow_up->pretensions);
    }
    h << "<h2 id=\"details\">Details</h2>\n" << candidates_html(*d);
    if (!d->findings.empty()) {
      h << "<details><summary>All findings (" << d->findings.size() << ")</summary>\n<ul>\n";
      for (const std::string& f : d->findings) h << "<li>" << html_escape(f) << "</li>\n";
      h << "</ul>\n</details>\n";
    }
  }
  if (!c.warnings.empty()) {
    h << "<h2 id=\"warnings\">Warnings</h2>\n<ul>\n";
    for (const std::string& w : c.warnings) h << "<li>" << html_escape(w) << "</li>\n";
    h << "</ul>\n";
  }
  if (!c.calibrated_config.empty()) {
    h << "<p class=\"small\">Calibrated config: <code>" << html_escape(c.calibrated_config)
      << "</code></p>\n";
  }
  h << "</body>\n</html>\n";
  return h.str();
}

std::string diagnosis_html(const Diagnosis& d, const RobotModel& nominal, const MeasurementSet& set,
                           const ReportContext& c) {
  PageInput in;
  in.heading = "Mismatch diagnosis";
  in.before = &nominal;
  in.after = &d.model_after;
  in.standard = d.before.residuals.empty() ? nullptr : &d.before;
  in.fit = d.after ? &*d.after : in.standard;
  in.diagnosis = &d;
  in.set = &set;
  in.context = &c;
  return html_page(in);
}

}  // namespace cdpr::report
