// Physics of the virtual robot: equilibrium against the elasto-static model, every hidden effect
// on the channels it should change (and no other), determinism, faults, lock-step.
#include "cdpr/sim/physics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "cdpr/calibration/elastostatics.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::sim {
namespace {

const std::string kSource = CDPR_SOURCE_DIR;

RobotModel load(const std::string& name) {
  Result<RobotModel> m = config::load_robot_config(kSource + "/config/" + name);
  EXPECT_TRUE(m.ok()) << m.status().to_string();
  return m.ok() ? *m : RobotModel{};
}

// A scenario whose truth is config/mini-measured.yaml, plus `extra` YAML lines.
Scenario scenario(const std::string& extra) {
  const std::string text =
      "name: test\ntruth: {config: " + kSource + "/config/mini-measured.yaml}\n" + extra;
  Result<Scenario> s = parse_scenario(text, "test.yaml", kSource);
  EXPECT_TRUE(s.ok()) << s.status().to_string();
  return s.ok() ? *s : Scenario{};
}

Physics make(const Scenario& s, std::uint64_t seed = 1) {
  const RobotModel nominal = load("mini.yaml");
  Result<RobotModel> truth = resolve_truth(s, nominal);
  EXPECT_TRUE(truth.ok()) << truth.status().to_string();
  Result<Physics> p = Physics::create(*truth, s, seed);
  EXPECT_TRUE(p.ok()) << p.status().to_string();
  return std::move(*p);
}

// The elasto-static model's own prediction for `lengths`, started just below `pose` (at the pose
// itself exact commands leave every cable slack and the solver without stiffness).
ElastostaticSummary reference(const RobotModel& truth, const Eigen::VectorXd& lengths,
                              const Pose& pose, ElastostaticData& data) {
  ElastostaticOptions o;
  o.wrench_tolerance = 1e-7;  // the physics' tolerance (stiff cables: 1e-8 N is below rounding)
  o.initial_pose = pose;
  o.initial_pose->position.z() -= 1e-3;
  return solve_elastostatics(truth, lengths, o, data);
}

// Counts that pay out `lengths` (unstretched, D-referenced) through the robot's own winch model.
Eigen::VectorXd counts_for(const RobotModel& robot, const Eigen::VectorXd& lengths) {
  Eigen::VectorXd c(lengths.size());
  for (int i = 0; i < lengths.size(); ++i) {
    c(i) = winch_length_to_counts<double>(robot.winches[static_cast<std::size_t>(i)], lengths(i));
  }
  return c;
}

Eigen::VectorXd ik_lengths(const RobotModel& robot, const Pose& pose) {
  KinematicsData k(robot);
  EXPECT_TRUE(inverse_kinematics(robot, pose, k));
  return k.lengths;
}

std::vector<Pose> test_poses() {
  return {Pose{}, Pose{Eigen::Vector3d(0.05, -0.04, 0.03), Eigen::Vector3d(0.02, -0.01, 0.03)},
          Pose{Eigen::Vector3d(-0.06, 0.03, -0.05), Eigen::Vector3d(-0.015, 0.02, -0.02)}};
}

double position_error(const Pose& a, const Pose& b) {
  return (a.position - b.position).norm();
}
double angle_error(const Pose& a, const Pose& b) {
  const Eigen::Matrix3d d =
      rotation_from_rpy<double>(a.rpy) * rotation_from_rpy<double>(b.rpy).transpose();
  return std::acos(std::clamp((d.trace() - 1.0) / 2.0, -1.0, 1.0));
}

// The pretension a robot is homed at so that it is held at home at the tensions it was homed
// with: the planner's own without a margin; with one its 1x leaves out (MINI's lower cables sit
// 0.6 N above f_min + 10 at home), the reference whose plan keeps it; none past the limits.
TEST(Physics, HomeReferenceTensionIsThePlannersChoiceKeepingTheMargin) {
  const RobotModel nominal = load("mini.yaml");
  EXPECT_EQ(home_reference_tension(nominal, 0.0), default_reference_tension(nominal));
  const double margin = 30.0;
  const double ref = home_reference_tension(nominal, margin);
  ASSERT_TRUE(std::isfinite(ref));
  EXPECT_GT(ref, default_reference_tension(nominal));
  CommandData data(nominal);
  ASSERT_TRUE(command_counts(nominal, nominal.home, ref, data, margin).ok());
  for (int i = 0; i < nominal.num_cables(); ++i) {
    EXPECT_GE(data.plan.tensions(i),
              nominal.cables[static_cast<std::size_t>(i)].f_min + margin - 1e-6)
        << "cable " << i + 1;
  }
  EXPECT_TRUE(std::isnan(home_reference_tension(nominal, 1e4)));
}

TEST(Physics, StiffCablesPutThePlatformAtTheTrueIkPose) {
  const Scenario s = scenario("effects: {cable_law: stiff}\n");
  Physics p = make(s);
  double t = 0.0;
  for (const Pose& pose : test_poses()) {
    const Eigen::VectorXd l = ik_lengths(p.truth(), pose);
    ASSERT_TRUE(p.step(counts_for(p.truth(), l), t).ok());
    t += 0.01;
    EXPECT_LT(position_error(p.state().pose, pose), 1e-6);
    EXPECT_LT(angle_error(p.state().pose, pose), 1e-5);
    // The same as the elasto-static model's own prediction.
    ElastostaticData data(p.truth());
    const ElastostaticSummary e = reference(p.truth(), l, pose, data);
    ASSERT_TRUE(e.success()) << e.status.to_string();
    EXPECT_LT(position_error(p.state().pose, e.pose), 1e-9);
    // The cables carry the platform's weight (their vertical components at least balance it).
    EXPECT_GE(p.state().tensions.sum(), p.truth().platform.mass * p.truth().gravity);
  }
}

TEST(Physics, HookeOffsetMatchesTheElastostaticPrediction) {
  const Scenario s = scenario("effects: {hooke: {ea: 15000}}\n");
  Physics p = make(s);
  double t = 0.0;
  for (const Pose& pose : test_poses()) {
    // Uncompensated commands: the elastic cables let the platform sag.
    const Eigen::VectorXd l = ik_lengths(p.truth(), pose);
    ASSERT_TRUE(p.step(counts_for(p.truth(), l), t).ok());
    t += 0.01;
    ElastostaticData data(p.truth());
    const ElastostaticSummary e = reference(p.truth(), l, pose, data);
    ASSERT_TRUE(e.success()) << e.status.to_string();
    EXPECT_GT(position_error(p.state().pose, pose), 1e-4);  // a real offset
    EXPECT_LT(position_error(p.state().pose, e.pose), 1e-9);
    EXPECT_LT(angle_error(p.state().pose, e.pose), 1e-8);
    EXPECT_LT((p.state().tensions - data.tensions).cwiseAbs().maxCoeff(), 1e-5);
  }
}

TEST(Physics, CompensatedTrueCommandsReachThePoseWithThePlannedTensions) {
  const Scenario s = scenario("effects: {hooke: {ea: 15000}}\n");
  Physics p = make(s);
  double t = 0.0;
  for (const Pose& pose : test_poses()) {
    Result<Eigen::VectorXd> f = simple_tension_distribution(p.truth(), pose, 40.0);
    ASSERT_TRUE(f.ok()) << f.status().to_string();
    CableCommandData cmd(p.truth());
    ASSERT_TRUE(inverse_kinematics_compensated(p.truth(), pose, *f, cmd));
    ASSERT_TRUE(p.step(counts_for(p.truth(), cmd.length_commands), t).ok());
    t += 0.01;
    EXPECT_LT(position_error(p.state().pose, pose), 1e-6);
    EXPECT_LT((p.state().tensions - *f).cwiseAbs().maxCoeff(), 1e-3);
  }
}

// Channels of one step, for comparisons.
struct Channels {
  Pose pose;
  Eigen::VectorXd tensions, raw, encoder, unstretched;
  double laser = 0.0;
};

Channels run(const Scenario& s, double time_s, std::uint64_t seed = 1) {
  const RobotModel nominal = load("mini.yaml");
  Physics p = make(s, seed);
  Result<Eigen::VectorXd> c = nominal_counts(nominal, test_poses()[1]);
  EXPECT_TRUE(c.ok()) << c.status().to_string();
  const Eigen::VectorXd counts = c->array().round().matrix();
  if (time_s > 0.0) {
    EXPECT_TRUE(p.step(counts, 0.0).ok());
  }
  const Status st = p.step(counts, time_s);
  EXPECT_TRUE(st.ok()) << st.to_string();
  return Channels{p.state().pose,
                  p.state().tensions,
                  p.state().force_raw,
                  p.state().encoder_counts,
                  p.state().unstretched_lengths,
                  p.state().lasers.at(0).reading};
}

double dpose(const Channels& a, const Channels& b) {
  return std::max(position_error(a.pose, b.pose), 0.1 * angle_error(a.pose, b.pose));
}
double dvec(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).cwiseAbs().maxCoeff();
}

