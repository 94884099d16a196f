// Physical ranges of the estimated parameters (ParameterBounds): enforced in the solver for every
// parameter kind, and an estimate on a bound is flagged and warned about.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

// MINI with the measured anchors as the truth, 25 random poses, rigid physics, default noise.
struct Data {
  scenario::Scenario s;
  MeasurementSet set;
};

const Data& mini_data() {
  static const Data d = [] {
    Data out;
    out.s = scenario::mini_scenario();
    const std::vector<Pose> poses =
        scenario::random_feasible_poses(out.s.nominal.robot, out.s.box, 25, 11, &out.s.truth.robot);
    SimulationOptions so;
    so.controller = &out.s.nominal;
    auto sim = simulate_measurements(out.s.truth, poses, SensorNoise{}, 5, so);
    EXPECT_TRUE(sim.ok()) << sim.status().to_string();
    if (sim.ok()) out.set = sim->set;
    return out;
  }();
  return d;
}

struct KindCase {
  ParameterKind kind;  // the estimates of IdentificationReport::parameters it concerns
  double half_range;   // the tight range set for the test (relative kinds)
  // Switches the kind on and narrows its range to `half_range`.
  std::function<void(IdentificationOptions&, double)> enable;
};

// "a_1.x", "o_1", "laser_1.plane.c", ...: which kind a case is about, for the trace.
std::string kind_name(ParameterKind kind) {
  return parameter_name({kind, 0, 0});
}

// Every estimate of `kind` lies inside its range of width `width`, at least one is held on the
// bound and listed by parameters_at_bound(), the report warns about it and is not trustworthy.
void expect_held_at_bound_and_reported(const IdentificationReport& rep, ParameterKind kind,
                                       double width) {
  int of_kind = 0, at_bound = 0;
  const std::vector<std::string> flagged = rep.parameters_at_bound();
  for (const ParameterEstimate& p : rep.parameters) {
    if (p.id.kind != kind) continue;
    ++of_kind;
    const double tol = 1e-9 * std::max(1.0, std::abs(p.initial));
    EXPECT_GE(p.value, p.lower - tol) << p.name;
    EXPECT_LE(p.value, p.upper + tol) << p.name;
    EXPECT_NEAR(p.upper - p.lower, width, 1e-9 * width) << p.name;
    if (p.at_bound) {
      ++at_bound;
      EXPECT_NE(std::find(flagged.begin(), flagged.end(), p.name), flagged.end()) << p.name;
    }
  }
  EXPECT_GT(of_kind, 0);
  EXPECT_GT(at_bound, 0) << rep.full_report();
  bool warned = false;
  for (const std::string& w : rep.warnings) warned = warned || w.find("bound") != std::string::npos;
  EXPECT_TRUE(warned);
  EXPECT_FALSE(rep.trustworthy());
}

// Each kind's range is narrowed far below what the data ask for (the truth or the noise moves the
// estimate by more): every estimate of that kind stays inside its range, at least one ends on a
// bound, and the report says so.
TEST(ParameterBounds, EveryParameterKindIsHeldInsideItsRange) {
  const std::vector<KindCase> kinds = {
      {ParameterKind::kFrameAnchor, 1e-4,
       [](IdentificationOptions& o, double h) { o.bounds.frame_anchor_m = h; }},
      {ParameterKind::kPlatformAnchor, 1e-5,
       [](IdentificationOptions& o, double h) {
         o.estimate_platform_anchors = true;
         o.estimate_frame_anchors = false;
         o.bounds.platform_anchor_m = h;
       }},
      {ParameterKind::kLengthOffset, 1e-5,
       [](IdentificationOptions& o, double h) { o.bounds.length_offset_m = h; }},
      {ParameterKind::kLengthScale, 1e-6,
       [](IdentificationOptions& o, double h) {
         o.estimate_length_scales = true;
         o.bounds.length_scale = h;
       }},
      {ParameterKind::kForceGain, 1e-5,
       [](IdentificationOptions& o, double h) {
         o.estimate_force_gains = true;
         o.bounds.force_gain = h;
       }},
      {ParameterKind::kForceOffset, 1e-6,
       [](IdentificationOptions& o, double h) {
         o.estimate_force_offsets = true;
         o.bounds.force_offset_fraction = h;  // x f_max (200 N) x gain (2): 4e-4 raw
       }},
      {ParameterKind::kLaserOrigin, 1e-5,
       [](IdentificationOptions& o, double h) {
         o.estimate_laser_origin = true;
         o.estimate_laser_plane = false;
         o.bounds.laser_origin_m = h;
       }},
      {ParameterKind::kLaserDirection, 1e-6,
       [](IdentificationOptions& o, double h) {
         o.estimate_laser_direction = true;
         o.estimate_laser_plane = false;
         o.bounds.laser_direction_rad = h;
       }},
      {ParameterKind::kLaserPlaneNormal, 1e-6,
       [](IdentificationOptions& o, double h) { o.bounds.plane_normal_rad = h; }},
      {ParameterKind::kLaserPlaneOffset, 1e-5,
       [](IdentificationOptions& o, double h) { o.bounds.plane_offset_m = h; }},
  };
  const Data& d = mini_data();
  for (const KindCase& k : kinds) {
    SCOPED_TRACE(kind_name(k.kind));
    IdentificationOptions opt;
    k.enable(opt, k.half_range);
    auto rep = identify(d.s.nominal, d.set, opt);
    ASSERT_TRUE(rep.ok()) << rep.status().to_string();
    const double expected = k.kind == ParameterKind::kForceOffset ? 2.0 * k.half_range * 200.0 * 2.0
                                                                  : 2.0 * k.half_range;
    expect_held_at_bound_and_reported(*rep, k.kind, expected);
  }
}

