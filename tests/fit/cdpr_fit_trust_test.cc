// Issue 41 through the cdpr-fit binary: the defects a real suspended robot exposed (reproduced on
// config/crane4.yaml with simulated recordings), held-out validation against the nominal model,
// and the uncertainty a failed fit states.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "cdpr/config/robot_config.hpp"
#include "fit_process.hpp"

namespace cdpr::fit_test {
namespace {

const std::string kCrane = kSource + "/config/crane4.yaml";

class Trust : public FitProcessTest {
 protected:
  Trust() : FitProcessTest("cdpr_fit_trust_test_") {}

  // A crane whose anchors are 2 cm further out and up than the nominal's (symmetric, so it still
  // hangs level at home) and whose platform is `mass` kg with its centre of mass at `com` (hanging
  // at home with `home_rpy`): a recording of `poses` designed poses with `channels`, commanded
  // through the nominal config, elastic physics.
  std::string crane_recording(const std::string& name, const std::string& channels, int poses = 15,
                              int seed = 5, const std::string& mass = "13.0",
                              const std::string& com = "[0, 0, -0.35]",
                              const std::string& home_rpy = "[0, 0, 0]") const {
    std::string yaml = slurp(kCrane);
    auto replace = [&](const std::string& from, const std::string& to) {
      const auto at = yaml.find(from);
      EXPECT_NE(at, std::string::npos) << from;
      if (at != std::string::npos) yaml.replace(at, from.size(), to);
    };
    replace("[1.0, -1.15, 1.8]", "[1.02, -1.17, 1.82]");
    replace("[-1.0, -1.15, 1.8]", "[-1.02, -1.17, 1.82]");
    replace("[-1.0, 1.15, 1.8]", "[-1.02, 1.17, 1.82]");
    replace("[1.0, 1.15, 1.8]", "[1.02, 1.17, 1.82]");
    replace("mass: 13.0", "mass: " + mass);
    replace("center_of_mass: [0, 0, -0.35]", "center_of_mass: " + com);
    replace("\n  rpy: [0, 0, 0]", "\n  rpy: " + home_rpy);
    const std::string truth = path(name + "-truth.yaml"), rec = path(name + ".csv");
    std::ofstream(truth) << yaml;
    const ProcessResult s = fit({"simulate", "--config", truth, "--nominal", kCrane, "--physics",
                                 "elastic", "--design", std::to_string(poses), "--channels",
                                 channels, "--seed", std::to_string(seed), "--out", rec});
    EXPECT_EQ(s.status, 0) << s.err;
    return rec;
  }

  // Diagnose each campaign and validate the model diagnose writes on the next one.
  void expect_weight_named_and_predicting(const std::string& config,
                                          const std::vector<std::string>& campaigns) const;

  // `rec` without its first data row (the home pose).
  std::string without_home_row(const std::string& rec) const {
    std::ifstream in(rec);
    std::ostringstream out;
    std::string line;
    bool header = false, dropped = false;
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#' && header && !dropped) {
        dropped = true;
        continue;
      }
      if (!line.empty() && line[0] != '#') header = true;
      out << line << "\n";
    }
    const std::string file = path("no-home.csv");
    std::ofstream(file) << out.str();
    return file;
  }
};

// A documented exit status, never a signal (the Eigen assertion aborted with 134).
void expect_documented(const ProcessResult& r) {
  EXPECT_THAT(r.status, ::testing::AnyOf(0, 1, 3, 4)) << r.err << r.out;
  EXPECT_THAT(r.err, Not(HasSubstr("Assertion")));
}

TEST_F(Trust, ImuYawZeroAloneWithoutAGaugeOnASuspendedRobotIsNoSignal) {
  const std::string rec = crane_recording("all", "swivel,inclinometer,imu-yaw");
  const ProcessResult r = fit({"calibrate", "--config", kCrane, "--recording", rec, "--gauge",
                               "none", "--estimate", "imu-yaw-zero"});
  expect_documented(r);
  // Every channel's analysis with a mounting parameter only its channel observes.
  for (const char* estimate : {"swivel-zeros", "inclinometer-mounting", "imu-yaw-zero"}) {
    for (const char* gauge : {"home", "none"}) {
      expect_documented(fit({"calibrate", "--config", kCrane, "--recording", rec, "--gauge", gauge,
                             "--estimate", estimate}));
    }
  }
}