// An effect of the cable physics: moves the platform, changes tensions, force readings and the
// laser, never the encoder readings.
void expect_physical_change(const Channels& base, const Channels& e, const char* what) {
  SCOPED_TRACE(what);
  EXPECT_GT(dpose(base, e), 1e-7);
  EXPECT_GT(dvec(base.tensions, e.tensions), 1e-4);
  EXPECT_GT(dvec(base.raw, e.raw), 1e-4);
  EXPECT_GT(std::abs(base.laser - e.laser), 1e-9);
  EXPECT_EQ(dvec(base.encoder, e.encoder), 0.0);
}

void expect_no_change(const Channels& base, const Channels& e, const char* what) {
  SCOPED_TRACE(what);
  EXPECT_LT(dpose(base, e), 1e-12);
  EXPECT_LT(dvec(base.tensions, e.tensions), 1e-9);
  EXPECT_LT(dvec(base.raw, e.raw), 1e-9);
  EXPECT_LT(std::abs(base.laser - e.laser), 1e-12);
  EXPECT_EQ(dvec(base.encoder, e.encoder), 0.0);
}

TEST(Physics, EachCableEffectChangesThePhysicalChannelsOnly) {
  const Channels base = run(scenario(""), 100.0);
  const char* cases[][2] = {
      {"hooke", "effects: {hooke: {ea: 12000}}\n"},
      {"polynomial", "effects: {polynomial: {order: 2, coefficients: [0, 0, 0, 0, 7.5e-5, 0]}}\n"},
      {"creep", "effects: {creep: {coefficient: 2.0e-5, tau: 10}}\n"},
      {"sag", "effects: {sag: true}\n"},
      {"pulley radius", "effects: {pulley_radius: 0.03}\n"},
      {"transmission", "effects: {transmission_scale: [0.002, -0.001, 0, 0.001, 0, 0, 0, 0]}\n"},
      {"encoder zero", "effects: {encoder_zero_offset: [0.001, 0, 0, 0, 0, -0.002, 0, 0]}\n"},
      {"thermal", "effects: {thermal: {alpha: 1.0e-4, rate: 0.05}}\n"},
  };
  for (const auto& c : cases) {
    expect_physical_change(base, run(scenario(c[1]), 100.0), c[0]);
  }
}

