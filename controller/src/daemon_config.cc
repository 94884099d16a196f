#include "cdpr/controller/daemon_config.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "cdpr/canopen/config.hpp"
#include "cdpr/config/yaml_reader.hpp"

namespace cdpr::controller {
namespace {

using config::Sign;
using config::YamlDocument;
using config::YamlField;

std::string resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || std::filesystem::path(p).is_absolute() || base_dir.empty()) return p;
  return (std::filesystem::path(base_dir) / p).lexically_normal().string();
}

// A number within [lo, hi] (unit in the message), kept at its default when absent.
Status in_range(const YamlField& map, std::string_view key, double lo, double hi,
                std::string_view unit, double& out) {
  const YamlField f = map[key];
  if (!f.present()) return Status::success();
  CDPR_ASSIGN_OR_RETURN(out, f.number_in(lo, hi, unit));
  return Status::success();
}

Status read_realtime(const YamlField& n, RealtimeSettings& rt) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys({"priority", "cpu", "sync_period_ms", "lock_memory"}));
  CDPR_RETURN_IF_ERROR(n.optional("priority", rt.priority, 0, 99));
  CDPR_RETURN_IF_ERROR(n.optional("cpu", rt.cpu, -1, 1023));
  double ms = 0.0;
  CDPR_RETURN_IF_ERROR(in_range(n, "sync_period_ms", 0.0, canopen::kMaxSyncPeriodMs, "ms", ms));
  if (ms != 0.0 && ms < canopen::kMinSyncPeriodMs) {
    char why[96];
    std::snprintf(why, sizeof why, "must be 0 (the network's) or within [%g, %g] ms",
                  canopen::kMinSyncPeriodMs, canopen::kMaxSyncPeriodMs);
    return n["sync_period_ms"].error(why);
  }
  rt.sync_period = std::chrono::nanoseconds(static_cast<std::int64_t>(std::llround(ms * 1e6)));
  return n.optional("lock_memory", rt.lock_memory);
}

Status read_identity(const YamlField& n, IdentitySettings& id) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys({"vendor_id", "drive_product_code", "force_product_code"}));
  constexpr std::int64_t kMax = 0xFFFFFFFFLL;
  CDPR_RETURN_IF_ERROR(n.optional("vendor_id", id.vendor_id, 0, kMax));
  CDPR_RETURN_IF_ERROR(n.optional("drive_product_code", id.drive_product_code, 0, kMax));
  return n.optional("force_product_code", id.force_product_code, 0, kMax);
}

Status read_motion(const YamlField& n, MotionSettings& m) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(
      n.check_keys({"max_linear_velocity", "max_linear_acceleration", "max_linear_jerk",
                    "max_angular_velocity", "max_angular_acceleration", "max_angular_jerk",
                    "tension_margin", "max_cable_speed", "max_cable_acceleration",
                    "stream_max_step", "stream_max_step_angle", "stream_deadline_cycles"}));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "max_linear_velocity", 1e-4, 10.0, "m/s", m.max_linear_velocity));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "max_linear_acceleration", 1e-4, 100.0, "m/s^2", m.max_linear_acceleration));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_linear_jerk", 1e-3, 1e4, "m/s^3", m.max_linear_jerk));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "max_angular_velocity", 1e-4, 10.0, "rad/s", m.max_angular_velocity));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "max_angular_acceleration", 1e-4, 100.0, "rad/s^2", m.max_angular_acceleration));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_angular_jerk", 1e-3, 1e4, "rad/s^3", m.max_angular_jerk));
  CDPR_RETURN_IF_ERROR(in_range(n, "tension_margin", 0.0, 1e5, "N", m.tension_margin));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_cable_speed", 1e-4, 10.0, "m/s", m.max_cable_speed));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "max_cable_acceleration", 1e-4, 100.0, "m/s^2", m.max_cable_acceleration));
  CDPR_RETURN_IF_ERROR(in_range(n, "stream_max_step", 1e-6, 0.1, "m", m.stream_max_step));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "stream_max_step_angle", 1e-6, 0.5, "rad", m.stream_max_step_angle));
  return n.optional("stream_deadline_cycles", m.stream_deadline_cycles, 1, 1000);
}

