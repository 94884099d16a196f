// Daemon::service, the supervisor's tick: the RT loop's events, a slack cable's warning, a latched
// fault and its reset, the hot swap's completion, and the state following the RT loop's mode.
#include <spdlog/spdlog.h>

#include <cstdio>

#include "cdpr/controller/daemon.hpp"
#include "daemon_text.hpp"

namespace cdpr::controller {
using json = nlohmann::json;

void Daemon::service() {
  reclaim();
  log_rt_events();
  const RtSnapshot s = rt_->snapshot();
  watch_slack(s);
  watch_tension_control(s);
  watch_health(s);
  follow_motion(s);
  const DaemonState st = state();
  if (s.fault.kind != FaultKind::kNone && st != DaemonState::kFault &&
      st != DaemonState::kStarting) {
    latch_fault(s);
    return;
  }
  if (st == DaemonState::kFault && s.fault.kind == FaultKind::kNone && s.all_enabled &&
      !worker_running_.load()) {
    after_fault_reset();
    return;
  }
  if (st == DaemonState::kApplying) {
    complete_swap(s);
    return;
  }
  follow_enable(s);
  if (!worker_running_.load() && (st == DaemonState::kHolding || st == DaemonState::kMoving)) {
    const bool moving = s.mode == RtMode::kMoving;
    transition(moving ? SupervisorEvent::kRtMoving : SupervisorEvent::kRtHolding,
               moving ? "moving" : "holding");
  }
}

void Daemon::log_rt_events() {
  const auto warn_bus = [this](const std::string& line) {
    spdlog::warn("CANopen: {}", line);
    publish("log", {{"level", "warning"}, {"message", line}});
  };
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
}

// A slack cable is named (status "warning", the log, a `warning` event) but does not stop the
// robot: an 8-cable robot keeps control with one slack cable (docs/daemon.md).
// The tension control frozen or decaying (stale or faulty force readings) is logged when it
// starts and when the control is active again.
void Daemon::watch_tension_control(const RtSnapshot& s) {
  const TensionControlState now = s.tension_control.state;
  if (now == tension_state_) return;
  const TensionControlState was = tension_state_;
  tension_state_ = now;
  const bool degraded =
      now == TensionControlState::kFrozen || now == TensionControlState::kDecaying;
  if (!degraded && was != TensionControlState::kFrozen && was != TensionControlState::kDecaying) {
    return;
  }
  const std::string line =
      degraded ? std::string("tension control ") + to_string(now) +
                     ": force readings stale or faulty, trims held then decaying to 0"
               : std::string("tension control ") + to_string(now) + " again";
  spdlog::warn("{}", line);
  publish("log", {{"level", "warning"}, {"message", line}});
}

void Daemon::watch_slack(const RtSnapshot& s) {
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
  if (!new_warning) return;
  if (!warning.empty()) {
    spdlog::warn("warning: {}", warning);
    publish("warning", {{"warning", "slack_cable"}, {"message", warning}});
  } else {
    spdlog::info("warning cleared: {}", old_warning);
    publish("warning", {{"warning", nullptr}, {"message", "cleared: " + old_warning}});
  }
}

void Daemon::latch_fault(const RtSnapshot& s) {
  const std::string text = detail::fault_text(s.fault);
  {
    std::lock_guard lock(mu_);
    last_fault_ = s.fault;
    fault_text_ = text;
  }
  spdlog::error("fault: {}", text);
  interrupt_swap(text);
  publish("fault", {{"fault", to_string(s.fault.kind)},
                    {"node", s.fault.node},
                    {"cable", s.fault.cable + 1},
                    {"message", text}});
  transition(SupervisorEvent::kFaultLatched, text);
}

// After fault_reset: the platform is where the quick stop left it. The RT loop holds the drives
// there (nothing moves); the pose is checked again, and when it cannot be trusted the daemon
// holds the counts and refuses motion until `home`.
void Daemon::after_fault_reset() {
  const Geometry* g = active_geometry();
  std::array<double, kMaxAxes> offsets;
  bool was_trusted = false;
  Pose before;
  {
    std::lock_guard lock(mu_);
    offsets = offsets_;
    was_trusted = trust_.trusted;
    before = trust_.pose;
  }
  PoseTrust t = verify_pose(g->model, offsets, nullptr, nullptr);
  if (!was_trusted && t.trusted) {
    // A pose that was not trusted before the fault is not trusted by a fault reset either.
    t.trusted = false;
    t.reason = "not homed since the start-up";
  }
  if (!t.trusted) t.pose = before;
  set_trust(t, "after the fault reset");
  post_hold(t);
  transition(SupervisorEvent::kFaultCleared,
             t.trusted ? "fault reset; holding where the platform stopped"
                       : "fault reset; holding the drives where they stopped, motion refused "
                         "until cdprctl home: " +
                             t.reason);
}

}  // namespace cdpr::controller
