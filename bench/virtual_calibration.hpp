// A calibration of the virtual robot as `cdpr-fit calibrate` makes it, for benchmarks that need a
// real (imperfect) calibrated model: cdpr-fit design-poses' 25 poses commanded with the nominal
// model through cdpr-sim's lock-step mode (5 laser samples per pose), the recording made from them,
// and identify() with `options`. Exits with a message when a step fails (benchmarks only).
#pragma once

#include <cstdint>

#include "bench_util.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::bench {

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