TEST(Physics, TimeEffectsGrowWithTime) {
  // Creep and thermal drift are zero at t = 0 and lengthen the cables later: the platform sinks.
  for (const char* e : {"effects: {creep: {coefficient: 2.0e-5, tau: 10}}\n",
                        "effects: {thermal: {alpha: 1.0e-4, rate: 0.05}}\n"}) {
    SCOPED_TRACE(e);
    expect_no_change(run(scenario(""), 0.0), run(scenario(e), 0.0), "at t = 0");
    const Channels early = run(scenario(e), 10.0);
    const Channels late = run(scenario(e), 100.0);
    const Channels base = run(scenario(""), 100.0);
    EXPECT_LT(early.pose.position.z(), base.pose.position.z());
    EXPECT_LT(late.pose.position.z(), early.pose.position.z());
  }
}

TEST(Physics, HookeSoftnessSinksThePlatform) {
  const Channels stiff = run(scenario("effects: {hooke: {ea: 40000}}\n"), 0.0);
  const Channels soft = run(scenario("effects: {hooke: {ea: 10000}}\n"), 0.0);
  EXPECT_LT(soft.pose.position.z(), stiff.pose.position.z() - 1e-5);
}

TEST(Physics, WinchEffectsShowInTheTrueLengths) {
  const Scenario s = scenario(
      "effects: {transmission_scale: 0.003, encoder_zero_offset: [0.001, 0, 0, 0, 0, -0.002, 0, "
      "0]}\n");
  Physics p = make(s);
  const Eigen::VectorXd counts = Eigen::VectorXd::Constant(8, 3.5e6);
  ASSERT_TRUE(p.step(counts, 0.0).ok());
  const double mpc = winch_metres_per_count(p.truth().winches[0]);
  EXPECT_NEAR(p.state().unstretched_lengths(0), 0.001 + 1.003 * 3.5e6 * mpc, 1e-12);
  EXPECT_NEAR(p.state().unstretched_lengths(5), -0.002 + 1.003 * 3.5e6 * mpc, 1e-12);
  EXPECT_NEAR(p.state().unstretched_lengths(2), 1.003 * 3.5e6 * mpc, 1e-12);
}

