// Files of the lock-step offline mode: the pose list it reads and the recording it writes, in the
// formats of drivers/recording (docs/recording-format.md).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"
#include "cdpr/status.hpp"

namespace cdpr::sim {

// What the recording's metadata says about its origin.
struct RecordingProvenance {
  std::string config_path;    // the nominal description
  std::string scenario_path;  // the scenario (its content stays hidden: only path and hash)
  std::uint64_t seed = 0;
  double dwell_s = 0.0;
  // Sigmas of the issue 18 channels (LockstepOptions), written as noise keys when > 0 and the
  // samples have the channel.
  double sigma_swivel = 0.0, sigma_inclination = 0.0, sigma_imu_yaw = 0.0;  // rad
};

// The recording of lock-step samples: commanded poses, measured lengths, tensions and lasers
// (through the nominal reading models; no laser columns when the nominal robot has none), and the
// swivel / inclinometer / IMU columns when the samples have them, one row per pose, poses
// numbered from 0. Metadata: format,
// units, robot, date, config file and hash, source "simulated", seed, scenario file and hash, and
// the noise levels converted to SI through the nominal models (keys only for non-zero levels).
Result<recording::Recording> make_recording(const std::vector<LockstepSample>& samples,
                                            const RobotModel& nominal, const Scenario& scenario,
                                            const RecordingProvenance& provenance);

}  // namespace cdpr::sim