Status read_tension_watch(const YamlField& n, TensionWatch& t) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys(
      {"slack_below", "overload_above", "cycles", "stuck_raw_units", "stuck_confirm_s"}));
  CDPR_RETURN_IF_ERROR(in_range(n, "slack_below", 0.0, 1e6, "N", t.slack_below));
  CDPR_RETURN_IF_ERROR(in_range(n, "overload_above", 0.0, 1e7, "N", t.overload_above));
  CDPR_RETURN_IF_ERROR(in_range(n, "stuck_raw_units", 0.0, 1e6, "raw units", t.stuck_raw_units));
  CDPR_RETURN_IF_ERROR(in_range(n, "stuck_confirm_s", 0.0, 60.0, "s", t.stuck_confirm_s));
  return n.optional("cycles", t.cycles, 1, 10000);
}

Status read_tension_control(const YamlField& n, TensionControlSettings& t) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(
      n.check_keys({"gain", "deadband", "max_rate", "max_trim", "stale_s", "hold_s", "decay_s"}));
  CDPR_RETURN_IF_ERROR(in_range(n, "gain", 0.0, 1e3, "1/s", t.gain));
  CDPR_RETURN_IF_ERROR(in_range(n, "deadband", 0.0, 1e5, "N", t.deadband));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_rate", 0.0, 10.0, "m/s", t.max_rate));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_trim", 0.0, 10.0, "m", t.max_trim));
  CDPR_RETURN_IF_ERROR(in_range(n, "stale_s", 0.0, 60.0, "s", t.stale_s));
  CDPR_RETURN_IF_ERROR(in_range(n, "hold_s", 0.0, 600.0, "s", t.hold_s));
  return in_range(n, "decay_s", 1e-3, 600.0, "s", t.decay_s);
}

Status read_monitoring(const YamlField& n, MonitoringSettings& m) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys(
      {"enabled", "period_s", "false_alarms_per_hour", "alert_position_m", "assess_period_s",
       "model_length_m", "model_force_n", "acceptance_position_m", "override_calibration",
       "reference_s", "move_speed_m_s", "max_following_m", "laser_max_age_s"}));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_following_m", 0.0, 1.0, "m", m.max_following_m));
  CDPR_RETURN_IF_ERROR(in_range(n, "laser_max_age_s", 1e-3, 60.0, "s", m.laser_max_age_s));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "acceptance_position_m", 0.0, 1.0, "m", m.acceptance_position_m));
  CDPR_RETURN_IF_ERROR(n.optional("override_calibration", m.override_calibration));
  CDPR_RETURN_IF_ERROR(in_range(n, "move_speed_m_s", 0.0, 10.0, "m/s", m.move_speed_m_s));
  CDPR_RETURN_IF_ERROR(in_range(n, "reference_s", 0.0, 86400.0, "s", m.reference_s));
  CDPR_RETURN_IF_ERROR(in_range(n, "model_length_m", 0.0, 1.0, "m", m.model_length_m));
  CDPR_RETURN_IF_ERROR(in_range(n, "model_force_n", 0.0, 1e4, "N", m.model_force_n));
  CDPR_RETURN_IF_ERROR(n.optional("enabled", m.enabled));
  CDPR_RETURN_IF_ERROR(in_range(n, "period_s", 0.01, 3600.0, "s", m.period_s));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "false_alarms_per_hour", 1e-6, 100.0, "1/h", m.false_alarms_per_hour));
  CDPR_RETURN_IF_ERROR(in_range(n, "alert_position_m", 1e-7, 1.0, "m", m.alert_position_m));
  return in_range(n, "assess_period_s", 1.0, 86400.0, "s", m.assess_period_s);
}

