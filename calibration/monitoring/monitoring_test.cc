// In-service monitoring on MINI: a true robot (settle_platform of a changed model) read with
// noise at poses commanded through the calibrated model. Clean readings stay quiet, each change
// is named with its size, the per-sample update allocates nothing.
#include "cdpr/calibration/monitoring.hpp"

#include <gtest/gtest.h>

#include <random>

#include "alloc_counter.hpp"
#include "cdpr/calibration/force_distribution.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

struct Change {
  int anchor = -1;
  Eigen::Vector3d anchor_move = Eigen::Vector3d::Zero();
  int force = -1;
  double force_offset = 0.0;  // N
  int slip = -1;
  double slip_m = 0.0;   // m: the drum paid out this much more than the encoder says
  double thermal = 0.0;  // relative growth of every unstretched cable (with its routing)
  double creep = 0.0;    // 1/N: extra compliance of every cable
};

class Robot {
 public:
  explicit Robot(const Change& change, std::uint64_t seed = 1)
      : model_(testing::mini_robot()), truth_(model_), change_(change), rng_(seed) {
    if (change.anchor >= 0) truth_.frame_anchors.col(change.anchor) += change.anchor_move;
    for (CableModel& c : truth_.cables) c.ea = 1.0 / (1.0 / c.ea + change.creep);
  }
  const RobotModel& model() const { return model_; }

  // The readings at `pose` commanded through the model (noise: 1e-5 m, 0.5 N).
  MonitorSample read(const Pose& pose, double t) {
    const double f_ref = default_reference_tension(model_);
    Result<Eigen::VectorXd> f = simple_tension_distribution(model_, pose, f_ref);
    EXPECT_TRUE(f.ok());
    Result<Eigen::VectorXd> l = unstretched_lengths(model_, pose, *f);
    EXPECT_TRUE(l.ok());
    Eigen::VectorXd true_l = *l;
    if (change_.slip >= 0) true_l(change_.slip) += change_.slip_m;
    for (int i = 0; i < true_l.size(); ++i) {
      true_l(i) +=
          change_.thermal * (model_.cables[static_cast<std::size_t>(i)].routing_length + (*l)(i));
    }
    Eigen::VectorXd tensions;
    Result<Pose> at = settle_platform(truth_, true_l, pose, &tensions);
    EXPECT_TRUE(at.ok());
    MonitorSample s;
    s.time_s = t;
    s.pose = pose;
    for (int i = 0; i < model_.num_cables(); ++i) {
      const auto u = static_cast<std::size_t>(i);
      s.lengths[u] = (*l)(i) + 1e-5 * normal_(rng_);
      s.tensions[u] =
          tensions(i) + 0.5 * normal_(rng_) + (i == change_.force ? change_.force_offset : 0.0);
    }
    return s;
  }

 private:
  RobotModel model_;
  RobotModel truth_;
  Change change_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
};

std::vector<Pose> poses() {
  std::vector<Pose> out;
  for (double x : {-0.08, 0.0, 0.08}) {
    for (double y : {-0.08, 0.08}) {
      for (double z : {-0.06, 0.06})
        out.push_back(Pose{Eigen::Vector3d(x, y, z), Eigen::Vector3d::Zero()});
    }
  }
  return out;
}

MonitorOptions options() {
  MonitorOptions o;
  o.noise.sigma_length = 1e-5;
  o.noise.sigma_force = 0.5;
  o.samples_per_hour = 3600.0;
  o.acceptance_position_rms_m = 5e-5;
  o.box.points_per_axis = 3;
  o.box.half_extent = Eigen::Vector3d::Constant(0.08);
  return o;
}

