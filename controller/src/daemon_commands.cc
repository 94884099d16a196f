// Daemon: the control requests (docs/control-protocol.md), dispatched through the protocol's
// command table (control_protocol.hpp: names, arguments, privileges) to one handler per command,
// and the status they report.
#include <spdlog/spdlog.h>

#include <array>
#include <cmath>
#include <limits>

#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/recording/recording.hpp"
#include "daemon_text.hpp"

namespace cdpr::controller {
using json = nlohmann::json;
using control::Command;
using control::ControlErrorCode;

namespace {

struct CommandHandler {
  Command command;
  Reply (Daemon::*run)(const json& args, const PeerInfo& peer);
};

void write_decision(const std::string& dir, const json& decision) {
  (void)io::write_file_atomically(
      dir + "/decision.json", decision.dump(2, ' ', false, json::error_handler_t::replace) + "\n");
}

}  // namespace

Daemon::Handler Daemon::handler(Command command) {
  // One row per command of the protocol, in its order (checked below at compile time).
  static constexpr std::array<CommandHandler, control::kCommandCount> kHandlers{{
      {Command::kStatus, &Daemon::cmd_status},
      {Command::kCalibrate, &Daemon::cmd_calibrate},
      {Command::kWatch, &Daemon::cmd_watch},
      {Command::kAbort, &Daemon::cmd_abort},
      {Command::kAccept, &Daemon::cmd_accept},
      {Command::kReject, &Daemon::cmd_reject},
      {Command::kGeometryShow, &Daemon::cmd_geometry_show},
      {Command::kGeometryDiff, &Daemon::cmd_geometry_diff},
      {Command::kGeometryHistory, &Daemon::cmd_geometry_history},
      {Command::kGeometryRollback, &Daemon::cmd_rollback},
      {Command::kReport, &Daemon::cmd_report},
      {Command::kStop, &Daemon::cmd_stop},
      {Command::kFaultReset, &Daemon::cmd_fault_reset},
      {Command::kMove, &Daemon::cmd_move},
      {Command::kEnable, &Daemon::cmd_enable},
      {Command::kDisable, &Daemon::cmd_disable},
      {Command::kHome, &Daemon::cmd_home},
      {Command::kRun, &Daemon::cmd_run},
      {Command::kStream, &Daemon::cmd_stream},
      {Command::kHealth, &Daemon::cmd_health},
  }};
  static_assert(
      [] {
        for (std::size_t i = 0; i < kHandlers.size(); ++i) {
          if (kHandlers[i].command != static_cast<Command>(i)) return false;
        }
        return true;
      }(),
      "kHandlers[i] must handle Command(i): one handler per protocol command");
  return kHandlers[static_cast<std::size_t>(command)].run;
}

Reply Daemon::handle(const std::string& cmd, const json& args, const PeerInfo& peer) {
  const control::CommandSpec* spec = control::find_command(cmd);
  if (spec == nullptr) {
    return Reply::failure(ControlErrorCode::kUnknownCommand, "unknown command '" + cmd + "'");
  }
  // (the server checked them already; an in-process caller gets the same answer)
  if (Status s = control::validate_args(*spec, args); !s.ok()) {
    return Reply::failure(ControlErrorCode::kBadRequest, std::string(s.message()));
  }
  try {
    return (this->*handler(spec->command))(args, peer);
  } catch (const std::exception& e) {
    return Reply::failure(ControlErrorCode::kInternal, std::string("internal error: ") + e.what());
  }
}

json Daemon::status() const {
  const RtSnapshot s = rt_->snapshot();
  std::lock_guard lock(mu_);
  const DaemonState st = supervisor_.state();
  json j;
  j["state"] = to_string(st);
  j["reason"] = state_reason_;
  j["daemon_version"] = kDaemonVersion;
  j["geometry_version"] = active_version_;
  j["fault"] = st == DaemonState::kFault
                   ? json{{"fault", to_string(last_fault_.kind)},
                          {"node", last_fault_.node},
                          {"cable", last_fault_.cable + 1},
                          {"message", fault_text_.empty() ? state_reason_ : fault_text_}}
                   : json(nullptr);
  const int m = s.num_cables;
  json tensions = json::array(), targets = json::array(), actual = json::array();
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    tensions.push_back(s.tensions[k]);
    targets.push_back(s.target_counts[k]);
    actual.push_back(s.actual_counts[k]);
  }
  j["rt"] = {
      {"mode", to_string(s.mode)},
      {"cycle", s.cycle},
      {"settled", s.settled},
      {"commanded_pose", detail::pose_json(s.pose())},
      {"tensions_n", s.have_tensions ? tensions : json(nullptr)},
      {"target_counts", targets},
      {"actual_counts", actual},
      {"largest_reference_step_counts", s.largest_reference_step},
      {"largest_move_step_counts", s.largest_move_step},
      // The safety chain: e-stop sources read open (bit j: source j + 1), brakes, disabled.
      {"estop_open", s.safety_open},
      {"brakes_released", s.brakes_released},
      {"disabled", s.disabled},
      // One cycle of the fastest normal cable motion (max_cable_speed), the bound a
      // re-reference step must stay under.
      {"one_cycle_motion_counts", config_.motion.max_cable_speed *
                                      std::chrono::duration<double>(network_.sync_period).count() /
                                      winch_metres_per_count(active_->model.winches[0])}};
  const TensionControlStatus& tc = s.tension_control;
  json trims = json::array();
  for (int i = 0; i < s.num_cables; ++i) {
    trims.push_back(tc.trim_counts[static_cast<std::size_t>(i)]);
  }
  // The null-space tension control: off, active, frozen or decaying (stale or faulty readings).
  j["rt"]["tension_control"] = {{"state", to_string(tc.state)},
                                {"in_band", tc.in_band},
                                {"saturated", tc.saturated},
                                {"largest_error_n", tc.largest_error},
                                {"trim_counts", trims}};
  j["warning"] = warning_.empty() ? json(nullptr) : json(warning_);
  j["drives"] = {{"enabled", s.all_enabled}};
  j["pose"] = {{"trusted", trust_.trusted},
               {"source", trust_.trusted ? json(trust_.source) : json(nullptr)},
               {"reason", trust_.trusted ? json(nullptr) : json(trust_.reason)}};
  j["homing"] = record_ ? json{{"method", record_->method},
                               {"time", record_->time},
                               {"geometry_version", record_->geometry_version}}
                        : json(nullptr);
  j["loop"] = loop_figures_;
  if (calibration_) {
    j["calibration"] = {{"id", calibration_->id},
                        {"outcome", to_string(calibration_->outcome)},
                        {"pose", calibration_->pose},
                        {"poses", calibration_->poses},
                        {"elapsed_s", calibration_->elapsed_s},
                        {"remaining_s", calibration_->remaining_s},
                        {"gates_passed", calibration_->gates_passed},
                        {"message", calibration_->message}};
  } else {
    j["calibration"] = nullptr;
  }
  motion_status(s, j);
  if (io_.laser != nullptr) {
    const modbus::LaserReading l = io_.laser->latest();
    j["laser_m"] = l.ok() ? json(l.distance_m) : json(nullptr);
  }
  return j;
}

