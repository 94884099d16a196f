// Issue 18 end to end through the cdpr-fit binary: a recording without a laser, with swivel
// angles and an inclinometer, simulated from a truth with hidden mounting errors, calibrated and
// diagnosed.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/calibration/suspended_statics.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/recording/recording.hpp"
#include "fit_process.hpp"

namespace cdpr::fit_test {
namespace {

using Process = ProcessResult;

class FitSensors : public FitProcessTest {
 protected:
  FitSensors() : FitProcessTest("cdpr_fit_sensors_test_") {}

  // The measured MINI with an inclinometer tilted on its mount and swivel encoders whose zeros
  // are off (besides the pulley reference directions, which differ from the nominal config's).
  std::string truth_with_mounting_errors() const {
    std::string yaml = slurp(kTruth);
    const std::string from = "  force_sensor: {gain: 2, offset: 0}\n";
    const auto at = yaml.find(from);
    EXPECT_NE(at, std::string::npos);
    yaml.insert(at + from.size(), "  swivel_encoder: {zero: 0.02}\n");
    yaml += "inclinometer: {mounting_rpy: [0.012, -0.017, 0]}\n";
    const std::string out = path("truth.yaml");
    std::ofstream(out) << yaml;
    return out;
  }

  // The calibrated config `cal` read back: its frame anchors at least halve the nominal
  // config's distance to the truth's (RMS), and the inclinometer's mounting tilt (0.012, -0.017
  // rad in the truth) is found to a fraction of its size. nullopt (with a failure) when a config
  // does not load.
  std::optional<cdpr::RobotModel> expect_anchors_and_mounting_found(const std::string& nominal_path,
                                                                    const std::string& truth,
                                                                    const std::string& cal) const {
    auto nominal = cdpr::config::load_robot_config(nominal_path);
    auto real = cdpr::config::load_robot_config(truth);
    auto calibrated = cdpr::config::load_robot_config(cal);
    EXPECT_TRUE(nominal.ok() && real.ok());
    EXPECT_TRUE(calibrated.ok()) << calibrated.status().to_string();
    if (!nominal.ok() || !real.ok() || !calibrated.ok()) return std::nullopt;
    auto rms = [](const cdpr::RobotModel& a, const cdpr::RobotModel& b) {
      return std::sqrt((a.frame_anchors - b.frame_anchors).colwise().squaredNorm().mean());
    };
    const double before = rms(*nominal, *real), after = rms(*calibrated, *real);
    EXPECT_LT(after, 0.5 * before) << before << " m -> " << after << " m";
    EXPECT_NEAR(calibrated->inclinometer.mounting_rpy(0), 0.012, 2e-3);
    EXPECT_NEAR(calibrated->inclinometer.mounting_rpy(1), -0.017, 2e-3);
    return *calibrated;
  }
};

TEST_F(FitSensors, SwivelAndInclinometerRecordingIsCalibratedAndDiagnosedWithoutALaser) {
  const std::string truth = truth_with_mounting_errors();
  const std::string rec = path("rec.csv");
  const Process s =
      fit({"simulate", "--config", truth, "--nominal", kNominal, "--physics", "elastic", "--design",
           "25", "--channels", "swivel,inclinometer", "--seed", "4", "--out", rec});
  ASSERT_EQ(s.status, 0) << s.err << s.out;
  EXPECT_THAT(s.out, HasSubstr("swivel angles, inclinometer"));

  // The file has the new columns and no laser column; it reads back.
  const std::string text = slurp(rec);
  EXPECT_THAT(text, HasSubstr("swivel_8,incl_roll,incl_pitch"));
  EXPECT_THAT(text, HasSubstr("# noise_swivel_rad: "));
  EXPECT_THAT(text, Not(HasSubstr("laser_1")));
  auto parsed = cdpr::recording::read_recording(rec);
  ASSERT_TRUE(parsed.ok()) << parsed.status().to_string();
  EXPECT_EQ(parsed->num_lasers, 0);

  const std::string cal = path("calibrated.yaml"), report = path("report.json");
  const Process c = fit(
      {"calibrate", "--config", kNominal, "--recording", rec, "--out", cal, "--report", report});
  ASSERT_EQ(c.status, 0) << c.err << c.out;
  EXPECT_THAT(c.out, HasSubstr("fixed by the home pose and gravity only"));
  const nlohmann::json j = nlohmann::json::parse(slurp(report));
  EXPECT_TRUE(j.at("converged").get<bool>());
  const std::string estimated = j.dump();
  EXPECT_THAT(estimated, HasSubstr("swivel-zeros"));
  EXPECT_THAT(estimated, HasSubstr("inclinometer-mounting"));
  EXPECT_THAT(estimated, Not(HasSubstr("laser-plane")));

  // The JSON report carries the channel analysis the text report prints: what fixes the world
  // frame, and what each channel makes identifiable.
  const nlohmann::json& ident = j.at("identifiability");
  EXPECT_THAT(ident.at("gauge").dump(), HasSubstr("fixed by the home pose and gravity only"));
  const auto channel = [&](const std::string& name) {
    for (const nlohmann::json& ch : ident.at("channels")) {
      if (ch.at("channel") == name) return ch;
    }
    return nlohmann::json();
  };
  const nlohmann::json swivel = channel("swivel angles");
  ASSERT_FALSE(swivel.is_null()) << ident.at("channels").dump();
  EXPECT_EQ(swivel.at("rows").get<std::size_t>(), 8 * parsed->poses.size());
  std::vector<std::string> made = swivel.at("makes_identifiable");
  for (int i = 1; i <= 8; ++i) {
    EXPECT_THAT(made, ::testing::Contains("swivel_zero_" + std::to_string(i)));
  }
  EXPECT_EQ(ident.at("rank").get<int>() - swivel.at("rank_without").get<int>(),
            static_cast<int>(made.size()));
  EXPECT_THAT(swivel.at("description").get<std::string>(), HasSubstr("makes 8 parameters"));
  const nlohmann::json incl = channel("inclinometer");
  ASSERT_FALSE(incl.is_null());
  made = incl.at("makes_identifiable").get<std::vector<std::string>>();
  EXPECT_THAT(
      made, ::testing::UnorderedElementsAre("inclinometer.mount.roll", "inclinometer.mount.pitch"));
  EXPECT_TRUE(channel("laser").is_null());
  // Every channel's description is the line the text report prints.
  for (const nlohmann::json& ch : ident.at("channels")) {
    EXPECT_THAT(c.out, HasSubstr("channel " + ch.at("description").get<std::string>()));
  }

  const auto calibrated = expect_anchors_and_mounting_found(kNominal, truth, cal);
  ASSERT_TRUE(calibrated.has_value());
  ASSERT_EQ(calibrated->swivel_encoders.size(), 8u);

  // diagnose: the nominal model, calibrated with these channels, explains the recording.
  const std::string djson = path("diagnose.json");
  const Process d = fit({"diagnose", "--config", kNominal, "--recording", rec, "--json", djson,
                         "--bootstrap", "20", "--folds", "3", "--seed", "2"});
  EXPECT_EQ(d.status, 0) << d.err << d.out;
  const nlohmann::json dj = nlohmann::json::parse(slurp(djson));
  EXPECT_EQ(dj.at("verdict"), "no_mismatch") << d.out;
  bool swivel_channel = false;
  for (const auto& ch : dj.at("channels")) {
    swivel_channel = swivel_channel || ch.dump().find("swivel angles") != std::string::npos;
  }
  EXPECT_TRUE(swivel_channel) << dj.at("channels").dump();
}

// Planning for the channels: design-poses and predict-accuracy --channels (issue 18).
TEST_F(FitSensors, PosesAreDesignedAndPredictedForTheChannelsGiven) {
  const std::string poses = path("poses.csv");
  const Process d =
      fit({"--json", "design-poses", "--config", kNominal, "--count", "10", "--points-per-axis",
           "3", "--channels", "swivel,inclinometer", "--out", poses});
  ASSERT_EQ(d.status, 0) << d.err << d.out;
  const nlohmann::json dj = nlohmann::json::parse(d.out);
  EXPECT_EQ(dj.at("channels"), nlohmann::json({"swivel", "inclinometer"}));
  const std::string estimated = dj.at("estimate").dump();
  EXPECT_THAT(estimated, HasSubstr("swivel-zeros"));
  EXPECT_THAT(estimated, HasSubstr("inclinometer-mounting"));
  EXPECT_THAT(estimated, Not(HasSubstr("laser-plane")));
  EXPECT_TRUE(dj.at("noise").contains("swivel_rad"));
  EXPECT_FALSE(dj.at("noise").contains("laser_m"));

  const Process p = fit({"--json", "predict-accuracy", "--config", kNominal, "--poses", poses,
                         "--points-per-axis", "3", "--channels", "swivel,inclinometer"});
  ASSERT_EQ(p.status, 0) << p.err << p.out;
  const nlohmann::json pj = nlohmann::json::parse(p.out);
  EXPECT_EQ(pj.at("rank").get<std::size_t>(), pj.at("parameters").size());
  bool has_swivel_zero = false;
  for (const nlohmann::json& q : pj.at("parameters")) {
    has_swivel_zero = has_swivel_zero || q.at("name") == "swivel_zero_1";
  }
  EXPECT_TRUE(has_swivel_zero);
  // The same poses predicted for the laser configuration: the swivel encoders sharpen the anchors.
  const Process l = fit({"--json", "predict-accuracy", "--config", kNominal, "--poses", poses,
                         "--points-per-axis", "3"});
  ASSERT_EQ(l.status, 0) << l.err;
  EXPECT_LT(pj.at("anchor_rms_std_m").get<double>(),
            nlohmann::json::parse(l.out).at("anchor_rms_std_m").get<double>());

  // Laser parameters without the laser would stay unobserved: refused.
  const Process bad = fit({"design-poses", "--config", kNominal, "--count", "5", "--channels",
                           "swivel", "--estimate", "anchors,laser-plane", "--out", path("b.csv")});
  EXPECT_NE(bad.status, 0);
  EXPECT_THAT(bad.err, HasSubstr("no laser"));
}

// Issue 18, second part: the 4-cable suspended crane end to end. The truth is config/crane4.yaml
// with two anchors off by 2-3 cm, swivel encoder zeros off and a tilted inclinometer; the
// recording (elastic physics, designed equilibrium poses, swivel angles, inclinometer, load cells)
// is calibrated and diagnosed from the shipped nominal config.
TEST_F(FitSensors, SuspendedCraneRecordingIsCalibratedAndDiagnosed) {
  const std::string nominal_path = kSource + "/config/crane4.yaml";
  std::string yaml = slurp(nominal_path);
  auto replace = [&](const std::string& from, const std::string& to) {
    const auto at = yaml.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    yaml.replace(at, from.size(), to);
  };
  replace("frame_anchor: [1.0, -1.15, 1.8]", "frame_anchor: [1.03, -1.13, 1.78]");
  replace("frame_anchor: [-1.0, 1.15, 1.8]", "frame_anchor: [-0.975, 1.17, 1.82]");
  replace("swivel_encoder: {zero: 0, direction: 1}", "swivel_encoder: {zero: 0.02, direction: 1}");
  replace("inclinometer: {mounting_rpy: [0, 0, 0]}",
          "inclinometer: {mounting_rpy: [0.012, -0.017, 0]}");
  // A suspended robot's config must hang at home: the true crane's home attitude is where it
  // hangs at the home position (the model check would refuse the level one).
  {
    auto moved = cdpr::config::load_robot_config(nominal_path);
    ASSERT_TRUE(moved.ok());
    moved->frame_anchors.col(0) = Eigen::Vector3d(1.03, -1.13, 1.78);
    moved->frame_anchors.col(2) = Eigen::Vector3d(-0.975, 1.17, 1.82);
    auto hang = cdpr::suspended_equilibrium_pose(*moved, moved->home);
    ASSERT_TRUE(hang.ok()) << hang.status().to_string();
    char rpy[160];
    std::snprintf(rpy, sizeof(rpy), "rpy: [%.17g, %.17g, 0]", hang->pose.rpy.x(),
                  hang->pose.rpy.y());
    replace("rpy: [0, 0, 0]", rpy);
  }
  const std::string truth = path("crane-truth.yaml");
  std::ofstream(truth) << yaml;

  const std::string rec = path("crane.csv");
  const Process s =
      fit({"simulate", "--config", truth, "--nominal", nominal_path, "--physics", "elastic",
           "--design", "20", "--channels", "swivel,inclinometer", "--seed", "4", "--out", rec});
  ASSERT_EQ(s.status, 0) << s.err << s.out;
  EXPECT_THAT(slurp(rec), HasSubstr("swivel_4,incl_roll,incl_pitch"));

  const std::string cal = path("crane-calibrated.yaml"), report = path("crane-report.json");
  const Process c = fit({"calibrate", "--config", nominal_path, "--recording", rec, "--out", cal,
                         "--report", report});
  ASSERT_EQ(c.status, 0) << c.err << c.out;
  EXPECT_THAT(c.out, HasSubstr("translation (x, y, z) and heading"));
  const nlohmann::json j = nlohmann::json::parse(slurp(report));
  EXPECT_TRUE(j.at("converged").get<bool>());
  const auto calibrated = expect_anchors_and_mounting_found(nominal_path, truth, cal);
  ASSERT_TRUE(calibrated.has_value());
  EXPECT_TRUE(calibrated->suspended);

  const std::string djson = path("crane-diagnose.json");
  const Process d = fit({"diagnose", "--config", nominal_path, "--recording", rec, "--json", djson,
                         "--bootstrap", "20", "--folds", "3", "--seed", "2"});
  EXPECT_EQ(d.status, 0) << d.err << d.out;
  const nlohmann::json dj = nlohmann::json::parse(slurp(djson));
  EXPECT_EQ(dj.at("verdict"), "no_mismatch") << d.out;
}

// The crane's accuracy prediction: its box targets are evaluated where it hangs (a level box
// would have no feasible point), so the predicted position error is finite and positive.
TEST_F(FitSensors, SuspendedCraneAccuracyIsPredicted) {
  const std::string config = kSource + "/config/crane4.yaml", poses = path("crane-poses.csv");
  const Process dp = fit({"design-poses", "--config", config, "--count", "15", "--out", poses});
  ASSERT_EQ(dp.status, 0) << dp.err << dp.out;
  const Process pa = fit({"--json", "predict-accuracy", "--config", config, "--poses", poses,
                          "--channels", "swivel,inclinometer", "--points-per-axis", "3"});
  ASSERT_EQ(pa.status, 0) << pa.err << pa.out;
  const nlohmann::json j = nlohmann::json::parse(pa.out);
  EXPECT_EQ(j.at("grid_points").get<int>(), 27);
  const double rms = j.at("position_rms_m").get<double>();
  EXPECT_TRUE(std::isfinite(rms));
  EXPECT_GT(rms, 0.0);
  EXPECT_GE(j.at("position_max_m").get<double>(), rms);
}

TEST_F(FitSensors, UnknownChannelIsRefused) {
  const Process s = fit({"simulate", "--config", kTruth, "--design", "8", "--channels", "sonar",
                         "--out", path("x.csv")});
  EXPECT_NE(s.status, 0);
  EXPECT_THAT(s.err + s.out, HasSubstr("unknown channel 'sonar'"));
}

}  // namespace
}  // namespace cdpr::fit_test