// Feeds `rounds` passes over the poses, one sample per second; the assessment.
MonitorAssessment run(Robot& robot, Monitor& monitor, int rounds) {
  double t = 0.0;
  for (int r = 0; r < rounds; ++r) {
    for (const Pose& p : poses()) monitor.add(robot.read(p, t += 1.0));
  }
  Result<MonitorAssessment> a = monitor.assess();
  EXPECT_TRUE(a.ok()) << a.status().to_string();
  return a.ok() ? *a : MonitorAssessment{};
}

Monitor must_create(const Robot& robot, const MonitorOptions& o) {
  Result<Monitor> m = Monitor::create(CalibratedModel::from_robot(robot.model()), o);
  EXPECT_TRUE(m.ok()) << m.status().to_string();
  return std::move(*m);
}

Monitor make(const Robot& robot) {
  return must_create(robot, options());
}

// Three passes over the poses with `change` in the true robot: the assessment, after at least
// one alarm.
MonitorAssessment assess_change(const Change& change) {
  Robot robot(change);
  Monitor monitor = make(robot);
  const MonitorAssessment a = run(robot, monitor, 3);
  EXPECT_GT(monitor.alarms(), 0);
  return a;
}

// Whether the assessment names `effect` on `cable` first (the description when not).
::testing::AssertionResult named(const MonitorAssessment& a, MonitorEffect effect, int cable) {
  if (a.changed && a.effects.front().effect == effect && a.effects.front().cable == cable) {
    return ::testing::AssertionSuccess();
  }
  return ::testing::AssertionFailure() << describe(a);
}

TEST(Monitor, CleanReadingsRaiseNoAlarmAndNameNoChange) {
  Robot robot(Change{});
  Monitor monitor = make(robot);
  const MonitorAssessment a = run(robot, monitor, 10);
  EXPECT_EQ(a.samples, 10 * static_cast<int>(poses().size()));
  EXPECT_EQ(monitor.alarms(), 0);
  EXPECT_FALSE(a.changed) << describe(a);
  EXPECT_EQ(a.position_rms_now_m, a.position_rms_acceptance_m);
  for (const MonitorRow& r : a.rows) EXPECT_LT(std::abs(r.mean_sigma), 0.5) << r.name;
}

TEST(Monitor, AMovedPulleyIsNamedWithItsDisplacement) {
  // 2 mm across cable 3 at home and 0.5 mm along it (a move along the cable alone looks like an
  // encoder slip; larger ones slacken MINI's cables).
  KinematicsData k(testing::mini_robot());
  ASSERT_TRUE(inverse_kinematics(testing::mini_robot(), Pose{}, k));
  const Eigen::Vector3d u = k.unit_vectors.col(2);
  const Eigen::Vector3d across = u.cross(Eigen::Vector3d::UnitZ()).normalized();
  Change c;
  c.anchor = 2;
  c.anchor_move = 0.002 * across + 0.0005 * u;
  const MonitorAssessment a = assess_change(c);
  ASSERT_TRUE(named(a, MonitorEffect::kFrameAnchor, 2));
  const EffectEstimate& e = a.effects.front();
  EXPECT_LT((e.value - c.anchor_move).norm(), 0.2 * c.anchor_move.norm()) << e.value.transpose();
  EXPECT_GT(a.position_rms_now_m, a.position_rms_acceptance_m + 1e-4);
  EXPECT_TRUE(a.proposal.needed);
  EXPECT_EQ(a.proposal.parameters.front(), "frame anchor 3 (x, y, z)");
  EXPECT_FALSE(a.proposal.full_sequence) << a.proposal.stopping_rule;
  EXPECT_GE(a.proposal.poses.size(), 2u);
  EXPECT_NE(describe(a).find("pulley moved (frame anchor 3)"), std::string::npos) << describe(a);
}

TEST(Monitor, AForceSensorDriftIsNamedAndMovesNoPosition) {
  Change c;
  c.force = 4;
  c.force_offset = 3.0;
  const MonitorAssessment a = assess_change(c);
  ASSERT_TRUE(named(a, MonitorEffect::kForceOffset, 4));
  EXPECT_NEAR(a.effects.front().value(0), 3.0, 0.3);
  EXPECT_EQ(a.position_rms_now_m, a.position_rms_acceptance_m);
}

