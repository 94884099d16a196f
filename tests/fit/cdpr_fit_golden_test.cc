// cdpr-fit's JSON reports for the documented sessions (docs/cdpr-fit.md "Typical session" and
// "Examples", README "Working from recorded data"), compared byte for byte with the copies in
// tests/fit/golden/. The reports are what scripts and the daemon's users read, so a refactoring
// must not change a character of them. The commands run in a fresh directory holding a link to
// config/, with the same relative paths as in the documents (the paths are part of the reports).
//
// Two things differ from run to run and are pinned: the solver's wall time (calibrate's
// "solve_time_s") is replaced by 0 on both sides, and the date a recording carries (and with it
// the recording's hash in the reports) is set to a fixed date in the file after `simulate`.
//
// After an intended change of a report, regenerate the copies and review their diff:
//   CDPR_UPDATE_GOLDEN=1 build/ci/tests/fit/fit_cdpr_fit_golden_test
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

#include "fit_process.hpp"

namespace {

namespace fs = std::filesystem;
using cdpr::fit_test::ProcessResult;
using cdpr::fit_test::slurp;

const fs::path kSource = CDPR_SOURCE_DIR;
const fs::path kGolden = kSource / "tests/fit/golden";

std::string without_wall_time(const std::string& json) {
  static const std::regex kSolveTime("\"solve_time_s\": [-+0-9.eE]+");
  return std::regex_replace(json, kSolveTime, "\"solve_time_s\": 0");
}

class CdprFitGolden : public cdpr::fit_test::FitProcessTest {
 protected:
  CdprFitGolden() : FitProcessTest("cdpr_fit_golden_") {}

  void SetUp() override {
    FitProcessTest::SetUp();
    fs::create_directory_symlink(kSource / "config", dir_ / "config");
  }

  // Runs `args` in the test directory; the report is stdout, or the file `report` when given.
  void expect_report(const std::string& golden, const std::vector<std::string>& args,
                     const std::string& report = "") {
    SCOPED_TRACE(golden);
    const ProcessResult r = fit(args, /*in_dir=*/true);
    ASSERT_EQ(r.status, 0) << r.err;
    const std::string got = without_wall_time(report.empty() ? r.out : slurp(path(report)));
    ASSERT_FALSE(got.empty());
    const fs::path copy = kGolden / golden;
    if (std::getenv("CDPR_UPDATE_GOLDEN") != nullptr) {
      std::ofstream(copy, std::ios::binary) << got;
      return;
    }
    ASSERT_TRUE(fs::exists(copy)) << copy << " is missing (CDPR_UPDATE_GOLDEN=1 writes it)";
    const std::string want = slurp(copy);
    EXPECT_EQ(got.size(), want.size());
    EXPECT_TRUE(got == want) << "differs from " << copy << "; the report is kept in " << dir_;
  }

  // Sets the "# date:" line of a recording in the test directory to a fixed date.
  void pin_date(const std::string& recording) {
    const std::string text = slurp(path(recording));
    static const std::regex kDate("# date: [^\n]*");
    const std::string pinned = std::regex_replace(text, kDate, "# date: 2025-01-01T00:00:00Z",
                                                  std::regex_constants::format_first_only);
    ASSERT_NE(pinned, text) << recording << " has no date line";
    std::ofstream(path(recording), std::ios::binary) << pinned;
  }
};

TEST_F(CdprFitGolden, TypicalSessionReportsAreUnchanged) {
  expect_report("design-poses.json", {"--json", "design-poses", "--config", "config/mini.yaml",
                                      "--count", "25", "--out", "poses.csv"});
  expect_report("predict-accuracy.json", {"--json", "predict-accuracy", "--config",
                                          "config/mini.yaml", "--poses", "poses.csv"});
  expect_report("simulate.json", {"--json",         "simulate",
                                  "--config",       "config/mini-measured.yaml",
                                  "--nominal",      "config/mini.yaml",
                                  "--physics",      "elastic",
                                  "--poses",        "poses.csv",
                                  "--noise-laser",  "0.001",
                                  "--noise-length", "1e-4",
                                  "--noise-force",  "1",
                                  "--seed",         "42",
                                  "--out",          "rec.csv"});
  pin_date("rec.csv");
  expect_report(
      "calibrate.json",
      {"calibrate", "--config", "config/mini.yaml", "--recording", "rec.csv", "--out",
       "calibrated.yaml", "--report", "report.json", "--truth", "config/mini-measured.yaml"},
      "report.json");
  expect_report("diagnose.json",
                {"diagnose", "--config", "config/mini.yaml", "--recording", "rec.csv", "--json",
                 "diagnose.json", "--html", "diagnose.html", "--out", "diagnosed.yaml"},
                "diagnose.json");
}

TEST_F(CdprFitGolden, ExampleReportsAreUnchanged) {
  expect_report("fit-cable.json", {"--json", "fit-cable", "--experiment",
                                   "config/examples/cable-experiment.csv", "--max-order", "6"});
  expect_report("fit-force-sensor.json", {"--json", "fit-force-sensor", "--experiment",
                                          "config/examples/force-experiment.csv"});
  expect_report("simulate-example-poses.json",
                {"--json", "simulate", "--config", "config/mini-measured.yaml", "--poses",
                 "config/examples/mini-poses.csv", "--seed", "42", "--out", "rec.csv"});
}

TEST_F(CdprFitGolden, ReadmeSessionReportsAreUnchanged) {
  expect_report("readme-design-poses.json",
                {"--json", "design-poses", "--config", "config/mini.yaml", "--count", "25", "--out",
                 "poses.csv"});
  expect_report("readme-simulate.json",
                {"--json", "simulate", "--config", "config/mini-measured.yaml", "--nominal",
                 "config/mini.yaml", "--physics", "elastic", "--poses", "poses.csv", "--seed", "1",
                 "--out", "rec.csv"});
  pin_date("rec.csv");
  expect_report("readme-calibrate.json",
                {"--json", "calibrate", "--config", "config/mini.yaml", "--recording", "rec.csv",
                 "--out", "mini-calibrated.yaml"});
}

}  // namespace