TEST_F(Trust, RecordingWithoutAHomeRowIsRefusedWithWhatToDo) {
  const std::string rec = without_home_row(crane_recording("lc", "none"));
  const ProcessResult c = fit({"calibrate", "--config", kCrane, "--recording", rec});
  EXPECT_EQ(c.status, 1) << c.out;
  EXPECT_THAT(c.err, HasSubstr("row 0, which the gauge holds at the config's home pose"));
  EXPECT_THAT(c.err, HasSubstr("no row is at home"));
  EXPECT_THAT(c.err, HasSubstr("--gauge start"));
  // diagnose has the same gauge and refuses the same way.
  const ProcessResult d = fit({"diagnose", "--config", kCrane, "--recording", rec});
  EXPECT_EQ(d.status, 1) << d.out;
  EXPECT_THAT(d.err, HasSubstr("--gauge start"));
  // Holding the first row at its commanded pose is a calibration whose frame anchors stay inside
  // their ranges (pinned at the config's home, an anchor ended on its bound).
  const std::string report = path("start.json");
  const ProcessResult s = fit({"calibrate", "--config", kCrane, "--recording", rec, "--gauge",
                               "start", "--report", report, "--out", path("start.yaml")});
  expect_documented(s);
  const nlohmann::json j = nlohmann::json::parse(slurp(report));
  for (const auto& name : j.at("fit_test").at("at_bound")) {
    EXPECT_NE(name.get<std::string>().substr(0, 2), "a_") << s.out;
  }
  EXPECT_TRUE(cdpr::config::load_robot_config(path("start.yaml")).ok());
}

TEST_F(Trust, EstimateNoneChecksAFixedModel) {
  const std::string rec = simulate_elastic(12, "mini.csv");
  const std::string report = path("none.json");
  const ProcessResult r = fit({"calibrate", "--config", kTruth, "--recording", rec, "--estimate",
                               "none", "--report", report});
  expect_documented(r);
  const nlohmann::json j = nlohmann::json::parse(slurp(report));
  EXPECT_TRUE(j.at("estimate").empty());
  EXPECT_GT(j.at("dof").get<int>(), 0);
  // On the crane the home pose's tilt is still estimated (gravity fixes the frame's tilt).
  const std::string crane = crane_recording("lc", "none");
  expect_documented(
      fit({"calibrate", "--config", kCrane, "--recording", crane, "--estimate", "none"}));
  const ProcessResult mixed =
      fit({"calibrate", "--config", kCrane, "--recording", crane, "--estimate", "none,anchors"});
  EXPECT_EQ(mixed.status, 1);
  EXPECT_THAT(mixed.err, HasSubstr("--estimate: none is a fixed model"));
}

// Every channel's sigma can be given on the command line of calibrate and diagnose: ten times
// the recorded sigma lowers that channel's share of chi^2 a hundredfold.
TEST_F(Trust, NoiseOverridesReachEveryChannel) {
  const std::string rec = crane_recording("all", "swivel,inclinometer,imu-yaw");
  auto chi2_with = [&](const std::vector<std::string>& extra) {
    std::vector<std::string> args = {"--json", "calibrate", "--config", kCrane, "--recording", rec};
    args.insert(args.end(), extra.begin(), extra.end());
    const ProcessResult r = fit(args);
    EXPECT_THAT(r.status, ::testing::AnyOf(0, 3, 4)) << r.err;
    return nlohmann::json::parse(r.out).at("chi2").get<double>();
  };
  const double base = chi2_with({});
  for (const char* option : {"--noise-length", "--noise-force", "--noise-swivel",
                             "--noise-inclination", "--noise-imu-yaw"}) {
    EXPECT_LT(chi2_with({option, "10"}), base) << option;
  }
  const ProcessResult d = fit({"diagnose", "--config",        kCrane,  "--recording",
                               rec,        "--noise-swivel",  "0.001", "--noise-inclination",
                               "0.0005",   "--noise-imu-yaw", "0.01",  "--noise-laser",
                               "0.001",    "--bootstrap",     "2",     "--folds",
                               "2",        "--gauge",         "home",  "--home-pose",
                               "0"});
  EXPECT_THAT(d.status, ::testing::AnyOf(0, 3, 4)) << d.err;
}

