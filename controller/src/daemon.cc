#include "cdpr/controller/daemon.hpp"

#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <thread>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/forward_kinematics.hpp"
#include "cdpr/calibration/mismatch.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/calibration_report.hpp"
#include "cdpr/controller/path_check.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/report/report.hpp"

namespace cdpr::controller {
namespace fs = std::filesystem;
using json = nlohmann::json;

const char* to_string(DaemonState s) {
  switch (s) {
    case DaemonState::kStarting:
      return "starting";
    case DaemonState::kHolding:
      return "holding";
    case DaemonState::kMoving:
      return "moving";
    case DaemonState::kMeasuring:
      return "measuring";
    case DaemonState::kIdentifying:
      return "identifying";
    case DaemonState::kAwaitingAcceptance:
      return "awaiting_acceptance";
    case DaemonState::kApplying:
      return "applying";
    case DaemonState::kFault:
      return "fault";
    case DaemonState::kStopped:
      return "stopped";
  }
  return "?";
}

namespace {

json pose_json(const Pose& p) {
  return json::array(
      {p.position.x(), p.position.y(), p.position.z(), p.rpy.x(), p.rpy.y(), p.rpy.z()});
}

json anchors_json(const RobotModel& m) {
  json a = json::array();
  for (Eigen::Index i = 0; i < m.frame_anchors.cols(); ++i) {
    const Eigen::Vector3d c = m.frame_anchors.col(i);
    a.push_back(json::array({c.x(), c.y(), c.z()}));
  }
  return a;
}

std::string fault_text(const RtFault& f) {
  std::string s = to_string(f.kind);
  if (f.node > 0) s += " at node " + std::to_string(f.node);
  if (f.cable >= 0) s += " on cable " + std::to_string(f.cable + 1);
  if (f.code != 0) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "0x%04X", f.code);
    s += std::string(" (EMCY ") + buf + ")";
  }
  if (f.kind == FaultKind::kSlackCable || f.kind == FaultKind::kOverload) {
    char buf[32];
    std::snprintf(buf, sizeof buf, " at %.1f N", f.value);
    s += buf;
  }
  if (f.kind == FaultKind::kForceStuck) {
    char buf[96];
    std::snprintf(buf, sizeof buf,
                  " (reading unchanged at %.1f N while the tension was made to change)", f.value);
    s += buf;
  }
  return s;
}

// A recording's text is its header block (metadata + column names) and its rows; the daemon
// writes the header once and then one row per measured pose.
std::pair<std::string, std::string> split_header(const std::string& text) {
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t end = text.find('\n', pos);
    const std::size_t next = end == std::string::npos ? text.size() : end + 1;
    if (text[pos] != '#') {  // the header line: everything after it is rows
      return {text.substr(0, next), text.substr(next)};
    }
    pos = next;
  }
  return {text, {}};
}

}  // namespace

Daemon::Daemon(DaemonConfig config, DaemonIo io) : config_(std::move(config)), io_(std::move(io)) {}

Daemon::~Daemon() {
  shutdown();
}

Result<std::unique_ptr<Daemon>> Daemon::create(DaemonConfig config, DaemonIo io) {
  if (io.bus == nullptr || io.clock == nullptr) {
    return Status(ErrorCode::kInvalidArgument, "daemon I/O: a CAN bus and a clock are required");
  }
  std::unique_ptr<Daemon> d(new Daemon(std::move(config), std::move(io)));
  auto robot = config::load_robot_config(d->config_.robot);
  if (!robot.ok()) return robot.status();
  d->nominal_ = std::move(*robot);
  auto network = canopen::load_config(d->config_.canopen);
  if (!network.ok()) return network.status();
  d->network_ = std::move(*network);
  if (!d->config_.can_interface.empty()) d->network_.interface = d->config_.can_interface;
  if (d->config_.realtime.sync_period.count() > 0) {
    d->network_.sync_period = d->config_.realtime.sync_period;
  }
  if (Status s = d->load_state(); !s.ok()) return s;

  canopen::MasterHooks hooks;
  const cdpr::Clock* clock = d->io_.clock;
  hooks.now = [clock] { return clock->now(); };
  hooks.idle = d->io_.idle;
  auto master = canopen::Master::create(*d->io_.bus, d->network_, hooks);
  if (!master.ok()) return master.status();
  d->master_ = std::move(*master);

  RtControllerOptions ro;
  const double cycle_s = std::chrono::duration<double>(d->network_.sync_period).count();
  const MeasuringSettings& ms = d->config_.measuring;
  ro.cycle_s = cycle_s;
  ro.slack_below = d->config_.tension_watch.slack_below;
  ro.overload_above = d->config_.tension_watch.overload_above;
  ro.watch_cycles = d->config_.tension_watch.cycles;
  ro.stuck_raw_units = d->config_.tension_watch.stuck_raw_units;
  ro.stuck_confirm_cycles = std::clamp(
      static_cast<int>(std::ceil(d->config_.tension_watch.stuck_confirm_s / cycle_s)), 1, 100000);
  ro.settle_cycles = std::clamp(static_cast<int>(std::ceil(ms.settle_window_s / cycle_s)), 2, 512);
  ro.settle_counts =
      ms.settle_position_tolerance / winch_metres_per_count(d->active_->model.winches[0]);
  ro.settle_tension = ms.settle_tension_tolerance;
  ro.slew_velocity = d->config_.motion.max_cable_speed;
  ro.slew_acceleration = d->config_.motion.max_cable_acceleration;
  auto rt = RtController::create(*d->master_, *d->active_, ro);
  if (!rt.ok()) return rt.status();
  d->rt_ = std::move(*rt);
  return d;
}

const Geometry* Daemon::make_geometry(int version, const RobotModel& model) {
  auto g = std::make_unique<Geometry>();
  g->version = version;
  g->model = model;
  g->reference_tension = default_reference_tension(model);
  geometries_.push_back(std::move(g));
  return geometries_.back().get();
}

Status Daemon::load_state() {
  auto store = StateStore::open(config_.state_directory);
  if (!store.ok()) return store.status();
  store_ = std::make_unique<StateStore>(std::move(*store));
  // A crash or a power loss between a write and its rename left its temporary file: never read,
  // removed here (logged) before anything is written.
  auto temps = store_->remove_leftover_temporaries();
  if (!temps.ok()) return temps.status();
  for (const std::string& t : *temps) {
    spdlog::warn(
        "state directory: leftover temporary file {} removed (a write interrupted before "
        "its rename)",
        t);
  }
  auto active = store_->active_version();
  if (!active.ok() && active.status().code() != ErrorCode::kNotFound) return active.status();
  if (!active.ok() && store_->geometry_versions().empty()) {
    // First start: the nominal robot description becomes version 1.
    auto v = store_->add_geometry(nominal_, {{"source", "nominal"}, {"file", config_.robot}});
    if (!v.ok()) return v.status();
    if (Status s = store_->activate(*v, {{"why", "first start: nominal geometry"}}); !s.ok()) {
      return s;
    }
    active = *v;
  } else if (!active.ok() && store_->geometry_versions() == std::vector<int>{1} &&
             store_->geometry_meta(1).ok() &&
             store_->geometry_meta(1)->value("source", std::string()) == "nominal") {
    // A first start killed between writing version 1 and activating it: finish it.
    spdlog::warn(
        "state directory: version 1 (the nominal geometry) exists but was never made "
        "active (a first start interrupted); activating it");
    if (Status s = store_->activate(1, {{"why",
                                         "first start: nominal geometry (completed after "
                                         "an interrupted first start)"}});
        !s.ok()) {
      return s;
    }
    active = 1;
  } else if (!active.ok()) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "%s: geometry versions exist but none is active (file 'active' missing);"
                         " restore it or remove the folder to start from the nominal geometry",
                         config_.state_directory.c_str());
  }
  auto model = store_->load_geometry(*active);
  if (!model.ok()) return model.status();
  if (model->num_cables() != nominal_.num_cables()) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "active geometry version %d has %d cables, %s has %d", *active,
                         model->num_cables(), config_.robot.c_str(), nominal_.num_cables());
  }
  active_version_ = *active;
  active_ = make_geometry(*active, *model);
  repair_recordings();
  return Status::success();
}

