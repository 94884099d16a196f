#include "cdpr/calibration/pose_design.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

// A small design for tests: 3 grid points per axis, one exchange pass.
PoseDesignOptions small_design(int num_poses) {
  PoseDesignOptions o;
  o.points_per_axis = 3;
  o.exchange_passes = 1;
  o.num_poses = num_poses;
  return o;
}

TEST(PoseDesign, DesignedSetIsFeasibleAndBeatsRandom) {
  scenario::Scenario s = scenario::mini_scenario();
  const PoseDesignOptions o = small_design(10);
  auto d = design_poses(s.nominal, o);
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  ASSERT_EQ(static_cast<int>(d->poses.size()), o.num_poses);
  EXPECT_EQ((d->poses[0].vector() - s.nominal.robot.home.vector()).norm(), 0.0);
  const double f_ref = default_reference_tension(s.nominal.robot);
  for (const Pose& p : d->poses)
    EXPECT_TRUE(simple_tension_distribution(s.nominal.robot, p, f_ref).ok());
  AccuracyBox box;
  box.points_per_axis = 3;
  auto cmp = compare_pose_sets(s.nominal, o, box, 3);
  ASSERT_TRUE(cmp.ok()) << cmp.status().to_string();
  ASSERT_EQ(cmp->size(), 3u);
  EXPECT_LT((*cmp)[0].anchor_rms_std_m, (*cmp)[1].anchor_rms_std_m);
}

// The design's tension margin: with it every designed pose has a tension distribution inside the
// narrowed limits; without it, a design tilted up to 25 degrees uses poses whose tensions come
// closer to the limits than the margin (the poses that overloaded a cable of the virtual MINI).
TEST(PoseDesign, TensionMarginKeepsEveryPoseAwayFromTheLimits) {
  const scenario::Scenario s = scenario::mini_scenario();
  PoseDesignOptions o = small_design(12);
  o.max_angle = 0.4363;
  const double margin = 30.0;
  const Result<RobotModel> narrowed = narrow_tension_limits(s.nominal.robot, margin);
  ASSERT_TRUE(narrowed.ok()) << narrowed.status().to_string();
  EXPECT_DOUBLE_EQ(narrowed->cables[0].f_max, s.nominal.robot.cables[0].f_max - margin);
  const double f_ref = default_reference_tension(s.nominal.robot);
  auto inside = [&](const std::vector<Pose>& poses) {
    int n = 0;
    for (const Pose& p : poses) n += simple_tension_distribution(*narrowed, p, f_ref).ok() ? 1 : 0;
    return n;
  };
  auto plain = design_poses(s.nominal, o);
  ASSERT_TRUE(plain.ok()) << plain.status().to_string();
  EXPECT_LT(inside(plain->poses), o.num_poses);
  o.tension_margin = margin;
  auto kept = design_poses(s.nominal, o);
  ASSERT_TRUE(kept.ok()) << kept.status().to_string();
  ASSERT_EQ(static_cast<int>(kept->poses.size()), o.num_poses);
  EXPECT_EQ(inside(kept->poses), o.num_poses);
  EXPECT_LT(kept->candidates, plain->candidates);
}

TEST(PoseDesign, RefusesAMarginThatLeavesNoTensionRange) {
  const scenario::Scenario s = scenario::mini_scenario();
  PoseDesignOptions o = small_design(5);
  const double f_max = s.nominal.robot.cables[0].f_max;
  o.tension_margin = f_max;
  auto d = design_poses(s.nominal, o);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(d.status().to_string().find("cable 1"), std::string::npos) << d.status().to_string();
  o.tension_margin = -1.0;
  EXPECT_EQ(design_poses(s.nominal, o).status().code(), ErrorCode::kInvalidArgument);
}

// log det of the information (poses profiled out) that `channels` give at `poses`.
double log_det_information(const CalibratedModel& model, const std::vector<Pose>& poses,
                           const SensorNoise& noise, const SensorChannels& channels,
                           const IdentificationOptions& identification) {
  SimulationOptions so;
  so.add_noise = false;
  so.use_channels(channels);
  auto sim = simulate_measurements(model, poses, noise, 0, so);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  if (!sim.ok()) return 0.0;
  auto gi = geometry_information(model, sim->set, poses, identification);
  EXPECT_TRUE(gi.ok()) << gi.status().to_string();
  if (!gi.ok()) return 0.0;
  const Eigen::LLT<Eigen::MatrixXd> llt(gi->information);
  EXPECT_EQ(llt.info(), Eigen::Success);
  return 2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
}

