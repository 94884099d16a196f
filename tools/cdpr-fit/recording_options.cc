#include "recording_options.hpp"

#include <cmath>
#include <cstdio>
#include <utility>

namespace cdpr::fit {

void apply_noise_overrides(const NoiseOverrides& noise, const recording::Recording& rec,
                           const std::string& file, MeasurementSet* set,
                           std::vector<std::string>* warnings) {
  namespace key = recording::key;
  struct Channel {
    const char* key;
    double override_value;
    double SensorNoise::*sigma;
    bool present;
  };
  const Channel channels[] = {
      {key::kNoiseLength, noise.length, &SensorNoise::sigma_length, true},
      {key::kNoiseLaser, noise.laser, &SensorNoise::sigma_laser, rec.num_lasers > 0},
      {key::kNoiseForce, noise.force, &SensorNoise::sigma_force, true},
      {key::kNoiseSwivel, noise.swivel, &SensorNoise::sigma_swivel, rec.has_swivel},
      {key::kNoiseInclination, noise.inclination, &SensorNoise::sigma_inclination,
       rec.has_inclinometer},
      {key::kNoiseImuYaw, noise.imu_yaw, &SensorNoise::sigma_imu_yaw, rec.has_imu_yaw},
      {key::kNoiseRefPosition, noise.reference_position, &SensorNoise::sigma_reference_position,
       false},
      {key::kNoiseRefAngle, noise.reference_angle, &SensorNoise::sigma_reference_angle, false},
  };
  for (const Channel& c : channels) {
    if (std::isfinite(c.override_value)) {
      set->noise.*(c.sigma) = c.override_value;
    } else if (c.present && !rec.metadata.has(c.key)) {
      warnings->push_back(file + " states no '" + c.key + "'; the default sigma is used");
    }
  }
}

namespace {

// The rows commanded at `home` (1 mm, 1 mrad), for the message.
std::vector<int> rows_at(const MeasurementSet& set, const Pose& home) {
  std::vector<int> rows;
  for (int j = 0; j < set.num_poses(); ++j) {
    const Pose& c = set.poses[static_cast<std::size_t>(j)].commanded;
    if ((c.position - home.position).norm() <= 1e-3 && (c.rpy - home.rpy).norm() <= 1e-3) {
      rows.push_back(j);
    }
  }
  return rows;
}

Status check_home_row(int home_pose, const MeasurementSet& set, const RobotModel& nominal,
                      const std::string& file) {
  const PoseMeasurement& row = set.poses[static_cast<std::size_t>(home_pose)];
  if (row.reference) return Status::success();  // the gauge holds its reference reading
  const double dp = (row.commanded.position - nominal.home.position).norm();
  const double da = (row.commanded.rpy - nominal.home.rpy).norm();
  if (dp <= 1e-3 && da <= 1e-3) return Status::success();
  const std::vector<int> at_home = rows_at(set, nominal.home);
  const std::string instead = at_home.empty() ? std::string("no row is at home")
                                              : "row " + std::to_string(at_home.front()) +
                                                    " is at home: --home-pose " +
                                                    std::to_string(at_home.front());
  char buf[480];
  std::snprintf(buf, sizeof(buf),
                "%s: row %d, which the gauge holds at the config's home pose, is commanded %.3g m, "
                "%.3g rad from it without a reference reading (pinned there it drags every anchor "
                "and offset); %s; or --gauge start (hold it at its commanded pose); or record home",
                file.c_str(), home_pose, dp, da, instead.c_str());
  return Status(ErrorCode::kInvalidArgument, buf);
}

}  // namespace

Status apply_gauge(const std::string& gauge, int home_pose, const MeasurementSet& set,
                   const RobotModel& nominal, const std::string& recording_file,
                   IdentificationOptions* options) {
  static const std::pair<const char*, Gauge> kWords[] = {{"home", Gauge::kHomePose},
                                                         {"start", Gauge::kHomePose},
                                                         {"laser-plane", Gauge::kLaserPlane},
                                                         {"both", Gauge::kHomePoseAndLaserPlane},
                                                         {"none", Gauge::kNone}};
  bool known = false;
  for (const auto& [word, g] : kWords) {
    if (gauge == word) {
      options->gauge = g;
      known = true;
    }
  }
  if (!known) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "--gauge %s: expected home, start, laser-plane, both or none",
                         gauge.c_str());
  }
  options->home_at_commanded = gauge == "start";
  if (home_pose < 0 || home_pose >= set.num_poses()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "--home-pose %d: the recording has rows 0..%d", home_pose,
                         set.num_poses() - 1);
  }
  options->home_pose_index = home_pose;
  if (gauge == "home" || gauge == "both") {
    CDPR_RETURN_IF_ERROR(check_home_row(home_pose, set, nominal, recording_file));
  }
  return Status::success();
}

}  // namespace cdpr::fit