// The configs calibrate writes reload, for every estimate item that applies to the robot, on a
// suspended crane and an over-constrained MINI.
TEST_F(Trust, EveryConfigCalibrateWritesReloads) {
  struct Robot {
    std::string config, recording;
    std::vector<std::string> items;
  };
  const std::vector<Robot> robots = {
      {kCrane,
       crane_recording("all", "swivel,inclinometer,imu-yaw", 12),
       {"anchors", "platform-anchors", "offsets", "scales", "stiffness", "stiffness-per-cable",
        "force-gains", "force-offsets", "swivel-zeros", "inclinometer-mounting", "imu-yaw-zero",
        "mass", "com", "none"}},
      {kNominal,
       simulate_elastic(12, "mini.csv"),
       {"anchors", "platform-anchors", "offsets", "scales", "stiffness", "stiffness-per-cable",
        "force-gains", "force-offsets", "laser-origin", "laser-direction", "laser-plane",
        "paper-anchors", "mass", "com", "none"}},
  };
  for (const Robot& robot : robots) {
    for (const std::string& item : robot.items) {
      const std::string out = path("cal.yaml");
      std::filesystem::remove(out);
      const std::string estimate =
          item == "none" || item == "paper-anchors" ? item : "anchors,offsets," + item;
      const ProcessResult r = fit({"calibrate", "--config", robot.config, "--recording",
                                   robot.recording, "--estimate", estimate, "--out", out});
      expect_documented(r);
      if (r.status == 1) continue;  // refused (unidentifiable): nothing written
      auto reloaded = cdpr::config::load_robot_config(out);
      EXPECT_TRUE(reloaded.ok()) << robot.config << " --estimate " << estimate << ": "
                                 << reloaded.status().to_string();
    }
  }
}

// The config diagnose --out writes reloads on the crane with a concealed heavier platform.
TEST_F(Trust, TheConfigDiagnoseWritesReloads) {
  const std::string rec = crane_recording("heavy", "none", 15, 5, "14.5");
  const std::string out = path("diagnosed.yaml");
  const ProcessResult d = fit({"diagnose", "--config", kCrane, "--recording", rec, "--out", out,
                               "--bootstrap", "5", "--folds", "3"});
  EXPECT_THAT(d.status, ::testing::AnyOf(0, 3, 4)) << d.err;
  auto reloaded = cdpr::config::load_robot_config(out);
  EXPECT_TRUE(reloaded.ok()) << reloaded.status().to_string();
}

// validate: the calibrated model of one MINI campaign predicts another campaign better than the
// nominal model; calibrate --validate exits 5 when the calibration does not beat the nominal.
TEST_F(Trust, CalibratedModelBeatsTheNominalOnAHeldOutCampaign) {
  const std::string a = simulate_elastic(15, "a.csv", 3), b = simulate_elastic(15, "b.csv", 8);
  const std::string cal = path("cal.yaml");
  const ProcessResult c =
      fit({"calibrate", "--config", kNominal, "--recording", a, "--out", cal, "--validate", b});
  EXPECT_EQ(c.status, 0) << c.out << c.err;
  EXPECT_THAT(c.out, HasSubstr("calibrated model beats the nominal one"));
  const ProcessResult v = fit({"--json", "validate", "--config", kNominal, "--recording", b,
                               "--model", kNominal, "--model", cal});
  ASSERT_EQ(v.status, 0) << v.err;
  const nlohmann::json j = nlohmann::json::parse(v.out);
  const auto& models = j.at("models");
  ASSERT_EQ(models.size(), 2u);
  const double nominal = models[0].at("chi2").get<double>();
  const double calibrated = models[1].at("chi2").get<double>();
  EXPECT_LT(calibrated, nominal);
  EXPECT_LT(calibrated / models[1].at("residuals").get<double>(), 1.5);
  // A "calibration" that changes nothing does not beat the nominal model: exit 5, said.
  const ProcessResult same = fit(
      {"calibrate", "--config", kNominal, "--recording", a, "--estimate", "none", "--validate", b});
  EXPECT_EQ(same.status, 5) << same.out;
  EXPECT_THAT(same.out, HasSubstr("DOES NOT BEAT"));
}