// Issue 18: MINI with swivel encoders and an inclinometer and no laser. Poses designed for those
// channels beat the poses designed for the laser on that robot, by the criterion each design
// optimises: the information about the parameters (D-optimal), and the predicted platform
// position error over the test box (position accuracy). (Not by every figure: the D-optimal
// design maximises the determinant over all parameters, swivel zeros and inclinometer mounting
// included, so the anchors' bound alone can come out a little larger, 0.3 % here.)
TEST(PoseDesign, DesignedForTheChannelsBeatsTheLaserDesignOnThem) {
  const scenario::Scenario s = scenario::mini_sensor_scenario();
  PoseDesignOptions laser;
  laser.points_per_axis = 3;
  laser.exchange_passes = 2;
  laser.num_poses = 12;
  laser.accuracy_box.points_per_axis = 3;
  PoseDesignOptions swivel = laser;
  swivel.channels.laser = false;
  swivel.channels.swivel = true;
  swivel.channels.inclinometer = true;
  fit_estimates_to_channels(swivel.channels, &swivel.identification);

  auto dl = design_poses(s.nominal, laser);
  ASSERT_TRUE(dl.ok()) << dl.status().to_string();
  auto ds = design_poses(s.nominal, swivel);
  ASSERT_TRUE(ds.ok()) << ds.status().to_string();
  ASSERT_EQ(ds->poses.size(), dl->poses.size());
  EXPECT_GT(log_det_information(s.nominal, ds->poses, swivel.noise, swivel.channels,
                                swivel.identification),
            log_det_information(s.nominal, dl->poses, swivel.noise, swivel.channels,
                                swivel.identification));

  laser.criterion = DesignCriterion::kPositionAccuracy;
  swivel.criterion = DesignCriterion::kPositionAccuracy;
  auto pl_design = design_poses(s.nominal, laser);
  ASSERT_TRUE(pl_design.ok()) << pl_design.status().to_string();
  auto ps_design = design_poses(s.nominal, swivel);
  ASSERT_TRUE(ps_design.ok()) << ps_design.status().to_string();
  PredictedAccuracyOptions po;
  po.box = swivel.accuracy_box;
  po.channels = swivel.channels;
  po.identification = swivel.identification;
  auto ps = predict_accuracy(s.nominal, ps_design->poses, swivel.noise, po);
  auto pl = predict_accuracy(s.nominal, pl_design->poses, swivel.noise, po);
  ASSERT_TRUE(ps.ok() && pl.ok());
  EXPECT_LT(ps->position_rms_m, pl->position_rms_m);
  // The design's own prediction is predict_accuracy's figure (up to the design's ridge).
  EXPECT_NEAR(ps_design->position_rms_m / ps->position_rms_m, 1.0, 1e-3);
}

// The smallest eigenvalue of the information about the laser's beam direction (u, v) with every
// parameter `identification` estimates and the poses profiled out: what a recording at `poses`
// says about a tilted laser mount in its least informed direction (1 / rad^2).
double beam_direction_information(const CalibratedModel& model, const std::vector<Pose>& poses,
                                  const PoseDesignOptions& o) {
  SimulationOptions so;
  so.add_noise = false;
  so.use_channels(o.channels);
  auto sim = simulate_measurements(model, poses, o.noise, 0, so);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  if (!sim.ok()) return 0.0;
  IdentificationOptions with = o.identification;
  with.estimate_laser_direction = true;
  auto gi = geometry_information(model, sim->set, poses, with);
  EXPECT_TRUE(gi.ok()) << gi.status().to_string();
  if (!gi.ok()) return 0.0;
  std::vector<int> beam, rest;
  for (int q = 0; q < static_cast<int>(gi->ids.size()); ++q) {
    (gi->ids[static_cast<std::size_t>(q)].kind == ParameterKind::kLaserDirection ? beam : rest)
        .push_back(q);
  }
  const Eigen::MatrixXd& F = gi->information;
  const Eigen::MatrixXd S =
      F(beam, beam) - F(beam, rest) * F(rest, rest).ldlt().solve(F(rest, beam));
  return Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(S).eigenvalues()(0);
}