Reply Daemon::cmd_status(const json&, const PeerInfo&) {
  return Reply::success(status());
}

Reply Daemon::cmd_watch(const json&, const PeerInfo&) {
  return Reply::success({{"watching", true}});
}

Reply Daemon::cmd_calibrate(const json& args, const PeerInfo& peer) {
  const bool dry_run = args.value("dry_run", false);
  const std::string csv = args.value("poses_csv", std::string());
  const DaemonState st = state();
  if (st == DaemonState::kFault) {
    return Reply::failure(ControlErrorCode::kFault, "the robot is in fault (" +
                                                        status()["reason"].get<std::string>() +
                                                        "): run fault-reset first");
  }
  if (const std::string why = motion_refusal(); !dry_run && !why.empty()) {
    return Reply::failure(ControlErrorCode::kInvalidState, "calibrate: " + why);
  }
  if (!dry_run && (st != DaemonState::kHolding || worker_running_.load())) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string("a calibration starts only while holding; the daemon is ") + to_string(st));
  }
  if (io_.laser == nullptr && !dry_run) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        "no laser is configured (" + config_.file + ": laser): the calibration needs it");
  }
  auto poses = plan_poses(csv);
  if (!poses.ok()) return Reply::failure(ControlErrorCode::kBadRequest, poses.status().to_string());
  if (dry_run) {
    json list = json::array();
    for (const Pose& p : *poses) list.push_back(detail::pose_json(p));
    return Reply::success({{"dry_run", true}, {"poses", list}, {"feasible", true}});
  }
  auto id = store_->new_calibration();
  if (!id.ok()) return Reply::failure(ControlErrorCode::kInternal, id.status().to_string());
  if (worker_.joinable()) worker_.join();
  const int count = static_cast<int>(poses->size());
  {
    std::lock_guard lock(mu_);
    calibration_ = Calibration{};
    calibration_->id = *id;
    calibration_->outcome = CalibrationRunOutcome::kMeasuring;
    calibration_->poses = count;
    calibration_->started_s = now_s();
  }
  abort_ = false;
  worker_running_ = true;
  spdlog::info("calibrate: calibration {} with {} poses requested by pid {} uid {} gid {}", *id,
               count, peer.pid, peer.uid, peer.gid);
  worker_ = std::thread(
      [this, p = std::move(*poses), peer]() mutable { run_calibration(std::move(p), peer); });
  return Reply::success({{"calibration", *id}, {"poses", count}});
}

