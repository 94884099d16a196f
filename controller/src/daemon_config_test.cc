#include "cdpr/controller/daemon_config.hpp"

#include <gtest/gtest.h>

#include <string>
#include <utility>

#include "cdpr/canopen/config.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::controller {
namespace {

TEST(DaemonConfig, ReadsEveryGroupAndResolvesPathsAgainstTheFile) {
  auto c = parse_daemon_config(
      "robot: mini.yaml\ncanopen: /abs/net.yaml\nlaser: lasers/l.yaml\n"
      "state_directory: state\n"
      "realtime: {priority: 70, cpu: 1, sync_period_ms: 20}\n"
      "identity: {vendor_id: 0x00CD9001}\n"
      "motion: {max_linear_velocity: 0.2}\n"
      "tension_watch: {stuck_raw_units: 10, stuck_confirm_s: 0.5}\n"
      "measuring: {poses: 30, max_angle: 0.4363, design_tension_margin: 15, design_angle_steps: 3, "
      "design_emphasis_weight: 1, laser_samples: 10, remeasure_rounds: 2}\n"
      "identification: {estimate: [anchors, scales], diagnose: false}\n"
      "acceptance: {mode: auto, max_anchor_change_m: 0.01}\n"
      "control: {socket: /run/x.sock, group: cdpr}\n"
      "report: {iso9283_measured: bench/iso9283.json}\n",
      "/etc/cdpr/cdprd.yaml");
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  EXPECT_EQ(c->robot, "/etc/cdpr/mini.yaml");
  EXPECT_EQ(c->canopen, "/abs/net.yaml");
  EXPECT_EQ(c->laser, "/etc/cdpr/lasers/l.yaml");
  EXPECT_EQ(c->state_directory, "/etc/cdpr/state");
  EXPECT_EQ(c->realtime.priority, 70);
  EXPECT_EQ(c->realtime.cpu, 1);
  EXPECT_EQ(c->realtime.sync_period, std::chrono::milliseconds(20));
  EXPECT_EQ(c->identity.vendor_id, 0x00CD9001u);
  EXPECT_DOUBLE_EQ(c->motion.max_linear_velocity, 0.2);
  EXPECT_DOUBLE_EQ(c->tension_watch.stuck_raw_units, 10.0);
  EXPECT_DOUBLE_EQ(c->tension_watch.stuck_confirm_s, 0.5);
  EXPECT_EQ(c->measuring.poses, 30);
  EXPECT_EQ(c->measuring.remeasure_rounds, 2);
  EXPECT_DOUBLE_EQ(c->measuring.max_angle, 0.4363);
  EXPECT_DOUBLE_EQ(c->measuring.design_tension_margin, 15.0);
  EXPECT_EQ(c->measuring.design_angle_steps, 3);
  EXPECT_DOUBLE_EQ(c->measuring.design_emphasis_weight, 1.0);
  EXPECT_TRUE(c->identification.options.estimate_length_scales);
  EXPECT_TRUE(c->identification.options.estimate_frame_anchors);
  EXPECT_FALSE(c->identification.options.estimate_length_offsets);  // exactly what is named
  EXPECT_FALSE(c->identification.diagnose);
  EXPECT_EQ(c->acceptance.mode, AcceptanceMode::kAuto);
  EXPECT_DOUBLE_EQ(c->acceptance.max_anchor_change_m, 0.01);
  EXPECT_EQ(c->control.group, "cdpr");
  EXPECT_EQ(c->report.iso9283_measured, "/etc/cdpr/bench/iso9283.json");
}

TEST(DaemonConfig, ErrorsNameFileLineAndField) {
  auto c = parse_daemon_config(
      "robot: r.yaml\ncanopen: n.yaml\nmotion:\n  max_linear_velocity: -1\n", "cdprd.yaml");
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().to_string().find("cdprd.yaml:4:"), std::string::npos)
      << c.status().to_string();
  EXPECT_NE(c.status().to_string().find("motion.max_linear_velocity"), std::string::npos);

