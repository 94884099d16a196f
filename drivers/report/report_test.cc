#include "cdpr/report/report.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "cdpr/calibration/mismatch.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/report/format.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr::report {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

TEST(ReportFormat, HtmlEscapingCoversMarkupAndQuotes) {
  EXPECT_EQ(html_escape("a<b>&\"c'd"), "a&lt;b&gt;&amp;&quot;c&#39;d");
  EXPECT_EQ(html_escape("EA = 21.4 +- 0.6 kN"), "EA = 21.4 +- 0.6 kN");
}

TEST(ReportFormat, NonFiniteNumbersBecomeNull) {
  EXPECT_TRUE(number_or_null(std::nan("")).is_null());
  EXPECT_EQ(to_json(Eigen::VectorXd(Eigen::Vector2d(1.5, INFINITY))).dump(), "[1.5,null]");
}

// Issue 16 item 1: bytes from inputs (paths, robot names, cells) reach the reports.
TEST(ReportFormat, InvalidUtf8BytesAreReplacedAndValidTextIsKept) {
  const std::string replacement = "\xEF\xBF\xBD";
  EXPECT_EQ(valid_utf8("MINI \xC3\xA9t\xC3\xA9 \xE2\x82\xAC \xF0\x9F\x98\x80"),
            "MINI \xC3\xA9t\xC3\xA9 \xE2\x82\xAC \xF0\x9F\x98\x80");
  EXPECT_EQ(valid_utf8("a\xFF"
                       "b"),
            "a" + replacement + "b");
  EXPECT_EQ(valid_utf8("\xC3"), replacement);                                      // truncated
  EXPECT_EQ(valid_utf8("\xC0\xAF"), replacement + replacement);                    // overlong '/'
  EXPECT_EQ(valid_utf8("\xED\xA0\x80"), replacement + replacement + replacement);  // surrogate
  EXPECT_EQ(html_escape("<\xFF>"), "&lt;" + replacement + "&gt;");
}

TEST(ReportFormat, JsonTextNeverThrowsOnInvalidUtf8) {
  nlohmann::json j = {{"robot", "MINI\xFF"}, {"path\xFE", "rec.csv"}};
  std::string text;
  ASSERT_NO_THROW(text = json_text(j));
  const nlohmann::json back = nlohmann::json::parse(text);
  EXPECT_EQ(back["robot"], "MINI\xEF\xBF\xBD");
  EXPECT_EQ(back["path\xEF\xBF\xBD"], "rec.csv");
}

// An identification of simulated MINI data: the report's inputs.
class CalibrationReport : public ::testing::Test {
 protected:
  void SetUp() override {
    s_ = scenario::mini_scenario();
    auto sim = scenario::simulate_random_poses(s_, 20, 3, 5);
    ASSERT_TRUE(sim.ok()) << sim.status().to_string();
    set_ = sim->set;
    auto rep = identify(s_.nominal, set_);
    ASSERT_TRUE(rep.ok()) << rep.status().to_string();
    id_ = *rep;
    in_.before = &s_.nominal;
    in_.after = &id_.estimate;
    in_.identification = &id_;
    in_.set = &set_;
    in_.context.title = "cdprd calibrate";
    in_.context.config = "mini.yaml";
    in_.context.config_hash = "fnv1a64:0123";
    in_.context.recording = "run-7.csv";
    in_.context.recording_hash = "fnv1a64:4567";
    in_.context.estimated = {"anchors", "offsets"};
  }

  // A diagnosis of the fixture's identification that names cable elasticity (accepted).
  Diagnosis elasticity_named() const {
    Diagnosis d;
    d.verdict = Diagnosis::Verdict::kMismatchNamed;
    d.headline = "Missing physics found: cable elasticity.";
    d.before = id_;
    d.model_after = id_.estimate;
    EffectFit e;
    e.id = "hooke_shared";
    e.name = "cable elasticity";
    e.accepted = true;
    d.accepted = {e};
    return d;
  }

  scenario::Scenario s_;
  MeasurementSet set_;
  IdentificationReport id_;
  CalibrationReportInput in_;
};