TEST(Physics, HysteresisAndPulleyFrictionFollowTheDirectionOfTheLastMove) {
  // Cable 2 (index 1) hysteresis 0.5 mm, cable 5 (index 4) pulley friction 3 N.
  const Scenario s = scenario(
      "effects: {cable_hysteresis: [0, 0.0005, 0, 0, 0, 0, 0, 0], pulley_friction: [0, 0, 0, 0, "
      "3, 0, 0, 0]}\n");
  Physics p = make(s);
  Physics plain = make(scenario(""));
  const int dir = p.truth().winches[1].direction;
  const Eigen::VectorXd c0 = Eigen::VectorXd::Constant(8, 3.5e6);
  // Pay every cable out by 1000 counts' worth of length, hold, then reel in.
  const Eigen::VectorXd out = c0 + Eigen::VectorXd::Constant(8, 1000.0 * dir);
  const Eigen::VectorXd in = c0;
  const double expected_sign[] = {0.0, 1.0, 1.0, -1.0};
  const Eigen::VectorXd* steps[] = {&c0, &out, &out, &in};
  for (int k = 0; k < 4; ++k) {
    SCOPED_TRACE(k);
    ASSERT_TRUE(p.step(*steps[k], k).ok());
    ASSERT_TRUE(plain.step(*steps[k], k).ok());
    for (int i = 0; i < 8; ++i) EXPECT_EQ(p.state().last_move(i), expected_sign[k]);
    const double l0 = plain.state().unstretched_lengths(1);
    EXPECT_NEAR(p.state().unstretched_lengths(1) - l0, 0.0005 * expected_sign[k], 1e-12);
    EXPECT_NEAR(p.state().unstretched_lengths(4), plain.state().unstretched_lengths(4), 1e-12);
    // The reading is the free span's tension plus the friction; the tension itself is the
    // equilibrium's (friction acts on the reading only).
    const ForceSensorModel& f = p.truth().force_sensors[4];
    const double read = (p.state().force_raw(4) - f.offset) / f.gain;
    EXPECT_NEAR(read - p.state().tensions(4), 3.0 * expected_sign[k], 1e-9);
  }
}

TEST(Physics, ForceSensorErrorsChangeOnlyTheRawReadings) {
  const Channels base = run(scenario(""), 0.0);
  const Channels e =
      run(scenario("effects: {force_sensor: {gain_error: 0.05, offset_error: [1, 0, 0, 0, 0, 0, 0, "
                   "-2]}}\n"),
          0.0);
  EXPECT_LT(dpose(base, e), 1e-12);
  EXPECT_LT(dvec(base.tensions, e.tensions), 1e-9);
  EXPECT_EQ(base.laser, e.laser);
  EXPECT_EQ(dvec(base.encoder, e.encoder), 0.0);
  // raw = (1 + e) gain F + offset error (the nominal offset is 0 in mini-measured.yaml).
  for (int i = 0; i < 8; ++i) {
    const double off = i == 0 ? 1.0 : (i == 7 ? -2.0 : 0.0);
    EXPECT_NEAR(e.raw(i), 1.05 * base.raw(i) + off, 1e-9);
  }
}

