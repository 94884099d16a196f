#include "cdpr/calibration/paper_method.hpp"

#include <gtest/gtest.h>

#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr {
namespace {

TEST(PaperMethod, ConvergesOnNoiseFreeData) {
  scenario::Scenario s = scenario::mini_scenario();
  // The paper fixed the coordinates outside V at measured (true) values.
  CalibratedModel start = s.nominal;
  const AnchorMask V = paper_anchor_mask();
  for (int i = 0; i < 8; ++i) {
    for (int q = 0; q < 3; ++q) {
      if (!V(q, i)) start.robot.frame_anchors(q, i) = s.truth.robot.frame_anchors(q, i);
    }
  }
  start.robot.lasers = s.truth.robot.lasers;  // the laser plane is known
  const std::vector<Pose> poses =
      scenario::random_feasible_poses(s.nominal.robot, s.box, 25, 11, &s.truth.robot);
  SimulationOptions so;
  so.add_noise = false;
  auto sim = simulate_measurements(s.truth, poses, SensorNoise{}, 1, so);
  ASSERT_TRUE(sim.ok()) << sim.status().to_string();
  auto rep = paper_method(start, sim->set);
  ASSERT_TRUE(rep.ok()) << rep.status().to_string();
  EXPECT_TRUE(rep->converged) << rep->summary();
  EXPECT_LT(rep->final_error_norm, 1e-6 * rep->initial_error_norm + 1e-8) << rep->summary();
  EXPECT_LT((rep->estimate.robot.frame_anchors - s.truth.robot.frame_anchors).cwiseAbs().maxCoeff(),
            1e-6)
      << rep->summary();
  EXPECT_GT(rep->fk_solves, 25 * 16);
}

TEST(PaperMethod, RefusesAWrongMask) {
  scenario::Scenario s = scenario::mini_scenario();
  PaperMethodOptions o;
  o.parameters = AnchorMask::Constant(3, 4, true);
  MeasurementSet set;
  auto rep = paper_method(s.nominal, set, o);
  EXPECT_FALSE(rep.ok());
}

}  // namespace
}  // namespace cdpr