TEST_F(CalibrationReport, JsonCarriesTheIdentificationAndItsInputs) {
  const Rendered r = render_calibration_report(in_);
  EXPECT_EQ(r.json.at("command"), "calibrate");
  EXPECT_EQ(r.json.at("inputs").at("recording_hash"), "fnv1a64:4567");
  EXPECT_EQ(r.json.at("inputs").at("poses"), set_.num_poses());
  EXPECT_EQ(r.json.at("frame_anchors").at("calibrated").size(), 8u);
  EXPECT_EQ(r.json.at("frame_anchors").at("calibrated").at(2).at(1).get<double>(),
            id_.estimate.robot.frame_anchors(1, 2));
  EXPECT_EQ(r.json.at("residuals").size(), id_.residuals.size());
  EXPECT_FALSE(r.json.contains("diagnosis"));
  EXPECT_EQ(r.json, identification_json(in_));  // the same document as calibrate's
  EXPECT_EQ(r.text, identification_text(in_));
  EXPECT_THAT(r.text, HasSubstr("cdprd calibrate: mini.yaml + run-7.csv (20 poses"));
}

TEST_F(CalibrationReport, HtmlShowsAnchorsWithTheirStdAndResidualsPerCableAndPose) {
  const Rendered r = render_calibration_report(in_);
  EXPECT_EQ(r.html.rfind("<!DOCTYPE html>", 0), 0u);
  EXPECT_THAT(r.html, HasSubstr("</html>\n"));
  EXPECT_THAT(r.html, HasSubstr("length residual / sigma per cable and pose, calibrated model"));
  EXPECT_THAT(r.html, HasSubstr("frame anchors, top view (x, y)"));
  EXPECT_THAT(r.html, HasSubstr("frame anchors, side view (x, z)"));
  EXPECT_THAT(r.html, HasSubstr("measured poses, top view (x, y)"));
  // Cable 3's standard deviation in the anchor table, from its three coordinates.
  double var = 0.0;
  for (const ParameterEstimate& p : id_.parameters) {
    if (p.id.kind == ParameterKind::kFrameAnchor && p.id.index == 2) var += p.std_dev * p.std_dev;
  }
  ASSERT_GT(var, 0.0);
  EXPECT_THAT(r.html, HasSubstr("<td class=\"n\">" + fmt(1e3 * std::sqrt(var), 3) + "</td></tr>"));
  EXPECT_THAT(r.html, Not(HasSubstr("<details><summary>All findings")));
}

// The decision comes before every plot: verdict, next step, effects, key figures.
TEST_F(CalibrationReport, TheDecisionComesBeforeThePlots) {
  const Rendered r = render_calibration_report(in_);
  const std::size_t first_plot = r.html.find("<svg");
  ASSERT_NE(first_plot, std::string::npos);
  for (const char* id :
       {"id=\"verdict\"", "id=\"next-step\"", "id=\"effects\"", "id=\"key-figures\""}) {
    SCOPED_TRACE(id);
    EXPECT_LT(r.html.find(id), first_plot);
  }
  // chi^2 / dof with its p-value (the daemon's gate computes the same).
  const double p = chi2_upper_tail(id_.chi2, std::max(1, id_.dof));
  EXPECT_THAT(r.html, HasSubstr("chi&sup2;/dof " + fmt(id_.chi2 / id_.dof, 4) + " (chi&sup2; " +
                                fmt(id_.chi2, 5) + " on " + std::to_string(id_.dof) +
                                " dof), p = " + fmt(p, 3)));
  EXPECT_THAT(r.html, HasSubstr("Next step:</b> Accept the calibrated model"));
}

// The largest anchor change and its standard deviation along the change (from the covariance).
TEST_F(CalibrationReport, LargestAnchorChangeCarriesItsUncertaintyAlongTheChange) {
  int worst = 0;
  double change = 0.0;
  const Eigen::Matrix3Xd& a0 = s_.nominal.robot.frame_anchors;
  const Eigen::Matrix3Xd& a1 = id_.estimate.robot.frame_anchors;
  for (int i = 0; i < a0.cols(); ++i) {
    if ((a1.col(i) - a0.col(i)).norm() > change) {
      change = (a1.col(i) - a0.col(i)).norm();
      worst = i;
    }
  }
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (std::size_t q = 0; q < id_.parameters.size(); ++q) {
    for (std::size_t k = 0; k < id_.parameters.size(); ++k) {
      const ParameterId& a = id_.parameters[q].id;
      const ParameterId& b = id_.parameters[k].id;
      const auto of_worst = [&](const ParameterId& id) {
        return id.kind == ParameterKind::kFrameAnchor && id.index == worst;
      };
      if (!of_worst(a) || !of_worst(b)) continue;
      cov(a.component, b.component) =
          id_.covariance(static_cast<Eigen::Index>(q), static_cast<Eigen::Index>(k));
    }
  }
  const Eigen::Vector3d u = (a1.col(worst) - a0.col(worst)).normalized();
  const double sd = std::sqrt(u.dot(cov * u));
  ASSERT_GT(sd, 0.0);
  const Rendered r = render_calibration_report(in_);
  EXPECT_THAT(r.html, HasSubstr("largest " + fmt(1e3 * change, 3) + " mm (cable " +
                                std::to_string(worst + 1) + ") ± " + fmt(1e3 * sd, 2) + " mm"));
}

