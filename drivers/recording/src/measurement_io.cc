// Recording <-> MeasurementSet.
#include <cmath>
#include <limits>

#include "cdpr/recording/recording.hpp"

namespace cdpr::recording {

namespace {

Status sigma_from(const Metadata& md, const char* k, double* sigma) {
  if (!md.has(k)) return Status::success();
  CDPR_ASSIGN_OR_RETURN(const double v, md.number(k));
  if (!(v > 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument, "metadata '%s': %s is not a positive sigma",
                         k, md.get(k).c_str());
  }
  *sigma = v;
  return Status::success();
}

// The optional campaign columns into a measurement (a start pose is all six cells or none).
Status campaign_to_measurement(const Recording& rec, const RecordedPose& p, PoseMeasurement* m) {
  if (rec.has_planned_tensions) m->planned_tensions = p.planned_tensions;
  m->scatter_length = p.scatter_length_m;
  m->scatter_force = p.scatter_force_n;
  m->supported = p.supported;
  if (!rec.has_start) return Status::success();
  const auto start = p.start.vector();
  const int filled = static_cast<int>(start.array().isFinite().count());
  if (filled == 6) {
    m->start = p.start;
  } else if (filled != 0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "pose %lld: start pose has %d of its 6 start_ cells filled (all or none)",
                         static_cast<long long>(p.index), filled);
  }
  return Status::success();
}

void campaign_from_measurement(const Recording& rec, const PoseMeasurement& p, RecordedPose* r) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (rec.has_planned_tensions) {
    r->planned_tensions = p.planned_tensions.size() == 0
                              ? Eigen::VectorXd::Constant(rec.num_cables, nan)
                              : Eigen::VectorXd(p.planned_tensions);
  }
  r->scatter_length_m = p.scatter_length;
  r->scatter_force_n = p.scatter_force;
  r->supported = p.supported;
  if (p.start) {
    r->start = *p.start;
  } else {
    r->start.position.setConstant(nan);
    r->start.rpy.setConstant(nan);
  }
}

}  // namespace

Result<MeasurementSet> to_measurement_set(const Recording& rec, const SensorNoise& defaults) {
  MeasurementSet set;
  set.noise = defaults;
  const Metadata& md = rec.metadata;
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseLength, &set.noise.sigma_length));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseForce, &set.noise.sigma_force));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseLaser, &set.noise.sigma_laser));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseRefPosition, &set.noise.sigma_reference_position));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseRefAngle, &set.noise.sigma_reference_angle));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseSwivel, &set.noise.sigma_swivel));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseInclination, &set.noise.sigma_inclination));
  CDPR_RETURN_IF_ERROR(sigma_from(md, key::kNoiseImuYaw, &set.noise.sigma_imu_yaw));
  bool any_tension = false;
  for (const RecordedPose& p : rec.poses) {
    if (p.tensions.size() > 0 && !p.tensions.array().isNaN().all()) any_tension = true;
  }
  set.poses.reserve(rec.poses.size());
  for (const RecordedPose& p : rec.poses) {
    if (p.lengths.size() != rec.num_cables || p.tensions.size() != rec.num_cables ||
        p.lasers.size() != rec.num_lasers ||
        (rec.has_swivel && p.swivels.size() != rec.num_cables)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "pose %lld: vector sizes do not match the recording's %d cables and %d "
                           "lasers",
                           static_cast<long long>(p.index), rec.num_cables, rec.num_lasers);
    }
    PoseMeasurement m;
    m.commanded = p.commanded;
    m.cable_lengths = p.lengths;
    if (any_tension) m.tensions = p.tensions;
    m.laser_distances = p.lasers;
    if (rec.has_swivel) m.swivel_angles = p.swivels;
    if (rec.has_inclinometer) m.inclination = p.inclination;
    if (rec.has_imu_yaw) m.imu_yaw = p.imu_yaw;
    m.time = p.time_s;
    m.temperature = p.temperature_c;
    CDPR_RETURN_IF_ERROR(campaign_to_measurement(rec, p, &m));
    if (rec.has_reference) {
      const auto ref = p.reference.vector();
      const int filled = static_cast<int>(ref.array().isFinite().count());
      if (filled == 6) {
        m.reference = p.reference;
      } else if (filled != 0) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "pose %lld: reference pose has %d of its 6 ref_ cells filled (all "
                             "or none)",
                             static_cast<long long>(p.index), filled);
      }
    }
    set.poses.push_back(std::move(m));
  }
  return set;
}

