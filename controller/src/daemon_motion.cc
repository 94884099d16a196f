// Daemon: path runs (`run FILE`) and the setpoint stream (`stream start|stop`), their abort and
// progress (docs/motion.md "Running a path", "Setpoint stream").
#include <spdlog/spdlog.h>

#include <cmath>

#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/path_program.hpp"
#include "cdpr/controller/daemon.hpp"

namespace cdpr::controller {
using json = nlohmann::json;
using control::ControlErrorCode;

namespace {

// A progress event at most this often (robot time), and at each new path line.
constexpr double kProgressEveryS = 1.0;

}  // namespace

// The rules every motion request shares with `move`: no fault, a trusted pose, holding, no
// calibration running.
std::optional<Reply> Daemon::refuse_motion(const char* what) {
  const DaemonState st = state();
  if (st == DaemonState::kFault) {
    return Reply::failure(ControlErrorCode::kFault, "the robot is in fault");
  }
  if (const std::string why = motion_refusal(); !why.empty()) {
    return Reply::failure(ControlErrorCode::kInvalidState, std::string(what) + ": " + why);
  }
  if (st != DaemonState::kHolding || worker_running_.load() ||
      rt_->snapshot().mode != RtMode::kHolding) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string(what) + " starts only while holding (state " + to_string(st) + ")");
  }
  return std::nullopt;
}

Reply Daemon::cmd_run(const json& args, const PeerInfo& peer) {
  const std::string file = args.value("source", std::string("program"));
  if (auto refused = refuse_motion("run")) return *refused;
  const Pose start = rt_->snapshot().pose();
  auto segments = parse_path_program(args["program"].get<std::string>(), file, start);
  if (!segments.ok()) {
    return Reply::failure(ControlErrorCode::kBadRequest, "run: " + segments.status().to_string());
  }
  const Geometry* g = active_geometry();
  PathLimits limits;
  limits.motion = motion_limits();
  limits.max_cable_velocity = config_.motion.max_cable_speed;
  auto path = Path::plan(start, *segments, limits, &g->model, file);
  if (!path.ok()) {
    return Reply::failure(ControlErrorCode::kBadRequest, "run: " + path.status().to_string());
  }
  // The whole path before any motion: tensions in the band with the margin, the box, the cable
  // lengths; the first failing point is named with its line.
  PathCheckOptions pc = path_check_options();
  pc.reference_tension = g->reference_tension;
  PathCheckSummary summary;
  if (Status s = check_path(g->model, *path, pc, &summary); !s.ok()) {
    return Reply::failure(ControlErrorCode::kBadRequest, "run: " + s.to_string());
  }
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kMove;
  const double duration = path->duration(), length = path->length();
  c->path = std::move(*path);
  const std::uint64_t seq = post(std::move(c));
  {
    std::lock_guard lock(mu_);
    run_ = Run{seq, file, duration, length};
  }
  spdlog::info("run {}: {:.2f} s, {:.3f} m, {} points checked, requested by pid {} uid {} gid {}",
               file, duration, length, summary.points, peer.pid, peer.uid, peer.gid);
  transition(SupervisorEvent::kMoveRequested, "path run " + file);
  publish("run", {{"run", seq}, {"file", file}, {"outcome", "running"}, {"duration_s", duration}});
  return Reply::success({{"run", seq},
                         {"file", file},
                         {"duration_s", duration},
                         {"length_m", length},
                         {"points_checked", summary.points}});
}

Reply Daemon::abort_motion(const PeerInfo& peer) {
  std::uint64_t seq = 0;
  {
    std::lock_guard lock(mu_);
    if (run_ && run_->outcome == "running") seq = run_->seq;
    if (stream_seq_ != 0) seq = std::max(seq, stream_seq_);
  }
  if (seq == 0) {
    return Reply::failure(ControlErrorCode::kInvalidState,
                          "no calibration, path run or stream is running");
  }
  spdlog::info("abort (smooth stop of command {}) requested by pid {} uid {} gid {}", seq, peer.pid,
               peer.uid, peer.gid);
  rt_->request_motion_stop(seq);
  return Reply::success({{"aborting", true}, {"command", seq}});
}

std::string Daemon::stream_socket_path() const {
  const std::string& c = config_.control.socket;
  const auto slash = c.find_last_of('/');
  return (slash == std::string::npos ? std::string() : c.substr(0, slash + 1)) +
         "cdprd-stream.sock";
}

Reply Daemon::cmd_stream(const json& args, const PeerInfo& peer) {
  const std::string action = args["action"].get<std::string>();
  if (action == "start") return start_stream(peer);
  if (action == "stop") return stop_stream(peer);
  return Reply::failure(ControlErrorCode::kBadRequest,
                        "stream: action '" + action + "' (start or stop)");
}

Reply Daemon::start_stream(const PeerInfo& peer) {
  if (auto refused = refuse_motion("stream")) return *refused;
  const Geometry* g = active_geometry();
  PathCheckOptions pc = path_check_options();
  pc.reference_tension = g->reference_tension;
  // (the geometry cannot change while the stream runs: a hot swap starts only while holding)
  auto check = [model = g->model, pc](const Pose& p) { return check_pose(model, p, pc); };
  auto sink = [this](const StreamSetpoint& sp) { return rt_->push_setpoint(sp); };
  std::shared_ptr<SetpointReceiver> old;
  {
    std::lock_guard lock(mu_);
    old = std::move(receiver_);
  }
  old.reset();  // a previous stream's (joins its thread)
  auto r = SetpointReceiver::open(stream_socket_path(), check, sink, *io_.clock);
  if (!r.ok()) return Reply::failure(ControlErrorCode::kInternal, r.status().to_string());
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kStream;
  const std::string path = (*r)->path();
  const std::uint64_t seq = post(std::move(c));
  {
    std::lock_guard lock(mu_);
    receiver_ = std::move(*r);
    stream_seq_ = seq;
  }
  spdlog::info("stream started on {} (command {}) by pid {} uid {} gid {}", path, seq, peer.pid,
               peer.uid, peer.gid);
  transition(SupervisorEvent::kMoveRequested, "setpoint stream");
  publish("stream", {{"stream", seq}, {"state", "started"}, {"socket", path}});
  return Reply::success({{"stream", seq}, {"socket", path}});
}