// With the identification options: the nominal model's error over the ISO 9283 box if the
// calibration is right, and the Cramer-Rao bound of the pose set after; without: said so.
TEST_F(CalibrationReport, PositionAccuracyBeforeAndAfterOverTheIsoBox) {
  const Rendered without = render_calibration_report(in_);
  EXPECT_THAT(without.html, HasSubstr("not computed (the identification options were not given)"));

  in_.context.identification = IdentificationOptions{};
  AccuracyBox box;
  box.center = s_.nominal.robot.home.position;
  auto before = measure_position_accuracy(id_.estimate, s_.nominal, box);
  ASSERT_TRUE(before.ok()) << before.status().to_string();
  std::vector<Pose> poses;
  for (const PoseMeasurement& p : set_.poses) poses.push_back(p.commanded);
  PredictedAccuracyOptions po;
  po.box = box;
  auto after = predict_accuracy(s_.nominal, poses, set_.noise, po);
  ASSERT_TRUE(after.ok()) << after.status().to_string();
  ASSERT_GT(before->position_rms_m, after->position_rms_m);  // the calibration matters here
  const Rendered r = render_calibration_report(in_);
  EXPECT_THAT(r.html,
              HasSubstr("nominal model " + fmt(1e3 * before->position_rms_m, 3) + " mm RMS (max " +
                        fmt(1e3 * before->position_max_m, 3) + ") &rarr; calibrated " +
                        fmt(1e3 * after->position_rms_m, 3) + " mm RMS"));
}

// Every plot has a text alternative: aria-label, <title> and <desc> with content.
TEST_F(CalibrationReport, EveryPlotHasATextAlternative) {
  const Rendered r = render_calibration_report(in_);
  int plots = 0;
  for (std::size_t at = r.html.find("<svg"); at != std::string::npos;
       at = r.html.find("<svg", at + 1)) {
    const std::string svg = r.html.substr(at, r.html.find("</svg>", at) - at);
    SCOPED_TRACE(svg.substr(0, 200));
    EXPECT_THAT(svg, HasSubstr("role=\"img\" aria-label=\""));
    EXPECT_THAT(svg, Not(HasSubstr("aria-label=\"\"")));
    EXPECT_THAT(svg, HasSubstr("<title>"));
    EXPECT_THAT(svg, Not(HasSubstr("<desc></desc>")));
    ++plots;
  }
  EXPECT_EQ(plots, 5);  // heat map, two anchor views, two pose views
  EXPECT_THAT(r.html, HasSubstr("@media print"));
  EXPECT_THAT(r.html, Not(HasSubstr("<script")));
  std::string page = r.html;  // nothing fetched: no address but the SVG namespace
  for (std::size_t at; (at = page.find("http://www.w3.org/2000/svg")) != std::string::npos;) {
    page.erase(at, 26);
  }
  EXPECT_THAT(page, Not(HasSubstr("http")));
}

TEST_F(CalibrationReport, ADiagnosisAddsItsSectionsToEveryRendering) {
  Diagnosis d;
  d.verdict = Diagnosis::Verdict::kNoMismatch;
  d.headline = "The model explains the recording within the noise.";
  d.before = id_;
  d.model_after = id_.estimate;
  in_.diagnosis = &d;
  const Rendered r = render_calibration_report(in_);
  EXPECT_EQ(r.json.at("diagnosis").at("verdict"), "no_mismatch");
  EXPECT_EQ(r.json.at("diagnosis"), diagnosis_json(d, s_.nominal.robot, set_, in_.context));
  EXPECT_THAT(r.text, HasSubstr("verdict: no_mismatch\n" + d.headline));
  EXPECT_THAT(r.html, HasSubstr("no_mismatch: " + d.headline));
  EXPECT_THAT(r.html, HasSubstr("Residuals against the explaining variable"));
  EXPECT_EQ(r.html.find("</body>"), r.html.rfind("</body>"));  // one page
}

