// Scenario drifts (drift.hpp): parsed with file/line/field errors, and applied by the physics as
// ramps in time to the channel each one reaches: a pulley move and an encoder slip move the
// platform and the tensions, a force-sensor drift only the raw force readings.
#include "cdpr/sim/drift.hpp"

#include <gtest/gtest.h>

#include <string>

#include "cdpr/calibration/winch.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::sim {
namespace {

const std::string kSource = CDPR_SOURCE_DIR;

Scenario scenario(const std::string& extra) {
  const std::string text =
      "name: drift\ntruth: {config: " + kSource + "/config/mini-measured.yaml}\n" + extra;
  Result<Scenario> s = parse_scenario(text, "drift.yaml", kSource);
  EXPECT_TRUE(s.ok()) << s.status().to_string();
  return s.ok() ? *s : Scenario{};
}

std::string error_of(const std::string& text) {
  Result<Scenario> s = parse_scenario(text, "bad.yaml");
  EXPECT_FALSE(s.ok()) << text;
  return s.ok() ? "" : std::string(s.status().message());
}

Physics make(const Scenario& s) {
  Result<RobotModel> nominal = config::load_robot_config(kSource + "/config/mini.yaml");
  EXPECT_TRUE(nominal.ok());
  Result<RobotModel> truth = resolve_truth(s, *nominal);
  EXPECT_TRUE(truth.ok()) << truth.status().to_string();
  Result<Physics> p = Physics::create(*truth, s, 1);
  EXPECT_TRUE(p.ok()) << p.status().to_string();
  return std::move(*p);
}

// Steps a physics at the same counts at times `t`, returning its state at the last.
PhysicsState hold(Physics& p, std::initializer_list<double> times) {
  const Eigen::VectorXd counts = Eigen::VectorXd::Constant(8, 3.5e6);
  for (double t : times) EXPECT_TRUE(p.step(counts, t).ok());
  return p.state();
}

TEST(Drift, RampsLinearlyFromItsStartAndThenStays) {
  Drift d;
  d.at_s = 100.0;
  d.duration_s = 50.0;
  EXPECT_EQ(d.fraction_at(99.0), 0.0);
  EXPECT_DOUBLE_EQ(d.fraction_at(125.0), 0.5);
  EXPECT_EQ(d.fraction_at(500.0), 1.0);
  d.duration_s = 0.0;  // a step
  EXPECT_EQ(d.fraction_at(100.0), 1.0);
}

TEST(Drift, EachKindParsesItsFields) {
  const Scenario s = scenario(
      "drifts:\n"
      "  - {type: pulley_move, cable: 3, at: 60, duration: 600, by: [0.005, 0, -0.001]}\n"
      "  - {type: force_sensor, cable: 2, duration: 3600, gain: 0.02, offset: 5}\n"
      "  - {type: encoder_slip, cable: 8, at: 10, counts: -300}\n");
  ASSERT_EQ(s.drifts.size(), 3u);
  EXPECT_EQ(s.drifts[0].kind, DriftKind::kPulleyMove);
  EXPECT_EQ(s.drifts[0].cable, 2);
  EXPECT_EQ(s.drifts[0].by, Eigen::Vector3d(0.005, 0, -0.001));
  EXPECT_EQ(s.drifts[0].line, 4);
  EXPECT_EQ(s.drifts[1].kind, DriftKind::kForceSensor);
  EXPECT_EQ(s.drifts[1].gain, 0.02);
  EXPECT_EQ(s.drifts[1].offset, 5.0);
  EXPECT_EQ(s.drifts[1].at_s, 0.0);
  EXPECT_EQ(s.drifts[2].kind, DriftKind::kEncoderSlip);
  EXPECT_EQ(s.drifts[2].counts, -300.0);
  EXPECT_EQ(s.drifts[2].duration_s, 0.0);
  EXPECT_EQ(to_string(DriftKind::kEncoderSlip), "encoder_slip");
}

TEST(Drift, ErrorsNameTheFileLineAndField) {
  EXPECT_EQ(error_of("drifts:\n  - {type: pulley_moved, cable: 1, by: [0, 0, 1]}\n"),
            "bad.yaml:2: drifts[0].type: unknown drift 'pulley_moved' (one of: pulley_move, "
            "force_sensor, encoder_slip)");
  EXPECT_NE(error_of("drifts:\n  - {type: pulley_move, cable: 1}\n").find("bad.yaml:2"),
            std::string::npos);
  EXPECT_NE(error_of("drifts:\n  - {type: encoder_slip, cable: 1, counts: 5, by: [0, 0, 1]}\n")
                .find("by: not used by a encoder_slip drift"),
            std::string::npos);
  EXPECT_NE(error_of("drifts:\n  - {type: force_sensor, cable: 1}\n").find("gain, offset"),
            std::string::npos);
  EXPECT_NE(error_of("drifts:\n  - {type: pulley_move, cable: 1, at: -1, by: [0, 0, 1]}\n")
                .find("drifts[0].at"),
            std::string::npos);
  Result<Scenario> s =
      parse_scenario("drifts:\n  - {type: encoder_slip, cable: 9, counts: 5}\n", "nine.yaml");
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(std::string(check_against(*s, 8).message()),
            "nine.yaml:2: drifts[0].cable: cable 9 does not exist (the robot has 8)");
}

TEST(Drift, PulleyMoveMovesTheAnchorOverItsDurationAndChangesTensionsNotEncoders) {
  const Scenario s = scenario(
      "drifts: [{type: pulley_move, cable: 3, at: 100, duration: 100, by: [0.004, 0, 0.003]}]\n");
  Physics plain = make(scenario(""));
  Physics p = make(s);
  const PhysicsState base = hold(plain, {0.0, 150.0, 300.0});
  const Eigen::Vector3d a0 = plain.truth().frame_anchors.col(2);
  hold(p, {0.0});
  EXPECT_EQ(p.truth().frame_anchors.col(2), a0);
  hold(p, {150.0});
  EXPECT_LT((p.truth().frame_anchors.col(2) - a0 - Eigen::Vector3d(0.002, 0, 0.0015)).norm(),
            1e-15);
  const PhysicsState after = hold(p, {300.0});
  EXPECT_LT((p.truth().frame_anchors.col(2) - a0 - Eigen::Vector3d(0.004, 0, 0.003)).norm(), 1e-15);
  EXPECT_EQ(after.encoder_counts, base.encoder_counts);
  EXPECT_GT((after.tensions - base.tensions).cwiseAbs().maxCoeff(), 1.0);  // N
  EXPECT_GT((after.pose.position - base.pose.position).norm(), 1e-5);
}

TEST(Drift, ForceSensorDriftChangesOnlyTheRawReadingOfItsCable) {
  const Scenario s = scenario(
      "drifts: [{type: force_sensor, cable: 2, at: 0, duration: 100, gain: 0.02, "
      "offset: 4}]\n");
  Physics plain = make(scenario(""));
  Physics p = make(s);
  const PhysicsState base = hold(plain, {0.0, 50.0});
  const PhysicsState half = hold(p, {0.0, 50.0});
  EXPECT_EQ(half.pose.position, base.pose.position);
  EXPECT_EQ(half.tensions, base.tensions);
  const ForceSensorModel& f = p.truth().force_sensors[1];
  const double expected = f.gain * 1.01 * base.tensions(1) + f.offset + 2.0;
  EXPECT_NEAR(half.force_raw(1), expected, 1e-9);
  EXPECT_EQ(half.force_raw(0), base.force_raw(0));
}

TEST(Drift, EncoderSlipLengthensTheTrueCableAtTheSameReportedCounts) {
  const Scenario s = scenario("drifts: [{type: encoder_slip, cable: 5, at: 10, counts: 400}]\n");
  Physics plain = make(scenario(""));
  Physics p = make(s);
  const PhysicsState base = hold(plain, {0.0, 20.0});
  const PhysicsState slipped = hold(p, {0.0, 20.0});
  const double mpc = winch_metres_per_count(p.truth().winches[4]);
  const double sign = p.truth().winches[4].direction;
  EXPECT_NEAR(slipped.unstretched_lengths(4) - base.unstretched_lengths(4), sign * 400.0 * mpc,
              1e-12);
  EXPECT_EQ(slipped.unstretched_lengths(3), base.unstretched_lengths(3));
  EXPECT_EQ(slipped.encoder_counts, base.encoder_counts);
}

}  // namespace
}  // namespace cdpr::sim