Reply Daemon::cmd_abort(const json&, const PeerInfo& peer) {
  if (!worker_running_.load()) return abort_motion(peer);
  spdlog::info("abort requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
  abort_ = true;
  return Reply::success({{"aborting", true}});
}

Reply Daemon::cmd_accept(const json&, const PeerInfo& peer) {
  std::shared_ptr<const RobotModel> proposed;
  int id = 0;
  int parent = 0;
  json monitoring;  // what the monitor takes from the calibration (monitoring_figures)
  {
    std::lock_guard lock(mu_);
    const DaemonState st = supervisor_.state();
    if (st != DaemonState::kAwaitingAcceptance || !calibration_ || !calibration_->proposed) {
      return Reply::failure(ControlErrorCode::kInvalidState,
                            std::string("nothing awaits acceptance (state ") + to_string(st) + ")");
    }
    proposed = calibration_->proposed;
    id = calibration_->id;
    parent = active_version_;
    monitoring = calibration_->summary.value("monitoring", json(nullptr));
  }
  auto version = store_->add_geometry(*proposed, {{"source", "calibration"},
                                                  {"calibration", id},
                                                  {"parent", parent},
                                                  {"monitoring", monitoring}});
  if (!version.ok()) {
    return Reply::failure(ControlErrorCode::kInternal, version.status().to_string());
  }
  write_decision(store_->calibration_dir(id), {{"decision", "accepted"},
                                               {"version", *version},
                                               {"peer", detail::peer_json(peer)},
                                               {"time", recording::utc_timestamp()}});
  {
    std::lock_guard lock(mu_);
    calibration_->outcome = CalibrationRunOutcome::kApplying;
  }
  spdlog::info("accept: calibration {} as geometry version {} (pid {} uid {} gid {})", id, *version,
               peer.pid, peer.uid, peer.gid);
  if (Status s = activate(
          *version,
          {{"why", "calibration " + std::to_string(id) + " accepted"}, {"calibration", id}}, &peer);
      !s.ok()) {
    transition(SupervisorEvent::kApplyFailed, "accept failed: " + s.to_string());
    return Reply::failure(ControlErrorCode::kInternal, s.to_string());
  }
  return Reply::success({{"calibration", id}, {"version", *version}});
}

Reply Daemon::cmd_reject(const json&, const PeerInfo& peer) {
  int id = 0;
  int active = 0;
  {
    std::lock_guard lock(mu_);
    const DaemonState st = supervisor_.state();
    if (st != DaemonState::kAwaitingAcceptance || !calibration_) {
      return Reply::failure(ControlErrorCode::kInvalidState,
                            std::string("nothing awaits acceptance (state ") + to_string(st) + ")");
    }
    id = calibration_->id;
    calibration_->outcome = CalibrationRunOutcome::kRejected;
    calibration_->proposed.reset();
    active = active_version_;
  }
  write_decision(store_->calibration_dir(id), {{"decision", "rejected"},
                                               {"peer", detail::peer_json(peer)},
                                               {"time", recording::utc_timestamp()}});
  spdlog::info("reject: calibration {} (pid {} uid {} gid {})", id, peer.pid, peer.uid, peer.gid);
  publish("calibration", {{"calibration", id},
                          {"version", nullptr},
                          {"outcome", to_string(CalibrationRunOutcome::kRejected)},
                          {"gates_passed", false},
                          {"message", "rejected by the operator"}});
  transition(SupervisorEvent::kRejected, "calibration " + std::to_string(id) +
                                             " rejected; geometry version " +
                                             std::to_string(active) + " stays active");
  return Reply::success({{"calibration", id}, {"version", active}});
}

Reply Daemon::cmd_rollback(const json& args, const PeerInfo& peer) {
  const int version = args["version"].get<int>();
  if (state() != DaemonState::kHolding || worker_running_.load()) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string("rollback only while holding (state ") + to_string(state()) + ")");
  }
  if (const std::string why = motion_refusal(); !why.empty()) {
    return Reply::failure(ControlErrorCode::kInvalidState, "rollback: " + why);
  }
  if (!store_->load_geometry(version).ok()) {
    return Reply::failure(ControlErrorCode::kNotFound,
                          "geometry version " + std::to_string(version) + " does not exist");
  }
  spdlog::info("rollback to geometry version {} (pid {} uid {} gid {})", version, peer.pid,
               peer.uid, peer.gid);
  if (Status s =
          activate(version, {{"why", "rollback to version " + std::to_string(version)}}, &peer);
      !s.ok()) {
    return Reply::failure(ControlErrorCode::kInternal, s.to_string());
  }
  return Reply::success({{"version", version}});
}