TEST(Physics, LaserErrorsChangeOnlyTheLaser) {
  const Channels base = run(scenario(""), 0.0);
  const Channels off = run(scenario("effects: {laser: {plane_offset: 0.002}}\n"), 0.0);
  expect_no_change(
      base, Channels{off.pose, off.tensions, off.raw, off.encoder, off.unstretched, base.laser},
      "plane offset, laser aside");
  // The floor rises by 2 mm along its (vertical) normal: the beam is ~vertical.
  EXPECT_NEAR(off.laser - base.laser, -0.002, 2e-5);
  for (const char* e : {"effects: {laser: {mount_offset: [0.001, 0.002, 0.003]}}\n",
                        "effects: {laser: {mount_tilt: [0.01, 0, 0]}}\n",
                        "effects: {laser: {plane_tilt: [0, 0.02, 0]}}\n"}) {
    SCOPED_TRACE(e);
    const Channels c = run(scenario(e), 0.0);
    EXPECT_GT(std::abs(c.laser - base.laser), 1e-6);
    EXPECT_LT(dpose(base, c), 1e-12);
    EXPECT_LT(dvec(base.raw, c.raw), 1e-9);
  }
}

TEST(Physics, NoiseGoesToItsOwnChannel) {
  const Channels base = run(scenario(""), 0.0);
  const Channels enc = run(scenario("noise: {encoder_counts: 50}\n"), 0.0);
  EXPECT_GT(dvec(base.encoder, enc.encoder), 0.0);
  EXPECT_LT(dvec(base.raw, enc.raw), 1e-12);
  EXPECT_EQ(base.laser, enc.laser);
  EXPECT_LT(dpose(base, enc), 1e-12);  // the encoder reading is not the motor position
  const Channels force = run(scenario("noise: {force_raw: 0.5}\n"), 0.0);
  EXPECT_GT(dvec(base.raw, force.raw), 1e-6);
  EXPECT_EQ(dvec(base.encoder, force.encoder), 0.0);
  EXPECT_EQ(base.laser, force.laser);
  const Channels laser = run(scenario("noise: {laser: 0.001}\n"), 0.0);
  EXPECT_GT(std::abs(base.laser - laser.laser), 1e-7);
  EXPECT_LT(dvec(base.raw, laser.raw), 1e-12);
}

TEST(Physics, DeterministicBySeed) {
  const Scenario s = scenario("noise: {encoder_counts: 3, force_raw: 0.2, laser: 0.0005}\n");
  const Channels a = run(s, 5.0, 42);
  const Channels b = run(s, 5.0, 42);
  const Channels c = run(s, 5.0, 43);
  EXPECT_EQ(dvec(a.encoder, b.encoder), 0.0);
  EXPECT_EQ(dvec(a.raw, b.raw), 0.0);
  EXPECT_EQ(a.laser, b.laser);
  EXPECT_GT(dvec(a.raw, c.raw), 0.0);
  EXPECT_NE(a.laser, c.laser);
}

TEST(Physics, LaserOutOfRangeAndNoTarget) {
  // The floor moved 0.6 m down: 1.15 m, beyond the 1.0 m range.
  Physics far = make(scenario("effects: {laser: {plane_offset: -0.6}}\n"));
  const Eigen::VectorXd l = ik_lengths(far.truth(), Pose{});
  ASSERT_TRUE(far.step(counts_for(far.truth(), l), 0.0).ok());
  EXPECT_EQ(far.state().lasers[0].status, LaserStatus::kOutOfRange);
  EXPECT_TRUE(std::isnan(far.state().lasers[0].reading));
  EXPECT_GT(far.state().lasers[0].true_distance, 1.0);  // floor ~1.15 m below the laser
  // Beam turned upwards, away from the floor.
  Physics side = make(scenario("effects: {laser: {mount_tilt: [3.141592653589793, 0, 0]}}\n"));
  ASSERT_TRUE(side.step(counts_for(side.truth(), l), 0.0).ok());
  EXPECT_EQ(side.state().lasers[0].status, LaserStatus::kNoTarget);
}

TEST(Physics, CableOverloadTripsAndLatches) {
  const RobotModel nominal = load("mini.yaml");
  Physics p =
      make(scenario("faults:\n  - {type: cable_overload, at: 1.0, cable: 5, limit: 1}\n"
                    "  - {type: cable_overload, at: 0, cable: 6, limit: 10000}\n"));
  Result<Eigen::VectorXd> c = nominal_counts(nominal, Pose{});
  ASSERT_TRUE(c.ok());
  ASSERT_TRUE(p.step(*c, 0.5).ok());
  EXPECT_GT(p.state().tensions(4), 1.0);
  EXPECT_FALSE(p.state().overloaded[4]);  // not armed yet
  ASSERT_TRUE(p.step(*c, 1.5).ok());
  EXPECT_TRUE(p.state().overloaded[4]);
  EXPECT_FALSE(p.state().overloaded[5]);
  ASSERT_TRUE(p.step(*c, 2.5).ok());
  EXPECT_TRUE(p.state().overloaded[4]);  // latched
}

