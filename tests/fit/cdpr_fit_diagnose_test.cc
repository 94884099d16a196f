// Integration tests of `cdpr-fit diagnose`: the real binary runs as a separate process
// (CDPR_FIT_BIN) on recordings that `cdpr-fit simulate` makes of the shipped MINI configs
// (CDPR_SOURCE_DIR/config), some of them altered here through the recording library to conceal an
// effect or to break them. The exit status, the JSON report (parsed), the HTML report and the
// calibrated config (loaded with the config library) are checked. The report helpers that need
// no process (HTML escaping, the explaining variable of an effect) are called directly.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "cdpr/config/robot_config.hpp"
#include "cdpr/recording/recording.hpp"
#include "fit_process.hpp"

namespace cdpr::fit_test {
namespace {

// A smaller bootstrap and fewer folds than the defaults (100 resamples, leave one pose out), for
// the runs that check the options are taken; the others use the defaults, as an engineer would.
const std::vector<std::string> kQuick = {"--bootstrap", "20", "--folds", "3", "--seed", "2"};

using Process = ProcessResult;

class Diagnose : public FitProcessTest {
 protected:
  Diagnose() : FitProcessTest("cdpr_fit_diagnose_test_") {}

  // Reads `in`, lets `change` alter it and writes it to `name`.
  std::string altered(const std::string& in, const std::string& name,
                      const std::function<void(cdpr::recording::Recording&)>& change) const {
    auto rec = cdpr::recording::read_recording(in);
    EXPECT_TRUE(rec.ok()) << rec.status().to_string();
    change(*rec);
    const std::string out = path(name);
    const cdpr::Status s = cdpr::recording::write_recording(*rec, out);
    EXPECT_TRUE(s.ok()) << s.to_string();
    return out;
  }