void Daemon::repair_recordings() {
  // Rows are appended whole with an fsync each; only a power loss in the middle of an append
  // leaves part of a row, without its newline, at the end. It is cut off, so the recording reads
  // back with every row measured before.
  for (int id : store_->calibrations()) {
    const std::string path = store_->calibration_dir(id) + "/recording.csv";
    auto text = read_text_file(path);
    if (!text.ok() || text->empty() || text->back() == '\n') continue;
    const std::size_t keep = text->rfind('\n') + 1;  // npos + 1 == 0: nothing whole
    std::error_code ec;
    fs::resize_file(path, keep, ec);
    if (ec) {
      spdlog::error("{}: torn last row ({} bytes) could not be cut off: {}", path,
                    text->size() - keep, ec.message());
    } else {
      spdlog::warn("{}: torn last row ({} bytes, a power loss while it was written) cut off", path,
                   text->size() - keep);
    }
  }
}

void Daemon::set_state(DaemonState s, const std::string& reason) {
  {
    std::lock_guard lock(mu_);
    if (state_ == s && state_reason_ == reason) return;
    state_ = s;
    state_reason_ = reason;
  }
  spdlog::info("state {}: {}", to_string(s), reason);
  publish("state", {{"state", to_string(s)}, {"reason", reason}});
}

void Daemon::publish(const std::string& event, json data) {
  std::function<void(const json&)> sink;
  {
    std::lock_guard lock(mu_);
    sink = sink_;
  }
  if (sink) sink(json{{"event", event}, {"data", std::move(data)}});
}

void Daemon::set_event_sink(std::function<void(const json&)> sink) {
  std::lock_guard lock(mu_);
  sink_ = std::move(sink);
}

double Daemon::now_s() const {
  return std::chrono::duration<double>(io_.clock->now()).count();
}

DaemonState Daemon::state() const {
  std::lock_guard lock(mu_);
  return state_;
}

void Daemon::set_loop_figures(json figures) {
  std::lock_guard lock(mu_);
  loop_figures_ = std::move(figures);
}

Status Daemon::check_identities() {
  const IdentitySettings& want = config_.identity;
  for (const canopen::NodeConfig& n : network_.nodes) {
    canopen::SdoClient* sdo = master_->sdo(n.id);
    if (sdo == nullptr) continue;
    auto vendor = sdo->read<std::uint32_t>({0x1018, 1}, master_->pump());
    if (!vendor.ok()) {
      Status s = vendor.status();
      return s.prepend("identity of node " + std::to_string(n.id) + " (" + n.name + "): ");
    }
    auto product = sdo->read<std::uint32_t>({0x1018, 2}, master_->pump());
    if (!product.ok()) {
      Status s = product.status();
      return s.prepend("identity of node " + std::to_string(n.id) + " (" + n.name + "): ");
    }
    std::uint32_t expected_product = 0;
    if (n.kind == canopen::NodeKind::kCia402Drive) expected_product = want.drive_product_code;
    if (n.kind == canopen::NodeKind::kForceSensor) expected_product = want.force_product_code;
    if (want.vendor_id != 0 && *vendor != want.vendor_id) {
      return Status::error(ErrorCode::kFailedPrecondition,
                           "node %d (%s): vendor id 0x%08X, the config (%s, identity.vendor_id) "
                           "expects 0x%08X",
                           int{n.id}, n.name.c_str(), *vendor, config_.file.c_str(),
                           want.vendor_id);
    }
    if (expected_product != 0 && *product != expected_product) {
      return Status::error(ErrorCode::kFailedPrecondition,
                           "node %d (%s): product code 0x%08X, the config (%s) expects 0x%08X",
                           int{n.id}, n.name.c_str(), *product, config_.file.c_str(),
                           expected_product);
    }
    spdlog::info("node {} ({}): vendor 0x{:08X}, product 0x{:08X}", int{n.id}, n.name, *vendor,
                 *product);
  }
  return Status::success();
}

Result<Pose> Daemon::pose_from_encoders(const RobotModel& model) {
  const RtSnapshot snap = rt_->snapshot();
  const int m = model.num_cables();
  Eigen::VectorXd lengths(m), tensions(m);
  const auto& offsets = rt_->encoder_offsets();
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double counts = snap.cycle > 0
                              ? snap.actual_counts[k]
                              : static_cast<double>(master_->drives()[k].actual_counts());
    lengths(i) = winch_counts_to_length<double>(model.winches[k], counts - offsets[k]);
    double f = snap.cycle > 0 ? snap.tensions[k] : 0.0;
    if (snap.cycle == 0 && !master_->force_sensors().empty()) {
      f = master_->force_sensors()[0].tension(k);
    }
    tensions(i) = std::max(f, 0.0);
  }
  ForwardKinematicsOptions options;
  options.initial_pose = snap.cycle > 0 ? snap.pose() : model.home;
  // Another geometry (hot swap, rollback) may not reach the encoders' lengths exactly: the
  // least-squares pose is wanted, and the RT loop slews the remainder.
  options.max_residual = 0.05;
  ForwardKinematicsData data(model);
  const ForwardKinematicsSummary fk =
      forward_kinematics_elastic(model, lengths, tensions, options, data);
  if (!fk.success()) {
    Status s = fk.status;
    return s.prepend("pose from the encoders: ");
  }
  return fk.pose;
}

Status Daemon::home() {
  const int m = nominal_.num_cables();
  std::array<double, kMaxAxes> offsets{};
  auto stored = store_->load_offsets();
  Pose pose = active_->model.home;
  if (stored.ok() && static_cast<int>(stored->size()) == m) {
    for (int i = 0; i < m; ++i)
      offsets[static_cast<std::size_t>(i)] = (*stored)[static_cast<std::size_t>(i)];
    rt_->set_encoder_offsets(offsets);
    auto p = pose_from_encoders(active_->model);
    if (!p.ok()) return p.status();
    pose = *p;
    spdlog::info(
        "homing: stored encoder offsets; pose from the encoders ({:.4f}, {:.4f}, {:.4f}) m",
        pose.position.x(), pose.position.y(), pose.position.z());
  } else {
    // The platform stands on the reference platform at home: the encoders read the active
    // model's commands there.
    CommandData data(active_->model);
    if (Status s = command_counts(active_->model, pose, active_->reference_tension, data);
        !s.ok()) {
      return s.prepend("homing at the home pose: ");
    }
    std::vector<double> list;
    for (int i = 0; i < m; ++i) {
      const auto k = static_cast<std::size_t>(i);
      offsets[k] = static_cast<double>(master_->drives()[k].actual_counts()) - data.cable.counts(i);
      list.push_back(offsets[k]);
    }
    rt_->set_encoder_offsets(offsets);
    if (Status s = store_->save_offsets(list, "reference platform at home"); !s.ok()) return s;
    spdlog::info("homing: platform on the reference platform at home; encoder offsets stored");
  }
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kReference;
  c->pose = pose;
  c->from_actual = true;
  post(std::move(c));
  return Status::success();
}

Status Daemon::start() {
  set_state(DaemonState::kStarting, "booting the CANopen network on " + network_.interface);
  if (Status s = master_->boot(); !s.ok()) {
    set_state(DaemonState::kFault, "start-up: " + s.to_string());
    return s;
  }
  if (Status s = check_identities(); !s.ok()) {
    set_state(DaemonState::kFault, "start-up: " + s.to_string());
    return s;
  }
  Status enabled = master_->enable_all(std::chrono::seconds(10));
  bool any_fault = false;
  for (const canopen::Drive& d : master_->drives()) {
    any_fault = any_fault || d.state() == canopen::cia402::State::kFault;
  }
  if (!enabled.ok() && any_fault) {
    // A fault latched from before the start (a quick stop, a power dip) is reset once; a drive
    // that faults again makes the start-up fail.
    spdlog::warn("start-up: {}; resetting the drive faults once", enabled.to_string());
    master_->clear_fault();
    for (canopen::Drive& d : master_->drives()) d.reset_fault();
    enabled = master_->enable_all(std::chrono::seconds(10));
    if (enabled.ok()) {
      // What the first attempt reported is logged here, not latched by the RT loop.
      canopen::Event e;
      while (master_->events().pop(e)) {
        spdlog::warn("start-up: node {}: {} (before the fault reset)", int{e.node},
                     canopen::to_string(e.type));
      }
    }
  }
  if (!enabled.ok()) {
    set_state(DaemonState::kFault, "start-up: " + enabled.to_string());
    return enabled;
  }
  if (Status s = home(); !s.ok()) {
    set_state(DaemonState::kFault, "start-up: " + s.to_string());
    return s;
  }
  running_since_ = io_.clock->now();  // boot-ups after this are reboots
  set_state(DaemonState::kHolding,
            "started with geometry version " + std::to_string(active_version_));
  return Status::success();
}