TEST(Physics, RefusesBadInput) {
  Physics p = make(scenario(""));
  EXPECT_FALSE(p.step(Eigen::VectorXd::Zero(3), 0.0).ok());
  const Eigen::VectorXd l = ik_lengths(p.truth(), Pose{});
  ASSERT_TRUE(p.step(counts_for(p.truth(), l), 1.0).ok());
  EXPECT_FALSE(p.step(counts_for(p.truth(), l), 0.5).ok());  // time goes backwards
}

TEST(Lockstep, MeasuresThroughTheNominalModels) {
  const RobotModel nominal = load("mini.yaml");
  const Scenario s = scenario("effects: {hooke: {ea: 18000}, transmission_scale: 0.001}\n");
  Physics p = make(s);
  const std::vector<Pose> poses = test_poses();
  Result<std::vector<LockstepSample>> r = run_lockstep(p, nominal, poses);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  ASSERT_EQ(r->size(), poses.size());
  for (std::size_t j = 0; j < poses.size(); ++j) {
    const LockstepSample& x = (*r)[j];
    EXPECT_TRUE(x.converged);
    EXPECT_NEAR(x.time_s, 2.0 * static_cast<double>(j + 1), 1e-12);
    // No noise: lengths are the nominal winch model of the commanded counts ...
    for (int i = 0; i < 8; ++i) {
      EXPECT_NEAR(
          x.lengths(i),
          winch_counts_to_length<double>(nominal.winches[static_cast<std::size_t>(i)], x.counts(i)),
          1e-12);
    }
    // ... tensions the true ones (the sensors have no hidden error here) ...
    EXPECT_LT(dvec(x.tensions, x.true_tensions), 1e-9);
    // ... and the platform is not where the nominal model thinks (hidden geometry and effects).
    EXPECT_GT(position_error(x.true_pose, x.commanded), 1e-4);
    EXPECT_LT(position_error(x.true_pose, x.commanded), 0.05);
    // The laser sees the true pose.
    EXPECT_NEAR(x.lasers(0),
                p.laser_at(0, x.true_pose.position, rotation_from_rpy<double>(x.true_pose.rpy))
                    .true_distance,
                1e-12);
  }
  // The recording writer round-trips it.
  Result<recording::Recording> rec = make_recording(*r, nominal, s, RecordingProvenance{});
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  Result<std::string> text = recording::format_recording(*rec);
  ASSERT_TRUE(text.ok()) << text.status().to_string();
  Result<recording::Recording> back = recording::parse_recording(*text, "rec.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->poses.size(), poses.size());
  EXPECT_EQ(back->poses[2].lengths, (*r)[2].lengths);
  EXPECT_EQ(back->poses[1].lasers(0), (*r)[1].lasers(0));
  EXPECT_EQ(back->metadata.get("source"), "simulated");
}

TEST(Lockstep, SameSeedSameRecording) {
  const RobotModel nominal = load("mini.yaml");
  const Scenario s = scenario("noise: {encoder_counts: 2, force_raw: 0.3, laser: 0.0002}\n");
  Physics a = make(s, 7), b = make(s, 7);
  LockstepOptions o;
  o.laser_samples = 5;
  auto ra = run_lockstep(a, nominal, test_poses(), o);
  auto rb = run_lockstep(b, nominal, test_poses(), o);
  ASSERT_TRUE(ra.ok() && rb.ok());
  for (std::size_t j = 0; j < ra->size(); ++j) {
    EXPECT_EQ((*ra)[j].lengths, (*rb)[j].lengths);
    EXPECT_EQ((*ra)[j].tensions, (*rb)[j].tensions);
    EXPECT_EQ((*ra)[j].lasers, (*rb)[j].lasers);
  }
}

// Issue 18: the lock-step mode also reads swivel encoders, an inclinometer and an IMU heading at
// the true pose, with their own noise stream (the physics' readings of a seed do not change).
TEST(Lockstep, SwivelAndInclinometerChannelsSeeTheTruePose) {
  const RobotModel nominal = load("mini.yaml");
  const Scenario s = scenario("noise: {encoder_counts: 2, force_raw: 0.3, laser: 0.0002}\n");
  Physics a = make(s, 7), b = make(s, 7);
  LockstepOptions plain;
  LockstepOptions with = plain;
  with.swivel = with.inclinometer = with.imu_yaw = true;
  with.sigma_swivel = with.sigma_inclination = with.sigma_imu_yaw = 0.0;  // exact readings
  auto ra = run_lockstep(a, nominal, test_poses(), plain);
  auto rb = run_lockstep(b, nominal, test_poses(), with);
  ASSERT_TRUE(ra.ok() && rb.ok()) << rb.status().to_string();
  const RobotModel& truth = b.truth();
  for (std::size_t j = 0; j < rb->size(); ++j) {
    const LockstepSample& x = (*rb)[j];
    EXPECT_EQ((*ra)[j].lengths, x.lengths);
    EXPECT_EQ((*ra)[j].tensions, x.tensions);
    EXPECT_EQ((*ra)[j].lasers, x.lasers);
    EXPECT_TRUE((*ra)[j].swivels.size() == 0 && std::isnan((*ra)[j].imu_yaw));
    ASSERT_EQ(x.swivels.size(), 8);
    KinematicsData kin(truth);
    ASSERT_TRUE(inverse_kinematics(truth, x.true_pose, kin));
    for (int i = 0; i < 8; ++i) EXPECT_NEAR(x.swivels(i), kin.swivel_angles(i), 1e-12) << i;
    EXPECT_NEAR(x.inclination(0), x.true_pose.rpy(0), 1e-12);  // level mount
    EXPECT_NEAR(x.inclination(1), x.true_pose.rpy(1), 1e-12);
    EXPECT_NEAR(x.imu_yaw, x.true_pose.rpy(2), 1e-12);
  }
  // The recording carries the columns.
  RecordingProvenance prov;
  prov.sigma_swivel = 1e-3;
  Result<recording::Recording> rec = make_recording(*rb, nominal, s, prov);
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  EXPECT_TRUE(rec->has_swivel && rec->has_inclinometer && rec->has_imu_yaw);
  EXPECT_EQ(rec->metadata.get(recording::key::kNoiseSwivel), "0.001");
  Result<std::string> text = recording::format_recording(*rec);
  ASSERT_TRUE(text.ok()) << text.status().to_string();
  Result<recording::Recording> back = recording::parse_recording(*text, "rec.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->poses[1].swivels, (*rb)[1].swivels);
}

// Heavy cables on a long move: the counts move linearly between two far corners of MINI at 0.2 rad
// roll, and on the way cables 1-3 go nearly slack (a few hundredths of a newton). From the previous
// pose the sag solver stalled there (no descent after step 3), and the recording failed with "no
// equilibrium with sagging cables" (the benchmark's separating poses for sag + Hooke + force gain,
// seed 1). The solver now starts again from the equilibrium without the cables' weight. The
// platform comes to rest where one step straight to the goal puts it: a static equilibrium does
// not depend on the path (no direction effect here).
TEST(Lockstep, HeavyCablesSurviveAMoveThatSlackensCablesOnTheWay) {
  const Scenario s = scenario("effects: {hooke: {ea: 15000}, sag: true}\n");
  const RobotModel nominal = load("mini.yaml");
  Result<RobotModel> resolved = resolve_truth(s, nominal);
  ASSERT_TRUE(resolved.ok()) << resolved.status().to_string();
  RobotModel truth = *resolved;
  for (CableModel& c : truth.cables) c.mass_per_length = 0.010;  // 1.5 mm steel wire rope
  const std::vector<Pose> poses = {
      Pose{Eigen::Vector3d(0.157764467, 0.1512, -0.16007071), Eigen::Vector3d(0.2, 0.0, 0.0)},
      Pose{Eigen::Vector3d(-0.157764467, -0.1512, -0.0533569034), Eigen::Vector3d(0.2, 0.0, 0.0)}};
  std::vector<LockstepSample> by_substeps[2];
  const int substeps[2] = {10, 1};
  for (int k = 0; k < 2; ++k) {
    Result<Physics> p = Physics::create(truth, s, 1);
    ASSERT_TRUE(p.ok()) << p.status().to_string();
    LockstepOptions o;
    o.substeps = substeps[k];
    Result<std::vector<LockstepSample>> r = run_lockstep(*p, nominal, poses, o);
    ASSERT_TRUE(r.ok()) << substeps[k] << " substeps: " << r.status().to_string();
    by_substeps[k] = std::move(*r);
  }
  const LockstepSample& stepped = by_substeps[0].back();
  const LockstepSample& direct = by_substeps[1].back();
  EXPECT_TRUE(stepped.converged);
  EXPECT_LT(position_error(stepped.true_pose, direct.true_pose), 1e-7);
  EXPECT_LT(angle_error(stepped.true_pose, direct.true_pose), 1e-6);
  EXPECT_LT(dvec(stepped.true_tensions, direct.true_tensions), 1e-4);
  EXPECT_GT(stepped.true_tensions.minCoeff(), 0.1);  // at the goal every cable pulls again
}

// Issue 18: the virtual robot serves a suspended 4-cable crane. The commands of equilibrium poses
// (planned with simple_tension_distribution's suspended branch) put the true crane, equal to the
// nominal one, at those poses with the planned tensions.
TEST(Physics, SuspendedCraneHangsAtTheCommandedEquilibria) {
  const std::string text = "name: crane\ntruth: {config: " + kSource + "/config/crane4.yaml}\n";
  Result<Scenario> s = parse_scenario(text, "crane.yaml", kSource);
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  const RobotModel crane = load("crane4.yaml");
  Result<RobotModel> truth = resolve_truth(*s, crane);
  ASSERT_TRUE(truth.ok()) << truth.status().to_string();
  Result<Physics> p = Physics::create(*truth, *s, 1);
  ASSERT_TRUE(p.ok()) << p.status().to_string();
  double t = 0.0;
  int reached = 0;
  for (const Eigen::Vector3d& d : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.2, -0.1, 0.05),
                                   Eigen::Vector3d(-0.15, 0.25, -0.1)}) {
    Pose target = crane.home;
    target.position += d;
    Result<SuspendedState> hang = suspended_equilibrium_pose(crane, target);
    ASSERT_TRUE(hang.ok()) << hang.status().to_string();
    Result<Eigen::VectorXd> f =
        simple_tension_distribution(crane, hang->pose, default_reference_tension(crane));
    ASSERT_TRUE(f.ok()) << f.status().to_string();
    Result<Eigen::VectorXd> counts = nominal_counts(crane, hang->pose);
    ASSERT_TRUE(counts.ok()) << counts.status().to_string();
    const Status st = p->step(*counts, t);
    ASSERT_TRUE(st.ok()) << st.to_string();
    t += 0.01;
    EXPECT_LT(position_error(p->state().pose, hang->pose), 1e-6);
    EXPECT_LT((p->state().pose.rpy - hang->pose.rpy).cwiseAbs().maxCoeff(), 1e-6);
    EXPECT_LT((p->state().tensions - *f).cwiseAbs().maxCoeff(), 1e-3);
    ++reached;
  }
  EXPECT_EQ(reached, 3);

  // The lock-step offline mode (cdpr-sim's recording path) over the same kind of poses.
  Result<Physics> q = Physics::create(*truth, *s, 2);
  ASSERT_TRUE(q.ok()) << q.status().to_string();
  std::vector<Pose> poses;
  for (const double dx : {0.0, 0.1, -0.2}) {
    Pose target = crane.home;
    target.position.x() += dx;
    Result<SuspendedState> hang = suspended_equilibrium_pose(crane, target);
    ASSERT_TRUE(hang.ok()) << hang.status().to_string();
    poses.push_back(hang->pose);
  }
  LockstepOptions lo;
  lo.swivel = true;
  lo.inclinometer = true;
  Result<std::vector<LockstepSample>> rec = run_lockstep(*q, crane, poses, lo);
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  ASSERT_EQ(rec->size(), poses.size());
  for (std::size_t k = 0; k < poses.size(); ++k) {
    EXPECT_TRUE((*rec)[k].converged);
    // Integer counts: the platform settles within the rounding of the commands.
    EXPECT_LT(position_error((*rec)[k].true_pose, poses[k]), 1e-3);
    EXPECT_EQ((*rec)[k].swivels.size(), 4);
    EXPECT_TRUE((*rec)[k].inclination.allFinite());
  }
}

}  // namespace
}  // namespace cdpr::sim
