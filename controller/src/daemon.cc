// Daemon: creation, start-up (identities, enabling, homing), the one transition function, and
// motion (commands to the RT loop and waiting for it). The other concerns: daemon.hpp.
#include "cdpr/controller/daemon.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <thread>

#include "cdpr/calibration/forward_kinematics.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/config/robot_config.hpp"
#include "daemon_text.hpp"

namespace cdpr::controller {
using json = nlohmann::json;
using detail::fault_text;

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
  CDPR_RETURN_IF_ERROR(check_safety_limits(d->config_.safety, d->nominal_.num_cables()));
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

  auto robot_io = CanopenRobotIO::create(*d->master_, d->io_.laser, d->config_.safety);
  if (!robot_io.ok()) return robot_io.status();
  d->robot_io_ = std::move(*robot_io);
  auto rt = RtController::create(*d->robot_io_, *d->active_, d->rt_options());
  if (!rt.ok()) return rt.status();
  d->rt_ = std::move(*rt);
  return d;
}

RtControllerOptions Daemon::rt_options() const {
  RtControllerOptions ro;
  const double cycle_s = std::chrono::duration<double>(network_.sync_period).count();
  const MeasuringSettings& ms = config_.measuring;
  ro.cycle_s = cycle_s;
  ro.slack_below = config_.tension_watch.slack_below;
  ro.overload_above = config_.tension_watch.overload_above;
  ro.watch_cycles = config_.tension_watch.cycles;
  ro.stuck_raw_units = config_.tension_watch.stuck_raw_units;
  ro.stuck_confirm_cycles = std::clamp(
      static_cast<int>(std::ceil(config_.tension_watch.stuck_confirm_s / cycle_s)), 1, 100000);
  ro.settle_cycles = std::clamp(static_cast<int>(std::ceil(ms.settle_window_s / cycle_s)), 2, 512);
  ro.settle_counts =
      ms.settle_position_tolerance / winch_metres_per_count(active_->model.winches[0]);
  ro.settle_tension = ms.settle_tension_tolerance;
  ro.slew_velocity = config_.motion.max_cable_speed;
  ro.slew_acceleration = config_.motion.max_cable_acceleration;
  ro.stop_limits = motion_limits();
  ro.stream_max_step = config_.motion.stream_max_step;
  ro.stream_max_step_angle = config_.motion.stream_max_step_angle;
  ro.stream_deadline_cycles = config_.motion.stream_deadline_cycles;
  safety_options(ro);
  const TensionControlSettings& tc = config_.tension_control;
  ro.tension_control = TensionControlOptions{tc.gain,     config_.motion.tension_margin,
                                             tc.deadband, tc.max_rate,
                                             tc.max_trim, tc.stale_s,
                                             tc.hold_s,   tc.decay_s};
  return ro;
}

void Daemon::safety_options(RtControllerOptions& ro) const {
  const SafetySettings& s = config_.safety;
  const auto cycles = [&ro](double seconds) {
    return std::clamp(static_cast<int>(std::ceil(seconds / ro.cycle_s)), 0, 1000000);
  };
  ro.brakes = s.brakes.control != BrakeControl::kNone;
  ro.brake_release_cycles = cycles(s.brakes.release_delay_s);
  ro.brake_apply_cycles = cycles(s.brakes.apply_delay_s);
  for (int i = 0; i < active_->model.num_cables(); ++i) {
    ro.min_cable_length[static_cast<std::size_t>(i)] = cable_length_limit(s, i, false);
    ro.max_cable_length[static_cast<std::size_t>(i)] = cable_length_limit(s, i, true);
  }
  ro.cable_length_tolerance = s.cable_length_tolerance;
  ro.workspace_box = s.workspace;
  ro.box_min = s.workspace_min;
  ro.box_max = s.workspace_max;
}

PathCheckOptions Daemon::path_check_options() const {
  const SafetySettings& s = config_.safety;
  PathCheckOptions pc;
  pc.tension_margin = config_.motion.tension_margin;
  if (s.workspace) {
    pc.workspace_box = Eigen::AlignedBox3d(Eigen::Vector3d(s.workspace_min.data()),
                                           Eigen::Vector3d(s.workspace_max.data()));
  }
  const int m = nominal_.num_cables();
  for (int i = 0; i < m && (!s.min_cable_length.empty() || !s.max_cable_length.empty()); ++i) {
    pc.min_cable_lengths.push_back(cable_length_limit(s, i, false));
    pc.max_cable_lengths.push_back(cable_length_limit(s, i, true));
  }
  return pc;
}