std::uint64_t Daemon::post(std::unique_ptr<MotionCommand> c) {
  std::lock_guard lock(mu_);
  c->seq = next_seq_++;
  MotionCommand* raw = c.get();
  commands_.push_back(std::move(c));
  rt_->post(raw);  // a replaced, never-taken command is reclaimed with the older ones
  return raw->seq;
}

void Daemon::reclaim() {
  std::lock_guard lock(mu_);
  const std::uint64_t in_use = rt_->command_in_use();
  while (commands_.size() > 1 && commands_.front()->seq < in_use) commands_.pop_front();
}

Status Daemon::wait_rt(const std::function<bool(const RtSnapshot&)>& done, double timeout_s,
                       const char* what, bool abortable) {
  const double t0 = now_s();
  const auto wall_end = std::chrono::steady_clock::now() +
                        std::chrono::duration<double>(std::max(60.0, 4.0 * timeout_s));
  for (;;) {
    const RtSnapshot s = rt_->snapshot();
    if (s.fault.kind != FaultKind::kNone) {
      return Status::error(ErrorCode::kAborted, "%s: robot fault: %s", what,
                           fault_text(s.fault).c_str());
    }
    if (abortable && abort_.load()) {
      return Status::error(ErrorCode::kAborted, "%s: aborted by the operator", what);
    }
    if (done(s)) return Status::success();
    if (now_s() - t0 > timeout_s || std::chrono::steady_clock::now() > wall_end) {
      return Status::error(ErrorCode::kTimeout, "%s: not done within %.1f s", what, timeout_s);
    }
    std::this_thread::sleep_for(io_.poll);
  }
}

Result<std::uint64_t> Daemon::start_move(const Pose& pose, double reference_tension) {
  const RtSnapshot s = rt_->snapshot();
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    g = active_;
  }
  MotionLimits limits;
  const MotionSettings& ms = config_.motion;
  limits.max_linear_velocity = ms.max_linear_velocity;
  limits.max_linear_acceleration = ms.max_linear_acceleration;
  limits.max_linear_jerk = ms.max_linear_jerk;
  limits.max_angular_velocity = ms.max_angular_velocity;
  limits.max_angular_acceleration = ms.max_angular_acceleration;
  limits.max_angular_jerk = ms.max_angular_jerk;
  auto traj = PoseTrajectory::plan(s.pose(), pose, limits);
  if (!traj.ok()) return traj.status();
  PathCheckOptions pc;
  pc.tension_margin = ms.tension_margin;
  pc.reference_tension = std::isnan(reference_tension) ? g->reference_tension : reference_tension;
  if (Status st = check_path(g->model, *traj, pc); !st.ok()) return st;
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kMove;
  c->trajectory = std::move(*traj);
  c->reference_tension = reference_tension;
  return post(std::move(c));
}

Status Daemon::move_to(const Pose& pose, double reference_tension, bool abortable) {
  auto seq = start_move(pose, reference_tension);
  if (!seq.ok()) return seq.status();
  const std::uint64_t id = *seq;
  return wait_rt([id](const RtSnapshot& r) { return r.command_done >= id; },
                 config_.measuring.settle_timeout_s + 600.0, "move", abortable);
}

Status Daemon::hold_still(bool abortable) {
  return wait_rt([](const RtSnapshot& r) { return r.mode == RtMode::kHolding && r.settled; },
                 config_.measuring.settle_timeout_s, "settling", abortable);
}

Status Daemon::activate(int version, const json& why, const PeerInfo* peer) {
  if (const RtSnapshot r = rt_->snapshot(); r.fault.kind != FaultKind::kNone) {
    return Status(ErrorCode::kFailedPrecondition,
                  "the robot is in fault (" + fault_text(r.fault) + "): run fault-reset first");
  }
  auto model = store_->load_geometry(version);
  if (!model.ok()) return model.status();
  json w = why;
  if (peer != nullptr) w["peer"] = {{"pid", peer->pid}, {"uid", peer->uid}, {"gid", peer->gid}};
  // Durable first: after a crash the daemon comes back with the version it was applying.
  if (Status s = store_->activate(version, w); !s.ok()) return s;
  // The pose the platform is at, as the new geometry sees it; the RT loop slews the targets from
  // where they are to the new geometry's targets for it (bumpless), then holds.
  auto pose = pose_from_encoders(*model);
  if (!pose.ok()) return pose.status();
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    g = make_geometry(version, *model);
  }
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kReference;
  c->pose = *pose;
  c->geometry = g;
  const std::uint64_t seq = post(std::move(c));
  {
    std::lock_guard lock(mu_);
    swap_target_ = version;
    swap_seq_ = seq;
    swap_why_ = w.value("why", std::string("activation"));
  }
  set_state(DaemonState::kApplying, "hot swap to geometry version " + std::to_string(version));
  return Status::success();
}

