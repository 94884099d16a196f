#include "cdpr/report/report.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>

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
    const std::vector<Pose> poses =
        scenario::random_feasible_poses(s_.nominal.robot, s_.box, 20, 3, &s_.truth.robot);
    SimulationOptions so;
    so.controller = &s_.nominal;
    auto sim = simulate_measurements(s_.truth, poses, SensorNoise{}, 5, so);
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
  EXPECT_THAT(r.html, HasSubstr("frame anchors: distance from the nominal position"));
  EXPECT_THAT(r.html, HasSubstr("length residuals per pose"));
  EXPECT_THAT(r.html, HasSubstr("length residual RMS per cable"));
  // Cable 3's standard deviation in the anchor table, from its three coordinates.
  double var = 0.0;
  for (const ParameterEstimate& p : id_.parameters) {
    if (p.name.rfind("a_3.", 0) == 0) var += p.std_dev * p.std_dev;
  }
  ASSERT_GT(var, 0.0);
  EXPECT_THAT(r.html, HasSubstr("<td class=\"n\">" + fmt(1e3 * std::sqrt(var), 3) + "</td></tr>"));
  EXPECT_THAT(r.html, Not(HasSubstr("Mismatch diagnosis")));
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
  EXPECT_THAT(r.html, HasSubstr("Mismatch diagnosis"));
  EXPECT_THAT(r.html, HasSubstr("Residuals against the explaining variable"));
  EXPECT_EQ(r.html.find("</body>"), r.html.rfind("</body>"));  // one page
}

}  // namespace
}  // namespace cdpr::report