void Daemon::transition(SupervisorEvent event, const std::string& reason) {
  Transition t;
  {
    std::lock_guard lock(mu_);
    const bool same_reason = reason == state_reason_;
    t = supervisor_.fire(event);
    if (t.accepted) {
      if (t.action == SupervisorAction::kStopSequence) abort_ = true;
      if (t.action == SupervisorAction::kReleaseWorker) worker_running_ = false;
      // (a self-transition with the same reason, e.g. the RT loop still holding, is no news)
      if (t.to == t.from && same_reason) return;
      state_reason_ = reason;
    }
  }
  if (!t.accepted) {
    spdlog::warn("state {}: {} refused ({}): {}", to_string(t.from), to_string(event), t.refusal,
                 reason);
    return;
  }
  spdlog::info("state {}: {}", to_string(t.to), reason);
  publish("state", {{"state", to_string(t.to)}, {"reason", reason}});
}

void Daemon::publish(const std::string& event, json data) {
  std::function<void(const json&)> sink;
  {
    std::lock_guard lock(sink_mu_);
    sink = sink_;
  }
  if (sink) sink(json{{"event", event}, {"data", std::move(data)}});
}

void Daemon::set_event_sink(std::function<void(const json&)> sink) {
  std::lock_guard lock(sink_mu_);
  sink_ = std::move(sink);
}

double Daemon::now_s() const {
  return std::chrono::duration<double>(io_.clock->now()).count();
}

DaemonState Daemon::state() const {
  std::lock_guard lock(mu_);
  return supervisor_.state();
}

const Geometry* Daemon::active_geometry() const {
  std::lock_guard lock(mu_);
  return active_;
}

int Daemon::active_version() const {
  std::lock_guard lock(mu_);
  return active_version_;
}

void Daemon::set_loop_figures(json figures) {
  std::lock_guard lock(mu_);
  loop_figures_ = std::move(figures);
}

void Daemon::shutdown() {
  abort_ = true;
  if (worker_.joinable()) worker_.join();
}

Status Daemon::apply_brakes_and_disable(double timeout_s) {
  if (config_.safety.brakes.control == BrakeControl::kNone) return Status::success();
  rt_->request_disable();
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (!rt_->snapshot().disabled) {
    if (std::chrono::steady_clock::now() > end) {
      return Status::error(ErrorCode::kTimeout, "brakes and disable: not done within %.1f s",
                           timeout_s);
    }
    std::this_thread::sleep_for(io_.poll);
  }
  spdlog::info("stopping: brakes applied, drives disabled");
  return Status::success();
}

// ---- Start-up ---------------------------------------------------------------------------------