Status read_measuring(const YamlField& n, const std::string& dir, MeasuringSettings& m) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys(
      {"poses", "pose_file", "max_angle", "design_tension_margin", "design_angle_steps",
       "design_emphasis_weight", "laser_samples", "laser_interval_s", "average_cycles",
       "settle_window_s", "settle_position_tolerance", "settle_tension_tolerance",
       "settle_timeout_s", "tension_band", "extra_pose_rounds", "remeasure_rounds",
       "noise_length_m", "noise_force_n", "noise_laser_m"}));
  CDPR_RETURN_IF_ERROR(n.optional("poses", m.poses, 7, 1000));
  CDPR_RETURN_IF_ERROR(n.optional("pose_file", m.pose_file));
  m.pose_file = resolve(dir, m.pose_file);
  CDPR_RETURN_IF_ERROR(in_range(n, "max_angle", 0.05, 0.7854, "rad", m.max_angle));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "design_tension_margin", 0.0, 1e5, "N", m.design_tension_margin));
  CDPR_RETURN_IF_ERROR(n.optional("design_angle_steps", m.design_angle_steps, 1, 6));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "design_emphasis_weight", 0.0, 100.0, "", m.design_emphasis_weight));
  CDPR_RETURN_IF_ERROR(n.optional("laser_samples", m.laser_samples, 1, 10000));
  CDPR_RETURN_IF_ERROR(in_range(n, "laser_interval_s", -1.0, 10.0, "s", m.laser_interval_s));
  CDPR_RETURN_IF_ERROR(n.optional("average_cycles", m.average_cycles, 1, 100000));
  CDPR_RETURN_IF_ERROR(in_range(n, "settle_window_s", 0.0, 60.0, "s", m.settle_window_s));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "settle_position_tolerance", 0.0, 0.1, "m", m.settle_position_tolerance));
  CDPR_RETURN_IF_ERROR(
      in_range(n, "settle_tension_tolerance", 0.0, 1e5, "N", m.settle_tension_tolerance));
  CDPR_RETURN_IF_ERROR(in_range(n, "settle_timeout_s", 0.01, 3600.0, "s", m.settle_timeout_s));
  CDPR_RETURN_IF_ERROR(in_range(n, "tension_band", 0.0, 1e5, "N", m.tension_band));
  CDPR_RETURN_IF_ERROR(n.optional("extra_pose_rounds", m.extra_pose_rounds, 0, 10));
  CDPR_RETURN_IF_ERROR(n.optional("remeasure_rounds", m.remeasure_rounds, 0, 10));
  CDPR_RETURN_IF_ERROR(in_range(n, "noise_length_m", 1e-12, 1.0, "m", m.noise_length_m));
  CDPR_RETURN_IF_ERROR(in_range(n, "noise_force_n", 1e-9, 1e5, "N", m.noise_force_n));
  return in_range(n, "noise_laser_m", 1e-12, 1.0, "m", m.noise_laser_m);
}

// identification.estimate: the words of cdpr-fit's --estimate (set_estimate, one vocabulary).
Status read_estimate(const YamlField& e, IdentificationOptions& o) {
  if (!e.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(e.expect_list("a list of estimate items, e.g. [anchors, offsets]"));
  if (e.size() == 0) return e.error("estimates nothing: name at least one item");
  std::vector<std::string> words;
  for (std::size_t i = 0; i < e.size(); ++i) {
    CDPR_ASSIGN_OR_RETURN(std::string w, e[i].text());
    // Each word alone first, so that an unknown one is named at its own line.
    IdentificationOptions scratch;
    if (Status s = set_estimate({w}, 0, scratch); !s.ok()) {
      return e[i].error(s.message());
    }
    words.push_back(std::move(w));
  }
  // The cable count is the robot file's: identify() refuses a mask that does not fit it.
  Status s = set_estimate(words, 0, o);
  return s.ok() ? s : e.error(s.message());
}

Status read_identification(const YamlField& n, IdentificationSettings& s) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys({"estimate", "diagnose", "bootstrap", "folds"}));
  CDPR_RETURN_IF_ERROR(read_estimate(n["estimate"], s.options));
  CDPR_RETURN_IF_ERROR(n.optional("diagnose", s.diagnose));
  CDPR_RETURN_IF_ERROR(n.optional("bootstrap", s.bootstrap, 1, 100000));
  CDPR_RETURN_IF_ERROR(n.optional("folds", s.folds, 0, 1000));
  if (s.folds == 1) {
    return n["folds"].error("1 fold holds out nothing: 0 (leave one pose out) or 2..1000");
  }
  return Status::success();
}

Status read_acceptance(const YamlField& n, AcceptanceGates& g) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(
      n.check_keys({"mode", "min_fit_p_value", "max_anchor_change_m",
                    "max_predicted_position_error_m", "allow_unresolved_mismatch"}));
  int mode = g.mode == AcceptanceMode::kAuto ? 1 : 0;
  CDPR_RETURN_IF_ERROR(n.optional_choice("mode", mode, {"manual", "auto"}));
  g.mode = mode == 1 ? AcceptanceMode::kAuto : AcceptanceMode::kManual;
  CDPR_RETURN_IF_ERROR(in_range(n, "min_fit_p_value", 0.0, 1.0, "", g.min_fit_p_value));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_anchor_change_m", 0.0, 10.0, "m", g.max_anchor_change_m));
  CDPR_RETURN_IF_ERROR(in_range(n, "max_predicted_position_error_m", 0.0, 10.0, "m",
                                g.max_predicted_position_error_m));
  return n.optional("allow_unresolved_mismatch", g.allow_unresolved_mismatch);
}

