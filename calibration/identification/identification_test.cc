#include "cdpr/calibration/identification.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

struct Data {
  scenario::Scenario s;
  std::vector<Pose> poses;
  SimulatedMeasurements sim;
};

Data make_data(int n, const SensorNoise& noise, std::uint64_t seed, bool add_noise) {
  Data d;
  d.s = scenario::mini_scenario();
  d.poses = scenario::random_feasible_poses(d.s.nominal.robot, d.s.box, n, 11, &d.s.truth.robot);
  SimulationOptions so;
  so.add_noise = add_noise;
  so.controller = &d.s.nominal;
  auto sim = simulate_measurements(d.s.truth, d.poses, noise, seed, so);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  if (sim.ok()) d.sim = *sim;
  return d;
}

double max_anchor_error(const CalibratedModel& est, const CalibratedModel& truth) {
  return (est.robot.frame_anchors - truth.robot.frame_anchors).cwiseAbs().maxCoeff();
}

TEST(Simulate, IsDeterministicBySeed) {
  const SensorNoise noise;
  const Data a = make_data(6, noise, 5, true);
  const Data b = make_data(6, noise, 5, true);
  const Data c = make_data(6, noise, 6, true);
  ASSERT_EQ(a.sim.set.num_poses(), 6);
  EXPECT_EQ(a.sim.set.poses[3].cable_lengths, b.sim.set.poses[3].cable_lengths);
  EXPECT_NE(a.sim.set.poses[3].cable_lengths, c.sim.set.poses[3].cable_lengths);
}

TEST(Simulate, NoiseFreeLengthsMatchTheTrueGeometryAtHome) {
  const Data d = make_data(3, SensorNoise{}, 1, false);
  // Homing sets the reading at home to the NOMINAL unstretched length.
  const RobotModel& nom = d.s.nominal.robot;
  auto f = simple_tension_distribution(nom, nom.home, default_reference_tension(nom));
  ASSERT_TRUE(f.ok());
  auto u = unstretched_lengths(nom, nom.home, *f);
  ASSERT_TRUE(u.ok());
  // Rigid physics: the truth's tensions differ slightly from the nominal plan, so compare loosely.
  EXPECT_LT((d.sim.set.poses[0].cable_lengths - *u).cwiseAbs().maxCoeff(), 2e-4);
}

TEST(Identification, NoiseFreeDataRecoversTheTruth) {
  const Data d = make_data(25, SensorNoise{}, 1, false);
  IdentificationOptions opt;
  auto rep = identify(d.s.nominal, d.sim.set, opt);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_TRUE(rep->converged) << rep->full_report();
  EXPECT_LT(max_anchor_error(rep->estimate, d.s.truth), 1e-6) << rep->full_report();
  EXPECT_LT((rep->estimate.readings.length_offsets - d.s.truth.readings.length_offsets)
                .cwiseAbs()
                .maxCoeff(),
            1e-6);
  // Poses too.
  double worst = 0.0;
  for (std::size_t j = 0; j < d.poses.size(); ++j) {
    worst = std::max(worst, (rep->poses[j].position - d.sim.true_poses[j].position).norm());
  }
  EXPECT_LT(worst, 1e-6);
  EXPECT_LT(rep->final_cost, 1e-10);
}

TEST(Identification, ErrorIsConsistentWithTheReportedStd) {
  SensorNoise noise;
  noise.sigma_length = 1e-4;
  noise.sigma_laser = 1e-3;
  noise.sigma_force = 2.0;
  const Data d = make_data(25, noise, 3, true);
  auto rep = identify(d.s.nominal, d.sim.set, IdentificationOptions{});
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_TRUE(rep->converged);
  // z-scores of every anchor coordinate: their RMS is ~1 for an honest covariance.
  double sum = 0.0;
  int count = 0;
  for (const ParameterEstimate& p : rep->parameters) {
    if (p.id.kind != ParameterKind::kFrameAnchor) continue;
    const double z =
        (p.value - d.s.truth.robot.frame_anchors(p.id.component, p.id.index)) / p.std_dev;
    sum += z * z;
    ++count;
  }
  ASSERT_EQ(count, 24);
  const double rms_z = std::sqrt(sum / count);
  EXPECT_GT(rms_z, 0.4) << rep->full_report();
  EXPECT_LT(rms_z, 1.8) << rep->full_report();
  // chi-square near its dof.
  EXPECT_NEAR(rep->chi2 / rep->dof, 1.0, 0.35) << rep->full_report();
  EXPECT_FALSE(rep->full_report().empty());
}