// A fit that fails its test says that its standard deviations are scaled by sqrt(chi2/dof).
TEST_F(Trust, AFailedFitScalesItsStandardDeviationsAndSaysSo) {
  const std::string rec = crane_recording("heavy", "none", 15, 5, "14.5");
  const std::string report = path("heavy.json");
  const ProcessResult c =
      fit({"calibrate", "--config", kCrane, "--recording", rec, "--report", report});
  EXPECT_EQ(c.status, 3) << c.out;
  EXPECT_THAT(c.out, HasSubstr("is scaled by sqrt(chi2/dof)"));
  const nlohmann::json j = nlohmann::json::parse(slurp(report));
  const double scale = j.at("uncertainty").at("scale").get<double>();
  EXPECT_NEAR(scale, std::sqrt(j.at("chi2").get<double>() / j.at("dof").get<double>()), 1e-9);
  EXPECT_TRUE(j.at("uncertainty").at("scaled_for_misfit").get<bool>());
}

// Issue 41, platform mass and centre of mass: a platform 12 % heavier than configured whose centre
// of mass is 10-20 mm off, two independent campaigns. Diagnosed, each names the platform's weight
// and nothing else, and the model diagnose writes predicts the other campaign better than the
// nominal model in every channel (the coverage over more campaigns: bench/weight_coverage.py
// --diagnose, docs/identification.md).
void Trust::expect_weight_named_and_predicting(const std::string& config,
                                               const std::vector<std::string>& campaigns) const {
  for (std::size_t k = 0; k < campaigns.size(); ++k) {
    const std::string& rec = campaigns[k];
    const std::string& held_out = campaigns[(k + 1) % campaigns.size()];
    const std::string diagnosed = path("diagnosed.yaml");
    const ProcessResult d = fit({"--json", "diagnose", "--config", config, "--recording", rec,
                                 "--out", diagnosed, "--bootstrap", "5", "--folds", "3"});
    ASSERT_THAT(d.status, ::testing::AnyOf(0, 3)) << d.err;
    const nlohmann::json j = nlohmann::json::parse(d.out);
    EXPECT_EQ(j.at("named_effects"), nlohmann::json::array({"platform_weight"}))
        << rec << ": " << j.at("headline");
    const ProcessResult v = fit({"--json", "validate", "--config", config, "--recording", held_out,
                                 "--model", config, "--model", diagnosed});
    ASSERT_EQ(v.status, 0) << v.err;
    const nlohmann::json validation = nlohmann::json::parse(v.out);
    const nlohmann::json& models = validation.at("models");
    ASSERT_EQ(models.size(), 2u);
    const auto& nominal = models[0].at("channels");
    const auto& channels = models[1].at("channels");
    ASSERT_EQ(channels.size(), nominal.size());
    for (std::size_t q = 0; q < channels.size(); ++q) {
      EXPECT_LT(channels[q].at("rms").get<double>(), nominal[q].at("rms").get<double>())
          << rec << " -> " << held_out << ", channel " << channels[q].at("channel");
    }
  }
}

TEST_F(Trust, WrongPlatformWeightOfTheCraneIsNamedAndPredictsTheOtherCampaign) {
  // The offset centre of mass tilts the hanging platform at home (the config must say where).
  const std::string mass = "14.56", com = "[0.015, -0.01, -0.33]";
  const std::string rpy = "[0.0197578, 0.0310434, 0]";
  expect_weight_named_and_predicting(
      kCrane, {crane_recording("wa", "swivel,inclinometer", 15, 5, mass, com, rpy),
               crane_recording("wb", "swivel,inclinometer", 15, 6, mass, com, rpy)});
}

TEST_F(Trust, WrongPlatformWeightOfMiniIsNamedAndPredictsTheOtherCampaign) {
  std::string yaml = slurp(kTruth);
  for (const auto& [from, to] :
       {std::pair<std::string, std::string>{"mass: 2.0", "mass: 2.24"},
        {"center_of_mass: [0, 0, 0]", "center_of_mass: [0.015, -0.01, 0.02]"}}) {
    const auto at = yaml.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    yaml.replace(at, from.size(), to);
  }
  const std::string truth = path("mini-heavy.yaml");
  std::ofstream(truth) << yaml;
  expect_weight_named_and_predicting(kNominal, {simulate_elastic(20, "wa.csv", 3, truth),
                                                simulate_elastic(20, "wb.csv", 8, truth)});
}

}  // namespace
}  // namespace cdpr::fit_test