Status read_start(const YamlField& n, StartSettings& st) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys({"enable", "home_without_record", "model_uncertainty_m"}));
  std::string enable = "operator";
  CDPR_RETURN_IF_ERROR(n.optional("enable", enable));
  if (enable != "operator" && enable != "at-start") {
    return n["enable"].error("expected operator or at-start");
  }
  st.enable =
      enable == "operator" ? StartSettings::Enable::kOperator : StartSettings::Enable::kAtStart;
  std::string home = "refuse";
  CDPR_RETURN_IF_ERROR(n.optional("home_without_record", home));
  if (home != "refuse" && home != "reference") {
    return n["home_without_record"].error("expected refuse or reference");
  }
  st.home_without_record = home == "reference";
  return in_range(n, "model_uncertainty_m", 0.0, 0.1, "m", st.model_uncertainty_m);
}

Status read_control(const YamlField& n, const std::string& dir, ControlSettings& c) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys({"socket", "group"}));
  CDPR_RETURN_IF_ERROR(n.optional("socket", c.socket));
  c.socket = resolve(dir, c.socket);
  return n.optional("group", c.group);
}

Status read_report(const YamlField& n, const std::string& dir, ReportSettings& r) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.check_keys({"iso9283_measured"}));
  CDPR_RETURN_IF_ERROR(n.optional("iso9283_measured", r.iso9283_measured));
  r.iso9283_measured = resolve(dir, r.iso9283_measured);
  return Status::success();
}

Result<DaemonConfig> read(const YamlDocument& doc) {
  DaemonConfig c;
  c.file = doc.file();
  const YamlField root = doc.root();
  CDPR_RETURN_IF_ERROR(root.expect_map("a mapping of daemon settings"));
  CDPR_RETURN_IF_ERROR(root.check_keys(
      {"robot", "canopen", "laser", "can_interface", "state_directory", "realtime", "identity",
       "motion", "tension_watch", "tension_control", "measuring", "identification", "acceptance",
       "start", "control", "safety", "monitoring", "report"}));
  const std::string dir = std::filesystem::path(c.file).parent_path().string();
  CDPR_ASSIGN_OR_RETURN(YamlField robot, root.required("robot", "the robot description"));
  CDPR_ASSIGN_OR_RETURN(c.robot, robot.text());
  CDPR_ASSIGN_OR_RETURN(YamlField canopen, root.required("canopen", "the CANopen network"));
  CDPR_ASSIGN_OR_RETURN(c.canopen, canopen.text());
  CDPR_RETURN_IF_ERROR(root.optional("laser", c.laser));
  CDPR_RETURN_IF_ERROR(root.optional("can_interface", c.can_interface));
  CDPR_RETURN_IF_ERROR(root.optional("state_directory", c.state_directory));
  c.robot = resolve(dir, c.robot);
  c.canopen = resolve(dir, c.canopen);
  c.laser = resolve(dir, c.laser);
  c.state_directory = resolve(dir, c.state_directory);
  CDPR_RETURN_IF_ERROR(read_realtime(root["realtime"], c.realtime));
  CDPR_RETURN_IF_ERROR(read_identity(root["identity"], c.identity));
  CDPR_RETURN_IF_ERROR(read_motion(root["motion"], c.motion));
  CDPR_RETURN_IF_ERROR(read_tension_watch(root["tension_watch"], c.tension_watch));
  CDPR_RETURN_IF_ERROR(read_tension_control(root["tension_control"], c.tension_control));
  CDPR_RETURN_IF_ERROR(read_measuring(root["measuring"], dir, c.measuring));
  CDPR_RETURN_IF_ERROR(read_identification(root["identification"], c.identification));
  CDPR_RETURN_IF_ERROR(read_acceptance(root["acceptance"], c.acceptance));
  CDPR_RETURN_IF_ERROR(read_start(root["start"], c.start));
  CDPR_RETURN_IF_ERROR(read_control(root["control"], dir, c.control));
  CDPR_RETURN_IF_ERROR(read_safety_settings(root["safety"], c.safety));
  CDPR_RETURN_IF_ERROR(read_monitoring(root["monitoring"], c.monitoring));
  CDPR_RETURN_IF_ERROR(read_report(root["report"], dir, c.report));
  return c;
}

}  // namespace

Result<DaemonConfig> parse_daemon_config(std::string_view yaml, std::string_view file) {
  CDPR_ASSIGN_OR_RETURN(YamlDocument doc, YamlDocument::parse(yaml, file));
  return read(doc);
}

Result<DaemonConfig> load_daemon_config(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(YamlDocument doc, YamlDocument::load(path, "daemon configuration"));
  return read(doc);
}

}  // namespace cdpr::controller
