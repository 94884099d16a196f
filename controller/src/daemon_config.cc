#include "cdpr/controller/daemon_config.hpp"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <sstream>

namespace cdpr::controller {
namespace {

// Field reading with "file:line:col: field 'a.b': reason" messages.
class Reader {
 public:
  explicit Reader(std::string_view file) : file_(file) {}

  Status error(const YAML::Node& at, const std::string& field, const std::string& why) const {
    const YAML::Mark m = at.Mark();
    if (m.line >= 0) {
      return Status::Error(ErrorCode::kParseError, "%s:%d:%d: field '%s': %s", file_.c_str(),
                           m.line + 1, m.column + 1, field.c_str(), why.c_str());
    }
    return Status::Error(ErrorCode::kParseError, "%s: field '%s': %s", file_.c_str(), field.c_str(),
                         why.c_str());
  }

  Status only(const YAML::Node& map, const std::string& prefix,
              std::initializer_list<const char*> known) const {
    if (!map.IsMap()) return error(map, prefix.empty() ? "(top)" : prefix, "must be a mapping");
    for (auto it = map.begin(); it != map.end(); ++it) {
      const std::string key = it->first.Scalar();
      bool ok = false;
      std::string list;
      for (const char* k : known) {
        ok = ok || key == k;
        list += (list.empty() ? "" : ", ") + std::string(k);
      }
      if (!ok) return error(it->first, join(prefix, key), "unknown field (known: " + list + ")");
    }
    return Status::Ok();
  }

  Status text(const YAML::Node& map, const char* key, const std::string& prefix,
              std::string& out) const {
    const YAML::Node n = map[key];
    if (!n) return Status::Ok();
    if (!n.IsScalar()) return error(n, join(prefix, key), "must be a string");
    out = n.Scalar();
    return Status::Ok();
  }

  Status number(const YAML::Node& map, const char* key, const std::string& prefix, double lo,
                double hi, const char* unit, double& out) const {
    const YAML::Node n = map[key];
    if (!n) return Status::Ok();
    double v = 0.0;
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, v) || !std::isfinite(v)) {
      return error(n, join(prefix, key), "expected a number in " + std::string(unit));
    }
    if (v < lo || v > hi) {
      std::ostringstream s;
      s << "must be within [" << lo << ", " << hi << "] " << unit << ", got " << v;
      return error(n, join(prefix, key), s.str());
    }
    out = v;
    return Status::Ok();
  }

  Status integer(const YAML::Node& map, const char* key, const std::string& prefix, long long lo,
                 long long hi, long long& out) const {
    const YAML::Node n = map[key];
    if (!n) return Status::Ok();
    long long v = 0;
    if (!n.IsScalar() || !YAML::convert<long long>::decode(n, v)) {
      return error(n, join(prefix, key), "expected an integer");
    }
    if (v < lo || v > hi) {
      return error(n, join(prefix, key),
                   "must be within [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " +
                       std::to_string(v));
    }
    out = v;
    return Status::Ok();
  }

  template <typename Int>
  Status integer_as(const YAML::Node& map, const char* key, const std::string& prefix, long long lo,
                    long long hi, Int& out) const {
    long long v = static_cast<long long>(out);
    if (Status s = integer(map, key, prefix, lo, hi, v); !s.ok()) return s;
    out = static_cast<Int>(v);
    return Status::Ok();
  }

  Status boolean(const YAML::Node& map, const char* key, const std::string& prefix,
                 bool& out) const {
    const YAML::Node n = map[key];
    if (!n) return Status::Ok();
    bool v = false;
    if (!n.IsScalar() || !YAML::convert<bool>::decode(n, v)) {
      return error(n, join(prefix, key), "expected true or false");
    }
    out = v;
    return Status::Ok();
  }

  static std::string join(const std::string& prefix, const std::string& key) {
    return prefix.empty() ? key : prefix + "." + key;
  }

 private:
  std::string file_;
};

#define CDPR_CFG(expr)             \
  do {                             \
    ::cdpr::Status cfg_s = (expr); \
    if (!cfg_s.ok()) return cfg_s; \
  } while (false)

std::string resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || std::filesystem::path(p).is_absolute() || base_dir.empty()) return p;
  return (std::filesystem::path(base_dir) / p).lexically_normal().string();
}

