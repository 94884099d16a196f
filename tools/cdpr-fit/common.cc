#include "common.hpp"

#include "cdpr/config/robot_config.hpp"
#include "cdpr/recording/recording.hpp"

namespace cdpr::fit {

Console& console() {
  static Console c;
  return c;
}

Result<RobotModel> load_config(const std::string& path) {
  auto model = config::load_robot_config(path);
  if (!model.ok()) return model.status();  // the loader names the file, line and field
  return model;
}

std::string hash_or_unknown(const std::string& path) {
  auto h = recording::file_hash(path);
  return h.ok() ? *h : std::string("unknown");
}

Result<SensorChannels> parse_channels(const std::vector<std::string>& words,
                                      const RobotModel& robot, const std::string& config) {
  SensorChannels c;
  c.laser = false;
  if (words.size() == 1 && words[0] == "none") return c;
  for (const std::string& w : words) {
    if (w == "laser") {
      c.laser = true;
    } else if (w == "swivel") {
      c.swivel = true;
    } else if (w == "inclinometer") {
      c.inclinometer = true;
    } else if (w == "imu-yaw") {
      c.imu_yaw = true;
    } else {
      return Status::error(ErrorCode::kInvalidArgument,
                           "--channels: unknown channel '%s' (one of laser, swivel, inclinometer, "
                           "imu-yaw, or none)",
                           w.c_str());
    }
  }
  if (c.laser && robot.lasers.empty()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "%s has no laser; leave 'laser' out of --channels (no laser columns, "
                         "no laser readings)",
                         config.c_str());
  }
  if (c.swivel) {
    for (int i = 0; i < robot.num_cables(); ++i) {
      if (!robot.pulleys[static_cast<std::size_t>(i)].enabled()) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "--channels swivel: cable %d of %s has no swivel pulley", i + 1,
                             config.c_str());
      }
    }
  }
  return c;
}

Status with_context(const Status& s, const std::string& context) {
  Status out = s;
  out.prepend(context + ": ");
  return out;
}

}  // namespace cdpr::fit