  Process diagnose(const std::string& recording, std::vector<std::string> extra) const {
    std::vector<std::string> args = {"diagnose", "--config", kNominal, "--recording", recording};
    args.insert(args.end(), extra.begin(), extra.end());
    return fit(args);
  }
};

TEST_F(Diagnose, RecordingOfACorrectModelExitsZeroWithJsonAndHtmlReports) {
  const std::string rec = simulate_elastic(25, "null.csv");
  const std::string json = path("report.json"), html = path("report.html");
  std::vector<std::string> args = {"--json", json, "--html", html};
  args.insert(args.end(), kQuick.begin(), kQuick.end());
  const Process r = diagnose(rec, args);
  ASSERT_EQ(r.status, 0) << r.err << r.out;
  EXPECT_THAT(r.out, HasSubstr("verdict: no_mismatch"));
  EXPECT_THAT(r.out, HasSubstr("mm"));  // lengths are shown to people in mm

  const nlohmann::json j = nlohmann::json::parse(slurp(json));
  EXPECT_TRUE(j.at("ok").get<bool>());
  EXPECT_EQ(j.at("command"), "diagnose");
  EXPECT_EQ(j.at("verdict"), "no_mismatch");
  EXPECT_FALSE(j.at("mismatch_found").get<bool>());
  EXPECT_EQ(j.at("exit_status").get<int>(), 0);
  EXPECT_TRUE(j.at("named_effects").empty());
  EXPECT_FALSE(j.at("headline").get<std::string>().empty());
  EXPECT_EQ(j.at("inputs").at("poses").get<int>(), 25);
  EXPECT_EQ(j.at("options").at("bootstrap").get<int>(), 20);
  EXPECT_EQ(j.at("options").at("folds").get<int>(), 3);
  EXPECT_EQ(j.at("cable_misfit_normalized").at("before").size(), 8u);
  EXPECT_FALSE(j.at("channels").empty());
  // No effect named: a suspect with its follow-up poses, or null.
  ASSERT_TRUE(j.contains("follow_up"));
  const nlohmann::json& fu = j.at("follow_up");
  if (!fu.is_null()) {
    EXPECT_FALSE(fu.at("suspect").get<std::string>().empty());
    EXPECT_LT(fu.at("p_value").get<double>(), 0.2);
    ASSERT_FALSE(fu.at("poses").empty());
    for (const auto& p : fu.at("poses")) EXPECT_EQ(p.size(), 6u);
    EXPECT_EQ(fu.at("pretensions_n").size(), fu.at("poses").size());
    EXPECT_THAT(r.out, HasSubstr("Follow-up poses"));
    EXPECT_THAT(slurp(html), HasSubstr("Suspected, not proven"));
  }

  ASSERT_TRUE(fs::exists(html));
  const std::string page = slurp(html);
  EXPECT_THAT(page, HasSubstr("<svg"));
  EXPECT_THAT(page, HasSubstr("</html>"));
  // Self-contained: no script, no stylesheet or image fetched from anywhere.
  EXPECT_THAT(page, Not(HasSubstr("<script")));
  EXPECT_THAT(page, Not(HasSubstr("src=")));
  EXPECT_THAT(page, Not(HasSubstr("<link")));
}

// The true cables are twice as soft as the nominal config says (EA 10 kN instead of 20 kN): an
// elasticity the standard identification (anchors, encoder offsets, laser plane) cannot absorb.
TEST_F(Diagnose, ConcealedSofterCablesAreNamedAndCarriedByTheCalibratedConfig) {
  auto truth = cdpr::config::load_robot_config(kTruth);
  ASSERT_TRUE(truth.ok()) << truth.status().to_string();
  constexpr double kTrueEa = 10000.0;  // N
  for (auto& c : truth->cables) {
    ASSERT_GT(c.ea, 1.5 * kTrueEa) << "the shipped MINI must be stiffer than the concealed truth";
    c.ea = kTrueEa;
  }
  const std::string soft = path("soft.yaml");
  {
    std::ofstream f(soft);
    f << cdpr::config::save_robot_config(*truth);
  }
  const std::string rec = simulate_elastic(25, "soft.csv", 3, soft);
  const std::string cal = path("calibrated.yaml"), html = path("report.html");
  const Process r = diagnose(rec, {"--json", "--out", cal, "--html", html});
  ASSERT_EQ(r.status, 3) << r.err << r.out;
  const nlohmann::json j = nlohmann::json::parse(r.out);  // --json without a file: stdout
  EXPECT_EQ(j.at("verdict"), "mismatch_named");
  EXPECT_TRUE(j.at("mismatch_found").get<bool>());
  EXPECT_EQ(j.at("exit_status").get<int>(), 3);
  ASSERT_FALSE(j.at("accepted").empty());
  EXPECT_EQ(j.at("accepted")[0].at("family"), "elasticity") << j.at("named_effects").dump();
  EXPECT_EQ(j.at("named_effects")[0], j.at("accepted")[0].at("id"));
  // Issue 16 item 9: every number means what its label says. The text cites the named effect's
  // FAMILY inclusion ("its family 'elasticity' selected in 66 % of the bootstrap resamples"),
  // not the candidate's own share (elasticity and compliance are confounded on MINI, and the
  // nonlinear elasticity nests the Hooke one: one member's own share can be 1 % while the family
  // is selected in most resamples). The family share is the same for every member and at least
  // each member's own share, and the named family is selected in most resamples.
  const auto& named = j.at("accepted")[0];
  const double family_inclusion = named.at("family_inclusion_probability").get<double>();
  for (const auto& c : j.at("candidates")) {
    if (c.at("family") != named.at("family")) continue;
    EXPECT_EQ(c.at("family_inclusion_probability").get<double>(), family_inclusion) << c.at("id");
    EXPECT_LE(c.at("inclusion_probability").get<double>(), family_inclusion + 1e-12) << c.at("id");
  }
  EXPECT_GE(family_inclusion, 0.5);
  // The held-out prediction improves when the effect is modelled.
  const auto& held = j.at("held_out");
  EXPECT_LT(held.at("rms_after_m").get<double>(), 0.5 * held.at("rms_before_m").get<double>());

  // The calibrated config loads and carries the softer cables.
  auto calibrated = cdpr::config::load_robot_config(cal);
  ASSERT_TRUE(calibrated.ok()) << calibrated.status().to_string();
  ASSERT_EQ(calibrated->num_cables(), 8);
  for (std::size_t i = 0; i < 8; ++i) {
    EXPECT_NEAR(calibrated->cables[i].ea, kTrueEa, 0.05 * kTrueEa) << "cable " << i + 1;
  }
  // The plot of an elasticity is against tension x loaded length, before and after.
  const std::string page = slurp(html);
  EXPECT_THAT(page, HasSubstr("tension x loaded length"));
  EXPECT_THAT(page, HasSubstr("class=\"f\""));  // "after" points
}

TEST_F(Diagnose, RecordingsThatDoNotFitTheConfigAreRefusedWithFileAndReason) {
  const std::string clean = simulate_elastic(20, "clean.csv");
  struct Case {
    std::string name;
    std::function<void(cdpr::recording::Recording&)> change;
    std::vector<std::string> expected;  // substrings of stderr
  };
  const std::vector<Case> cases = {
      {"seven-cables.csv",
       [](cdpr::recording::Recording& r) {
         r.num_cables = 7;
         for (auto& p : r.poses) {
           p.lengths.conservativeResize(7);
           p.tensions.conservativeResize(7);
         }
       },
       {"seven-cables.csv vs", "cable count mismatch", "7 cables", "has 8"}},
      {"millimetres.csv",
       [](cdpr::recording::Recording& r) {
         for (auto& p : r.poses) p.lengths *= 1000.0;
       },
       {"millimetres.csv: length_1..length_8: looks like mm, expected m"}},
      {"laser-mm.csv",
       [](cdpr::recording::Recording& r) {
         for (auto& p : r.poses) p.lasers *= 1000.0;
       },
       // every cell is checked in file order: the first laser reading names its line and column
       {"laser-mm.csv:", " (laser_1): ", "outside the plausible range",
        "looks like mm, expected m"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string rec = altered(clean, c.name, c.change);
    const std::string out = path(c.name + ".yaml"), html = path(c.name + ".html");
    const Process r = diagnose(rec, {"--out", out, "--html", html});
    EXPECT_EQ(r.status, 1) << r.out;
    EXPECT_THAT(r.err, HasSubstr("cdpr-fit diagnose: error: "));
    for (const std::string& e : c.expected) EXPECT_THAT(r.err, HasSubstr(e));
    EXPECT_FALSE(fs::exists(out)) << "nothing may be written for a refused recording";
    EXPECT_FALSE(fs::exists(html));
  }
  // A file that says it is in mm is refused by the reader, naming its line.
  const std::string text = slurp(clean);
  const std::string from = "# units: SI", to = "# units: mm";
  const std::size_t at = text.find(from);
  ASSERT_NE(at, std::string::npos);
  const std::string mm = path("units-mm.csv");
  {
    std::ofstream f(mm);
    f << text.substr(0, at) << to << text.substr(at + from.size());
  }
  const Process r = diagnose(mm, {"--json"});
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("units-mm.csv:"));
  EXPECT_THAT(r.err, HasSubstr("units 'mm' are not supported"));
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_FALSE(j.at("ok").get<bool>());
}

TEST_F(Diagnose, RecordingTooSmallToTellEffectsApartIsInconclusive) {
  // Enough poses to calibrate, fewer than DiagnosisOptions::min_poses (12) to compare effects.
  const std::string rec = simulate_elastic(8, "small.csv");
  const Process r = diagnose(rec, {"--json"});
  ASSERT_EQ(r.status, 4) << r.err << r.out;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j.at("verdict"), "inconclusive");
  EXPECT_EQ(j.at("exit_status").get<int>(), 4);
  EXPECT_EQ(j.at("inputs").at("poses").get<int>(), 8);
  EXPECT_TRUE(j.at("named_effects").empty());
  EXPECT_FALSE(j.at("headline").get<std::string>().empty());

  // Too few even for the standard calibration: still inconclusive, and no config is written
  // because nothing was calibrated.
  const std::string two =
      altered(rec, "two.csv", [](cdpr::recording::Recording& x) { x.poses.resize(2); });
  const std::string out = path("two.yaml");
  const Process r2 = diagnose(two, {"--out", out});
  EXPECT_EQ(r2.status, 4) << r2.err << r2.out;
  EXPECT_THAT(r2.out, HasSubstr("not written"));
  EXPECT_FALSE(fs::exists(out));
}

// One mistyped length cell (a wild reading): inconclusive (exit 4), the reading named in the
// words and the JSON, no physics named.
TEST_F(Diagnose, AWildReadingIsNamedAndTheVerdictIsInconclusive) {
  const std::string clean = simulate_elastic(25, "clean.csv");
  const std::string rec = altered(clean, "wild.csv", [](cdpr::recording::Recording& x) {
    x.poses[4].lengths(2) += 0.25;  // 250 mm: a digit slipped
  });
  const std::string json = path("wild.json"), out = path("wild.yaml");
  const Process r = diagnose(rec, {"--json", json, "--out", out});
  ASSERT_EQ(r.status, 4) << r.err << r.out;
  // The identification is dragged by the wild reading: no calibrated config, and it says so.
  EXPECT_FALSE(fs::exists(out));
  EXPECT_THAT(r.out, HasSubstr("not written: the recording holds a gross reading"));
  EXPECT_THAT(r.out, HasSubstr("verdict: inconclusive"));
  EXPECT_THAT(r.out, HasSubstr("cable length 3 of the 5th pose: off by 250."));
  const nlohmann::json j = nlohmann::json::parse(slurp(json));
  EXPECT_EQ(j.at("verdict"), "inconclusive");
  EXPECT_TRUE(j.at("named_effects").empty());
  ASSERT_EQ(j.at("gross_readings").size(), 1u);
  const nlohmann::json& g = j.at("gross_readings").at(0);
  EXPECT_EQ(g.at("pose").get<int>(), 5);
  EXPECT_EQ(g.at("channel"), "cable length");
  EXPECT_EQ(g.at("index").get<int>(), 3);
  EXPECT_NEAR(g.at("residual_si").get<double>(), -0.25, 0.005);
}

// --folds 0: leave one pose out; the report says so.
TEST_F(Diagnose, FoldsZeroHoldsOutOnePoseAtATime) {
  const std::string rec = simulate_elastic(12, "loo.csv");
  const std::string json = path("loo.json");
  const Process r = diagnose(rec, {"--json", json, "--bootstrap", "20", "--folds", "0"});
  ASSERT_EQ(r.status, 0) << r.err << r.out;
  EXPECT_THAT(r.out, HasSubstr("leave-one-pose-out cross-validation"));
  const nlohmann::json j = nlohmann::json::parse(slurp(json));
  EXPECT_EQ(j.at("options").at("folds").get<int>(), 0);
  EXPECT_EQ(j.at("held_out").at("source"), "leave-one-pose-out cross-validation");
}

TEST_F(Diagnose, UsageErrorsExitWithTwo) {
  EXPECT_EQ(fit({"diagnose", "--config", kNominal}).status, 2);  // --recording missing
  const std::string rec = simulate_elastic(12, "rec.csv");
  EXPECT_EQ(fit({"diagnose", "--config", kNominal, "--recording", rec, "--folds", "1"}).status, 2);
  EXPECT_EQ(fit({"diagnose", "--config", kNominal, "--recording", rec, "--folds", "-1"}).status, 2);
  EXPECT_EQ(fit({"diagnose", "--config", kNominal, "--recording", rec, "--folds", "0x"}).status, 2);
  EXPECT_EQ(
      fit({"diagnose", "--config", kNominal, "--recording", rec, "--noise-length", "-1"}).status,
      2);
  const Process help = fit({"diagnose", "--help"});
  EXPECT_EQ(help.status, 0);
  EXPECT_THAT(help.out, HasSubstr("--validate"));
}

}  // namespace
}  // namespace cdpr::fit_test