// Force noise enters the equilibrium residual through the geometry (cov = sigma_F^2 A^T A). With
// that covariance frozen at the start the expected noise term depends on the anchors and pulls
// them: at 3 N on this set the mean anchor error was about 2.5 standard errors of the mean. With
// the covariance at the current geometry (the profile likelihood of the true tensions) the mean
// error over the seeds must be consistent with zero.
// The equilibrium residual A^T F + w carries the force noise with covariance sigma_F^2 A^T A,
// which depends on the pose and the anchors. It is whitened with that covariance at the CURRENT
// estimate (the profile likelihood of the true tensions), so the objective is one fixed function
// of the parameters and the estimate cannot depend on where the solver starts. With the
// covariance frozen at the starting geometry it did (and the expected noise term then depended
// on the anchors and dragged them: a bias of about 1-2 standard errors at 1-3 N on MINI).
TEST(Identification, EstimateDoesNotDependOnTheStartingModel) {
  SensorNoise noise;
  noise.sigma_length = 1e-4;
  noise.sigma_laser = 1e-3;
  noise.sigma_force = 2.0;
  const Data d = make_data(25, noise, 7, true);
  IdentificationOptions tight;  // converge fully, so that the comparison is about the objective
  tight.function_tolerance = 1e-15;
  tight.parameter_tolerance = 1e-13;
  auto a = identify(d.s.nominal, d.sim.set, tight);
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  CalibratedModel other = d.s.nominal;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.01, 0.01);
  for (int i = 0; i < other.robot.num_cables(); ++i) {
    for (int q = 0; q < 3; ++q) other.robot.frame_anchors(q, i) += u(rng);
  }
  auto b = identify(other, d.sim.set, tight);
  ASSERT_TRUE(b.ok()) << b.status().to_string();
  ASSERT_TRUE(a->converged && b->converged);
  const double diff =
      (a->estimate.robot.frame_anchors - b->estimate.robot.frame_anchors).cwiseAbs().maxCoeff();
  EXPECT_LT(diff, 1e-7) << "the two starts end " << diff << " m apart";
  EXPECT_NEAR(a->chi2, b->chi2, 1e-6 * a->chi2);
}

TEST(Identification, ATensionReadingWithinFourSigmasOfZeroIsASlackCable) {
  SensorNoise noise;
  noise.sigma_force = 1.0;
  IdentificationOptions opt;
  EXPECT_DOUBLE_EQ(slack_threshold(opt, noise), 4.0);  // 4 sigma above the 3 N floor
  noise.sigma_force = 0.25;
  EXPECT_DOUBLE_EQ(slack_threshold(opt, noise), 3.0);  // the floor
  // A slack cable whose reading came out at 3.5 N (sigma 1 N) has no length row: its length,
  // longer than the chord by the slack, would otherwise misfit.
  Data d = make_data(25, SensorNoise{}, 3, true);
  d.sim.set.poses[4].tensions(2) = 3.5;
  d.sim.set.poses[4].cable_lengths(2) += 0.01;  // 10 mm of slack
  auto rep = identify(d.s.nominal, d.sim.set, opt);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_TRUE(std::isnan(rep->residuals[4].length_normalized(2)));
  EXPECT_LT(rep->chi2, rep->dof + 4.0 * std::sqrt(2.0 * rep->dof));
  // With the old 3 N threshold alone it is fitted as taut and wrecks the fit.
  opt.slack_tension_sigmas = 0.0;
  auto taut = identify(d.s.nominal, d.sim.set, opt);
  ASSERT_TRUE(taut.ok()) << taut.status().to_string();
  EXPECT_FALSE(std::isnan(taut->residuals[4].length_normalized(2)));
  EXPECT_GT(taut->chi2, rep->chi2 + 100.0);
}