void Daemon::service() {
  const auto warn_bus = [this](const std::string& line) {
    spdlog::warn("CANopen: {}", line);
    publish("log", {{"level", "warning"}, {"message", line}});
  };
  reclaim();
  RtEvent e;
  while (rt_->pop_event(e)) {
    const canopen::Event& ev = e.event;
    std::string what = std::string(canopen::to_string(ev.type));
    if (ev.type == canopen::EventType::kEmcy) {
      char buf[64];
      std::snprintf(buf, sizeof buf, " code 0x%04X register 0x%02X", ev.emcy.code,
                    ev.emcy.error_register);
      what += buf;
    }
    if (ev.type == canopen::EventType::kBootUp && running_since_.count() > 0 &&
        ev.time > running_since_) {
      // A node that boots while the daemon runs has lost its configuration (PDO mapping, CSP):
      // only a restart of cdprd configures it again.
      std::lock_guard lock(mu_);
      rebooted_nodes_.insert(int{ev.node});
    }
    const bool serious =
        ev.type == canopen::EventType::kBootUp || ev.type == canopen::EventType::kEmcy ||
        ev.type == canopen::EventType::kHeartbeatLost || ev.type == canopen::EventType::kBusOff ||
        ev.type == canopen::EventType::kDriveFault || ev.type == canopen::EventType::kDriveStuck ||
        ev.type == canopen::EventType::kRxOverflow || ev.type == canopen::EventType::kSyncOverrun ||
        ev.type == canopen::EventType::kTxFailed;
    if (serious) {  // one line per condition and its count while it lasts
      const std::string line = "node " + std::to_string(ev.node) + ": " + what;
      if (auto l = bus_log_.report(line, line, ev.time)) warn_bus(*l);
    } else {
      spdlog::debug("CANopen: node {}: {}", int{ev.node}, what);
    }
  }
  for (const std::string& l : bus_log_.expire(io_.clock->now())) warn_bus(l);
  const RtSnapshot s = rt_->snapshot();
  // A slack cable is named (status "warning", the log, a `warning` event) but does not stop the
  // robot: an 8-cable robot keeps control with one slack cable (docs/daemon.md).
  std::string warning;
  for (int i = 0; i < s.num_cables && warning.empty(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (s.slack_cycles[k] >= config_.tension_watch.cycles) {
      char buf[96];
      std::snprintf(buf, sizeof buf, "slack_cable on cable %d at %.1f N", i + 1, s.tensions[k]);
      warning = buf;
    }
  }
  bool new_warning = false;
  std::string old_warning;
  {
    std::lock_guard lock(mu_);
    // A slack cable stays the same warning while its tension changes.
    const auto stem = [](const std::string& w) { return w.substr(0, w.find(" at ")); };
    if (stem(warning) != stem(warning_)) {
      new_warning = true;
      old_warning = warning_;
    }
    warning_ = warning;
  }
  if (new_warning) {
    if (!warning.empty()) {
      spdlog::warn("warning: {}", warning);
      publish("warning", {{"warning", "slack_cable"}, {"message", warning}});
    } else {
      spdlog::info("warning cleared: {}", old_warning);
      publish("warning", {{"warning", nullptr}, {"message", "cleared: " + old_warning}});
    }
  }
  DaemonState st = state();
  if (s.fault.kind != FaultKind::kNone && st != DaemonState::kFault &&
      st != DaemonState::kStarting) {
    const std::string text = fault_text(s.fault);
    std::optional<int> interrupted;
    int previous = 0;
    {
      std::lock_guard lock(mu_);
      last_fault_ = s.fault;
      fault_text_ = text;
      interrupted = swap_target_;
      swap_target_.reset();
      previous = active_version_;
      if (interrupted && calibration_ && calibration_->outcome == "applying") {
        calibration_->outcome = "failed";
        calibration_->message = "hot swap interrupted by a fault: " + text;
      }
    }
    abort_ = true;
    spdlog::error("fault: {}", text);
    if (interrupted && *interrupted != previous) {
      // The new version was made durable before the swap; the swap did not complete, so the
      // previous version is the active one again, on disk too (the RT loop gets it back at the
      // fault reset, see below).
      const Status r = store_->activate(
          previous, {{"why", "hot swap to version " + std::to_string(*interrupted) +
                                 " interrupted by a fault: " + text}});
      if (r.ok()) {
        spdlog::warn("hot swap to geometry version {} interrupted; version {} stays active",
                     *interrupted, previous);
      } else {
        spdlog::error("hot swap interrupted; cannot make version {} active again: {}", previous,
                      r.to_string());
      }
    }
    publish("fault", {{"fault", to_string(s.fault.kind)},
                      {"node", s.fault.node},
                      {"cable", s.fault.cable + 1},
                      {"message", text}});
    set_state(DaemonState::kFault, text);
    return;
  }
  if (st == DaemonState::kFault && s.fault.kind == FaultKind::kNone && s.all_enabled &&
      !worker_running_.load()) {
    // After fault_reset: the platform is where the quick stop left it.
    auto pose = pose_from_encoders(active_->model);
    if (!pose.ok()) {
      set_state(DaemonState::kFault, "after fault reset: " + pose.status().to_string());
      return;
    }
    auto c = std::make_unique<MotionCommand>();
    c->type = MotionCommand::Type::kReference;
    c->pose = *pose;
    c->from_actual = true;
    {
      // The active geometry explicitly: a hot swap the fault interrupted may have handed the RT
      // loop the new one already.
      std::lock_guard lock(mu_);
      c->geometry = active_;
    }
    post(std::move(c));
    set_state(DaemonState::kHolding, "fault reset; holding where the platform stopped");
    return;
  }
  if (st == DaemonState::kApplying) {
    std::optional<int> target;
    std::uint64_t seq = 0;
    {
      std::lock_guard lock(mu_);
      target = swap_target_;
      seq = swap_seq_;
    }
    if (target && s.command_done >= seq) {
      int calibration = 0;
      {
        std::lock_guard lock(mu_);
        active_version_ = *target;
        for (const auto& g : geometries_) {
          if (g->version == *target) active_ = g.get();
        }
        swap_target_.reset();
        if (calibration_ && calibration_->outcome == "applying") {
          calibration_->outcome = "applied";
          calibration_->proposed_version = *target;
          calibration = calibration_->id;
        }
      }
      spdlog::info("geometry version {} applied; largest target step {:.1f} counts", *target,
                   s.largest_reference_step);
      publish("calibration", {{"version", *target},
                              {"calibration", calibration > 0 ? json(calibration) : json(nullptr)},
                              {"outcome", "applied"},
                              {"largest_step_counts", s.largest_reference_step},
                              {"message", swap_why_}});
      set_state(DaemonState::kHolding, "geometry version " + std::to_string(*target) + " applied");
    }
    return;
  }
  if (!worker_running_.load() && (st == DaemonState::kHolding || st == DaemonState::kMoving)) {
    set_state(s.mode == RtMode::kMoving ? DaemonState::kMoving : DaemonState::kHolding,
              s.mode == RtMode::kMoving ? "moving" : "holding");
  }
}

void Daemon::shutdown() {
  abort_ = true;
  if (worker_.joinable()) worker_.join();
}

// ---------------------------------------------------------------------------------------------
// The calibration sequence
// ---------------------------------------------------------------------------------------------

Result<std::vector<Pose>> Daemon::plan_poses(const std::string& poses_csv) {
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    g = active_;
  }
  std::vector<Pose> poses;
  if (!poses_csv.empty()) {
    auto list = recording::parse_pose_list(poses_csv, "calibrate request (poses_csv)");
    if (!list.ok()) return list.status();
    poses = list->poses;
  } else if (!config_.measuring.pose_file.empty()) {
    auto list = recording::read_pose_list(config_.measuring.pose_file);
    if (!list.ok()) return list.status();
    poses = list->poses;
  } else {
    PoseDesignOptions o;
    o.num_poses = config_.measuring.poses;
    o.max_angle = config_.measuring.max_angle;
    o.angle_steps = config_.measuring.design_angle_steps;
    o.emphasis_weight = config_.measuring.design_emphasis_weight;
    // Candidates keep the design margin, at least the planning margin so that no designed pose is
    // dropped below for it.
    o.tension_margin =
        std::max(config_.measuring.design_tension_margin, config_.motion.tension_margin);
    fit_design_box_to_robot(g->model, o);
    auto d = design_poses(CalibratedModel::from_robot(g->model), o);
    if (!d.ok()) return d.status();
    poses = d->poses;
  }
  // Every pose must be reachable with the tension margin; a designed pose that is not is dropped
  // (the design's own test has no margin), a pose the operator gave is refused.
  PathCheckOptions pc;
  pc.tension_margin = config_.motion.tension_margin;
  std::vector<Pose> kept;
  const bool designed = poses_csv.empty() && config_.measuring.pose_file.empty();
  for (std::size_t j = 0; j < poses.size(); ++j) {
    if (Status s = check_pose(g->model, poses[j], pc); !s.ok()) {
      if (!designed || j == 0) return s.prepend("pose " + std::to_string(j) + ": ");
      spdlog::warn("designed pose {} dropped: {}", j, s.to_string());
      continue;
    }
    kept.push_back(poses[j]);
  }
  return kept;
}

Status Daemon::regulate_tensions(int pose_index) {
  const double band = config_.measuring.tension_band;
  if (band <= 0.0 || master_->force_sensors().empty()) return Status::success();
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    g = active_;
  }
  const int m = g->model.num_cables();
  std::array<double, kMaxAxes> trim{};
  // Before calibration the nominal geometry can be several mm off the robot's (MINI: 14.5 mm RMS
  // at the anchors), so at a tilted pose a cable can hang several mm slack: the steps for a slack
  // cable grow to take that up (about 20 mm in all on the MINI) and are capped, so a cable that
  // catches mid-step ends at most half-way up its band.
  constexpr int kRegulationSteps = 8;
  for (int iteration = 0; iteration < kRegulationSteps; ++iteration) {
    const std::uint64_t id = rt_->request_average();
    const int n = std::max(3, config_.measuring.average_cycles / 2);
    if (Status s = wait_rt(
            [id, n](const RtSnapshot& r) { return r.average_id == id && r.average_cycles >= n; },
            config_.measuring.settle_timeout_s, "tension reading", true);
        !s.ok()) {
      return s;
    }
    const RtSnapshot r = rt_->snapshot();
    trim = r.trim_counts;
    // Into the planned band of each cable, [f_min - band, f_max + band] (the planner itself puts
    // tensions on f_min): a cable below it is shortened, one above it lengthened, by the tension
    // missing over the cable's stiffness (mostly internal force: the platform barely moves).
    bool inside = true;
    for (int i = 0; i < m; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const CableModel& c = g->model.cables[k];
      const double lo = c.f_min - band, hi = c.f_max + band;
      const double f = r.average_tensions[k];
      const double want = std::clamp(f, lo, std::max(lo, hi));
      if (want == f) continue;
      inside = false;
      spdlog::debug(
          "pose {}: regulation {}: cable {} at {:.2f} N, band [{:.1f}, {:.1f}] N, trim {:.0f} "
          "counts",
          pose_index, iteration, i + 1, f, lo, hi, trim[k]);
      const double ea = c.ea > 0.0 ? c.ea : 1e9;
      const double length = loaded_length(
          c, std::max(0.05,
                      winch_counts_to_length<double>(
                          g->model.winches[k], r.average_counts[k] - rt_->encoder_offsets()[k])));
      // A slack cable (no tension) has an unknown slack length to take up: the step grows with
      // each iteration, up to half the band's worth of stretch.
      const double cap = 0.5 * (std::max(lo, hi) - lo) * length / ea;
      const double dl = std::clamp(
          -(want + (want > f ? 1.5 : -1.5) * band - f) * length / ea * (1 << iteration), -cap, cap);
      trim[k] += winch_counts_change<double>(g->model.winches[k], dl);
    }
    if (inside) return Status::success();
    auto c = std::make_unique<MotionCommand>();
    c->type = MotionCommand::Type::kTrim;
    c->trim = trim;
    const std::uint64_t seq = post(std::move(c));
    if (Status s = wait_rt([seq](const RtSnapshot& rs) { return rs.command_done >= seq; },
                           config_.measuring.settle_timeout_s, "tension regulation", true);
        !s.ok()) {
      return s;
    }
    if (Status s = hold_still(true); !s.ok()) return s;
  }
  spdlog::warn(
      "pose {}: a tension is still outside [f_min - {:.1f}, f_max + {:.1f}] N after {} "
      "regulation steps",
      pose_index, band, band, kRegulationSteps);
  return Status::success();
}

