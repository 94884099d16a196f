// In-service monitoring in the daemon (docs/monitoring.md): while the robot holds a trusted pose,
// the supervisor's tick feeds one sample per monitoring.period_s to the consistency monitor of the
// active geometry (calibration/monitoring); a detector's first alarm and, after it, a change the
// assessment names (or a predicted position error past the alert) raise `health` events; the
// `health` request shows the assessment. Nothing here moves the robot.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/daemon.hpp"

namespace cdpr::controller {
using json = nlohmann::json;
using control::ControlErrorCode;

namespace {

json vector_json(const Eigen::VectorXd& v) {
  json a = json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back(v(i));
  return a;
}

json health_json(const Monitor& monitor, const MonitorAssessment& a, int version,
                 const HealthCounts& counts, const json& figures) {
  json rows = json::array();
  for (const MonitorRow& r : a.rows) {
    rows.push_back({{"name", r.name},
                    {"statistic", r.statistic},
                    {"threshold", r.threshold},
                    {"mean_sigma", r.mean_sigma},
                    {"alarms", r.alarms}});
  }
  json effects = json::array();
  for (std::size_t k = 0; k < a.effects.size() && k < 3; ++k) {
    const EffectEstimate& e = a.effects[k];
    effects.push_back({{"id", e.id},
                       {"words", e.words},
                       {"cable", e.cable >= 0 ? json(e.cable + 1) : json(nullptr)},
                       {"value", vector_json(e.value)},
                       {"std", vector_json(e.std)},
                       {"significant", e.significant},
                       {"since_s", std::isnan(e.since_s) ? json(nullptr) : json(e.since_s)}});
  }
  const ReidentificationProposal& p = a.proposal;
  const double first = monitor.first_alarm_time_s();
  return {{"enabled", true},
          {"geometry_version", version},
          {"samples", a.samples},
          {"samples_moving", counts.moving},
          {"moving_skipped_following", counts.moving_skipped_following},
          {"laser_samples", counts.laser},
          {"laser_skipped", counts.laser_skipped},
          {"referenced", a.referenced},
          {"reference_consistent", a.reference_consistent},
          {"alarms", monitor.alarms()},
          {"first_alarm_s", std::isnan(first) ? json(nullptr) : json(first)},
          {"rows", rows},
          {"changed", a.changed},
          {"effects", effects},
          {"position_rms_acceptance_m", a.position_rms_acceptance_m},
          {"position_rms_now_m", a.position_rms_now_m},
          {"figures", figures},
          {"proposal",
           {{"needed", p.needed},
            {"full_sequence", p.full_sequence},
            {"parameters", p.parameters},
            {"poses", p.poses.size()},
            {"predicted_position_m", p.predicted_position_m},
            {"stopping_rule", p.stopping_rule}}},
          {"text", describe(a)}};
}

// What a geometry's metadata says the calibration that made it reported for the monitor.
struct Reported {
  bool calibrated = false;  // made by an accepted calibration
  std::string source;       // "calibration <id>"
  json figures;             // its "monitoring" (calibration_report.hpp monitoring_figures)
};

// One figure, {value, source}: the calibration's, else the config's (`missing` collects the keys
// a calibrated geometry lacks).
json monitor_figure(const Reported& r, const char* key, double config_value,
                    const MonitoringSettings& mc, std::vector<std::string>& missing) {
  if (mc.override_calibration) {
    return {{"value", config_value}, {"source", "config (monitoring.override_calibration)"}};
  }
  const json v = r.figures.is_object() ? r.figures.value(key, json(nullptr)) : json(nullptr);
  if (v.is_number() && std::isfinite(v.get<double>()) && v.get<double>() >= 0.0) {
    return {{"value", v.get<double>()}, {"source", r.source}};
  }
  if (r.calibrated) missing.emplace_back(key);
  return {{"value", config_value}, {"source", "config"}};
}

// The monitor's model uncertainty and acceptance figure for geometry `version`, with where each
// came from: the calibration that made it, else the config (the nominal geometry, a state file
// written before the calibration stated them, a figure it could not give); logged.
json monitor_figures(const MonitoringSettings& mc, const Result<json>& meta, int version) {
  Reported r;
  if (meta.ok() && meta->is_object() && meta->value("source", std::string()) == "calibration") {
    r.calibrated = true;
    const json id = meta->value("calibration", json(nullptr));
    r.source = "calibration " + (id.is_number_integer() ? id.dump() : std::string("?"));
    r.figures = meta->value("monitoring", json(nullptr));
  }
  std::vector<std::string> missing;
  json f = {{"model_length_m", monitor_figure(r, "model_length_m", mc.model_length_m, mc, missing)},
            {"model_force_n", monitor_figure(r, "model_force_n", mc.model_force_n, mc, missing)},
            {"acceptance_position_m",
             monitor_figure(r, "predicted_position_rms_m", mc.acceptance_position_m, mc, missing)}};
  if (!missing.empty()) {
    std::string keys;
    for (const std::string& k : missing) keys += (keys.empty() ? "" : ", ") + k;
    spdlog::warn(
        "health: geometry {} ({}) states no {} (a state file from before they were kept, or a "
        "figure the calibration could not give): the config's monitoring values instead",
        version, r.source, keys);
  } else {
    spdlog::info("health: monitoring geometry {} with the model uncertainty of {}", version,
                 f["model_length_m"]["source"].get<std::string>());
  }
  return f;
}

}  // namespace

Status Daemon::restart_monitor(const Geometry& g) {
  const MonitoringSettings& mc = config_.monitoring;
  monitor_figures_ = monitor_figures(mc, store_->geometry_meta(g.version), g.version);
  MonitorOptions o;
  o.noise.sigma_length = config_.measuring.noise_length_m;
  o.noise.sigma_force = config_.measuring.noise_force_n;
  o.noise.sigma_laser = config_.measuring.noise_laser_m;
  o.noise.model_length = monitor_figures_["model_length_m"]["value"].get<double>();
  o.noise.model_force = monitor_figures_["model_force_n"]["value"].get<double>();
  o.acceptance_position_rms_m = monitor_figures_["acceptance_position_m"]["value"].get<double>();
  // The box the calibration predicted its accuracy over (calibration_report.cc).
  o.box.center = g.model.home.position;
  o.reference_s = mc.reference_s;
  o.false_alarms_per_hour = mc.false_alarms_per_hour;
  o.samples_per_hour = 3600.0 / mc.period_s;
  monitor_.reset();
  monitor_version_ = g.version;
  health_counts_ = {};
  health_alerted_ = false;
  health_alarmed_ = false;
  monitor_assess_ns_ = 0;
  Result<Monitor> m = Monitor::create(CalibratedModel::from_robot(g.model), o);
  if (!m.ok()) return m.status();
  monitor_ = std::make_unique<Monitor>(std::move(*m));
  return Status::success();
}

// The commanded platform speed since the previous supervisor tick (m/s; infinity on the first).
double Daemon::health_speed(const RtSnapshot& s) {
  const Pose p = s.pose();
  double speed = std::numeric_limits<double>::infinity();
  if (health_last_ns_ >= 0 && s.now_ns > health_last_ns_) {
    const Eigen::Vector3d last(health_last_position_[0], health_last_position_[1],
                               health_last_position_[2]);
    speed = (p.position - last).norm() / (1e-9 * static_cast<double>(s.now_ns - health_last_ns_));
  }
  health_last_position_ = {p.position.x(), p.position.y(), p.position.z()};
  health_last_ns_ = s.now_ns;
  return speed;
}

// The largest following error of the drives (target vs actual counts) as cable length, m.
double Daemon::following_error_m(const RtSnapshot& s, const RobotModel& model) {
  double worst = 0.0;
  for (int i = 0; i < model.num_cables() && i < s.num_cables; ++i) {
    const auto k = static_cast<std::size_t>(i);
    worst = std::max(worst, std::abs(winch_length_change<double>(
                                model.winches[k], s.target_counts[k] - s.actual_counts[k])));
  }
  return worst;
}

// The laser's newest reading (taken by its own poll thread; CLOCK_MONOTONIC stamps) when it is
// ok, taken after the supervisor saw this hold settled and at most laser_max_age_s old; NaN and
// counted as skipped otherwise. None when the daemon or the geometry has no laser.
double Daemon::health_laser(const Geometry& g) {
  constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
  if (io_.laser == nullptr || g.model.lasers.empty()) return kNone;
  const modbus::LaserReading r = io_.laser->latest();
  const std::int64_t age_ns = modbus::monotonic_ns() - r.stamp_ns;
  const bool fresh = r.ok() && r.sequence > 0 && health_settled_mono_ns_ >= 0 &&
                     r.stamp_ns >= health_settled_mono_ns_ &&
                     static_cast<double>(age_ns) <= config_.monitoring.laser_max_age_s * 1e9 &&
                     std::isfinite(r.distance_m);
  if (!fresh) {
    ++health_counts_.laser_skipped;
    return kNone;
  }
  ++health_counts_.laser;
  return r.distance_m;
}

void Daemon::watch_health(const RtSnapshot& s) {
  const MonitoringSettings& mc = config_.monitoring;
  if (!mc.enabled) return;
  // A settled hold, or a slow (quasi-static) move when move_speed_m_s allows it.
  const DaemonState ds = state();
  const bool holding = ds == DaemonState::kHolding && s.mode == RtMode::kHolding && s.settled &&
                       !worker_running_.load();
  bool moving = false;
  {
    std::lock_guard lock(health_mu_);
    const double speed = health_speed(s);
    moving = mc.move_speed_m_s > 0.0 && ds == DaemonState::kMoving && s.mode == RtMode::kMoving &&
             speed <= mc.move_speed_m_s;
    // The laser's readings count from the first tick that saw this hold settled.
    if (!holding) {
      health_settled_mono_ns_ = -1;
    } else if (health_settled_mono_ns_ < 0) {
      health_settled_mono_ns_ = modbus::monotonic_ns();
    }
  }
  if ((!holding && !moving) || worker_running_.load() || !s.have_tensions) return;
  const Geometry* g = nullptr;
  std::array<double, kMaxAxes> offsets{};
  {
    std::lock_guard lock(mu_);
    if (!trust_.trusted) return;
    g = active_;
    offsets = offsets_;
  }
  if (g == nullptr) return;
  std::lock_guard lock(health_mu_);
  if (g->version != monitor_version_) {
    if (Status st = restart_monitor(*g); !st.ok()) {
      spdlog::warn("health: no monitoring of geometry {}: {}", g->version, st.message());
      return;
    }
    monitor_start_ns_ = s.now_ns;
    monitor_sample_ns_ = s.now_ns - static_cast<std::int64_t>(mc.period_s * 1e9);
  }
  if (!monitor_ || static_cast<double>(s.now_ns - monitor_sample_ns_) < mc.period_s * 1e9) return;
  monitor_sample_ns_ = s.now_ns;
  // A move is quasi-static only while the drives follow their targets closely.
  if (moving && following_error_m(s, g->model) > mc.max_following_m) {
    ++health_counts_.moving_skipped_following;
    return;
  }
  MonitorSample sample;
  sample.time_s = 1e-9 * static_cast<double>(s.now_ns - monitor_start_ns_);
  sample.pose = s.pose();
  Eigen::VectorXd lengths, tensions;
  encoder_lengths(s, g->model, offsets, lengths, tensions);
  for (Eigen::Index i = 0; i < lengths.size() && i < kMonitorMaxCables; ++i) {
    sample.lengths[static_cast<std::size_t>(i)] = lengths(i);
    sample.tensions[static_cast<std::size_t>(i)] = tensions(i);
  }
  // One laser on the platform (DaemonIo): the geometry's first laser model.
  if (holding) sample.lasers[0] = health_laser(*g);
  const int before = monitor_->samples();
  const bool alarm = monitor_->add(sample);
  if (moving && monitor_->samples() > before) ++health_counts_.moving;
  if (alarm && !health_alarmed_) {
    health_alarmed_ = true;
    const std::string row = monitor_->row_name(monitor_->first_alarm_row());
    spdlog::warn("health: the readings left the model of geometry {} ({})", g->version, row);
    publish("health",
            {{"alarm", row}, {"geometry_version", g->version}, {"time_s", sample.time_s}});
  }
  const double since_assessed = 1e-9 * static_cast<double>(s.now_ns - monitor_assess_ns_);
  if (monitor_->alarms() == 0 || health_alerted_ || since_assessed < mc.assess_period_s) return;
  monitor_assess_ns_ = s.now_ns;
  const Result<MonitorAssessment> a = monitor_->assess();
  if (!a.ok()) return;
  if (a->changed || a->position_rms_now_m - a->position_rms_acceptance_m > mc.alert_position_m) {
    health_alerted_ = true;
    const std::string words =
        a->effects.empty() ? std::string("no named change") : a->effects.front().words;
    spdlog::warn(
        "health: {}; predicted position error {:.3f} mm (at acceptance {:.3f} mm): "
        "cdprctl health",
        words, 1e3 * a->position_rms_now_m, 1e3 * a->position_rms_acceptance_m);
    publish("health", health_json(*monitor_, *a, g->version, health_counts_, monitor_figures_));
  }
}

Reply Daemon::cmd_health(const json&, const PeerInfo&) {
  if (!config_.monitoring.enabled) {
    return Reply::success(
        {{"enabled", false},
         {"message", "in-service monitoring is off (monitoring.enabled in the daemon config)"}});
  }
  std::lock_guard lock(health_mu_);
  if (!monitor_ || monitor_->samples() == 0) {
    return Reply::success({{"enabled", true},
                           {"samples", 0},
                           {"figures", monitor_ ? monitor_figures_ : json(nullptr)},
                           {"message",
                            "no sample yet: the monitor samples while the robot holds a trusted "
                            "pose under a geometry"}});
  }
  const Result<MonitorAssessment> a = monitor_->assess();
  if (!a.ok()) {
    return Reply::failure(ControlErrorCode::kInternal,
                          "health: the assessment failed: " + std::string(a.status().message()));
  }
  return Reply::success(
      health_json(*monitor_, *a, monitor_version_, health_counts_, monitor_figures_));
}

}  // namespace cdpr::controller