Status read_realtime(const Reader& r, const YAML::Node& n, RealtimeSettings& rt) {
  if (!n) return Status::Ok();
  CDPR_CFG(r.only(n, "realtime", {"priority", "cpu", "sync_period_ms", "lock_memory"}));
  CDPR_CFG(r.integer_as(n, "priority", "realtime", 0, 99, rt.priority));
  CDPR_CFG(r.integer_as(n, "cpu", "realtime", -1, 1023, rt.cpu));
  double ms = 0.0;
  CDPR_CFG(r.number(n, "sync_period_ms", "realtime", 0.0, 1000.0, "ms", ms));
  rt.sync_period = std::chrono::nanoseconds(static_cast<std::int64_t>(std::llround(ms * 1e6)));
  CDPR_CFG(r.boolean(n, "lock_memory", "realtime", rt.lock_memory));
  return Status::Ok();
}

Status read_identity(const Reader& r, const YAML::Node& n, IdentitySettings& id) {
  if (!n) return Status::Ok();
  CDPR_CFG(r.only(n, "identity", {"vendor_id", "drive_product_code", "force_product_code"}));
  constexpr long long kMax = 0xFFFFFFFFLL;
  CDPR_CFG(r.integer_as(n, "vendor_id", "identity", 0, kMax, id.vendor_id));
  CDPR_CFG(r.integer_as(n, "drive_product_code", "identity", 0, kMax, id.drive_product_code));
  CDPR_CFG(r.integer_as(n, "force_product_code", "identity", 0, kMax, id.force_product_code));
  return Status::Ok();
}

Status read_motion(const Reader& r, const YAML::Node& n, MotionSettings& m) {
  if (!n) return Status::Ok();
  const std::string p = "motion";
  CDPR_CFG(r.only(n, p,
                  {"max_linear_velocity", "max_linear_acceleration", "max_linear_jerk",
                   "max_angular_velocity", "max_angular_acceleration", "max_angular_jerk",
                   "tension_margin", "max_cable_speed", "max_cable_acceleration"}));
  CDPR_CFG(r.number(n, "max_linear_velocity", p, 1e-4, 10.0, "m/s", m.max_linear_velocity));
  CDPR_CFG(
      r.number(n, "max_linear_acceleration", p, 1e-4, 100.0, "m/s^2", m.max_linear_acceleration));
  CDPR_CFG(r.number(n, "max_linear_jerk", p, 1e-3, 1e4, "m/s^3", m.max_linear_jerk));
  CDPR_CFG(r.number(n, "max_angular_velocity", p, 1e-4, 10.0, "rad/s", m.max_angular_velocity));
  CDPR_CFG(r.number(n, "max_angular_acceleration", p, 1e-4, 100.0, "rad/s^2",
                    m.max_angular_acceleration));
  CDPR_CFG(r.number(n, "max_angular_jerk", p, 1e-3, 1e4, "rad/s^3", m.max_angular_jerk));
  CDPR_CFG(r.number(n, "tension_margin", p, 0.0, 1e5, "N", m.tension_margin));
  CDPR_CFG(r.number(n, "max_cable_speed", p, 1e-4, 10.0, "m/s", m.max_cable_speed));
  CDPR_CFG(
      r.number(n, "max_cable_acceleration", p, 1e-4, 100.0, "m/s^2", m.max_cable_acceleration));
  return Status::Ok();
}

Status read_tension_watch(const Reader& r, const YAML::Node& n, TensionWatch& t) {
  if (!n) return Status::Ok();
  CDPR_CFG(r.only(n, "tension_watch", {"slack_below", "overload_above", "cycles"}));
  CDPR_CFG(r.number(n, "slack_below", "tension_watch", 0.0, 1e6, "N", t.slack_below));
  CDPR_CFG(r.number(n, "overload_above", "tension_watch", 0.0, 1e7, "N", t.overload_above));
  CDPR_CFG(r.integer_as(n, "cycles", "tension_watch", 1, 10000, t.cycles));
  return Status::Ok();
}