Status Daemon::measure_pose(const Pose& pose, double reference_tension,
                            recording::RecordedPose& row) {
  if (Status s = move_to(pose, reference_tension, true); !s.ok()) return s;
  if (Status s = hold_still(true); !s.ok()) return s;
  if (Status s = regulate_tensions(static_cast<int>(row.index)); !s.ok()) return s;
  const std::uint64_t id = rt_->request_average();
  double laser = std::numeric_limits<double>::quiet_NaN();
  if (io_.laser != nullptr) {
    modbus::MeasureOptions mo;
    mo.interval_s = config_.measuring.laser_interval_s;
    auto r = io_.laser->measure(config_.measuring.laser_samples, mo);
    if (!r.ok()) {
      Status s = r.status();
      return s.prepend("laser: ");
    }
    laser = r->mean_m;
  }
  const int n = config_.measuring.average_cycles;
  if (Status s = wait_rt(
          [id, n](const RtSnapshot& r) { return r.average_id == id && r.average_cycles >= n; },
          config_.measuring.settle_timeout_s + 0.01 * n, "encoder averaging", true);
      !s.ok()) {
    return s;
  }
  const RtSnapshot r = rt_->snapshot();
  if (r.fault.kind != FaultKind::kNone) {  // (e.g. a stuck force reading: the row is refused)
    return Status::error(ErrorCode::kAborted, "encoder averaging: robot fault: %s",
                         fault_text(r.fault).c_str());
  }
  if (!r.settled) return Status(ErrorCode::kAborted, "the platform moved while it was measured");

  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    g = active_;
  }
  const int m = g->model.num_cables();
  row.commanded = pose;
  row.lengths.resize(m);
  row.tensions.resize(m);
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    row.lengths(i) = winch_counts_to_length<double>(
        g->model.winches[k], r.average_counts[k] - rt_->encoder_offsets()[k]);
    row.tensions(i) = master_->force_sensors().empty() ? std::numeric_limits<double>::quiet_NaN()
                                                       : r.average_tensions[k];
  }
  row.lasers = Eigen::VectorXd::Constant(static_cast<int>(g->model.lasers.size()), laser);
  row.reference = Pose{Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN()),
                       Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN())};
  return Status::success();
}

void Daemon::finish_calibration(const std::string& outcome, const std::string& message) {
  int id = 0;
  {
    std::lock_guard lock(mu_);
    if (calibration_) {
      calibration_->outcome = outcome;
      calibration_->message = message;
      id = calibration_->id;
    }
  }
  spdlog::info("calibration {}: {}: {}", id, outcome, message);
  publish("calibration", {{"version", nullptr},
                          {"calibration", id},
                          {"outcome", outcome},
                          {"gates_passed", false},
                          {"message", message}});
}

