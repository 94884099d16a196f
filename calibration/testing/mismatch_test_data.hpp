// Test data shared by the mismatch locator's tests (mismatch_test.cc, diagnosis_test.cc): MINI
// with rigid cables in the truth and the model, so that the identification's model is exact unless
// a test conceals an effect in the readings. Not installed.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace cdpr::testing {

struct RigidMini {
  scenario::Scenario s;
  std::vector<Pose> poses;
};

inline RigidMini rigid_mini(int num_poses) {
  RigidMini d;
  d.s = scenario::mini_scenario();
  for (auto* model : {&d.s.nominal, &d.s.truth}) {
    for (auto& c : model->robot.cables) c.elongation = ElongationKind::kRigid;
  }
  auto off = homing_offsets(d.s.truth.robot, d.s.nominal.robot,
                            default_reference_tension(d.s.nominal.robot));
  EXPECT_TRUE(off.ok());
  if (off.ok()) d.s.truth.readings.length_offsets = *off;
  d.poses =
      scenario::random_feasible_poses(d.s.nominal.robot, d.s.box, num_poses, 11, &d.s.truth.robot);
  return d;
}

inline SimulatedMeasurements simulate(const RigidMini& d, std::uint64_t seed) {
  SimulationOptions so;
  so.controller = &d.s.nominal;
  auto sim = simulate_measurements(d.s.truth, d.poses, SensorNoise{}, seed, so);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  return sim.ok() ? *sim : SimulatedMeasurements{};
}

// An elongation strain(F) L of the whole loaded cable, hidden in the readings (the encoder pays
// out the unstretched length, which is shorter than the geometry by the elongation).
template <typename Strain>
void conceal_elongation(const RigidMini& d, SimulatedMeasurements& sim, Strain strain) {
  KinematicsData kin(d.s.truth.robot);
  for (std::size_t j = 0; j < sim.set.poses.size(); ++j) {
    ASSERT_TRUE(inverse_kinematics(d.s.truth.robot, sim.true_poses[j], kin));
    for (int i = 0; i < d.s.truth.robot.num_cables(); ++i) {
      const double loaded =
          loaded_length(d.s.truth.robot.cables[static_cast<std::size_t>(i)], kin.lengths(i));
      sim.set.poses[j].cable_lengths(i) -= strain(sim.true_tensions[j](i)) * loaded;
    }
  }
}

// Hooke elongation F L / (EA + F).
inline void conceal_hooke(const RigidMini& d, SimulatedMeasurements& sim, double ea) {
  conceal_elongation(d, sim, [ea](double f) { return f / (ea + f); });
}

}  // namespace cdpr::testing