Reply Daemon::cmd_geometry_show(const json& args, const PeerInfo&) {
  const int active = active_version();
  const int version = args.contains("version") ? args["version"].get<int>() : active;
  auto model = store_->load_geometry(version);
  if (!model.ok()) return Reply::failure(ControlErrorCode::kNotFound, model.status().to_string());
  json meta = store_->geometry_meta(version).ok() ? *store_->geometry_meta(version) : json(nullptr);
  return Reply::success({{"version", version},
                         {"active", version == active},
                         {"robot", model->name},
                         {"frame_anchors_m", detail::anchors_json(*model)},
                         {"meta", meta}});
}

Reply Daemon::cmd_geometry_diff(const json& args, const PeerInfo&) {
  const int a = args["from"].get<int>(), b = args["to"].get<int>();
  auto ma = store_->load_geometry(a);
  if (!ma.ok()) return Reply::failure(ControlErrorCode::kNotFound, ma.status().to_string());
  auto mb = store_->load_geometry(b);
  if (!mb.ok()) return Reply::failure(ControlErrorCode::kNotFound, mb.status().to_string());
  json cables = json::array();
  double largest = 0.0;
  for (std::size_t i = 0; i < ma->cables.size() && i < mb->cables.size(); ++i) {
    const Eigen::Index c = static_cast<Eigen::Index>(i);
    const Eigen::Vector3d d = mb->frame_anchors.col(c) - ma->frame_anchors.col(c);
    largest = std::max(largest, d.norm());
    cables.push_back({{"cable", i + 1},
                      {"delta_m", json::array({d.x(), d.y(), d.z()})},
                      {"distance_m", d.norm()}});
  }
  return Reply::success(
      {{"from", a}, {"to", b}, {"frame_anchors", cables}, {"largest_change_m", largest}});
}

Reply Daemon::cmd_geometry_history(const json&, const PeerInfo&) {
  json versions = json::array();
  for (int v : store_->geometry_versions()) {
    auto meta = store_->geometry_meta(v);
    versions.push_back(meta.ok() ? *meta : json{{"version", v}});
  }
  auto h = store_->history();
  json act = json::array();
  if (h.ok()) {
    for (auto& e : *h) act.push_back(e);
  }
  return Reply::success(
      {{"active", active_version()}, {"versions", versions}, {"activations", act}});
}