void Daemon::run_calibration(std::vector<Pose> poses, PeerInfo peer) {
  // The worker yields to the RT loop and the supervisor (it computes for seconds when it
  // identifies; on one CPU, e.g. inside user-mode-linux, it would otherwise delay the cycles).
  if (::setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), 10) != 0) {
    spdlog::debug("calibration worker: setpriority: {}", std::strerror(errno));
  }
  int id = 0;
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    id = calibration_->id;
    g = active_;
  }
  const std::string dir = store_->calibration_dir(id);
  const MeasuringSettings& ms = config_.measuring;
  const int m = g->model.num_cables();
  const int k = static_cast<int>(g->model.lasers.size());
  set_state(DaemonState::kMeasuring,
            "calibration " + std::to_string(id) + ": " + std::to_string(poses.size()) + " poses");
  // The recording: noise of the averaged readings, provenance, one row per pose as it is measured.
  recording::Recording rec;
  rec.num_cables = m;
  rec.num_lasers = std::max(k, 1);
  rec.metadata.set(recording::key::kFormat, "cdpr-recording 1");
  rec.metadata.set(recording::key::kUnits, "SI");
  rec.metadata.set(recording::key::kRobot, g->model.name);
  rec.metadata.set(recording::key::kDate, recording::utc_timestamp());
  rec.metadata.set(recording::key::kConfigFile, store_->geometry_path(g->version));
  if (auto h = recording::file_hash(store_->geometry_path(g->version)); h.ok()) {
    rec.metadata.set(recording::key::kConfigHash, *h);
  }
  rec.metadata.set(recording::key::kSource, "robot (cdprd)");
  rec.metadata.set("daemon", kDaemonVersion);
  rec.metadata.set("geometry_version", std::to_string(g->version));
  // The noise of an average: white noise shrinks with the number of readings, the quantisation of
  // a reading does not when the noise is too small to dither it (a force node's raw unit is
  // 1/gain N, an encoder's one count), so both add up.
  const double n_avg = static_cast<double>(ms.average_cycles);
  double q_force = 0.0, q_length = winch_metres_per_count(g->model.winches[0]);
  for (const canopen::NodeConfig& n : network_.nodes) {
    for (double gain : n.force.gain)
      q_force = std::max(q_force, gain != 0.0 ? 1.0 / std::abs(gain) : 0.0);
  }
  const double sigma_length =
      std::sqrt(ms.noise_length_m * ms.noise_length_m / n_avg + q_length * q_length / 12.0);
  const double sigma_force =
      std::sqrt(ms.noise_force_n * ms.noise_force_n / n_avg + q_force * q_force / 12.0);
  rec.metadata.set_number(recording::key::kNoiseLength, sigma_length);
  rec.metadata.set_number(recording::key::kNoiseForce, sigma_force);
  rec.metadata.set_number(recording::key::kNoiseLaser,
                          ms.noise_laser_m / std::sqrt(static_cast<double>(ms.laser_samples)));
  AppendOnlyFile file;
  const std::string rec_path = dir + "/recording.csv";
  bool header_written = false;
  const double t0 = now_s();

  std::vector<double> row_pretensions;  // per recorded row, the pretension it was measured at
  auto measure_list = [&](const std::vector<Pose>& list, const std::vector<double>& pretensions,
                          int first_index) -> Status {
    for (std::size_t j = 0; j < list.size(); ++j) {
      const int index = first_index + static_cast<int>(j);
      recording::RecordedPose row;
      row.index = index;
      const double pre =
          j < pretensions.size() ? pretensions[j] : std::numeric_limits<double>::quiet_NaN();
      if (Status s = measure_pose(list[j], pre, row); !s.ok()) {
        return s.prepend("pose " + std::to_string(index) + ": ");
      }
      row_pretensions.push_back(pre);
      row.time_s = now_s() - t0;
      recording::Recording one = rec;
      one.poses = {row};
      auto text = recording::format_recording(one);
      if (!text.ok()) return text.status();
      auto [head, body] = split_header(*text);
      if (!header_written) {
        if (Status s = file.open(rec_path, true); !s.ok()) return s;
        if (Status s = file.append(head); !s.ok()) return s;
        header_written = true;
      }
      if (Status s = file.append(body); !s.ok()) return s;
      rec.poses.push_back(row);
      const double elapsed = now_s() - t0;
      const int done = index + 1;
      const int total = static_cast<int>(poses.size());
      const double remaining = done < total ? elapsed / done * (total - done) : 0.0;
      RtSnapshot r = rt_->snapshot();
      json tensions = json::array();
      for (int i = 0; i < m; ++i) tensions.push_back(r.tensions[static_cast<std::size_t>(i)]);
      {
        std::lock_guard lock(mu_);
        calibration_->pose = done;
        calibration_->elapsed_s = elapsed;
        calibration_->remaining_s = remaining;
      }
      publish("progress",
              {{"phase", "measuring"},
               {"calibration", id},
               {"pose", done},
               {"poses", std::max(total, done)},
               {"elapsed_s", elapsed},
               {"remaining_s", remaining},
               {"tensions", tensions},
               {"laser_m", row.lasers.size() > 0 ? json(row.lasers(0)) : json(nullptr)}});
    }
    // Back to where the calibration started (home for a designed set) while the worker
    // identifies and the result awaits the operator: a designed pose sits near the tension
    // limits of the geometry that is about to change, and a hot swap there (accept, reject's
    // rollback later) may leave one geometry no feasible tension distribution or a cable slack.
    if (Status s = move_to(poses.front(), std::numeric_limits<double>::quiet_NaN(), true);
        !s.ok()) {
      return s.prepend("back to the first pose: ");
    }
    return Status::success();
  };

  auto fail = [&](const Status& s) {
    const bool aborted = s.code() == ErrorCode::kAborted && abort_.load() &&
                         rt_->snapshot().fault.kind == FaultKind::kNone;
    finish_calibration(aborted ? "aborted" : "failed", s.to_string());
    // The worker's part is over before the state says so: a request that follows the state
    // change at once (a script's next `calibrate`) must not find the worker still running.
    worker_running_ = false;
    if (rt_->snapshot().fault.kind == FaultKind::kNone) {
      set_state(DaemonState::kHolding, std::string("calibration ") +
                                           (aborted ? "aborted" : "failed") +
                                           "; the active geometry is unchanged");
    }
  };

  if (Status s = measure_list(poses, {}, 0); !s.ok()) return fail(s);

  // Identification and diagnosis; extra poses when the locator asks for them.
  set_state(DaemonState::kIdentifying, "calibration " + std::to_string(id) + ": identifying");
  const CalibratedModel initial = CalibratedModel::from_robot(g->model);
  Result<Diagnosis> diagnosis = Status(ErrorCode::kInternal, "not run");
  Result<IdentificationReport> report = Status(ErrorCode::kInternal, "not run");
  MeasurementSet set;
  // Rows of the recording left out of the identification (a gross reading, measured again as a
  // new row); the file keeps them as evidence.
  std::vector<bool> left_out;
  std::vector<RemeasuredPose> remeasured;
  int remeasure_round = 0;
  // After the follow-up poses of a suspect beside named effects, the next diagnosis is
  // confirmatory (follow_up_groups): it decides the suspect beside the named effects.
  std::vector<std::string> confirm_groups;
  // A suspect held back for weak evidence beside named effects (FollowUp::held_back): the
  // confirmatory diagnosis after its follow-up poses names it only with strong evidence.
  std::string confirm_suspect;
  for (int round = 0;;) {
    auto read = recording::read_recording(rec_path);
    if (!read.ok()) return fail(read.status());
    auto ms_set = recording::to_measurement_set(*read);
    if (!ms_set.ok()) return fail(ms_set.status());
    set = std::move(*ms_set);
    left_out.resize(static_cast<std::size_t>(set.num_poses()), false);
    std::vector<int> rows;  // the recording's row of each pose of `set`
    {
      MeasurementSet kept;
      kept.noise = set.noise;
      for (int j = 0; j < static_cast<int>(set.poses.size()); ++j) {
        if (left_out[static_cast<std::size_t>(j)]) continue;
        kept.poses.push_back(std::move(set.poses[static_cast<std::size_t>(j)]));
        rows.push_back(j);
      }
      set = std::move(kept);
    }
    report = identify(initial, set, config_.identification.options);
    if (!report.ok()) return fail(report.status());
    if (!config_.identification.diagnose) break;
    DiagnosisOptions dopt;
    dopt.bootstrap_samples = config_.identification.bootstrap;
    dopt.cv_folds = config_.identification.folds;
    dopt.screen.only_groups = confirm_groups;
    dopt.confirm_suspect = confirm_suspect;
    diagnosis = diagnose(initial, set, nullptr, config_.identification.options, dopt);
    if (!diagnosis.ok()) return fail(diagnosis.status());
    if (!diagnosis->gross_readings.empty() && remeasure_round < ms.remeasure_rounds) {
      // A gross reading (a beam on the wrong target, a glitch): its pose is measured again and the
      // row is left out; the extra-pose rounds are not spent on it.
      ++remeasure_round;
      std::vector<Pose> again;
      std::vector<double> pretensions;
      const int first = static_cast<int>(rec.poses.size());
      for (GrossReading gr : diagnosis->gross_readings) {
        const int row = rows[static_cast<std::size_t>(gr.pose)];
        gr.pose = row;  // in words, the recording's row (rows left out before shift the set's)
        if (left_out[static_cast<std::size_t>(row)]) {  // (two readings of one pose)
          for (RemeasuredPose& r : remeasured) {
            if (r.row == row) r.reading += "; " + describe(gr);
          }
          continue;
        }
        left_out[static_cast<std::size_t>(row)] = true;
        remeasured.push_back({row, first + static_cast<int>(again.size()), describe(gr)});
        again.push_back(rec.poses[static_cast<std::size_t>(row)].commanded);
        pretensions.push_back(row_pretensions[static_cast<std::size_t>(row)]);
      }
      for (std::size_t j = remeasured.size() - again.size(); j < remeasured.size(); ++j) {
        spdlog::warn(
            "calibration {}: pose {} is measured again as pose {} ({}); its row stays in "
            "the recording and is left out of the identification",
            id, remeasured[j].row + 1, remeasured[j].again + 1, remeasured[j].reading);
      }
      set_state(DaemonState::kMeasuring, "calibration " + std::to_string(id) + ": " +
                                             std::to_string(again.size()) +
                                             " poses measured again (gross reading)");
      {
        std::lock_guard lock(mu_);
        calibration_->poses += static_cast<int>(again.size());
      }
      poses.insert(poses.end(), again.begin(), again.end());
      if (Status s = measure_list(again, pretensions, first); !s.ok()) return fail(s);
      set_state(DaemonState::kIdentifying, "calibration " + std::to_string(id) + ": identifying");
      continue;
    }
    if (round++ >= ms.extra_pose_rounds) break;
    // Separating poses of the confounded pairs; a suspect's follow-up poses (with nothing named;
    // beside named effects when held back for weak evidence, or follow_up_beside_named).
    ExtraPoseRound more = extra_pose_round(*diagnosis);
    confirm_groups = std::move(more.confirm_groups);
    confirm_suspect = std::move(more.confirm_suspect);
    const std::vector<Pose>& extra = more.poses;
    const std::vector<double>& pretensions = more.pretensions;
    if (extra.empty()) break;
    spdlog::info("calibration {}: the mismatch locator asks for {} extra poses", id, extra.size());
    set_state(DaemonState::kMeasuring, "calibration " + std::to_string(id) + ": " +
                                           std::to_string(extra.size()) + " extra poses");
    {
      std::lock_guard lock(mu_);
      calibration_->poses += static_cast<int>(extra.size());
    }
    poses.insert(poses.end(), extra.begin(), extra.end());
    if (Status s = measure_list(extra, pretensions, static_cast<int>(rec.poses.size())); !s.ok()) {
      return fail(s);
    }
    set_state(DaemonState::kIdentifying, "calibration " + std::to_string(id) + ": identifying");
  }

  // A fault or an abort while the worker identified ends the sequence here (the recording is
  // kept): nothing may await acceptance, let alone be accepted automatically, while the robot
  // is stopped or the operator asked to stop.
  if (const RtSnapshot r = rt_->snapshot(); r.fault.kind != FaultKind::kNone) {
    return fail(
        Status(ErrorCode::kAborted, "robot fault while identifying: " + fault_text(r.fault)));
  }
  if (abort_.load()) {
    return fail(Status(ErrorCode::kAborted, "identification: aborted by the operator"));
  }

  // The result and the gates.
  CalibrationOutcome out =
      evaluate_calibration(g->model, set, *report, diagnosis.ok() ? &*diagnosis : nullptr,
                           config_.acceptance, config_.identification.options);
  CalibrationReportContext ctx;
  ctx.calibration = id;
  ctx.daemon = kDaemonVersion;
  ctx.geometry_version = g->version;
  ctx.recording = rec_path;
  ctx.robot_config = config_.robot;
  ctx.canopen_config = config_.canopen;
  ctx.laser_config = config_.laser;
  ctx.daemon_config = config_.file;
  ctx.started = rec.metadata.get(recording::key::kDate);
  ctx.measuring_s = now_s() - t0;
  ctx.remeasured = remeasured;
  // The calibration report of cdpr-fit (the library), under the daemon's decision.
  const CalibratedModel after_model = diagnosis.ok() ? diagnosis->model_after : report->estimate;
  report::CalibrationReportInput rin;
  rin.before = &initial;
  rin.after = &after_model;
  rin.identification = &*report;
  rin.set = &set;
  rin.diagnosis = diagnosis.ok() ? &*diagnosis : nullptr;
  rin.context.title = "cdprd calibration " + std::to_string(id);
  // Files named relative to the report's directory (the page sits beside the recording).
  rin.context.config =
      std::filesystem::path(store_->geometry_path(g->version)).lexically_relative(dir).string();
  rin.context.config_hash = rec.metadata.get(recording::key::kConfigHash);
  rin.context.recording = std::filesystem::path(rec_path).lexically_relative(dir).string();
  rin.context.identification = config_.identification.options;
  if (auto h = recording::file_hash(rec_path); h.ok()) rin.context.recording_hash = *h;
  rin.context.bootstrap = config_.identification.bootstrap;
  rin.context.folds = config_.identification.folds;
  const report::Rendered rendered = report::render_calibration_report(rin);
  json summary = calibration_json(out, ctx);
  summary["calibration_report"] = rendered.json;
  Status wrote = io::write_file_atomically(
      dir + "/report.json",
      summary.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  if (wrote.ok()) {
    wrote =
        io::write_file_atomically(dir + "/report.html", calibration_html(out, ctx, rendered.html));
  }
  if (wrote.ok()) wrote = io::write_file_atomically(dir + "/report.txt", rendered.text);
  if (wrote.ok()) {
    wrote =
        io::write_file_atomically(dir + "/model_before.yaml", config::save_robot_config(g->model));
  }
  if (wrote.ok()) {
    wrote =
        io::write_file_atomically(dir + "/model_after.yaml", config::save_robot_config(out.model));
  }
  if (!wrote.ok()) return fail(wrote);
  {
    std::lock_guard lock(mu_);
    calibration_->outcome = "awaiting_acceptance";
    calibration_->gates_passed = out.gates_passed;
    calibration_->summary = summary;
    calibration_->proposed = std::make_shared<RobotModel>(out.model);
    calibration_->before_version = g->version;
    calibration_->message = out.verdict;
  }
  worker_running_ = false;  // before the state: see fail() above
  set_state(DaemonState::kAwaitingAcceptance,
            "calibration " + std::to_string(id) + ": " + out.verdict +
                (out.gates_passed ? "; every gate passed" : "; gates failed: " + out.failed_gates));
  publish("calibration", {{"calibration", id},
                          {"version", nullptr},
                          {"outcome", "awaiting_acceptance"},
                          {"gates_passed", out.gates_passed},
                          {"message", out.verdict}});
  if (config_.acceptance.mode == AcceptanceMode::kAuto && out.gates_passed) {
    const Reply r = cmd_accept(peer);
    if (!r.ok) spdlog::error("automatic acceptance failed: {}", r.message);
  }
}