// The stiffness range is absolute: EA within [ea_factor_min, ea_factor_max] x the config's EA.
// The truth is 25 % softer than the config; with the range [0.9, 1.1] x EA the shared and the
// per-cable estimates end on the lower bound, with the default range they do not.
TEST(ParameterBounds, StiffnessStaysWithinItsFactorOfTheConfig) {
  scenario::Scenario s = scenario::mini_scenario();
  CalibratedModel truth = s.truth;
  for (auto& c : truth.robot.cables) c.ea *= 0.75;
  const std::vector<Pose> poses =
      scenario::random_feasible_poses(s.nominal.robot, s.box, 25, 11, &truth.robot);
  SimulationOptions so;
  so.controller = &s.nominal;
  auto sim = simulate_measurements(truth, poses, SensorNoise{}, 5, so);
  ASSERT_TRUE(sim.ok()) << sim.status().to_string();
  for (StiffnessEstimate kind : {StiffnessEstimate::kShared, StiffnessEstimate::kPerCable}) {
    IdentificationOptions opt;
    opt.estimate_stiffness = kind;
    auto free_fit = identify(s.nominal, sim->set, opt);
    ASSERT_TRUE(free_fit.ok()) << free_fit.status().to_string();
    EXPECT_TRUE(free_fit->parameters_at_bound().empty()) << free_fit->full_report();
    opt.bounds.ea_factor_min = 0.9;
    opt.bounds.ea_factor_max = 1.1;
    auto bounded = identify(s.nominal, sim->set, opt);
    ASSERT_TRUE(bounded.ok()) << bounded.status().to_string();
    int at_lower = 0;
    for (const ParameterEstimate& p : bounded->parameters) {
      if (p.id.kind != ParameterKind::kStiffness) continue;
      EXPECT_NEAR(p.lower, -0.1, 1e-12);
      EXPECT_NEAR(p.upper, 0.1, 1e-12);
      EXPECT_GE(p.value, -0.1 - 1e-12);
      at_lower += p.at_bound && p.value < 0.0 ? 1 : 0;
    }
    EXPECT_GT(at_lower, 0) << bounded->full_report();
    for (int i = 0; i < s.nominal.robot.num_cables(); ++i) {
      EXPECT_GE(bounded->estimate.robot.cables[static_cast<std::size_t>(i)].ea,
                0.9 * s.nominal.robot.cables[static_cast<std::size_t>(i)].ea * (1 - 1e-9));
    }
  }
}

}  // namespace
}  // namespace cdpr

