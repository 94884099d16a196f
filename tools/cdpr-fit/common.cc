#include "common.hpp"

#include <cmath>
#include <cstdio>

#include "cdpr/config/robot_config.hpp"
#include "cdpr/recording/recording.hpp"

namespace cdpr::fit {

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

nlohmann::json number_or_null(double v) {
  if (!std::isfinite(v)) return nullptr;
  return v;
}

nlohmann::json to_json(const Eigen::VectorXd& v) {
  nlohmann::json a = nlohmann::json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back(number_or_null(v(i)));
  return a;
}

nlohmann::json to_json(const Eigen::Matrix3Xd& m) {
  nlohmann::json a = nlohmann::json::array();
  for (Eigen::Index c = 0; c < m.cols(); ++c) a.push_back(to_json(Eigen::VectorXd(m.col(c))));
  return a;
}

std::string fmt(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

}  // namespace cdpr::fit
