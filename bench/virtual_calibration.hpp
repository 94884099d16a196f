// A calibration of the virtual robot as `cdpr-fit calibrate` makes it, for benchmarks that need a
// real (imperfect) calibrated model: cdpr-fit design-poses' 25 poses commanded with the nominal
// model through cdpr-sim's lock-step mode (5 laser samples per pose), the recording made from them,
// and identify() with `options`. Exits with a message when a step fails (benchmarks only).
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::bench {

template <typename T>
T must_ok(Result<T> r, const char* what) {
  if (!r.ok()) {
    std::fprintf(stderr, "bench: %s: %s\n", what, r.status().to_string().c_str());
    std::exit(1);
  }
  return std::move(*r);
}

inline IdentificationReport calibrate_virtual_robot(const RobotModel& nominal,
                                                    const RobotModel& truth,
                                                    const sim::Scenario& scenario,
                                                    std::uint64_t seed,
                                                    const IdentificationOptions& options) {
  const CalibratedModel initial = CalibratedModel::from_robot(nominal);
  PoseDesignOptions design;
  design.num_poses = 25;
  const PoseDesign poses = must_ok(design_poses(initial, design), "pose design");
  auto physics = must_ok(sim::Physics::create(truth, scenario, seed), "physics");
  sim::LockstepOptions lo;
  lo.laser_samples = 5;
  const auto samples = must_ok(sim::run_lockstep(physics, nominal, poses.poses, lo), "lockstep");
  const auto rec = must_ok(sim::make_recording(samples, nominal, scenario, {}), "recording");
  const auto set = must_ok(recording::to_measurement_set(rec), "measurement set");
  return must_ok(identify(initial, set, options), "identify");
}

}  // namespace cdpr::bench