Reply Daemon::cmd_report(const json& args, const PeerInfo&) {
  std::vector<int> ids = store_->calibrations();
  int id = ids.empty() ? 0 : ids.back();
  if (args.contains("version")) id = args["version"].get<int>();
  const std::string dir = store_->calibration_dir(id);
  auto text = read_text_file(dir + "/report.json");
  if (id == 0 || !text.ok()) {
    return Reply::failure(ControlErrorCode::kNotFound,
                          "no report for calibration " + std::to_string(id));
  }
  json report = json::parse(*text, nullptr, false);
  if (report.is_discarded()) {
    return Reply::failure(ControlErrorCode::kInternal, dir + "/report.json is not JSON");
  }
  json result = {{"calibration", id}, {"report", report}};
  if (args.value("html", false)) {
    auto html = read_text_file(dir + "/report.html");
    if (!html.ok()) return Reply::failure(ControlErrorCode::kNotFound, html.status().to_string());
    result["html"] = *html;
  }
  return Reply::success(result);
}

Reply Daemon::cmd_stop(const json&, const PeerInfo& peer) {
  spdlog::warn("quick stop requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
  rt_->request_quick_stop();
  abort_ = true;
  return Reply::success({{"stopping", true}});
}

Reply Daemon::cmd_fault_reset(const json&, const PeerInfo& peer) {
  if (state() != DaemonState::kFault) {
    return Reply::failure(ControlErrorCode::kInvalidState, "no fault to reset");
  }
  std::string nodes;
  {
    std::lock_guard lock(mu_);
    for (int n : rebooted_nodes_) nodes += (nodes.empty() ? "" : ", ") + std::to_string(n);
  }
  if (!nodes.empty()) {
    spdlog::warn("fault reset refused: node(s) {} rebooted while the daemon ran", nodes);
    return Reply::failure(
        ControlErrorCode::kFault,
        "node(s) " + nodes + " rebooted and lost their configuration: restart cdprd");
  }
  if (const std::uint32_t open = rt_->snapshot().safety_open; open != 0) {
    const std::string which = estop_sources(open);
    spdlog::warn("fault reset refused: e-stop input open: {}", which);
    return Reply::failure(ControlErrorCode::kFault,
                          "e-stop input open, silent or stale: " + which + ": close it first");
  }
  spdlog::info("fault reset requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
  if (worker_.joinable() && !worker_running_.load()) worker_.join();
  rt_->request_fault_reset();
  return Reply::success({{"resetting", true}});
}

Reply Daemon::cmd_move(const json& args, const PeerInfo& peer) {
  Eigen::Matrix<double, 6, 1> v;
  for (int i = 0; i < 6; ++i) v(i) = args["pose"][static_cast<std::size_t>(i)].get<double>();
  const DaemonState st = state();
  if (st == DaemonState::kFault) {
    return Reply::failure(ControlErrorCode::kFault, "the robot is in fault");
  }
  if (const std::string why = motion_refusal(); !why.empty()) {
    return Reply::failure(ControlErrorCode::kInvalidState, "move: " + why);
  }
  if (st != DaemonState::kHolding || worker_running_.load() ||
      rt_->snapshot().mode != RtMode::kHolding) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string("a move starts only while holding (state ") + to_string(st) + ")");
  }
  const Pose pose = Pose::from_vector(v);
  auto seq = start_move(pose, std::numeric_limits<double>::quiet_NaN());
  if (!seq.ok()) return Reply::failure(ControlErrorCode::kBadRequest, seq.status().to_string());
  spdlog::info("move to ({:.4f}, {:.4f}, {:.4f}) m requested by pid {} uid {} gid {}",
               pose.position.x(), pose.position.y(), pose.position.z(), peer.pid, peer.uid,
               peer.gid);
  transition(SupervisorEvent::kMoveRequested, "move requested");
  return Reply::success({{"move", *seq}});
}

}  // namespace cdpr::controller