namespace cdpr {
namespace {

// Issue 15's runaway: `--estimate stiffness` on a suspended frame ended at EA = 1.6e12 N, "did not
// converge". Reproduced with a suspended 8-cable frame (every anchor on top, a 20 kg platform
// hanging in them) whose true cables are much stiffer than the config's 20 kN: the data ask for
// no elongation at all, EA = EA_config (1 + e) has no finite optimum and the solver walks e
// upwards. With the physical range the estimate stops at 10 x the config's EA and says so.
TEST(ParameterBounds, StiffnessOnASuspendedFrameNoLongerRunsAway) {
  testing::BoxRobotSpec spec = testing::mini_spec();
  spec.name = "suspended";
  spec.bottom_xy = {0.35, 0.5};
  spec.bottom_z = 0.4415;  // the "bottom" cables also come from the top
  spec.mass = 20.0;
  RobotModel nominal = testing::make_box_robot(spec, true);
  for (int i = 0; i < nominal.num_cables(); ++i) {
    nominal.pulleys[static_cast<std::size_t>(i)].frame =
        testing::vertical_swivel_frame(nominal.frame_anchors.col(i), /*cable_goes_up=*/false);
  }
  scenario::add_down_laser(nominal, -0.6);
  RobotModel truth = nominal;
  for (auto& c : truth.cables) c.ea = 1e9;  // practically rigid
  const CalibratedModel nominal_model = CalibratedModel::from_robot(nominal);
  auto homed = homed_truth(truth, nominal);
  ASSERT_TRUE(homed.ok()) << homed.status().to_string();
  testing::WorkspaceBox box;
  box.center = Eigen::Vector3d(0.0, 0.0, -0.1);
  box.half_extent = Eigen::Vector3d(0.12, 0.12, 0.1);
  box.max_angle = 0.1;
  const std::vector<Pose> poses = scenario::random_feasible_poses(nominal, box, 25, 3, &truth);
  ASSERT_EQ(poses.size(), 25u);
  SimulationOptions so;
  so.controller = &nominal_model;
  auto sim = simulate_measurements(*homed, poses, SensorNoise{}, 9, so);
  ASSERT_TRUE(sim.ok()) << sim.status().to_string();

  IdentificationOptions opt;
  opt.estimate_stiffness = StiffnessEstimate::kShared;
  opt.bounds.ea_factor_max = std::numeric_limits<double>::infinity();  // as before the ranges
  auto unbounded = identify(nominal_model, sim->set, opt);
  ASSERT_TRUE(unbounded.ok()) << unbounded.status().to_string();
  const double ea_unbounded = unbounded->estimate.robot.cables[0].ea;
  std::printf("unbounded: EA = %.3g N (config %.3g N), %s, %d iterations\n", ea_unbounded,
              nominal.cables[0].ea, unbounded->converged ? "converged" : "did not converge",
              unbounded->iterations);
  EXPECT_GT(ea_unbounded, 10.0 * nominal.cables[0].ea);

  opt.bounds = ParameterBounds{};
  auto bounded = identify(nominal_model, sim->set, opt);
  ASSERT_TRUE(bounded.ok()) << bounded.status().to_string();
  const double ea_bounded = bounded->estimate.robot.cables[0].ea;
  std::printf("bounded: EA = %.3g N, at bound: %zu parameter(s)\n", ea_bounded,
              bounded->parameters_at_bound().size());
  EXPECT_NEAR(ea_bounded, 10.0 * nominal.cables[0].ea, 1e-6 * ea_bounded);
  ASSERT_EQ(bounded->parameters_at_bound(), std::vector<std::string>{"ea_scale"});
  EXPECT_FALSE(bounded->trustworthy());
}

}  // namespace
}  // namespace cdpr