// MINI cannot pitch 15 degrees anywhere in its box, so with the full angle alone (angle_steps 1,
// the default) no designed pose is pitched, and the beam direction's component that only a pitch
// shows has no information at all. With half tilts (angle_steps 2) and the beam direction
// emphasised (a tilted laser mount, which the mismatch locator tests and the calibration does not
// estimate) both components are informed, while the calibration's predicted accuracy (the anchors'
// RMS bound, the position error over the box) stays within 3 % of the plain D-optimal design's
// (measured: the smallest eigenvalue 11.5 times the half-tilt plain design's, anchors 1.276 mm
// against 1.277 mm, position 0.464 mm against 0.471 mm). Without the laser the emphasis is left
// out.
TEST(PoseDesign, EmphasisedBeamDirectionIsSeenAtLittleCostToTheCalibration) {
  const scenario::Scenario s = scenario::mini_config_scenario();
  PoseDesignOptions full_angle_only;
  full_angle_only.exchange_passes = 1;
  ASSERT_EQ(full_angle_only.angle_steps, 1);
  ASSERT_EQ(full_angle_only.emphasis_weight, 0.0);
  PoseDesignOptions plain = full_angle_only;
  plain.angle_steps = 2;
  PoseDesignOptions emphasised = plain;
  emphasised.emphasis_weight = 3.0;
  auto de = design_poses(s.nominal, emphasised);
  auto dp = design_poses(s.nominal, plain);
  auto d1 = design_poses(s.nominal, full_angle_only);
  ASSERT_TRUE(de.ok() && dp.ok() && d1.ok());
  EXPECT_TRUE(dp->emphasised.empty());
  ASSERT_EQ(de->emphasised, std::vector<ParameterKind>{ParameterKind::kLaserDirection});
  auto pitched = [](const std::vector<Pose>& poses) {
    return std::count_if(poses.begin(), poses.end(),
                         [](const Pose& p) { return std::abs(p.rpy.y()) > 1e-6; });
  };
  EXPECT_EQ(pitched(d1->poses), 0);
  EXPECT_GT(pitched(de->poses), 0);
  const double beam_full_angle = beam_direction_information(s.nominal, d1->poses, plain);
  const double beam_plain = beam_direction_information(s.nominal, dp->poses, plain);
  const double beam_emphasised = beam_direction_information(s.nominal, de->poses, plain);
  EXPECT_LT(beam_full_angle, 1e-6 * beam_emphasised);  // measured 0
  EXPECT_GT(beam_emphasised, 5.0 * beam_plain);        // measured 11.5

  PredictedAccuracyOptions po;
  po.box.half_extent = plain.half_extent;
  auto pe = predict_accuracy(s.nominal, de->poses, plain.noise, po);
  auto pp = predict_accuracy(s.nominal, dp->poses, plain.noise, po);
  ASSERT_TRUE(pe.ok() && pp.ok());
  EXPECT_LT(pe->anchor_rms_std_m, 1.03 * pp->anchor_rms_std_m);
  EXPECT_LT(pe->position_rms_m, 1.03 * pp->position_rms_m);

  PoseDesignOptions no_laser = small_design(15);
  no_laser.channels.laser = false;
  fit_estimates_to_channels(no_laser.channels, &no_laser.identification);
  PoseDesignOptions no_laser_emphasised = no_laser;
  no_laser_emphasised.emphasis_weight = 3.0;
  auto dn = design_poses(s.nominal, no_laser_emphasised);
  auto dnp = design_poses(s.nominal, no_laser);
  ASSERT_TRUE(dn.ok() && dnp.ok()) << dn.status().to_string();
  EXPECT_TRUE(dn->emphasised.empty());
  // A robot without a laser: nothing to see, nothing reported as emphasised.
  CalibratedModel laserless = s.nominal;
  laserless.robot.lasers.clear();
  auto dl = design_poses(laserless, no_laser_emphasised);
  ASSERT_TRUE(dl.ok()) << dl.status().to_string();
  EXPECT_TRUE(dl->emphasised.empty());
  EXPECT_EQ(dl->emphasis_log_det, 0.0);
  ASSERT_EQ(dn->poses.size(), dnp->poses.size());
  for (std::size_t k = 0; k < dn->poses.size(); ++k) {
    EXPECT_EQ((dn->poses[k].vector() - dnp->poses[k].vector()).norm(), 0.0) << "pose " << k;
  }

  PoseDesignOptions bad = small_design(5);
  bad.emphasis = {ParameterKind::kHomePose};
  bad.emphasis_weight = 1.0;
  auto db = design_poses(s.nominal, bad);
  ASSERT_FALSE(db.ok());
  EXPECT_EQ(db.status().code(), ErrorCode::kInvalidArgument);
  PoseDesignOptions no_steps = small_design(5);
  no_steps.angle_steps = 0;
  auto dz = design_poses(s.nominal, no_steps);
  ASSERT_FALSE(dz.ok());
  EXPECT_EQ(dz.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(dz.status().to_string().find("angle_steps"), std::string::npos);
  PoseDesignOptions negative = small_design(5);
  negative.emphasis_weight = -1.0;
  auto dw = design_poses(s.nominal, negative);
  ASSERT_FALSE(dw.ok());
  EXPECT_NE(dw.status().to_string().find("emphasis_weight"), std::string::npos);
}

TEST(PoseDesign, RefusesLaserParametersWithoutTheLaser) {
  const scenario::Scenario s = scenario::mini_sensor_scenario();
  PoseDesignOptions o;
  o.points_per_axis = 3;
  o.num_poses = 5;
  o.channels.laser = false;  // the default options still estimate the laser plane
  auto d = design_poses(s.nominal, o);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.status().code(), ErrorCode::kInvalidArgument);
}

}  // namespace
}  // namespace cdpr