TEST(Identification, TooFewPosesAreRefused) {
  const Data d = make_data(3, SensorNoise{}, 1, false);
  auto rep = identify(d.s.nominal, d.sim.set, IdentificationOptions{});
  ASSERT_FALSE(rep.ok());
  EXPECT_EQ(rep.status().code(), ErrorCode::kFailedPrecondition);
  EXPECT_NE(rep.status().to_string().find("too few poses"), std::string::npos)
      << rep.status().to_string();
}

TEST(Identification, OpenGaugeIsRefusedWithTheDirections) {
  const Data d = make_data(25, SensorNoise{}, 1, false);
  IdentificationOptions opt;
  opt.gauge = Gauge::kNone;
  auto rep = identify(d.s.nominal, d.sim.set, opt);
  ASSERT_FALSE(rep.ok());
  EXPECT_EQ(rep.status().code(), ErrorCode::kFailedPrecondition);
  EXPECT_NE(rep.status().to_string().find("gauge"), std::string::npos) << rep.status().to_string();
}

TEST(Identifiability, NamesAnchorAlongCableAgainstOffset) {
  // Pure translations in a small box: an anchor moving along its cable is nearly
  // indistinguishable from the encoder zero of that cable.
  scenario::Scenario s = scenario::mini_scenario();
  testing::WorkspaceBox box = s.box;
  box.half_extent = Eigen::Vector3d::Constant(0.02);
  box.max_angle = 0.0;
  const std::vector<Pose> poses =
      scenario::random_feasible_poses(s.nominal.robot, box, 25, 3, &s.truth.robot);
  SimulationOptions so;
  so.add_noise = false;
  auto sim = simulate_measurements(s.truth, poses, SensorNoise{}, 1, so);
  ASSERT_TRUE(sim.ok());
  IdentificationOptions opt;
  opt.use_equilibrium = false;
  opt.use_laser = false;
  opt.estimate_laser_plane = false;
  IdentifiabilityOptions io;
  io.weak_tolerance = 1e-2;
  auto rep = analyze_identifiability(s.nominal, sim->set, opt, io);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  ASSERT_FALSE(rep->directions.empty()) << rep->summary();
  bool named = false;
  for (const ParameterDirection& d : rep->directions) {
    for (int i = 1; i <= 8; ++i) {
      const std::string c = std::to_string(i);
      if (d.description.find("a_" + c + " along cable " + c) != std::string::npos &&
          d.description.find("length offset of cable " + c) != std::string::npos) {
        named = true;
      }
    }
  }
  EXPECT_TRUE(named) << rep->summary();
}

