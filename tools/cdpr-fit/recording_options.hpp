// What calibrate, diagnose and validate share about a recording's options: the sensor sigmas
// given on the command line and the gauge (what fixes the world frame) checked against the
// recording.
#pragma once

#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/status.hpp"

namespace cdpr::fit {

// Sensor sigmas replacing the recording's noise_* metadata, one per channel; NaN = the
// recording's (or the default when it states none).
struct NoiseOverrides {
  static constexpr double kUnset = std::numeric_limits<double>::quiet_NaN();
  double length = kUnset;              // m
  double laser = kUnset;               // m
  double force = kUnset;               // N
  double swivel = kUnset;              // rad
  double inclination = kUnset;         // rad
  double imu_yaw = kUnset;             // rad
  double reference_position = kUnset;  // m
  double reference_angle = kUnset;     // rad
};

// Sets the overridden sigmas in `set` and warns (in `warnings`, naming `file`) about every
// channel `rec` has whose sigma neither the recording nor an override states.
void apply_noise_overrides(const NoiseOverrides& noise, const recording::Recording& rec,
                           const std::string& file, MeasurementSet* set,
                           std::vector<std::string>* warnings);

// --gauge (home, start, laser-plane, both, none) and --home-pose into `options`, checked against
// the recording: with a home gauge the row `home_pose` must be at the config's home pose (or carry
// a reference reading). A row commanded elsewhere would be pinned at the config's home and drag
// every anchor and encoder offset with it: that is refused (kInvalidArgument) with what to do
// instead (a row that is at home, --gauge start, a reference reading).
Status apply_gauge(const std::string& gauge, int home_pose, const MeasurementSet& set,
                   const RobotModel& nominal, const std::string& recording_file,
                   IdentificationOptions* options);

}  // namespace cdpr::fit