TEST(Monitor, AnEncoderSlipIsNamedWithItsLength) {
  Change c;
  c.slip = 6;
  c.slip_m = 5e-4;
  const MonitorAssessment a = assess_change(c);
  ASSERT_TRUE(named(a, MonitorEffect::kEncoderSlip, 6));
  EXPECT_NEAR(a.effects.front().value(0), 5e-4, 1e-4);
}

TEST(Monitor, CableGrowthIsNamedThermalWhenItFollowsTheLengthAndCreepWhenTheTension) {
  Change thermal;
  thermal.thermal = -1.2e-4;  // 10 K on a polymer cable
  const MonitorAssessment a = assess_change(thermal);
  ASSERT_TRUE(named(a, MonitorEffect::kThermalGrowth, -1));
  EXPECT_NEAR(a.effects.front().value(0), thermal.thermal, 0.1 * std::abs(thermal.thermal));
  EXPECT_GT(a.position_rms_now_m, a.position_rms_acceptance_m);
  Change creep;
  creep.creep = 5e-6;
  const MonitorAssessment b = assess_change(creep);
  ASSERT_TRUE(named(b, MonitorEffect::kCreepGrowth, -1));
  // Hooke's F L / (EA + F) makes the extra compliance about (1 + F / EA)^-1 of it.
  EXPECT_NEAR(b.effects.front().value(0), creep.creep, 0.1 * creep.creep);
}

TEST(Monitor, AStepAfterACleanPeriodIsFittedFromItsBlockWithItsFullSize) {
  // 10 clean passes, then 2 with a slip: the window's average would hold a sixth of it.
  Robot clean(Change{});
  Change c;
  c.slip = 1;
  c.slip_m = 3e-4;
  Robot slipped(c, 2);
  MonitorOptions o = options();
  o.block_samples = static_cast<int>(poses().size());
  Monitor monitor = must_create(clean, o);
  run(clean, monitor, 10);
  const double t0 = 10.0 * static_cast<double>(poses().size());
  double t = t0;
  for (int r = 0; r < 2; ++r) {
    for (const Pose& p : poses()) monitor.add(slipped.read(p, t += 1.0));
  }
  Result<MonitorAssessment> a = monitor.assess();
  ASSERT_TRUE(a.ok());
  ASSERT_TRUE(named(*a, MonitorEffect::kEncoderSlip, 1));
  EXPECT_NEAR(a->effects.front().value(0), 3e-4, 3e-5);
  EXPECT_EQ(a->effects.front().since_s, t0 + 1.0);
}

TEST(Monitor, AddAllocatesNothing) {
  Robot robot(Change{});
  Monitor monitor = make(robot);
  std::vector<MonitorSample> samples;
  for (const Pose& p : poses()) samples.push_back(robot.read(p, 1.0 + samples.size()));
  monitor.add(samples.front());  // first touch of everything
  test::AllocationCounter count;
  for (const MonitorSample& s : samples) monitor.add(s);
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(monitor.samples(), static_cast<int>(samples.size()) + 1);
}

TEST(Monitor, SkipsIncompleteSamplesAndRefusesTooManyCables) {
  Robot robot(Change{});
  Monitor monitor = make(robot);
  MonitorSample s = robot.read(Pose{}, 1.0);
  s.tensions[3] = MonitorSample::kMissing;
  EXPECT_FALSE(monitor.add(s));
  EXPECT_EQ(monitor.samples(), 0);
  RobotModel big = testing::mini_robot();
  big.frame_anchors.conservativeResize(3, kMonitorMaxCables + 1);
  EXPECT_FALSE(Monitor::create(CalibratedModel::from_robot(big), options()).ok());
}

}  // namespace
}  // namespace cdpr
