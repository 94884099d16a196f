// Cable force sensors: raw = gain * tension + offset (robot_model.hpp; the paper's rig has
// gain 2, Jin et al. 2018, Sec. 3.2), its inverse, and the least-squares calibration of gain and
// offset from known-mass experiments (a mass m hanging on the cable gives tension m * g).
#pragma once

#include <cassert>
#include <span>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Raw reading for a tension (N). Template: double or ceres::Jet.
template <typename T>
T force_sensor_raw(const ForceSensorModel& sensor, const T& tension) {
  return sensor.gain * tension + sensor.offset;
}

// Tension (N) from a raw reading. Precondition: gain != 0 (validated with the model).
template <typename T>
T force_sensor_tension(const ForceSensorModel& sensor, const T& raw) {
  assert(sensor.gain != 0.0);
  return (raw - sensor.offset) / sensor.gain;
}

// One known-mass experiment: the total hanging mass (hook and hanger included) and the sensor's
// raw reading (averaged over a still period).
struct ForceCalibrationSample {
  double mass = 0.0;  // kg
  double raw = 0.0;   // sensor units
};

struct ForceSensorFit {
  ForceSensorModel sensor;   // gain (raw per N) and offset (raw)
  double gain_stderr = 0.0;  // standard errors from the residual scatter (n - 2 dof)
  double offset_stderr = 0.0;
  double residual_rms = 0.0;      // raw units, sqrt(SSR / (n - 2))
  double max_abs_residual = 0.0;  // raw units
  int num_samples = 0;
};

// Ordinary least squares of raw = gain * (m g) + offset. Refuses, with kInvalidArgument and the
// offending sample, fewer than 3 samples, a non-finite value, a negative mass, gravity <= 0, or
// fewer than 2 distinct masses (the gain is not identifiable); kFailedPrecondition when the raw
// readings do not depend on the load (|gain| < 3 standard errors: sensor not connected?).
Result<ForceSensorFit> fit_force_sensor(std::span<const ForceCalibrationSample> samples,
                                        double gravity = 9.81);

}  // namespace cdpr