  auto unknown = parse_daemon_config("robot: r.yaml\ncanopen: n.yaml\nmotoin: {}\n", "d.yaml");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.status().to_string().find("d.yaml:3: motoin: unknown field"), std::string::npos)
      << unknown.status().to_string();

  auto missing = parse_daemon_config("canopen: n.yaml\n", "d.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.status().to_string().find("robot: missing"), std::string::npos)
      << missing.status().to_string();

  auto mode =
      parse_daemon_config("robot: r\ncanopen: n\nacceptance: {mode: sometimes}\n", "d.yaml");
  ASSERT_FALSE(mode.ok());
  EXPECT_NE(
      mode.status().to_string().find("acceptance.mode: 'sometimes' is not one of manual, auto"),
      std::string::npos)
      << mode.status().to_string();

  auto twice = parse_daemon_config("robot: r\ncanopen: n\nmotion: {}\nmotion: {}\n", "d.yaml");
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().to_string().find("given twice"), std::string::npos)
      << twice.status().to_string();

  // Values out of range are refused, naming the group and the key. A tilt beyond 45 degrees is
  // among them (the design would plan poses no CDPR reaches safely).
  const std::pair<std::string, std::string> out_of_range[] = {
      {"tension_watch: {stuck_raw_units: -2}", "tension_watch.stuck_raw_units"},
      {"measuring: {remeasure_rounds: 11}", "measuring.remeasure_rounds"},
      {"measuring: {max_angle: 1.2}", "measuring.max_angle"},
      {"measuring: {design_tension_margin: -1}", "measuring.design_tension_margin"},
      {"measuring: {design_angle_steps: 0}", "measuring.design_angle_steps"},
      {"measuring: {design_emphasis_weight: -1}", "measuring.design_emphasis_weight"},
      {"monitoring: {max_following_m: -1e-4}", "monitoring.max_following_m"},
      {"monitoring: {laser_max_age_s: 0}", "monitoring.laser_max_age_s"},
  };
  for (const auto& [group, field] : out_of_range) {
    auto refused = parse_daemon_config("robot: r\ncanopen: n\n" + group + "\n", "d.yaml");
    ASSERT_FALSE(refused.ok()) << group;
    EXPECT_NE(refused.status().to_string().find(field), std::string::npos)
        << refused.status().to_string();
  }

  auto bad_yaml = parse_daemon_config("robot: [unclosed\n", "d.yaml");
  ASSERT_FALSE(bad_yaml.ok());
  EXPECT_NE(bad_yaml.status().to_string().find("d.yaml:"), std::string::npos);
}

TEST(DaemonConfig, SafetyReadsSourcesBrakesLimitsAndTheBox) {
  auto c = parse_daemon_config(
      "robot: r\ncanopen: n\nsafety:\n"
      "  estop:\n"
      "    - {kind: drive_input, node: 1, bit: 16}\n"
      "    - {kind: pdo_bit, node: 10, index: 0x6000, sub: 1, bit: 3, stale_s: 0.05}\n"
      "  brakes: {control: output, bit: 0, release_delay_s: 0.3, apply_delay_s: 0.1}\n"
      "  cable_length: {min: 0.05, max: [1, 2], tolerance: 0.001}\n"
      "  workspace: {min: [-0.3, -0.3, -0.2], max: [0.3, 0.3, 0.4]}\n",
      "d.yaml");
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  const SafetySettings& s = c->safety;
  ASSERT_EQ(s.estop.size(), 2u);
  EXPECT_EQ(s.estop[0].index, 0x60FD) << "drive_input reads the drive's digital inputs";
  EXPECT_EQ(s.estop[0].bit, 16);
  EXPECT_EQ(s.estop[1].index, 0x6000);
  EXPECT_EQ(s.estop[1].sub, 1);
  EXPECT_DOUBLE_EQ(s.estop[1].stale_s, 0.05);
  EXPECT_NE(s.estop[1].where.find("d.yaml:6"), std::string::npos) << s.estop[1].where;
  EXPECT_EQ(s.brakes.control, BrakeControl::kOutput);
  EXPECT_EQ(s.brakes.index, 0x60FE);
  EXPECT_DOUBLE_EQ(s.brakes.release_delay_s, 0.3);
  EXPECT_DOUBLE_EQ(cable_length_limit(s, 1, false), 0.05) << "one minimum for all";
  EXPECT_DOUBLE_EQ(cable_length_limit(s, 1, true), 2.0);
  EXPECT_TRUE(s.workspace);
  EXPECT_DOUBLE_EQ(s.workspace_max[2], 0.4);
  EXPECT_TRUE(check_safety_limits(s, 2).ok());
  const Status three = check_safety_limits(s, 3);
  EXPECT_NE(three.to_string().find("2 cable lengths for a robot of 3 cables"), std::string::npos)
      << three.to_string();

  const std::pair<std::string, std::string> refused[] = {
      {"estop: [{kind: relay, node: 1, bit: 0}]", "'relay' is not one of drive_input, pdo_bit"},
      {"estop: [{kind: pdo_bit, node: 1, bit: 0}]", "index: missing"},
      {"estop: [{kind: drive_input, node: 1, bit: 32}]", "safety.estop[0].bit"},
      {"estop: [{kind: drive_input, node: 1, index: 0x6000, bit: 1}]", "no index or sub"},
      {"brakes: {control: sometimes}", "safety.brakes.control"},
      {"workspace: {min: [0, 0, 0], max: [1, 1, 0]}", "max must exceed min on every axis (z)"},
      {"cable_length: {min: -1}", "safety.cable_length.min"},
  };
  for (const auto& [group, text] : refused) {
    auto r = parse_daemon_config("robot: r\ncanopen: n\nsafety:\n  " + group + "\n", "d.yaml");
    ASSERT_FALSE(r.ok()) << group;
    EXPECT_NE(r.status().to_string().find(text), std::string::npos) << r.status().to_string();
  }
}