// ---------------------------------------------------------------------------------------------
// Control requests
// ---------------------------------------------------------------------------------------------

json Daemon::status() const {
  const RtSnapshot s = rt_->snapshot();
  std::lock_guard lock(mu_);
  json j;
  j["state"] = to_string(state_);
  j["reason"] = state_reason_;
  j["daemon_version"] = kDaemonVersion;
  j["geometry_version"] = active_version_;
  j["fault"] = state_ == DaemonState::kFault
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
      {"commanded_pose", pose_json(s.pose())},
      {"tensions_n", s.have_tensions ? tensions : json(nullptr)},
      {"target_counts", targets},
      {"actual_counts", actual},
      {"largest_reference_step_counts", s.largest_reference_step},
      {"largest_move_step_counts", s.largest_move_step},
      // One cycle of the fastest normal cable motion (max_cable_speed), the bound a
      // re-reference step must stay under.
      {"one_cycle_motion_counts", config_.motion.max_cable_speed *
                                      std::chrono::duration<double>(network_.sync_period).count() /
                                      winch_metres_per_count(active_->model.winches[0])}};
  j["warning"] = warning_.empty() ? json(nullptr) : json(warning_);
  j["loop"] = loop_figures_;
  if (calibration_) {
    j["calibration"] = {{"id", calibration_->id},
                        {"outcome", calibration_->outcome},
                        {"pose", calibration_->pose},
                        {"poses", calibration_->poses},
                        {"elapsed_s", calibration_->elapsed_s},
                        {"remaining_s", calibration_->remaining_s},
                        {"gates_passed", calibration_->gates_passed},
                        {"message", calibration_->message}};
  } else {
    j["calibration"] = nullptr;
  }
  if (io_.laser != nullptr) {
    const modbus::LaserReading l = io_.laser->latest();
    j["laser_m"] = l.ok() ? json(l.distance_m) : json(nullptr);
  }
  return j;
}

Reply Daemon::cmd_status() const {
  return Reply::success(status());
}

Reply Daemon::cmd_calibrate(const json& args, const PeerInfo& peer) {
  if (!args.is_object()) return Reply::failure("bad_request", "args must be an object");
  const bool dry_run =
      args.contains("dry_run") && args["dry_run"].is_boolean() && args["dry_run"].get<bool>();
  std::string csv;
  if (args.contains("poses_csv")) {
    if (!args["poses_csv"].is_string()) {
      return Reply::failure("bad_request", "poses_csv must be a string (the pose list's text)");
    }
    csv = args["poses_csv"].get<std::string>();
  }
  const DaemonState st = state();
  if (st == DaemonState::kFault) {
    return Reply::failure("fault", "the robot is in fault (" +
                                       status()["reason"].get<std::string>() +
                                       "): run fault-reset first");
  }
  if (!dry_run && (st != DaemonState::kHolding || worker_running_.load())) {
    return Reply::failure("invalid_state", std::string("a calibration starts only while holding; "
                                                       "the daemon is ") +
                                               to_string(st));
  }
  if (io_.laser == nullptr && !dry_run) {
    return Reply::failure("invalid_state", "no laser is configured (" + config_.file +
                                               ": laser): the calibration needs it");
  }
  auto poses = plan_poses(csv);
  if (!poses.ok()) return Reply::failure("bad_request", poses.status().to_string());
  if (dry_run) {
    json list = json::array();
    for (const Pose& p : *poses) list.push_back(pose_json(p));
    return Reply::success({{"dry_run", true}, {"poses", list}, {"feasible", true}});
  }
  auto id = store_->new_calibration();
  if (!id.ok()) return Reply::failure("internal", id.status().to_string());
  if (worker_.joinable()) worker_.join();
  {
    std::lock_guard lock(mu_);
    calibration_ = Calibration{};
    calibration_->id = *id;
    calibration_->outcome = "measuring";
    calibration_->poses = static_cast<int>(poses->size());
    calibration_->started_s = now_s();
  }
  abort_ = false;
  worker_running_ = true;
  spdlog::info("calibrate: calibration {} with {} poses requested by pid {} uid {} gid {}", *id,
               poses->size(), peer.pid, peer.uid, peer.gid);
  worker_ = std::thread(
      [this, p = std::move(*poses), peer]() mutable { run_calibration(std::move(p), peer); });
  return Reply::success({{"calibration", *id}, {"poses", calibration_->poses}});
}

