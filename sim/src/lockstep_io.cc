#include "cdpr/sim/lockstep_io.hpp"

#include <cmath>

#include "cdpr/calibration/winch.hpp"

namespace cdpr::sim {

Result<recording::Recording> make_recording(const std::vector<LockstepSample>& samples,
                                            const RobotModel& nominal, const Scenario& scenario,
                                            const RecordingProvenance& provenance) {
  namespace key = recording::key;
  const int m = nominal.num_cables();
  const int k = static_cast<int>(nominal.lasers.size());
  recording::Recording rec;
  rec.num_cables = m;
  rec.num_lasers = k;
  for (const LockstepSample& s : samples) {
    rec.has_swivel = rec.has_swivel || s.swivels.size() == m;
    rec.has_inclinometer = rec.has_inclinometer || !s.inclination.array().isNaN().all();
    rec.has_imu_yaw = rec.has_imu_yaw || !std::isnan(s.imu_yaw);
  }
  recording::Metadata& md = rec.metadata;
  md.set(key::kFormat, "cdpr-recording 1");
  md.set(key::kUnits, std::string(recording::kUnitsSI));
  md.set(key::kRobot, nominal.name);
  md.set(key::kDate, recording::utc_timestamp());
  if (!provenance.config_path.empty()) {
    md.set(key::kConfigFile, provenance.config_path);
    Result<std::string> h = recording::file_hash(provenance.config_path);
    if (h.ok()) md.set(key::kConfigHash, *h);
  }
  md.set(key::kSource, "simulated");
  md.set(key::kSeed, std::to_string(provenance.seed));
  if (!provenance.scenario_path.empty()) {
    md.set("scenario_file", provenance.scenario_path);
    Result<std::string> h = recording::file_hash(provenance.scenario_path);
    if (h.ok()) md.set("scenario_hash", *h);
  }
  if (provenance.dwell_s > 0.0) md.set_number("sim_dwell_s", provenance.dwell_s);
  // Noise levels in SI through the nominal models (cable 1's winch and sensor).
  const double length_sigma =
      scenario.noise.encoder_counts * winch_metres_per_count(nominal.winches.front());
  const double force_sigma =
      scenario.noise.force_raw / std::abs(nominal.force_sensors.front().gain);
  if (length_sigma > 0.0) md.set_number(key::kNoiseLength, length_sigma);
  if (force_sigma > 0.0) md.set_number(key::kNoiseForce, force_sigma);
  if (scenario.noise.laser > 0.0 && k > 0) md.set_number(key::kNoiseLaser, scenario.noise.laser);
  if (rec.has_swivel && provenance.sigma_swivel > 0.0) {
    md.set_number(key::kNoiseSwivel, provenance.sigma_swivel);
  }
  if (rec.has_inclinometer && provenance.sigma_inclination > 0.0) {
    md.set_number(key::kNoiseInclination, provenance.sigma_inclination);
  }
  if (rec.has_imu_yaw && provenance.sigma_imu_yaw > 0.0) {
    md.set_number(key::kNoiseImuYaw, provenance.sigma_imu_yaw);
  }

  for (std::size_t j = 0; j < samples.size(); ++j) {
    const LockstepSample& s = samples[j];
    recording::RecordedPose p;
    p.index = static_cast<std::int64_t>(j);
    p.time_s = s.time_s;
    p.commanded = s.commanded;
    p.lengths = s.lengths;
    p.tensions = s.tensions;
    p.lasers = s.lasers;
    if (rec.has_swivel) {
      p.swivels = s.swivels.size() == m ? s.swivels : Eigen::VectorXd::Constant(m, kNaN);
    }
    p.inclination = s.inclination;
    p.imu_yaw = s.imu_yaw;
    p.reference = Pose{Eigen::Vector3d::Constant(kNaN), Eigen::Vector3d::Constant(kNaN)};
    rec.poses.push_back(p);
  }
  return rec;
}

}  // namespace cdpr::sim