Status read_measuring(const Reader& r, const YAML::Node& n, const std::string& dir,
                      MeasuringSettings& m) {
  if (!n) return Status::Ok();
  const std::string p = "measuring";
  CDPR_CFG(r.only(n, p,
                  {"poses", "pose_file", "laser_samples", "laser_interval_s", "average_cycles",
                   "settle_window_s", "settle_position_tolerance", "settle_tension_tolerance",
                   "settle_timeout_s", "tension_band", "extra_pose_rounds", "noise_length_m",
                   "noise_force_n", "noise_laser_m"}));
  CDPR_CFG(r.integer_as(n, "poses", p, 7, 1000, m.poses));
  CDPR_CFG(r.text(n, "pose_file", p, m.pose_file));
  m.pose_file = resolve(dir, m.pose_file);
  CDPR_CFG(r.integer_as(n, "laser_samples", p, 1, 10000, m.laser_samples));
  CDPR_CFG(r.number(n, "laser_interval_s", p, -1.0, 10.0, "s", m.laser_interval_s));
  CDPR_CFG(r.integer_as(n, "average_cycles", p, 1, 100000, m.average_cycles));
  CDPR_CFG(r.number(n, "settle_window_s", p, 0.0, 60.0, "s", m.settle_window_s));
  CDPR_CFG(r.number(n, "settle_position_tolerance", p, 0.0, 0.1, "m", m.settle_position_tolerance));
  CDPR_CFG(r.number(n, "settle_tension_tolerance", p, 0.0, 1e5, "N", m.settle_tension_tolerance));
  CDPR_CFG(r.number(n, "settle_timeout_s", p, 0.01, 3600.0, "s", m.settle_timeout_s));
  CDPR_CFG(r.number(n, "tension_band", p, 0.0, 1e5, "N", m.tension_band));
  CDPR_CFG(r.integer_as(n, "extra_pose_rounds", p, 0, 10, m.extra_pose_rounds));
  CDPR_CFG(r.number(n, "noise_length_m", p, 1e-12, 1.0, "m", m.noise_length_m));
  CDPR_CFG(r.number(n, "noise_force_n", p, 1e-9, 1e5, "N", m.noise_force_n));
  CDPR_CFG(r.number(n, "noise_laser_m", p, 1e-12, 1.0, "m", m.noise_laser_m));
  return Status::Ok();
}

Status read_identification(const Reader& r, const YAML::Node& n, IdentificationSettings& s) {
  if (!n) return Status::Ok();
  const std::string p = "identification";
  CDPR_CFG(r.only(n, p,
                  {"frame_anchors", "platform_anchors", "length_offsets", "length_scales",
                   "force_gains", "force_offsets", "laser_origin", "laser_direction", "laser_plane",
                   "diagnose", "bootstrap", "folds"}));
  IdentificationOptions& o = s.options;
  CDPR_CFG(r.boolean(n, "frame_anchors", p, o.estimate_frame_anchors));
  CDPR_CFG(r.boolean(n, "platform_anchors", p, o.estimate_platform_anchors));
  CDPR_CFG(r.boolean(n, "length_offsets", p, o.estimate_length_offsets));
  CDPR_CFG(r.boolean(n, "length_scales", p, o.estimate_length_scales));
  CDPR_CFG(r.boolean(n, "force_gains", p, o.estimate_force_gains));
  CDPR_CFG(r.boolean(n, "force_offsets", p, o.estimate_force_offsets));
  CDPR_CFG(r.boolean(n, "laser_origin", p, o.estimate_laser_origin));
  CDPR_CFG(r.boolean(n, "laser_direction", p, o.estimate_laser_direction));
  CDPR_CFG(r.boolean(n, "laser_plane", p, o.estimate_laser_plane));
  CDPR_CFG(r.boolean(n, "diagnose", p, s.diagnose));
  CDPR_CFG(r.integer_as(n, "bootstrap", p, 1, 100000, s.bootstrap));
  CDPR_CFG(r.integer_as(n, "folds", p, 2, 1000, s.folds));
  return Status::Ok();
}

