// A model checked on a recording it was not fitted to (held-out validation): the recording's
// poses are re-fitted with every model parameter fixed, and each channel's residual RMS says how
// well the model predicts it. The same gate decides whether a calibrated model beats the nominal
// one (`cdpr-fit validate`, `cdpr-fit calibrate --validate`; cdprd can hold poses back for it).
//
// The recording's readings were made with another model (`made_with`: the controller's config
// that homed the encoders and converted the load cells). They are read as `model` reads the same
// raw values: the length readings through `model`'s winches (unstretched = (1 + s) reading + o,
// s and o from the two winch models), the tensions through its force sensors. Pure math: no I/O.
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// `set`'s tension readings, made with the force sensors of `made_with`, as `read_with`'s sensors
// read the same raw values (raw = gain F + offset). A cable whose sensors are the same keeps its
// readings as they are.
MeasurementSet tensions_read_with(const MeasurementSet& set, const RobotModel& made_with,
                                  const RobotModel& read_with);

// The reading model that turns length readings made with `made_with`'s winches into `model`'s
// unstretched lengths: the same encoder counts through the other winch (offset and length per
// count).
ReadingModel readings_of(const RobotModel& model, const RobotModel& made_with);

// One channel's prediction: RMS of the residuals in SI (m, N, rad) and in sigmas.
struct ChannelPrediction {
  std::string channel;  // "cable lengths", "laser", "equilibrium", "swivel angles", ...
  std::string unit;     // "m", "N", "rad"
  int rows = 0;
  double rms = 0.0;             // SI
  double rms_normalized = 0.0;  // in sigmas (the equilibrium: whitened)
};

struct ModelPrediction {
  std::vector<ChannelPrediction> channels;  // the channels the recording has, in a fixed order
  double chi2 = 0.0;                        // of every residual, poses re-fitted
  int residuals = 0;
  int dof = 0;
  bool converged = false;
  std::vector<Pose> poses;  // re-fitted
};

// The poses of `set` re-fitted with `model` fixed (every pose free, the world frame that of the
// model), the residuals per channel. `channels` selects the residuals as IdentificationOptions'
// use_* do (the estimate_* and gauge fields are ignored). Errors: as identify().
Result<ModelPrediction> predict_recording(const RobotModel& model, const RobotModel& made_with,
                                          const MeasurementSet& set,
                                          const IdentificationOptions& channels = {});

// Whether `candidate` predicts at least as well as `reference` on a held-out recording: its
// whole-recording chi^2 (every channel in sigmas) is lower. `why` (optional) says so per channel.
bool beats(const ModelPrediction& candidate, const ModelPrediction& reference,
           std::string* why = nullptr);

}  // namespace cdpr