// identification.estimate takes cdpr-fit's --estimate words: every word of the one table, and the
// same options as set_estimate() gives the CLI; an unknown word is refused at its line.
TEST(DaemonConfig, EstimateUsesTheWordsOfCdprFitsEstimate) {
  for (const EstimateItem& item : estimate_items()) {
    const std::string word(item.word);
    auto c = parse_daemon_config(
        "robot: r\ncanopen: n\nidentification: {estimate: [" + word + "]}\n", "d.yaml");
    ASSERT_TRUE(c.ok()) << word << ": " << c.status().to_string();
    IdentificationOptions cli;
    ASSERT_TRUE(set_estimate({word}, item.required_cables, cli).ok()) << word;
    EXPECT_EQ(estimate_words(c->identification.options), estimate_words(cli)) << word;
  }
  auto typo = parse_daemon_config(
      "robot: r\ncanopen: n\nidentification:\n  estimate:\n    - anchors\n    - ofsets\n",
      "d.yaml");
  ASSERT_FALSE(typo.ok());
  EXPECT_NE(typo.status().to_string().find("d.yaml:6:"), std::string::npos)
      << typo.status().to_string();
  EXPECT_NE(typo.status().to_string().find("unknown estimate item 'ofsets'"), std::string::npos);
  auto old_key = parse_daemon_config(
      "robot: r\ncanopen: n\nidentification: {frame_anchors: true}\n", "d.yaml");
  EXPECT_FALSE(old_key.ok());
  auto nothing =
      parse_daemon_config("robot: r\ncanopen: n\nidentification: {estimate: []}\n", "d.yaml");
  EXPECT_FALSE(nothing.ok());
}

// The mismatch locator's cross-validation: leave one pose out unless K >= 2 folds are asked for;
// one fold would hold out nothing and is refused where it is written.
TEST(DaemonConfig, FoldsLeaveOnePoseOutByDefaultAndRefuseOne) {
  auto dflt = parse_daemon_config("robot: r\ncanopen: n\n", "d.yaml");
  ASSERT_TRUE(dflt.ok()) << dflt.status().to_string();
  EXPECT_EQ(dflt->identification.folds, 0);
  auto five = parse_daemon_config("robot: r\ncanopen: n\nidentification: {folds: 5}\n", "d.yaml");
  ASSERT_TRUE(five.ok()) << five.status().to_string();
  EXPECT_EQ(five->identification.folds, 5);
  for (const char* bad : {"1", "-1", "1001", "many"}) {
    auto c = parse_daemon_config(
        std::string("robot: r\ncanopen: n\nidentification:\n  folds: ") + bad + "\n", "d.yaml");
    ASSERT_FALSE(c.ok()) << bad;
    EXPECT_NE(c.status().to_string().find("d.yaml:4:"), std::string::npos)
        << c.status().to_string();
    EXPECT_NE(c.status().to_string().find("identification.folds"), std::string::npos)
        << c.status().to_string();
  }
}

TEST(DaemonConfig, TheShippedRobotPcConfigAndTheFilesItNamesLoad) {
  auto c = load_daemon_config(CDPR_SOURCE_DIR "/config/cdprd.yaml");
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  EXPECT_TRUE(config::load_robot_config(c->robot).ok()) << c->robot;
  auto net = canopen::load_config(c->canopen);
  EXPECT_TRUE(net.ok()) << net.status().to_string();
  auto laser = modbus::load_laser_config(c->laser);
  EXPECT_TRUE(laser.ok()) << laser.status().to_string();
  EXPECT_EQ(c->control.socket, "/run/cdpr/cdprd.sock");
  EXPECT_EQ(c->state_directory, "/var/lib/cdpr");
}

}  // namespace
}  // namespace cdpr::controller