Status read_acceptance(const Reader& r, const YAML::Node& n, AcceptanceGates& g) {
  if (!n) return Status::Ok();
  const std::string p = "acceptance";
  CDPR_CFG(r.only(n, p,
                  {"mode", "min_fit_p_value", "max_anchor_change_m",
                   "max_predicted_position_error_m", "allow_unresolved_mismatch"}));
  std::string mode;
  CDPR_CFG(r.text(n, "mode", p, mode));
  if (mode == "manual" || mode.empty()) {
    g.mode = AcceptanceMode::kManual;
  } else if (mode == "auto") {
    g.mode = AcceptanceMode::kAuto;
  } else {
    return r.error(n["mode"], "acceptance.mode", "expected 'manual' or 'auto', got '" + mode + "'");
  }
  CDPR_CFG(r.number(n, "min_fit_p_value", p, 0.0, 1.0, "", g.min_fit_p_value));
  CDPR_CFG(r.number(n, "max_anchor_change_m", p, 0.0, 10.0, "m", g.max_anchor_change_m));
  CDPR_CFG(r.number(n, "max_predicted_position_error_m", p, 0.0, 10.0, "m",
                    g.max_predicted_position_error_m));
  CDPR_CFG(r.boolean(n, "allow_unresolved_mismatch", p, g.allow_unresolved_mismatch));
  return Status::Ok();
}

Status read_control(const Reader& r, const YAML::Node& n, const std::string& dir,
                    ControlSettings& c) {
  if (!n) return Status::Ok();
  CDPR_CFG(r.only(n, "control", {"socket", "group"}));
  CDPR_CFG(r.text(n, "socket", "control", c.socket));
  c.socket = resolve(dir, c.socket);
  CDPR_CFG(r.text(n, "group", "control", c.group));
  return Status::Ok();
}

}  // namespace

Result<DaemonConfig> parse_daemon_config(std::string_view yaml, std::string_view file) {
  DaemonConfig c;
  c.file = std::string(file);
  const Reader r(file);
  YAML::Node root;
  try {
    root = YAML::Load(std::string(yaml));
  } catch (const YAML::Exception& e) {
    return Status::Error(ErrorCode::kParseError, "%.*s:%d:%d: %s", static_cast<int>(file.size()),
                         file.data(), e.mark.line + 1, e.mark.column + 1, e.msg.c_str());
  }
  if (!root || !root.IsMap()) {
    return Status::Error(ErrorCode::kParseError, "%.*s: expected a mapping of daemon settings",
                         static_cast<int>(file.size()), file.data());
  }
  CDPR_CFG(r.only(
      root, "",
      {"robot", "canopen", "laser", "can_interface", "state_directory", "realtime", "identity",
       "motion", "tension_watch", "measuring", "identification", "acceptance", "control"}));
  const std::string dir = std::filesystem::path(std::string(file)).parent_path().string();
  for (const char* required : {"robot", "canopen"}) {
    if (!root[required]) return r.error(root, required, "is missing");
  }
  CDPR_CFG(r.text(root, "robot", "", c.robot));
  CDPR_CFG(r.text(root, "canopen", "", c.canopen));
  CDPR_CFG(r.text(root, "laser", "", c.laser));
  CDPR_CFG(r.text(root, "can_interface", "", c.can_interface));
  CDPR_CFG(r.text(root, "state_directory", "", c.state_directory));
  c.robot = resolve(dir, c.robot);
  c.canopen = resolve(dir, c.canopen);
  c.laser = resolve(dir, c.laser);
  c.state_directory = resolve(dir, c.state_directory);
  CDPR_CFG(read_realtime(r, root["realtime"], c.realtime));
  CDPR_CFG(read_identity(r, root["identity"], c.identity));
  CDPR_CFG(read_motion(r, root["motion"], c.motion));
  CDPR_CFG(read_tension_watch(r, root["tension_watch"], c.tension_watch));
  CDPR_CFG(read_measuring(r, root["measuring"], dir, c.measuring));
  CDPR_CFG(read_identification(r, root["identification"], c.identification));
  CDPR_CFG(read_acceptance(r, root["acceptance"], c.acceptance));
  CDPR_CFG(read_control(r, root["control"], dir, c.control));
  return c;
}

Result<DaemonConfig> load_daemon_config(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::Error(ErrorCode::kNotFound, "%s: cannot open", path.c_str());
  std::ostringstream s;
  s << in.rdbuf();
  return parse_daemon_config(s.str(), path);
}

}  // namespace cdpr::controller
