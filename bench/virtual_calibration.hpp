// A calibration of the virtual robot as `cdpr-fit calibrate` makes it, for benchmarks that need a
// real (imperfect) calibrated model: cdpr-fit design-poses' 25 poses commanded with the nominal
// model through cdpr-sim's lock-step mode (5 laser samples per pose), the recording made from them,
// and identify() with `options`; and the homing of the virtual robot on its reference platform
// (homed_on_reference). Exits with a message when a step fails (benchmarks only).
#pragma once

#include <cstdint>

#include "bench_util.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::bench {

// `truth` with its winches' length offsets moved so that the NOMINAL model's home counts at
// pretension `reference_tension` (NaN: the nominal default) stand the true platform at home at the
// true planner's tensions of that pretension, the scenario's hidden effects included: the robot
// homed on its reference platform (cdprd's reference homing, cdpr-sim --home reference).
inline RobotModel homed_on_reference(const RobotModel& truth, const RobotModel& nominal,
                                     const sim::Scenario& scenario, double reference_tension) {
  const auto physics = must(sim::Physics::create(truth, scenario, 0), "physics");
  const Eigen::VectorXd on_reference =
      must(sim::true_pose_counts(physics, truth.home, reference_tension), "true home counts");
  const Eigen::VectorXd commanded =
      must(sim::nominal_counts(nominal, nominal.home, reference_tension), "nominal home counts");
  RobotModel homed = truth;
  for (int i = 0; i < truth.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    const WinchModel& w = truth.winches[k];
    homed.winches[k].length_offset += (1.0 + scenario.effects.transmission_scale.at(i)) *
                                      (winch_counts_to_length<double>(w, on_reference(i)) -
                                       winch_counts_to_length<double>(w, commanded(i)));
  }
  return homed;
}

inline IdentificationReport calibrate_virtual_robot(const RobotModel& nominal,
                                                    const RobotModel& truth,
                                                    const sim::Scenario& scenario,
                                                    std::uint64_t seed,
                                                    const IdentificationOptions& options) {
  const CalibratedModel initial = CalibratedModel::from_robot(nominal);
  PoseDesignOptions design;
  design.num_poses = 25;
  const PoseDesign poses = must(design_poses(initial, design), "pose design");
  auto physics = must(sim::Physics::create(truth, scenario, seed), "physics");
  sim::LockstepOptions lo;
  lo.laser_samples = 5;
  const auto samples = must(sim::run_lockstep(physics, nominal, poses.poses, lo), "lockstep");
  const auto rec = must(sim::make_recording(samples, nominal, scenario, {}), "recording");
  const auto set = must(recording::to_measurement_set(rec), "measurement set");
  return must(identify(initial, set, options), "identify");
}

}  // namespace cdpr::bench
