// Scenario files: the shipped examples load, fields are checked with file/line/field messages,
// the true robot is resolved (config file, seeded perturbation, cable-law effects).
#include "cdpr/sim/scenario.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "cdpr/config/robot_config.hpp"

namespace cdpr::sim {
namespace {

const std::string kSource = CDPR_SOURCE_DIR;

RobotModel nominal() {
  Result<RobotModel> m = config::load_robot_config(kSource + "/config/mini.yaml");
  EXPECT_TRUE(m.ok()) << m.status().to_string();
  return m.ok() ? *m : RobotModel{};
}

std::string error_of(const std::string& text) {
  Result<Scenario> s = parse_scenario(text, "bad.yaml");
  EXPECT_FALSE(s.ok()) << text;
  return s.ok() ? "" : std::string(s.status().message());
}

TEST(Scenario, ShippedExamplesLoadAndResolve) {
  const RobotModel nom = nominal();
  int found = 0;
  for (const auto& e : std::filesystem::directory_iterator(kSource + "/config/scenarios")) {
    if (e.path().extension() != ".yaml") continue;
    SCOPED_TRACE(e.path().string());
    Result<Scenario> s = load_scenario(e.path().string());
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    Result<RobotModel> truth = resolve_truth(*s, nom);
    ASSERT_TRUE(truth.ok()) << truth.status().to_string();
    EXPECT_EQ(truth->num_cables(), nom.num_cables());
    EXPECT_FALSE(s->laser.register_map_path.empty());
    EXPECT_TRUE(std::filesystem::exists(s->laser.register_map_path));
    ++found;
  }
  EXPECT_GE(found, 3);
}

TEST(Scenario, MiniNoneIsTheMeasuredRobot) {
  Result<Scenario> s = load_scenario(kSource + "/config/scenarios/mini-none.yaml");
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  Result<RobotModel> truth = resolve_truth(*s, nominal());
  ASSERT_TRUE(truth.ok());
  Result<RobotModel> measured = config::load_robot_config(kSource + "/config/mini-measured.yaml");
  ASSERT_TRUE(measured.ok());
  EXPECT_EQ(truth->frame_anchors, measured->frame_anchors);
  EXPECT_EQ(truth->cables[3].ea, measured->cables[3].ea);
  EXPECT_EQ(s->noise.encoder_counts, 0.0);
  EXPECT_TRUE(s->faults.empty());
}

TEST(Scenario, MiniEverythingHasEveryEffectAndFault) {
  Result<Scenario> s = load_scenario(kSource + "/config/scenarios/mini-everything.yaml");
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  const HiddenEffects& e = s->effects;
  EXPECT_TRUE(e.hooke_ea.given());
  EXPECT_TRUE(e.creep.has_value());
  EXPECT_TRUE(e.sag);
  EXPECT_TRUE(e.thermal.has_value());
  EXPECT_TRUE(e.pulley_radius.given());
  EXPECT_TRUE(e.transmission_scale.given());
  EXPECT_TRUE(e.encoder_zero_offset.given());
  EXPECT_TRUE(e.force_gain_error.given());
  EXPECT_TRUE(e.force_offset_error.given());
  EXPECT_GT(e.laser_mount_offset.norm(), 0.0);
  EXPECT_GT(e.plane_tilt.norm(), 0.0);
  bool kinds[8] = {};
  for (const Fault& f : s->faults) kinds[static_cast<int>(f.kind)] = true;
  for (bool k : kinds) EXPECT_TRUE(k);
}

TEST(Scenario, FaultsAreCarriedAsData) {
  Result<Scenario> s = parse_scenario(
      "faults:\n"
      "  - {type: drive_fault, at: 10, cable: 3, emcy: 0x7500}\n"
      "  - {type: sdo_abort, at: 0, cable: 1, object: 0x6064, subindex: 0, code: 0x06090011}\n"
      "  - {type: laser_timeout, at: 5, duration: 1.5}\n"
      "  - {type: cable_overload, at: 0, cable: 8, limit: 150}\n",
      "f.yaml");
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  ASSERT_EQ(s->faults.size(), 4u);
  EXPECT_EQ(s->faults[0].kind, FaultKind::kDriveFault);
  EXPECT_EQ(s->faults[0].cable, 2);
  EXPECT_EQ(s->faults[0].emcy_code, 0x7500);
  EXPECT_TRUE(s->faults[0].is_can());
  EXPECT_EQ(s->faults[1].object, 0x6064);
  EXPECT_EQ(s->faults[1].abort_code, 0x06090011u);
  EXPECT_EQ(s->faults[3].emcy_code, 0x2310);  // the default overload code
  EXPECT_EQ(s->faults[3].tension_limit, 150.0);
  EXPECT_EQ(s->laser_fault_at(4.9), nullptr);
  ASSERT_NE(s->laser_fault_at(5.0), nullptr);
  EXPECT_EQ(s->laser_fault_at(5.0)->kind, FaultKind::kLaserTimeout);
  EXPECT_EQ(s->laser_fault_at(6.5), nullptr);
  EXPECT_EQ(s->faults[2].line, 4);
}

TEST(Scenario, ErrorsNameFileLineAndField) {
  EXPECT_EQ(error_of("name: x\neffects:\n  hooke: {ea: -3}\n"),
            "bad.yaml:3: effects.hooke.ea: expected a positive number (N), got -3");
  EXPECT_EQ(
      error_of("effects:\n  hoke: {ea: 3}\n").rfind("bad.yaml:2: effects.hoke: unknown field", 0),
      0u);
  EXPECT_NE(error_of("noise: {laser: abc}\n")
                .find("bad.yaml:1: noise.laser: expected a non-negative number (m), got abc"),
            std::string::npos);
  EXPECT_NE(error_of("faults:\n  - {type: explode, at: 1}\n").find("bad.yaml:2: faults[0].type"),
            std::string::npos);
  EXPECT_NE(error_of("faults:\n  - {type: drive_fault, at: 1}\n").find("faults[0].cable: missing"),
            std::string::npos);
  EXPECT_NE(error_of("faults:\n  - {type: bus_off, at: 1, limit: 3}\n").find("faults[0].limit"),
            std::string::npos);
  EXPECT_NE(error_of("effects:\n  polynomial: {order: 2, coefficients: [1, 2]}\n")
                .find("needs 6 coefficients"),
            std::string::npos);
  EXPECT_NE(error_of("effects:\n  sag: true\n  polynomial: {order: 0, coefficients: [0]}\n")
                .find("effects.sag"),
            std::string::npos);
  EXPECT_NE(error_of("effects: [1, 2\n").find("YAML syntax"), std::string::npos);
  Result<Scenario> missing = load_scenario("/nonexistent/scenario.yaml");
  EXPECT_EQ(missing.status().code(), ErrorCode::kNotFound);
}

// Issue 16 item 10: as the robot loader, the scenario loader refuses a key given twice (the
// second would silently win) and reads a file saved with a UTF-8 byte order mark.
TEST(Scenario, DuplicateKeysAreRefusedAtTheirLine) {
  EXPECT_NE(error_of("name: a\nnoise: {laser: 0.001}\nname: b\n")
                .find("bad.yaml:3: name: field given twice"),
            std::string::npos);
  EXPECT_NE(
      error_of("effects:\n  hooke: {ea: 3, ea: 4}\n").find("effects.hooke.ea: field given twice"),
      std::string::npos);
}

TEST(Scenario, AByteOrderMarkIsAccepted) {
  Result<Scenario> s = parse_scenario("\xEF\xBB\xBFname: bom\nnoise: {laser: 0.001}\n", "bom.yaml");
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  EXPECT_EQ(s->name, "bom");
}

TEST(Scenario, PerCableListsMustMatchTheRobot) {
  Result<Scenario> s = parse_scenario("effects:\n  pulley_radius: [0.02, 0.03]\n", "pc.yaml");
  ASSERT_TRUE(s.ok());
  Result<RobotModel> t = resolve_truth(*s, nominal());
  ASSERT_FALSE(t.ok());
  EXPECT_EQ(std::string(t.status().message()),
            "pc.yaml:2: effects.pulley_radius: 2 values for a robot with 8 cables (give 1 or 8)");
  Result<Scenario> f =
      parse_scenario("faults: [{type: drive_silent, at: 0, cable: 9}]\n", "f.yaml");
  ASSERT_TRUE(f.ok());
  EXPECT_FALSE(resolve_truth(*f, nominal()).ok());
}

TEST(Scenario, SeededPerturbationIsReproducible) {
  const RobotModel nom = nominal();
  auto truth = [&](int seed, double sd) {
    Result<Scenario> s =
        parse_scenario("truth:\n  perturb: {frame_anchor_std: " + std::to_string(sd) +
                           ", seed: " + std::to_string(seed) + "}\n",
                       "p.yaml");
    EXPECT_TRUE(s.ok());
    Result<RobotModel> t = resolve_truth(*s, nom);
    EXPECT_TRUE(t.ok());
    return *t;
  };
  const RobotModel a = truth(7, 0.005), b = truth(7, 0.005), c = truth(8, 0.005);
  EXPECT_EQ(a.frame_anchors, b.frame_anchors);
  EXPECT_NE(a.frame_anchors, c.frame_anchors);
  EXPECT_EQ(a.platform_anchors, nom.platform_anchors);
  const double rms = std::sqrt((a.frame_anchors - nom.frame_anchors).squaredNorm() / 24.0);
  EXPECT_GT(rms, 0.002);  // 24 draws of std 5 mm
  EXPECT_LT(rms, 0.009);
}

TEST(Scenario, CableLawEffects) {
  const RobotModel nom = nominal();
  Result<Scenario> stiff = parse_scenario("effects: {cable_law: stiff, stiff_ea: 1e9}\n", "s.yaml");
  ASSERT_TRUE(stiff.ok());
  Result<RobotModel> t = resolve_truth(*stiff, nom);
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t->cables[0].elongation, ElongationKind::kHooke);
  EXPECT_EQ(t->cables[0].ea, 1e9);
  Result<Scenario> hooke = parse_scenario(
      "effects: {hooke: {ea: [1, 2, 3, 4, 5, 6, 7, 8]}, pulley_radius: 0.03}\n", "h.yaml");
  ASSERT_TRUE(hooke.ok());
  t = resolve_truth(*hooke, nom);
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t->cables[6].ea, 7.0);
  EXPECT_EQ(t->pulleys[6].radius, 0.03);
}

}  // namespace
}  // namespace cdpr::sim

namespace cdpr::sim {
namespace {

TEST(Scenario, DirectionDependentEffectsParseAndRejectNegativeValues) {
  Result<Scenario> s = parse_scenario(
      "name: t\neffects: {cable_hysteresis: [0, 0.0005, 0, 0, 0.0005, 0, 0, 0], pulley_friction: "
      "2.5}\n",
      "t.yaml");
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  EXPECT_EQ(s->effects.cable_hysteresis.at(1), 0.0005);
  EXPECT_EQ(s->effects.cable_hysteresis.at(0), 0.0);
  EXPECT_EQ(s->effects.pulley_friction.at(6), 2.5);
  EXPECT_NE(error_of("name: t\neffects: {pulley_friction: -1}\n").find("pulley_friction"),
            std::string::npos);
  EXPECT_NE(check_against(*s, 6).message().find("effects.cable_hysteresis"), std::string::npos);
}

}  // namespace
}  // namespace cdpr::sim