Status Daemon::check_identities() {
  const IdentitySettings& want = config_.identity;
  identities_.clear();
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
    if (n.kind == canopen::NodeKind::kCia402Drive) {
      auto serial = sdo->read<std::uint32_t>({0x1018, 4}, master_->pump());
      if (!serial.ok()) {
        Status s = serial.status();
        return s.prepend("serial number of node " + std::to_string(n.id) + " (" + n.name + "): ");
      }
      identities_.push_back({int{n.id}, *vendor, *product, *serial});
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

std::string Daemon::estop_sources(std::uint32_t open) const {
  std::string which;
  for (std::size_t j = 0; j < config_.safety.estop.size(); ++j) {
    if (((open >> j) & 1u) == 0) continue;
    which += (which.empty() ? "" : "; ") + std::string("source ") + std::to_string(j + 1) + " (" +
             config_.safety.estop[j].where + ")";
  }
  return which;
}

Status Daemon::check_estop() {
  if (config_.safety.estop.empty()) return Status::success();
  // A fresh TPDO of each source's node first (an event-driven one comes within its timer).
  double stale_s = 0.0;
  for (const EStopSource& e : config_.safety.estop) stale_s = std::max(stale_s, e.stale_s);
  (void)master_->wait_for([&] { return robot_io_->safety_open(io_.clock->now()) == 0; },
                          std::chrono::duration_cast<std::chrono::nanoseconds>(
                              std::chrono::duration<double>(2.0 * stale_s)),
                          "e-stop inputs");
  const std::uint32_t open = robot_io_->safety_open(io_.clock->now());
  if (open == 0) return Status::success();
  return Status(ErrorCode::kFailedPrecondition,
                "e-stop input open, silent or stale: " + estop_sources(open) +
                    ": close it, then start cdprd again");
}

Status Daemon::enable_drives() {
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
  return enabled;
}

Status Daemon::start() {
  transition(SupervisorEvent::kBoot, "booting the CANopen network on " + network_.interface);
  const bool at_start = config_.start.enable == StartSettings::Enable::kAtStart;
  Status s = master_->boot();
  if (s.ok()) s = check_identities();
  if (s.ok()) s = check_estop();
  if (s.ok()) s = restore_homing();
  if (s.ok() && at_start) s = enable_drives();
  if (!s.ok()) {
    transition(SupervisorEvent::kStartFailed, "start-up: " + s.to_string());
    return s;
  }
  PoseTrust trust;
  {
    std::lock_guard lock(mu_);
    trust = trust_;
  }
  // Taken by the RT loop once every drive is enabled (now, or at `enable`): it holds the actual
  // positions, nothing moves.
  post_hold(trust);
  running_since_ = io_.clock->now();  // boot-ups after this are reboots
  std::string why = "started with geometry version " + std::to_string(active_version());
  why += trust.trusted ? "; pose from " + trust.source
                       : "; motion refused until cdprctl home: " + trust.reason;
  if (at_start) {
    transition(SupervisorEvent::kStarted, why + "; holding where the drives are");
  } else {
    transition(SupervisorEvent::kStartedDisabled, why + "; drives disabled until cdprctl enable");
  }
  return Status::success();
}

void Daemon::encoder_lengths(const RtSnapshot& snap, const RobotModel& model,
                             const std::array<double, kMaxAxes>& offsets, Eigen::VectorXd& lengths,
                             Eigen::VectorXd& tensions) {
  const int m = model.num_cables();
  lengths.resize(m);
  tensions.resize(m);
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
}

Result<Pose> Daemon::pose_from_encoders(const RobotModel& model) {
  const RtSnapshot snap = rt_->snapshot();
  std::array<double, kMaxAxes> offsets;
  {
    std::lock_guard lock(mu_);
    offsets = offsets_;
  }
  Eigen::VectorXd lengths, tensions;
  encoder_lengths(snap, model, offsets, lengths, tensions);
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

// ---- Motion -----------------------------------------------------------------------------------

std::uint64_t Daemon::post(std::unique_ptr<MotionCommand> c, bool first) {
  std::lock_guard lock(motion_mu_);
  c->seq = next_seq_++;
  MotionCommand* raw = c.get();
  commands_.push_back(std::move(c));
  // A replaced, never-taken command is reclaimed with the older ones.
  if (first) {
    rt_->post_first(raw);
  } else {
    rt_->post(raw);
  }
  return raw->seq;
}

void Daemon::reclaim() {
  std::lock_guard lock(motion_mu_);
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
  const Geometry* g = active_geometry();
  auto traj = PoseTrajectory::plan(s.pose(), pose, motion_limits());
  if (!traj.ok()) return traj.status();
  PathCheckOptions pc = path_check_options();
  pc.reference_tension = std::isnan(reference_tension) ? g->reference_tension : reference_tension;
  if (Status st = check_path(g->model, *traj, pc); !st.ok()) return st;
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kMove;
  c->trajectory = std::move(*traj);
  c->reference_tension = reference_tension;
  return post(std::move(c));
}

MotionLimits Daemon::motion_limits() const {
  MotionLimits limits;
  const MotionSettings& ms = config_.motion;
  limits.max_linear_velocity = ms.max_linear_velocity;
  limits.max_linear_acceleration = ms.max_linear_acceleration;
  limits.max_linear_jerk = ms.max_linear_jerk;
  limits.max_angular_velocity = ms.max_angular_velocity;
  limits.max_angular_acceleration = ms.max_angular_acceleration;
  limits.max_angular_jerk = ms.max_angular_jerk;
  return limits;
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

}  // namespace cdpr::controller