namespace cdpr {
namespace {

// The sensor channels' parameter kinds (issue 18): swivel encoder zeros, inclinometer mounting
// roll and pitch, IMU heading zero. MINI with swivel encoders, inclinometer and IMU; the truth
// hides zeros of up to 0.05 rad, a mounting of (0.012, -0.017) rad and a heading zero of 0.4 rad.
struct SensorKindCase {
  ParameterKind kind;      // the estimates of IdentificationReport::parameters it concerns
  double default_half;     // ParameterBounds' default half range
  double narrow_half;      // a range the truth lies outside of
  double truth_magnitude;  // the largest true deviation of the kind from the config, rad
  std::function<void(IdentificationOptions&, double)> narrow;
};

const MeasurementSet& sensor_set(const scenario::Scenario& s) {
  static const MeasurementSet set = [&s] {
    const std::vector<Pose> poses =
        scenario::random_feasible_poses(s.nominal.robot, s.box, 25, 11, &s.truth.robot);
    SimulationOptions so;
    so.controller = &s.nominal;
    so.laser = false;
    so.swivel = true;
    so.inclinometer = true;
    so.imu_yaw = true;
    auto sim = simulate_measurements(s.truth, poses, SensorNoise{}, 3, so);
    EXPECT_TRUE(sim.ok()) << sim.status().to_string();
    return sim.ok() ? sim->set : MeasurementSet{};
  }();
  return set;
}

IdentificationOptions sensor_kind_options() {
  IdentificationOptions o;
  o.estimate_laser_plane = false;
  o.estimate_swivel_zeros = true;
  o.estimate_inclinometer_mounting = true;
  o.estimate_imu_yaw_zero = true;
  return o;
}

std::vector<SensorKindCase> sensor_kinds(const scenario::Scenario& s) {
  const RobotModel& t = s.truth.robot;
  const RobotModel& n = s.nominal.robot;
  double swivel = 0.0;
  for (int i = 0; i < t.num_cables(); ++i)
    swivel = std::max(swivel, std::abs(t.swivel_encoder(i).zero - n.swivel_encoder(i).zero));
  const double mount =
      std::max(std::abs(t.inclinometer.mounting_rpy(0) - n.inclinometer.mounting_rpy(0)),
               std::abs(t.inclinometer.mounting_rpy(1) - n.inclinometer.mounting_rpy(1)));
  const double yaw = std::abs(t.inclinometer.yaw_zero - n.inclinometer.yaw_zero);
  const ParameterBounds defaults;
  return {
      {ParameterKind::kSwivelZero, defaults.swivel_zero_rad, 0.2 * swivel, swivel,
       [](IdentificationOptions& o, double h) { o.bounds.swivel_zero_rad = h; }},
      {ParameterKind::kInclinometerMount, defaults.inclinometer_mount_rad, 0.2 * mount, mount,
       [](IdentificationOptions& o, double h) { o.bounds.inclinometer_mount_rad = h; }},
      {ParameterKind::kImuYawZero, defaults.imu_yaw_zero_rad, 0.2 * yaw, yaw,
       [](IdentificationOptions& o, double h) { o.bounds.imu_yaw_zero_rad = h; }},
  };
}

// With the default ranges (0.5, 0.2 and 3.2 rad) the true values lie well inside: every estimate
// of the three kinds has the documented range and none ends on a bound.
TEST(ParameterBounds, SensorKindsHaveTheirDefaultRangesAndFitInside) {
  const scenario::Scenario s = scenario::mini_sensor_scenario();
  const MeasurementSet& set = sensor_set(s);
  auto rep = identify(s.nominal, set, sensor_kind_options());
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  for (const SensorKindCase& k : sensor_kinds(s)) {
    SCOPED_TRACE(kind_name(k.kind));
    ASSERT_GT(k.truth_magnitude, 0.0);
    ASSERT_LT(k.truth_magnitude, k.default_half);
    int of_kind = 0;
    for (const ParameterEstimate& p : rep->parameters) {
      if (p.id.kind != k.kind) continue;
      ++of_kind;
      EXPECT_NEAR(p.upper - p.lower, 2.0 * k.default_half, 1e-9 * k.default_half) << p.name;
      EXPECT_FALSE(p.at_bound) << p.name;
    }
    EXPECT_GT(of_kind, 0);
  }
  EXPECT_TRUE(rep->parameters_at_bound().empty()) << rep->full_report();
}

// Narrowed to a fifth of the true deviation, each kind would run outside its range: every
// estimate stays inside, at least one is held on the bound, and the report flags and warns.
TEST(ParameterBounds, SensorKindsAreHeldAtTheirBoundAndReported) {
  const scenario::Scenario s = scenario::mini_sensor_scenario();
  const MeasurementSet& set = sensor_set(s);
  for (const SensorKindCase& k : sensor_kinds(s)) {
    SCOPED_TRACE(kind_name(k.kind));
    IdentificationOptions opt = sensor_kind_options();
    k.narrow(opt, k.narrow_half);
    auto rep = identify(s.nominal, set, opt);
    ASSERT_TRUE(rep.ok()) << rep.status().to_string();
    expect_held_at_bound_and_reported(*rep, k.kind, 2.0 * k.narrow_half);
  }
}

}  // namespace
}  // namespace cdpr