// A suspect held back beside a named effect for weak evidence: the JSON says so and carries its
// BIC; an ordinary suspect's BIC is null; the page lists its follow-up poses.
TEST_F(CalibrationReport, AHeldBackSuspectCarriesItsWeakEvidence) {
  Diagnosis d = elasticity_named();
  FollowUp fu;
  fu.suspect = "laser_direction";
  fu.name = "laser beam direction (a tilted mount)";
  fu.parameters = 2;
  fu.held_back = true;
  fu.bic_delta = -1.1;
  fu.poses = {Pose{}, Pose{}};
  fu.pretensions = {40.0, 40.0};
  d.follow_up = fu;
  in_.diagnosis = &d;
  const Rendered r = render_calibration_report(in_);
  const nlohmann::json& j = r.json.at("diagnosis").at("follow_up");
  EXPECT_EQ(j.at("suspect"), "laser_direction");
  EXPECT_TRUE(j.at("held_back").get<bool>());
  EXPECT_DOUBLE_EQ(j.at("bic_delta").get<double>(), -1.1);
  EXPECT_EQ(j.at("poses").size(), 2u);
  EXPECT_THAT(r.html, HasSubstr(fu.name));
  d.follow_up->held_back = false;
  const Rendered plain = render_calibration_report(in_);
  EXPECT_FALSE(plain.json.at("diagnosis").at("follow_up").at("held_back").get<bool>());
  EXPECT_TRUE(plain.json.at("diagnosis").at("follow_up").at("bic_delta").is_null());
}

// A named effect with its value +- std and the share of the standard fit's excess chi^2 it
// removes; the residual maps before/after; the findings folded.
TEST_F(CalibrationReport, NamedEffectsTableShowsValueStdAndShareOfTheMisfit) {
  Diagnosis d = elasticity_named();
  d.findings = {d.headline, "Channel 'cable lengths' misfits."};
  d.before.chi2 = 2.0 * id_.dof;
  d.after = id_;
  EffectFit& e = d.accepted[0];
  e.modelled_in_config = true;
  e.chi2_before = d.before.chi2;
  e.chi2_after = 1.1 * id_.dof;
  e.parameters.push_back({"EA", "N", 21400.0, 600.0, "EA = 21.4 +- 0.6 kN"});
  d.candidates = {e};
  in_.diagnosis = &d;
  const Rendered r = render_calibration_report(in_);
  const double share = (e.chi2_before - e.chi2_after) / (d.before.chi2 - d.before.dof);
  EXPECT_THAT(r.html, HasSubstr("<tr><td>cable elasticity</td><td class=\"vals\">EA = 21.4 +- 0.6 "
                                "kN</td><td class=\"n\">" +
                                fmt(100.0 * share, 3) + " %</td></tr>"));
  EXPECT_THAT(r.html, HasSubstr("Next step:</b> Accept the calibrated model: it carries the "
                                "named effect."));
  EXPECT_THAT(r.html, HasSubstr("per cable and pose, before: standard identification"));
  EXPECT_THAT(r.html, HasSubstr("per cable and pose, after: with the named effects"));
  EXPECT_THAT(r.html, HasSubstr("<details><summary>All findings (2)</summary>"));
  EXPECT_THAT(r.html, Not(HasSubstr("<h2>Findings")));
}

// Confounded pairs: those with a named effect in a short table, the others folded.
TEST_F(CalibrationReport, ConfoundedPairsThatBearOnTheVerdictComeFirstTheRestFolded) {
  Diagnosis d = elasticity_named();
  ConfoundedFinding f;
  f.first = "hooke_shared";
  f.second = "compliance_shared";
  f.first_fit.name = "cable elasticity";
  f.second_fit.name = "winch compliance";
  f.correlation = 0.95;
  d.confounded = {f};
  for (int k = 0; k < 3; ++k) {
    d.screen.confounded.push_back({"drift_" + std::to_string(k), "creep_" + std::to_string(k), 0.99,
                                   "drift and creep are confounded"});
  }
  in_.diagnosis = &d;
  const Rendered r = render_calibration_report(in_);
  const std::size_t relevant = r.html.find("<table id=\"confounded-relevant\">");
  const std::size_t folded = r.html.find("<details><summary>3 other confounded pairs");
  ASSERT_NE(relevant, std::string::npos);
  ASSERT_NE(folded, std::string::npos);
  EXPECT_LT(relevant, folded);
  EXPECT_LT(r.html.find("<td>winch compliance</td>", relevant), folded);
  EXPECT_GT(r.html.find("<td>drift_0</td>"), folded);
  EXPECT_THAT(r.html, HasSubstr("measure the separating poses of the 1 confounded pair"));
}

}  // namespace
}  // namespace cdpr::report
