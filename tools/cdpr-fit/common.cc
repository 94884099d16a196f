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

Status with_context(const Status& s, const std::string& context) {
  Status out = s;
  out.prepend(context + ": ");
  return out;
}

}  // namespace cdpr::fit