Result<Recording> from_measurement_set(const MeasurementSet& set, Metadata metadata) {
  if (set.poses.empty()) return Status(ErrorCode::kInvalidArgument, "measurement set is empty");
  Recording rec;
  const PoseMeasurement& first = set.poses.front();
  rec.num_cables = static_cast<int>(first.cable_lengths.size());
  rec.num_lasers = static_cast<int>(first.laser_distances.size());
  rec.has_reference = false;
  rec.has_temperature = false;
  for (const PoseMeasurement& p : set.poses) {
    if (p.reference) rec.has_reference = true;
    if (std::isfinite(p.temperature)) rec.has_temperature = true;
    if (p.swivel_angles.size() != 0) rec.has_swivel = true;
    if (!p.inclination.array().isNaN().all()) rec.has_inclinometer = true;
    if (!std::isnan(p.imu_yaw)) rec.has_imu_yaw = true;
    if (p.planned_tensions.size() != 0) rec.has_planned_tensions = true;
    if (!std::isnan(p.scatter_length)) rec.has_scatter_length = true;
    if (!std::isnan(p.scatter_force)) rec.has_scatter_force = true;
    if (p.supported) rec.has_supported = true;
    if (p.start) rec.has_start = true;
  }
  metadata.set_number(key::kNoiseLength, set.noise.sigma_length);
  metadata.set_number(key::kNoiseForce, set.noise.sigma_force);
  if (rec.num_lasers > 0) metadata.set_number(key::kNoiseLaser, set.noise.sigma_laser);
  if (rec.has_swivel) metadata.set_number(key::kNoiseSwivel, set.noise.sigma_swivel);
  if (rec.has_inclinometer) {
    metadata.set_number(key::kNoiseInclination, set.noise.sigma_inclination);
  }
  if (rec.has_imu_yaw) metadata.set_number(key::kNoiseImuYaw, set.noise.sigma_imu_yaw);
  if (rec.has_reference) {
    metadata.set_number(key::kNoiseRefPosition, set.noise.sigma_reference_position);
    metadata.set_number(key::kNoiseRefAngle, set.noise.sigma_reference_angle);
  }
  rec.metadata = std::move(metadata);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (std::size_t j = 0; j < set.poses.size(); ++j) {
    const PoseMeasurement& p = set.poses[j];
    if (p.cable_lengths.size() != rec.num_cables ||
        (p.tensions.size() != 0 && p.tensions.size() != rec.num_cables) ||
        p.laser_distances.size() != rec.num_lasers ||
        (p.swivel_angles.size() != 0 && p.swivel_angles.size() != rec.num_cables)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "measurement set: pose %zu has other vector sizes than pose 0", j);
    }
    RecordedPose r;
    r.index = static_cast<std::int64_t>(j);
    r.time_s = std::isfinite(p.time) ? p.time : static_cast<double>(j);
    r.commanded = p.commanded;
    r.lengths = p.cable_lengths;
    r.tensions = p.tensions.size() == 0 ? Eigen::VectorXd::Constant(rec.num_cables, nan)
                                        : Eigen::VectorXd(p.tensions);
    r.lasers = p.laser_distances;
    if (rec.has_swivel) {
      r.swivels = p.swivel_angles.size() == 0 ? Eigen::VectorXd::Constant(rec.num_cables, nan)
                                              : Eigen::VectorXd(p.swivel_angles);
    }
    r.inclination = p.inclination;
    r.imu_yaw = p.imu_yaw;
    if (p.reference) {
      r.reference = *p.reference;
    } else {
      r.reference.position.setConstant(nan);
      r.reference.rpy.setConstant(nan);
    }
    r.temperature_c = p.temperature;
    campaign_from_measurement(rec, p, &r);
    rec.poses.push_back(std::move(r));
  }
  return rec;
}

}  // namespace cdpr::recording
