#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "cdpr/controller/calibration_report.hpp"

namespace cdpr::controller {
namespace {

bool contains(const std::string& text, const std::string& what) {
  return text.find(what) != std::string::npos;
}

// The paper's figures as the section prints them, derived from the constants.
std::string paper_mm(double m, const char* f) {
  char buf[32];
  std::snprintf(buf, sizeof buf, f, m * 1e3);
  return buf;
}

CalibrationOutcome predicted(double nominal_m, double calibrated_m) {
  CalibrationOutcome o;
  o.model.name = "MINI";
  o.iso9283_predicted.nominal_m = nominal_m;
  o.iso9283_predicted.calibrated_m = calibrated_m;
  o.iso9283_predicted.points = 5;
  return o;
}

report::Iso9283Measured measured() {
  report::Iso9283Measured m;
  m.setup = "virtual MINI, seed 7";
  m.nominal = {2.0e-3, 1.8e-6, 1.49e-3, 0.849e-3, 1.1e-6, 1.3e-6};
  m.calibrated = {0.5e-3, 1.0e-6, 0.61e-3, 0.42e-3, 1.05e-6, 0.97e-6};
  return m;
}

class Iso9283Section : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = (std::filesystem::temp_directory_path() /
             ("cdpr_iso9283_" + std::to_string(::getpid()) + "_" +
              ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".json"))
                .string();
    std::filesystem::remove(path_);
  }
  void TearDown() override { std::filesystem::remove(path_); }
  void write(const std::string& text) { std::ofstream(path_) << text; }

  std::string path_;
};

TEST_F(Iso9283Section, GivesThePapersFiguresTheCommandAndThePredictionWithoutAMeasuredFile) {
  const CalibrationOutcome o = predicted(2.0e-3, 0.5e-3);
  CalibrationReportContext c;
  load_iso9283_measured("", c);
  const std::string html = iso9283_html(o, c);
  const std::string text = iso9283_text(o, c);
  for (const std::string& page : {html, text}) {
    EXPECT_TRUE(contains(page, "ISO 9283 (position and path)"));
    EXPECT_TRUE(contains(page, kIso9283Command));
    EXPECT_TRUE(contains(page, "+58 % position accuracy"));
    EXPECT_TRUE(contains(page, paper_mm(report::kPaperPathAccuracyM, "%.3f")));
    EXPECT_TRUE(contains(page, paper_mm(report::kPaperPathRepeatabilityM, "%.2f")));
    EXPECT_TRUE(contains(page, "Predicted, not measured"));
    EXPECT_TRUE(contains(page, "nominal model 2.000 mm"));
    EXPECT_TRUE(contains(page, "calibrated 0.500 mm"));
    EXPECT_TRUE(contains(page, "+75 % position accuracy predicted"));  // 1 - 0.5 / 2
    EXPECT_TRUE(contains(page, "No measured figures are configured"));
  }
  const nlohmann::json j = iso9283_json(o, c);
  EXPECT_DOUBLE_EQ(j["paper"]["position_accuracy_gain"].get<double>(),
                   report::kPaperPositionAccuracyGain);
  EXPECT_DOUBLE_EQ(j["paper"]["path_accuracy_m"].get<double>(), report::kPaperPathAccuracyM);
  EXPECT_DOUBLE_EQ(j["predicted"]["calibrated_m"].get<double>(), 0.5e-3);
  EXPECT_TRUE(j["measured"].is_null());
  EXPECT_EQ(j["command"], kIso9283Command);
}

TEST_F(Iso9283Section, AMeasuredFileFillsTheTableNominalAgainstCalibrated) {
  write(report::iso9283_json(measured()).dump(2));
  CalibrationReportContext c;
  load_iso9283_measured(path_, c);
  ASSERT_TRUE(c.iso9283_measured.has_value()) << c.iso9283_problem;
  const CalibrationOutcome o = predicted(2.0e-3, 0.5e-3);
  const std::string html = iso9283_html(o, c);
  EXPECT_TRUE(contains(html,
                       "<td>AP, mm</td><td class=\"n\">2.0000</td><td class=\"n\">0.5000 "
                       "(+75 % position accuracy)</td>"));
  EXPECT_TRUE(contains(html,
                       "<td>AT line, mm</td><td class=\"n\">1.4900</td><td "
                       "class=\"n\">0.6100</td>"));
  EXPECT_TRUE(contains(html, "virtual MINI, seed 7"));
  const std::string text = iso9283_text(o, c);
  EXPECT_TRUE(contains(text, "RT circle, mm: nominal 0.0013, calibrated 0.0010"));
  const nlohmann::json j = iso9283_json(o, c);
  EXPECT_DOUBLE_EQ(j["measured"]["calibrated"]["at_circle_m"].get<double>(), 0.42e-3);
  EXPECT_EQ(j["measured_problem"], "");
}

TEST_F(Iso9283Section, AMissingFileIsSaidInTheReportAndNamesThePath) {
  CalibrationReportContext c;
  load_iso9283_measured(path_, c);
  EXPECT_FALSE(c.iso9283_measured.has_value());
  EXPECT_TRUE(contains(c.iso9283_problem, path_));
  const std::string html = iso9283_html(predicted(1e-3, 1e-3), c);
  EXPECT_TRUE(contains(html, "could not be read"));
  EXPECT_TRUE(contains(html, "+58 % position accuracy"));  // the paper's column stays
}

TEST_F(Iso9283Section, AMalformedFileNamesTheFieldAndShowsNoNumbers) {
  nlohmann::json doc = report::iso9283_json(measured());
  doc["calibrated"]["at_line_m"] = -1.0;
  const std::pair<std::string, std::string> bad[] = {
      {doc.dump(), "calibrated.at_line_m: expected a number of metres >= 0"},
      {"{\"format\": \"cdpr-iso9283-v1\", \"nominal\": 3}", "nominal: missing"},
      {"{\"format\": \"something-else\"}", "format: expected"},
      {"not json at all", "not a JSON object"},
      {"", "not a JSON object"},
  };
  for (const auto& [text, message] : bad) {
    write(text);
    CalibrationReportContext c;
    load_iso9283_measured(path_, c);
    EXPECT_FALSE(c.iso9283_measured.has_value()) << text;
    EXPECT_TRUE(contains(c.iso9283_problem, message)) << c.iso9283_problem;
    EXPECT_TRUE(contains(c.iso9283_problem, path_)) << c.iso9283_problem;
    EXPECT_FALSE(contains(iso9283_html(predicted(1e-3, 1e-3), c), "0.6100"));
  }
}

TEST_F(Iso9283Section, APredictionThatFailedSaysWhyAndTheDecisionPageCarriesTheSection) {
  CalibrationOutcome o;
  o.iso9283_predicted_problem = "predicted accuracy unavailable: singular";
  IdentificationReport fit;
  o.fit = &fit;
  o.standard = &fit;
  CalibrationReportContext c;
  const std::string html = calibration_html(o, c, "<html><body></body></html>");
  EXPECT_TRUE(contains(html, "<section id=\"iso9283\">"));
  EXPECT_TRUE(contains(html, "not computed (predicted accuracy unavailable: singular)"));
  const nlohmann::json j = calibration_json(o, c);
  EXPECT_EQ(j["iso9283"]["predicted"]["points"], 0);
  EXPECT_TRUE(j["iso9283"]["predicted"]["nominal_m"].is_null());
}

}  // namespace
}  // namespace cdpr::controller
