// The renderings of a Diagnosis: JSON, text and the HTML page of cdpr-fit diagnose.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "cdpr/calibration/residual_explanation.hpp"
#include "cdpr/report/format.hpp"
#include "cdpr/report/report.hpp"
#include "report_internal.hpp"
#include "svg.hpp"

namespace cdpr::report {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

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
          {"round", e.round},
          {"modelled_in_config", e.modelled_in_config},
          {"parameters", params}};
}

nlohmann::json unexplained_json(const std::vector<UnexplainedStructure>& all) {
  nlohmann::json out = nlohmann::json::array();
  for (const UnexplainedStructure& u : all) {
    nlohmann::json cables = nlohmann::json::array(), poses = nlohmann::json::array();
    for (int c : u.cables) cables.push_back(c + 1);
    for (int j : u.poses) poses.push_back(j);
    out.push_back({{"channel", u.channel},
                   {"variable", u.variable},
                   {"cables", cables},
                   {"slopes", u.slopes},
                   {"unit", u.unit},
                   {"p_values", u.p_values},
                   {"poses", poses},
                   {"closest_candidate", u.closest_candidate},
                   {"closest_correlation", number_or_null(u.closest_correlation)},
                   {"description", u.description}});
  }
  return out;
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

// Extra poses to measure (separating or follow-up) as text lines.
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

}  // namespace

std::string verdict_key(Diagnosis::Verdict v) {
  std::string key = to_string(v);  // "mismatch named" -> "mismatch_named"
  for (char& c : key) c = c == ' ' ? '_' : c;
  return key;
}

namespace {

// Residual RMS per cable in sigmas before and after the accepted effects.
struct CableMisfit {
  std::vector<double> before, after;  // `after` empty without a refit
};

CableMisfit cable_misfit(const Diagnosis& d, int num_cables) {
  CableMisfit m;
  m.before = cable_rms(d.before.residuals, num_cables);
  if (d.after) m.after = cable_rms(d.after->residuals, num_cables);
  return m;
}

}  // namespace

nlohmann::json diagnosis_json(const Diagnosis& d, const RobotModel& nominal,
                              const MeasurementSet& set, const ReportContext& c) {
  const CableMisfit misfit = cable_misfit(d, nominal.num_cables());
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
    follow_up = {
        {"suspect", f.suspect},
        {"name", f.name},
        {"parameters", f.parameters},
        {"p_value", number_or_null(f.p_value)},
        {"p_adjusted", number_or_null(f.p_adjusted)},
        {"poses", poses},
        {"pretensions_n", vector_json(f.pretensions)},
        {"log_det_information_before", number_or_null(f.information_before)},
        {"log_det_information_after", number_or_null(f.information_after)},
        {"held_back", f.held_back},
        {"bic_delta", f.held_back ? number_or_null(f.bic_delta) : nlohmann::json(nullptr)}};
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
                                 {"p_beyond_structure", number_or_null(s.p_beyond_structure)},
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
  nlohmann::json gross = nlohmann::json::array();
  for (const GrossReading& g : d.gross_readings) {
    gross.push_back({{"pose", g.pose + 1},  // counted from 1, as in the words
                     {"channel", g.channel},
                     {"index", g.index < 0 ? nlohmann::json(nullptr) : nlohmann::json(g.index + 1)},
                     {"residual_si", number_or_null(g.residual)},
                     {"sigmas", number_or_null(g.sigmas)}});
  }
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
        {"poses", set.num_poses()},
        {"cables", nominal.num_cables()},
        {"lasers", static_cast<int>(nominal.lasers.size())}}},
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
      {"gross_readings", gross},
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
        {"unexplained", unexplained_json(d.screen.unexplained)},
        {"candidates", screen_candidates}}},
      {"screen_after",
       d.screen_after
           ? nlohmann::json{{"chi2", number_or_null(d.screen_after->chi2)},
                            {"dof", d.screen_after->dof},
                            {"p_value", number_or_null(d.screen_after->p_value)},
                            {"unexplained", unexplained_json(d.screen_after->unexplained)}}
           : nlohmann::json(nullptr)},
      {"calibrated_config",
       c.calibrated_config.empty() ? nlohmann::json(nullptr) : nlohmann::json(c.calibrated_config)},
      {"warnings", c.warnings},
      {"noise",
       {{"length_m", set.noise.sigma_length},
        {"laser_m", set.noise.sigma_laser},
        {"force_n", set.noise.sigma_force}}},
  };
}

std::string diagnosis_text(const Diagnosis& d, const RobotModel& nominal, const MeasurementSet& set,
                           const ReportContext& c) {
  const int lasers = static_cast<int>(nominal.lasers.size());
  std::ostringstream h;
  h << c.title << ": " << c.config << " + " << c.recording << " (" << set.num_poses() << " poses, "
    << nominal.num_cables() << " cables, " << lasers << " laser" << (lasers == 1 ? "" : "s")
    << ")\n";
  if (!c.validation.empty()) h << "validation recording: " << c.validation << "\n";
  h << "\nverdict: " << verdict_key(d.verdict) << "\n" << d.headline << "\n";
  if (!d.findings.empty()) {
    h << "\nFindings:\n";
    for (const std::string& f : d.findings) {
      if (f != d.headline) h << "  - " << f << "\n";  // the headline is printed just above
    }
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
    // P(in): the share of the bootstrap resamples that selected this candidate itself; family:
    // that selected it or a candidate of its family (confounded members split the first).
    std::snprintf(line, sizeof line, "  %-30s %6s %6s %10s %9s %12s %12s %4s\n", "id", "P(in)",
                  "family", "LRT p", "dBIC", "CV before mm", "CV after mm", "");
    h << line;
    for (const EffectFit& e : d.candidates) {
      std::snprintf(line, sizeof line, "  %-30s %6.2f %6.2f %10s %9.1f %12s %12s %4s\n",
                    e.id.c_str(), e.inclusion_probability, e.family_inclusion_probability,
                    p_text(e.lrt_p_value).c_str(), e.bic_delta, mm(e.cv_rms_before).c_str(),
                    mm(e.cv_rms_after).c_str(), e.accepted ? "yes" : "");
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

}  // namespace cdpr::report