Reply Daemon::stop_stream(const PeerInfo& peer) {
  std::uint64_t seq = 0;
  {
    std::lock_guard lock(mu_);
    seq = stream_seq_;
  }
  if (seq == 0) return Reply::failure(ControlErrorCode::kInvalidState, "no stream is running");
  spdlog::info("stream stop (command {}) requested by pid {} uid {} gid {}", seq, peer.pid,
               peer.uid, peer.gid);
  rt_->request_motion_stop(seq);
  return Reply::success({{"stopping", true}, {"stream", seq}});
}

// The supervisor's tick: a run's progress and end, a stream's end.
void Daemon::follow_motion(const RtSnapshot& s) {
  json event;
  const char* name = "run";
  std::shared_ptr<SetpointReceiver> closing;
  {
    std::lock_guard lock(mu_);
    if (run_ && run_->outcome == "running") {
      Run& r = *run_;
      const bool active = s.command_taken == r.seq;
      if (s.command_done >= r.seq || (active && s.fault.kind != FaultKind::kNone)) {
        r.outcome = s.fault.kind != FaultKind::kNone ? "fault"
                    : s.move.stopped                 ? "aborted"
                                                     : "done";
        event = {{"run", r.seq},
                 {"file", r.file},
                 {"outcome", r.outcome},
                 {"elapsed_s", s.move.elapsed_s},
                 {"line", s.move.line}};
      } else if (active && (s.move.elapsed_s - r.reported_s >= kProgressEveryS ||
                            s.move.line != r.reported_line)) {
        r.reported_s = s.move.elapsed_s;
        r.reported_line = s.move.line;
        event = {{"run", r.seq},
                 {"file", r.file},
                 {"outcome", "running"},
                 {"fraction", r.duration_s > 0.0 ? s.move.elapsed_s / r.duration_s : 1.0},
                 {"elapsed_s", s.move.elapsed_s},
                 {"line", s.move.line}};
      }
    }
    if (stream_seq_ != 0 && (s.command_done >= stream_seq_ || s.fault.kind != FaultKind::kNone ||
                             s.command_taken > stream_seq_)) {
      name = event.is_null() ? "stream" : name;
      const json ended = {{"stream", stream_seq_},
                          {"state", "ended"},
                          {"why", to_string(s.stream.end)},
                          {"setpoint", s.stream.end_seq},
                          {"value", s.stream.end_value}};
      if (event.is_null()) event = ended;
      stream_seq_ = 0;
      closing = std::move(receiver_);
      if (closing) stream_counters_ = closing->counters();
      spdlog::info("stream ended: {}", ended.dump());
    }
  }
  closing.reset();
  if (!event.is_null()) publish(name, event);
}

void Daemon::motion_status(const RtSnapshot& s, json& j) const {
  if (run_) {
    const Run& r = *run_;
    const bool active = r.outcome == "running" && s.command_taken == r.seq;
    const double elapsed = active ? s.move.elapsed_s : 0.0;
    j["run"] = {{"run", r.seq},
                {"file", r.file},
                {"outcome", r.outcome},
                {"stopping", active && s.move.stopping},
                {"fraction", r.duration_s > 0.0 && active ? elapsed / r.duration_s
                             : r.outcome == "done"        ? 1.0
                                                          : 0.0},
                {"elapsed_s", elapsed},
                {"duration_s", r.duration_s},
                {"line", active ? s.move.line : 0}};
  } else {
    j["run"] = nullptr;
  }
  const StreamStatus& st = s.stream;
  json stream = {{"state", to_string(st.state)},
                 {"socket", stream_socket_path()},
                 {"applied", st.applied},
                 {"last_seq", st.last_seq},
                 {"holds", st.holds},
                 {"ended", to_string(st.end)},
                 {"ended_setpoint", st.end_seq},
                 {"ended_value", st.end_value}};
  if (st.latency_count > 0) {
    const double n = static_cast<double>(st.latency_count);
    const double mean = st.latency_sum / n;
    const double var = std::max(0.0, st.latency_sum_sq / n - mean * mean);
    stream["latency_us"] = {{"last", static_cast<double>(st.latency_ns) * 1e-3},
                            {"mean", mean * 1e-3},
                            {"stddev", std::sqrt(var) * 1e-3},
                            {"min", static_cast<double>(st.latency_min_ns) * 1e-3},
                            {"max", static_cast<double>(st.latency_max_ns) * 1e-3},
                            {"count", st.latency_count}};
  }
  {
    const StreamCounters c = receiver_ ? receiver_->counters() : stream_counters_;
    stream["received"] = c.received;
    stream["malformed"] = c.malformed;
    stream["gaps"] = c.gaps;
    stream["reordered"] = c.reordered;
    stream["refused"] = c.refused;
    stream["overflow"] = c.overflow;
  }
  j["stream"] = stream;
}

}  // namespace cdpr::controller
