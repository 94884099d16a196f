// check_plausible: what a recording of a cable robot in SI units can hold (recording.hpp).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/recording/recording.hpp"

namespace cdpr::recording {

namespace {

constexpr const char* kCmd[6] = {"cmd_x", "cmd_y", "cmd_z", "cmd_roll", "cmd_pitch", "cmd_yaw"};
constexpr const char* kRef[6] = {"ref_x", "ref_y", "ref_z", "ref_roll", "ref_pitch", "ref_yaw"};
constexpr const char* kStart[6] = {"start_x",    "start_y",     "start_z",
                                   "start_roll", "start_pitch", "start_yaw"};
constexpr const char* kAxis[6] = {"x", "y", "z", "roll", "pitch", "yaw"};

// A unit name for a factor between the readings and what the config expects.
const char* unit_guess(double ratio) {
  if (ratio > 300.0 && ratio < 3000.0) return "looks like mm, expected m";
  if (ratio > 30.0 && ratio < 300.0) return "looks like cm, expected m";
  if (ratio > 0.0003 && ratio < 0.003) return "looks like km, expected m";
  return "does not look like m";
}

struct Frame {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double size = 1e-3;  // m
};

Frame frame_of(const RobotModel& model) {
  Frame f;
  if (model.frame_anchors.cols() == 0) return f;
  const Eigen::Vector3d lo = model.frame_anchors.rowwise().minCoeff();
  const Eigen::Vector3d hi = model.frame_anchors.rowwise().maxCoeff();
  f.centre = 0.5 * (lo + hi);
  f.size = std::max((hi - lo).norm(), 1e-3);
  return f;
}

// "<where>: <value> <unit> is outside the plausible range [lo, hi] <unit> (<why>)", with a unit
// hint when the value would fit in mm.
// `open_low`: the range excludes `lo` ("(0, 1]").
Status out_of_range(const std::string& where, double v, double lo, double hi, const char* unit,
                    const std::string& why, bool open_low = false) {
  const bool mm =
      std::string(unit) == "m" && std::abs(v) > hi && v / 1000.0 >= lo && v / 1000.0 <= hi;
  return Status::error(ErrorCode::kInvalidArgument,
                       "%s: %.6g %s is outside the plausible range %c%.6g, %.6g] %s (%s%s)",
                       where.c_str(), v, unit, open_low ? '(' : '[', lo, hi, unit, why.c_str(),
                       mm ? "; looks like mm, expected m" : "");
}

std::string cell(std::string_view file, int line, int column, const char* name) {
  char buf[96];
  if (line > 0) {
    std::snprintf(buf, sizeof buf, ":%d: column %d (%s)", line, column, name);
  } else {
    std::snprintf(buf, sizeof buf, ": %s", name);
  }
  return std::string(file) + buf;
}

Status check_pose(const Pose& pose, const Frame& frame, const PlausibilityLimits& limits,
                  std::string_view file, int line, const char* const names[6],
                  const std::vector<int>& columns) {
  const double half = limits.position_frame_multiple * frame.size;
  char why[128];
  std::snprintf(why, sizeof why, "%.6g frame sizes of %.6g m around the frame centre",
                limits.position_frame_multiple, frame.size);
  for (int a = 0; a < 3; ++a) {
    const double v = pose.position(a);
    if (std::isnan(v)) continue;
    const double lo = frame.centre(a) - half, hi = frame.centre(a) + half;
    if (!(v >= lo && v <= hi)) {
      return out_of_range(cell(file, line, columns[static_cast<std::size_t>(a)], names[a]), v, lo,
                          hi, "m", why);
    }
  }
  for (int a = 0; a < 3; ++a) {
    const double v = pose.rpy(a);
    if (std::isnan(v)) continue;
    if (std::abs(v) > limits.max_abs_angle_rad) {
      return out_of_range(cell(file, line, columns[static_cast<std::size_t>(a + 3)], names[a + 3]),
                          v, -limits.max_abs_angle_rad, limits.max_abs_angle_rad, "rad",
                          "an angle");
    }
  }
  return Status::success();
}

Status check_noise(const Metadata& md, std::string_view file, const PlausibilityLimits& limits) {
  struct Noise {
    const char* key;
    double max;
    const char* unit;
  };
  const Noise noises[] = {{key::kNoiseLength, limits.max_noise_m, "m"},
                          {key::kNoiseLaser, limits.max_noise_m, "m"},
                          {key::kNoiseForce, limits.max_noise_force_n, "N"},
                          {key::kNoiseRefPosition, limits.max_noise_m, "m"},
                          {key::kNoiseRefAngle, limits.max_noise_angle_rad, "rad"}};
  for (const Noise& n : noises) {
    if (!md.has(n.key)) continue;
    auto v = md.number(n.key);
    if (!v.ok()) continue;  // not a number: to_measurement_set names it
    if (!(*v > 0.0 && *v <= n.max)) {
      return out_of_range(std::string(file) + ": metadata " + n.key, *v, 0.0, n.max, n.unit,
                          "a sensor standard deviation", /*open_low=*/true);
    }
  }
  return Status::success();
}

}  // namespace

Status check_plausible(const Recording& rec, const RobotModel& model, std::string_view file,
                       const PlausibilityLimits& limits) {
  CDPR_RETURN_IF_ERROR(check_noise(rec.metadata, file, limits));
  const Frame frame = frame_of(model);
  const int m = rec.num_cables, k = rec.num_lasers;
  // Columns (1-based): the file's own (Recording::header), else the canonical order.
  auto column = [&](const std::string& name, int canonical) {
    const auto it = std::find(rec.header.begin(), rec.header.end(), name);
    return it == rec.header.end() ? canonical : static_cast<int>(it - rec.header.begin()) + 1;
  };
  std::vector<int> cmd_cols, ref_cols, start_cols;
  const int first_length = 9, first_tension = first_length + m, first_laser = first_tension + m;
  for (int a = 0; a < 6; ++a) {
    cmd_cols.push_back(column(kCmd[a], 3 + a));
    ref_cols.push_back(column(kRef[a], first_laser + k + a));
    start_cols.push_back(column(kStart[a], 0));  // 0: not known (a recording not read from a file)
  }
  const int temperature_col =
      column("temperature_c", first_laser + k + (rec.has_reference ? 6 : 0));

  // The unit of the lengths as a whole: the median ratio to the nominal inverse kinematics is
  // not moved by a few bad cells (those are named below, one by one).
  KinematicsData kin(model.num_cables());
  // The inverse kinematics needs a complete model (a loaded config is one).
  const bool complete = model.platform_anchors.cols() == model.num_cables() &&
                        static_cast<int>(model.pulleys.size()) == model.num_cables();
  std::vector<double> ratios;
  double largest = 0.0;
  int largest_cable = 0, largest_line = 0;
  double sum_reading = 0.0, sum_nominal = 0.0;
  for (const RecordedPose& p : rec.poses) {
    const bool ik = complete && p.commanded.vector().allFinite() &&
                    (p.commanded.position - frame.centre).cwiseAbs().maxCoeff() <=
                        limits.position_frame_multiple * frame.size &&
                    inverse_kinematics(model, p.commanded, kin);
    for (Eigen::Index i = 0; i < p.lengths.size() && i < model.num_cables(); ++i) {
      const double v = p.lengths(i);
      if (!std::isfinite(v)) continue;
      if (std::abs(v) > largest) {
        largest = std::abs(v);
        largest_cable = static_cast<int>(i) + 1;
        largest_line = p.line;
      }
      if (!ik || !(kin.lengths(i) > 0.0)) continue;
      ratios.push_back(std::abs(v) / kin.lengths(i));
      sum_reading += std::abs(v);
      sum_nominal += kin.lengths(i);
    }
  }
  if (!ratios.empty()) {
    std::nth_element(ratios.begin(), ratios.begin() + static_cast<long>(ratios.size() / 2),
                     ratios.end());
    const double median = ratios[ratios.size() / 2];
    if (median > limits.unit_ratio || median < 1.0 / limits.unit_ratio) {
      const double n = static_cast<double>(ratios.size());
      return Status::error(ErrorCode::kInvalidArgument,
                           "%.*s: length_1..length_%d: %s (median ratio %.4g to the nominal "
                           "inverse kinematics at the commanded poses, mean %.4g vs %.4g m; "
                           "largest %.4g in length_%d on line %d)",
                           static_cast<int>(file.size()), file.data(), m, unit_guess(median),
                           median, sum_reading / n, sum_nominal / n, largest, largest_cable,
                           largest_line);
    }
  }

  const double max_length = limits.length_frame_multiple * frame.size;
  char length_why[96];
  std::snprintf(length_why, sizeof length_why, "%.6g frame sizes of %.6g m",
                limits.length_frame_multiple, frame.size);
  for (const RecordedPose& p : rec.poses) {
    CDPR_RETURN_IF_ERROR(check_pose(p.commanded, frame, limits, file, p.line, kCmd, cmd_cols));
    // `positive`: the range is (0, bound] (a cable length, a distance), else [-bound, bound].
    auto check_cells = [&](const Eigen::VectorXd& v, const char* prefix, int first_col,
                           double bound, const char* unit, const char* why, bool positive) {
      for (Eigen::Index i = 0; i < v.size(); ++i) {
        const double x = v(i);
        if (std::isnan(x) || (positive ? x > 0.0 && x <= bound : std::abs(x) <= bound)) continue;
        char name[32];
        std::snprintf(name, sizeof name, "%s%ld", prefix, static_cast<long>(i) + 1);
        return out_of_range(cell(file, p.line, column(name, first_col + static_cast<int>(i)), name),
                            x, positive ? 0.0 : -bound, bound, unit, why, positive);
      }
      return Status::success();
    };
    CDPR_RETURN_IF_ERROR(check_cells(p.lengths, "length_", first_length, max_length, "m",
                                     length_why, /*positive=*/true));
    CDPR_RETURN_IF_ERROR(check_cells(p.tensions, "tension_", first_tension,
                                     limits.max_abs_tension_n, "N", "a cable tension",
                                     /*positive=*/false));
    CDPR_RETURN_IF_ERROR(check_cells(p.lasers, "laser_", first_laser, max_length, "m", length_why,
                                     /*positive=*/true));
    if (rec.has_reference) {
      CDPR_RETURN_IF_ERROR(check_pose(p.reference, frame, limits, file, p.line, kRef, ref_cols));
    }
    if (rec.has_start) {
      CDPR_RETURN_IF_ERROR(check_pose(p.start, frame, limits, file, p.line, kStart, start_cols));
    }
    if (rec.has_planned_tensions) {
      CDPR_RETURN_IF_ERROR(check_cells(p.planned_tensions, "planned_tension_", 0,
                                       limits.max_abs_tension_n, "N", "a cable tension",
                                       /*positive=*/false));
    }
    if (rec.has_temperature && !std::isnan(p.temperature_c) &&
        !(p.temperature_c >= limits.min_temperature_c &&
          p.temperature_c <= limits.max_temperature_c)) {
      return out_of_range(cell(file, p.line, temperature_col, "temperature_c"), p.temperature_c,
                          limits.min_temperature_c, limits.max_temperature_c, "degC",
                          "a temperature");
    }
  }
  return Status::success();
}

Status check_plausible(const PoseList& list, const RobotModel& model, std::string_view file,
                       const PlausibilityLimits& limits) {
  const Frame frame = frame_of(model);
  const std::vector<int> cols = {2, 3, 4, 5, 6, 7};
  for (std::size_t j = 0; j < list.poses.size(); ++j) {
    const int line = j < list.lines.size() ? list.lines[j] : 0;
    CDPR_RETURN_IF_ERROR(check_pose(list.poses[j], frame, limits, file, line, kAxis, cols));
  }
  return Status::success();
}

}  // namespace cdpr::recording