// The words of every parameter kind in the named directions, pinned: hand-made information whose
// weak directions are known (blocks I - c w w^T of the column-normalised information, one block per
// direction, c close to 1; one parameter with no information at all).
TEST(Identifiability, NamesEveryParameterKindInWords) {
  using K = ParameterKind;
  struct Block {
    std::vector<ParameterId> ids;
    std::vector<double> w;        // the weak direction (each entry +-1: a uniform diagonal)
    std::set<std::string> words;  // the expected component descriptions
  };
  const std::vector<Block> blocks = {
      {{{K::kFrameAnchor, 0, 0},
        {K::kFrameAnchor, 0, 1},
        {K::kFrameAnchor, 0, 2},
        {K::kLengthOffset, 0, -1}},
       {1, 1, 1, -1},
       {"a_1 along cable 1", "the length offset of cable 1"}},
      {{{K::kFrameAnchor, 1, 1}, {K::kLengthScale, 1, -1}},
       {1, -1},
       {"a_2.y", "the transmission scale of cable 2"}},
      {{{K::kFrameAnchor, 2, 0}, {K::kFrameAnchor, 2, 1}, {K::kFrameAnchor, 2, 2}},
       {1, 1, 1},
       {"a_3 along (0.58, 0.58, 0.58)"}},
      {{{K::kStiffness, 3, -1}, {K::kStiffness, -1, -1}},
       {1, -1},
       {"the stiffness EA of cable 4", "the shared cable stiffness EA"}},
      {{{K::kForceGain, 0, -1}, {K::kForceOffset, 5, -1}},
       {1, 1},
       {"the force sensor gain of cable 1", "the force sensor offset of cable 6"}},
      {{{K::kPlatformAnchor, 1, 1}, {K::kSwivelZero, 4, -1}},
       {1, -1},
       {"b_2.y (platform anchor)", "the swivel encoder zero of cable 5"}},
      {{{K::kInclinometerMount, -1, 0}, {K::kInclinometerMount, -1, 1}},
       {1, 1},
       {"the inclinometer's mounting roll", "the inclinometer's mounting pitch"}},
      {{{K::kImuYawZero, -1, -1}, {K::kLaserPlaneOffset, 0, -1}},
       {1, -1},
       {"the IMU's heading zero", "laser_1.plane.c"}},
      {{{K::kHomePose, -1, 3}}, {0}, {"home.roll"}},  // no information at all
  };
  GeometryInformation gi;
  int P = 0;
  for (const Block& b : blocks) P += static_cast<int>(b.ids.size());
  gi.information = Eigen::MatrixXd::Zero(P, P);
  gi.anchor_columns = Eigen::Matrix3Xi::Constant(3, 3, -1);
  gi.home_cable_directions.resize(3, 3);
  gi.home_cable_directions << Eigen::Vector3d::Ones().normalized(), Eigen::Vector3d::UnitX(),
      Eigen::Vector3d::UnitZ();
  gi.num_residuals = 100;
  int col = 0;
  for (std::size_t k = 0; k < blocks.size(); ++k) {
    const Block& b = blocks[k];
    const int n = static_cast<int>(b.ids.size());
    Eigen::VectorXd w(n);
    for (int q = 0; q < n; ++q) w(q) = b.w[static_cast<std::size_t>(q)];
    if (w.norm() > 0) {
      w.normalize();
      const double c = 1.0 - 1e-4 * static_cast<double>(k + 1);  // distinct weak values
      gi.information.block(col, col, n, n) =
          Eigen::MatrixXd::Identity(n, n) - c * w * w.transpose();
    }
    for (int q = 0; q < n; ++q) {
      const ParameterId& id = b.ids[static_cast<std::size_t>(q)];
      gi.ids.push_back(id);
      gi.names.push_back(parameter_name(id));
      if (id.kind == K::kFrameAnchor) gi.anchor_columns(id.component, id.index) = col + q;
    }
    col += n;
  }
  IdentifiabilityOptions io;
  io.weak_tolerance = 0.5;
  const IdentifiabilityReport r = analyze_identifiability(gi, io);
  ASSERT_EQ(r.directions.size(), blocks.size()) << r.summary();
  EXPECT_EQ(r.unobserved, std::vector<int>{P - 1});
  for (const Block& b : blocks) {
    bool found = false;
    for (const ParameterDirection& d : r.directions) {
      std::set<std::string> words;
      for (const DirectionComponent& c : d.components) {
        // The sign of a direction is arbitrary: "a_3 along (-0.58, ...)" is the same direction.
        std::string text = c.description;
        if (text.find(" along (-") != std::string::npos) {
          for (std::size_t at = 0; (at = text.find("-", at)) != std::string::npos;)
            text.erase(at, 1);
        }
        words.insert(text);
      }
      if (words != b.words) continue;
      found = true;
      for (const DirectionComponent& c : d.components) {
        EXPECT_NE(d.description.find(c.description), std::string::npos) << d.description;
      }
      if (b.words.size() == 1) {
        EXPECT_EQ(d.description, d.components[0].description + " is not determined by the data");
      } else {
        EXPECT_NE(d.description.find(" trades against "), std::string::npos) << d.description;
      }
    }
    EXPECT_TRUE(found) << *b.words.begin() << "\n" << r.summary();
  }
  EXPECT_TRUE(r.directions.front().null) << r.summary();
  EXPECT_EQ(r.directions.front().description, "home.roll is not determined by the data");
}

}  // namespace
}  // namespace cdpr
