// A calibration of the virtual robot as cdprd makes it (controller/src/daemon_calibration.cc), for
// benchmarks that compare a calibrated model with the truth: the daemon config's pose design
// (measuring_design_options) and its tension-margin check of the designed poses, the poses
// commanded with the nominal model through cdpr-sim's lock-step mode at the pretension the robot
// was homed with, the config's identification (identify), the mismatch locator (diagnose) with
// the extra-pose rounds it asks for (extra_pose_round, measured in lock-step too), and the model
// evaluate_calibration proposes for acceptance. Not reproduced: the RT loop's moves, settling and
// pose-by-pose tension regulation (lock-step sets the motor positions and lets the physics settle),
// the gross-reading re-measuring round, the daemon's averaged-noise recording header (the
// scenario's noise is written instead). Exits with a message when a step fails (benchmarks only).
#pragma once

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "bench_util.hpp"
#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/controller/calibration_report.hpp"
#include "cdpr/controller/daemon_config.hpp"
#include "cdpr/controller/tension_control.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace cdpr::bench {

// The pretension cdprd holds the home pose at: the tension control's (band margin plus guard)
// when the config runs it, else the nominal planner's default (NaN).
inline double cdprd_home_pretension(const controller::DaemonConfig& config,
                                    const RobotModel& nominal) {
  if (config.tension_control.gain <= 0.0) return std::nan("");
  return sim::home_reference_tension(
      nominal, config.motion.tension_margin + controller::TensionControlOptions{}.guard);
}

struct CdprdCalibration {
  RobotModel model;  // the model proposed for acceptance
  int poses = 0;     // rows identified, extra poses included
  int dropped = 0;   // designed poses dropped for the tension margin
  std::string verdict;
  std::vector<std::string> named_effects;
  bool gates_passed = false;
};

// `truth` must be homed on its reference platform at `pretension` (homed_on_reference).
inline CdprdCalibration calibrate_as_cdprd(const RobotModel& nominal, const RobotModel& truth,
                                           const sim::Scenario& scenario, std::uint64_t seed,
                                           const controller::DaemonConfig& config,
                                           double pretension) {
  const CalibratedModel initial = CalibratedModel::from_robot(nominal);
  const PoseDesign design = must(
      design_poses(initial, controller::measuring_design_options(config, nominal)), "pose design");
  CdprdCalibration out;
  PathCheckOptions pc;
  pc.tension_margin = config.motion.tension_margin;
  std::vector<Pose> poses;
  for (const Pose& p : design.poses) {
    if (check_pose(nominal, p, pc).ok() || poses.empty()) {
      poses.push_back(p);
    } else {
      ++out.dropped;
    }
  }
  auto physics = must(sim::Physics::create(truth, scenario, seed), "physics");
  sim::LockstepOptions lo;
  lo.laser_samples = config.measuring.laser_samples;
  lo.reference_tension = pretension;
  std::vector<sim::LockstepSample> samples =
      must(sim::run_lockstep(physics, nominal, poses, lo), "lockstep");
  const IdentificationOptions& options = config.identification.options;
  DiagnosisOptions dopt;
  dopt.bootstrap_samples = config.identification.bootstrap;
  dopt.cv_folds = config.identification.folds;
  for (int round = 0;; ++round) {
    const auto rec = must(sim::make_recording(samples, nominal, scenario, {}), "recording");
    const MeasurementSet set = must(recording::to_measurement_set(rec), "measurement set");
    const IdentificationReport report = must(identify(initial, set, options), "identify");
    std::optional<Diagnosis> diagnosis;
    controller::ExtraPoseRound more;
    if (config.identification.diagnose) {
      diagnosis = must(diagnose(initial, set, nullptr, options, dopt), "diagnose");
      if (round < config.measuring.extra_pose_rounds)
        more = controller::extra_pose_round(*diagnosis);
      dopt.screen.only_groups = more.confirm_groups;
      dopt.confirm_suspect = more.confirm_suspect;
    }
    if (more.poses.empty()) {
      const controller::CalibrationOutcome o = controller::evaluate_calibration(
          nominal, set, report, diagnosis ? &*diagnosis : nullptr, config.acceptance, options);
      out.model = o.model;
      out.poses = set.num_poses();
      out.verdict = o.verdict;
      out.named_effects = o.named_effects;
      out.gates_passed = o.gates_passed;
      return out;
    }
    lo.start_time_s = samples.back().time_s + lo.dwell_s;
    for (std::size_t j = 0; j < more.poses.size(); ++j) {
      const double f = j < more.pretensions.size() ? more.pretensions[j] : std::nan("");
      lo.reference_tension = std::isnan(f) ? pretension : f;
      const auto s = must(sim::run_lockstep(physics, nominal, {&more.poses[j], 1}, lo), "lockstep");
      samples.insert(samples.end(), s.begin(), s.end());
      lo.start_time_s += lo.dwell_s;
    }
    lo.reference_tension = pretension;
  }
}

}  // namespace cdpr::bench