Reply Daemon::cmd_accept(const PeerInfo& peer) {
  std::shared_ptr<const RobotModel> proposed;
  int id = 0;
  {
    std::lock_guard lock(mu_);
    if (state_ != DaemonState::kAwaitingAcceptance || !calibration_ || !calibration_->proposed) {
      return Reply::failure("invalid_state", std::string("nothing awaits acceptance (state ") +
                                                 to_string(state_) + ")");
    }
    proposed = calibration_->proposed;
    id = calibration_->id;
  }
  auto version = store_->add_geometry(
      *proposed, {{"source", "calibration"}, {"calibration", id}, {"parent", active_version_}});
  if (!version.ok()) return Reply::failure("internal", version.status().to_string());
  const std::string dir = store_->calibration_dir(id);
  json decision = {{"decision", "accepted"},
                   {"version", *version},
                   {"peer", {{"pid", peer.pid}, {"uid", peer.uid}, {"gid", peer.gid}}},
                   {"time", recording::utc_timestamp()}};
  (void)io::write_file_atomically(
      dir + "/decision.json",
      decision.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  {
    std::lock_guard lock(mu_);
    calibration_->outcome = "applying";
  }
  spdlog::info("accept: calibration {} as geometry version {} (pid {} uid {} gid {})", id, *version,
               peer.pid, peer.uid, peer.gid);
  if (Status s = activate(
          *version,
          {{"why", "calibration " + std::to_string(id) + " accepted"}, {"calibration", id}}, &peer);
      !s.ok()) {
    set_state(DaemonState::kHolding, "accept failed: " + s.to_string());
    return Reply::failure("internal", s.to_string());
  }
  return Reply::success({{"calibration", id}, {"version", *version}});
}

Reply Daemon::cmd_reject(const PeerInfo& peer) {
  int id = 0;
  {
    std::lock_guard lock(mu_);
    if (state_ != DaemonState::kAwaitingAcceptance || !calibration_) {
      return Reply::failure("invalid_state", std::string("nothing awaits acceptance (state ") +
                                                 to_string(state_) + ")");
    }
    id = calibration_->id;
    calibration_->outcome = "rejected";
    calibration_->proposed.reset();
  }
  json decision = {{"decision", "rejected"},
                   {"peer", {{"pid", peer.pid}, {"uid", peer.uid}, {"gid", peer.gid}}},
                   {"time", recording::utc_timestamp()}};
  (void)io::write_file_atomically(
      store_->calibration_dir(id) + "/decision.json",
      decision.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  spdlog::info("reject: calibration {} (pid {} uid {} gid {})", id, peer.pid, peer.uid, peer.gid);
  publish("calibration", {{"calibration", id},
                          {"version", nullptr},
                          {"outcome", "rejected"},
                          {"gates_passed", false},
                          {"message", "rejected by the operator"}});
  set_state(DaemonState::kHolding, "calibration " + std::to_string(id) +
                                       " rejected; geometry version " +
                                       std::to_string(active_version_) + " stays active");
  return Reply::success({{"calibration", id}, {"version", active_version_}});
}

Reply Daemon::cmd_rollback(const json& args, const PeerInfo& peer) {
  if (!args.is_object() || !args.contains("version") || !args["version"].is_number_integer()) {
    return Reply::failure("bad_request", "geometry_rollback needs {\"version\": <integer>}");
  }
  const int version = args["version"].get<int>();
  if (state() != DaemonState::kHolding || worker_running_.load()) {
    return Reply::failure("invalid_state", std::string("rollback only while holding (state ") +
                                               to_string(state()) + ")");
  }
  if (!store_->load_geometry(version).ok()) {
    return Reply::failure("not_found",
                          "geometry version " + std::to_string(version) + " does not exist");
  }
  spdlog::info("rollback to geometry version {} (pid {} uid {} gid {})", version, peer.pid,
               peer.uid, peer.gid);
  if (Status s =
          activate(version, {{"why", "rollback to version " + std::to_string(version)}}, &peer);
      !s.ok()) {
    return Reply::failure("internal", s.to_string());
  }
  return Reply::success({{"version", version}});
}

Reply Daemon::cmd_geometry_show(const json& args) const {
  int version = 0;
  {
    std::lock_guard lock(mu_);
    version = active_version_;
  }
  if (args.is_object() && args.contains("version")) {
    if (!args["version"].is_number_integer()) {
      return Reply::failure("bad_request", "version must be an integer");
    }
    version = args["version"].get<int>();
  }
  auto model = store_->load_geometry(version);
  if (!model.ok()) return Reply::failure("not_found", model.status().to_string());
  json meta = store_->geometry_meta(version).ok() ? *store_->geometry_meta(version) : json(nullptr);
  return Reply::success({{"version", version},
                         {"active", version == active_version_},
                         {"robot", model->name},
                         {"frame_anchors_m", anchors_json(*model)},
                         {"meta", meta}});
}

Reply Daemon::cmd_geometry_diff(const json& args) const {
  if (!args.is_object() || !args.contains("from") || !args.contains("to") ||
      !args["from"].is_number_integer() || !args["to"].is_number_integer()) {
    return Reply::failure("bad_request", "geometry_diff needs {\"from\": <int>, \"to\": <int>}");
  }
  const int a = args["from"].get<int>(), b = args["to"].get<int>();
  auto ma = store_->load_geometry(a);
  if (!ma.ok()) return Reply::failure("not_found", ma.status().to_string());
  auto mb = store_->load_geometry(b);
  if (!mb.ok()) return Reply::failure("not_found", mb.status().to_string());
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

Reply Daemon::cmd_geometry_history() const {
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
  std::lock_guard lock(mu_);
  return Reply::success(
      {{"active", active_version_}, {"versions", versions}, {"activations", act}});
}

Reply Daemon::cmd_report(const json& args) const {
  std::vector<int> ids = store_->calibrations();
  int id = ids.empty() ? 0 : ids.back();
  if (args.is_object() && args.contains("version")) {
    if (!args["version"].is_number_integer()) {
      return Reply::failure("bad_request", "version must be an integer (a calibration number)");
    }
    id = args["version"].get<int>();
  }
  const std::string dir = store_->calibration_dir(id);
  auto text = read_text_file(dir + "/report.json");
  if (id == 0 || !text.ok()) {
    return Reply::failure("not_found", "no report for calibration " + std::to_string(id));
  }
  json report = json::parse(*text, nullptr, false);
  if (report.is_discarded()) return Reply::failure("internal", dir + "/report.json is not JSON");
  json result = {{"calibration", id}, {"report", report}};
  if (args.is_object() && args.value("html", false)) {
    auto html = read_text_file(dir + "/report.html");
    if (!html.ok()) return Reply::failure("not_found", html.status().to_string());
    result["html"] = *html;
  }
  return Reply::success(result);
}

Reply Daemon::cmd_move(const json& args, const PeerInfo& peer) {
  if (!args.is_object() || !args.contains("pose") || !args["pose"].is_array() ||
      args["pose"].size() != 6) {
    return Reply::failure("bad_request",
                          "move needs {\"pose\": [x, y, z, roll, pitch, yaw]} (m, rad)");
  }
  Eigen::Matrix<double, 6, 1> v;
  for (int i = 0; i < 6; ++i) {
    const json& x = args["pose"][static_cast<std::size_t>(i)];
    if (!x.is_number() || !std::isfinite(x.get<double>())) {
      return Reply::failure("bad_request", "move: pose entries must be finite numbers");
    }
    v(i) = x.get<double>();
  }
  const DaemonState st = state();
  if (st == DaemonState::kFault) return Reply::failure("fault", "the robot is in fault");
  if (st != DaemonState::kHolding || worker_running_.load() ||
      rt_->snapshot().mode != RtMode::kHolding) {
    return Reply::failure("invalid_state", std::string("a move starts only while holding (state ") +
                                               to_string(st) + ")");
  }
  const Pose pose = Pose::from_vector(v);
  auto seq = start_move(pose, std::numeric_limits<double>::quiet_NaN());
  if (!seq.ok()) return Reply::failure("bad_request", seq.status().to_string());
  spdlog::info("move to ({:.4f}, {:.4f}, {:.4f}) m requested by pid {} uid {} gid {}",
               pose.position.x(), pose.position.y(), pose.position.z(), peer.pid, peer.uid,
               peer.gid);
  set_state(DaemonState::kMoving, "move requested");
  return Reply::success({{"move", *seq}});
}

Reply Daemon::handle(const std::string& cmd, const json& args, const PeerInfo& peer) {
  try {
    if (cmd == "status") return cmd_status();
    if (cmd == "calibrate") return cmd_calibrate(args, peer);
    if (cmd == "watch") return Reply::success({{"watching", true}});
    if (cmd == "abort") {
      if (!worker_running_.load()) {
        return Reply::failure("invalid_state", "no calibration is running");
      }
      spdlog::info("abort requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
      abort_ = true;
      return Reply::success({{"aborting", true}});
    }
    if (cmd == "accept") return cmd_accept(peer);
    if (cmd == "reject") return cmd_reject(peer);
    if (cmd == "geometry_show") return cmd_geometry_show(args);
    if (cmd == "geometry_diff") return cmd_geometry_diff(args);
    if (cmd == "geometry_history") return cmd_geometry_history();
    if (cmd == "geometry_rollback") return cmd_rollback(args, peer);
    if (cmd == "report") return cmd_report(args);
    if (cmd == "move") return cmd_move(args, peer);
    if (cmd == "stop") {
      spdlog::warn("quick stop requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
      rt_->request_quick_stop();
      abort_ = true;
      return Reply::success({{"stopping", true}});
    }
    if (cmd == "fault_reset") {
      if (state() != DaemonState::kFault) {
        return Reply::failure("invalid_state", "no fault to reset");
      }
      {
        std::lock_guard lock(mu_);
        if (!rebooted_nodes_.empty()) {
          std::string nodes;
          for (int n : rebooted_nodes_) nodes += (nodes.empty() ? "" : ", ") + std::to_string(n);
          spdlog::warn("fault reset refused: node(s) {} rebooted while the daemon ran", nodes);
          return Reply::failure("fault", "node(s) " + nodes +
                                             " rebooted and lost their configuration: restart "
                                             "cdprd");
        }
      }
      spdlog::info("fault reset requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
      if (worker_.joinable() && !worker_running_.load()) worker_.join();
      rt_->request_fault_reset();
      return Reply::success({{"resetting", true}});
    }
    return Reply::failure("unknown_command", "unknown command '" + cmd + "'");
  } catch (const std::exception& e) {
    return Reply::failure("internal", std::string("internal error: ") + e.what());
  }
}

}  // namespace cdpr::controller
