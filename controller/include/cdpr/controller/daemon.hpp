// cdprd's supervisor: everything around the RT cycle (docs/daemon.md).
//
//   auto d = Daemon::create(config, io);     // loads the robot, network, state directory
//   d->start();                              // boot the bus, check identities, enable, home
//   RT thread:          d->cycle(now)        // every SYNC period (RtController::cycle)
//   supervisor thread:  d->service()         // every ~10 ms: events, faults, hot swap, progress
//   control socket:     d->handle(request)   // status, calibrate, accept, rollback, ...
//
// The daemon is written against its I/O (DaemonIo: a CAN bus endpoint, the laser driver, a clock
// and an idle hook), so a test composes it with the virtual robot on the in-process bus and a
// manual clock, and cdprd composes it with SocketCAN, the Modbus laser and CLOCK_MONOTONIC.
//
// The state machine (status "state") is the table of supervisor.hpp (docs/architecture.md); every
// transition goes through Daemon::transition, which logs it with its reason and publishes it as a
// `state` event. The code is split by concern: daemon.cc (creation, start-up, homing, motion),
// daemon_service.cc (the supervisor's tick), daemon_state.cc (state directory, geometry versions,
// hot swap), daemon_calibration.cc (the calibration run; its measuring steps are
// measuring_sequence.hpp), daemon_commands.cc (control requests and status).
#pragma once

#include <atomic>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/monitoring.hpp"
#include "cdpr/can/can_bus.hpp"
#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/master.hpp"
#include "cdpr/controller/canopen_robot_io.hpp"
#include "cdpr/controller/control_protocol.hpp"
#include "cdpr/controller/daemon_config.hpp"
#include "cdpr/controller/log_coalescer.hpp"
#include "cdpr/controller/rt_controller.hpp"
#include "cdpr/controller/setpoint_stream.hpp"
#include "cdpr/controller/state_store.hpp"
#include "cdpr/controller/supervisor.hpp"
#include "cdpr/modbus/laser_sensor.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/version.hpp"

namespace cdpr::controller {

// `cdprd --version`, and the daemon named in its recordings and reports (cmake/CdprVersion.cmake).
inline constexpr const char* kDaemonVersion = "cdprd " CDPR_VERSION_STRING;

class MeasuringSequence;    // measuring_sequence.hpp
struct CalibrationOutcome;  // calibration_report.hpp

struct DaemonIo {
  can::CanBus* bus = nullptr;            // the master's endpoint
  modbus::LaserSensor* laser = nullptr;  // nullptr: no laser (calibration refused)
  const cdpr::Clock* clock = nullptr;    // CLOCK_MONOTONIC in cdprd, a ManualClock in tests
  std::function<void()> idle;            // while a blocking master call waits (tests step sims)
  // Wall-clock sleep of the supervisor's and the sequence's polling (tests may shorten it).
  std::chrono::microseconds poll{1000};
};

// What the in-service monitor's samples carried, for one geometry (daemon_health.cc).
struct HealthCounts {
  int moving = 0;                    // samples taken during moves
  int moving_skipped_following = 0;  // moves not sampled: a following error above the bound
  int laser = 0;                     // samples at holds with a laser reading
  int laser_skipped = 0;             // samples at holds without one (stale, failed, pre-settle)
};

struct PeerInfo {
  int pid = -1, uid = -1, gid = -1;
};

// The answer to a control request: a result, or a named error (docs/control-protocol.md).
struct Reply {
  bool ok = true;
  nlohmann::json result = nlohmann::json::object();
  control::ControlErrorCode error = control::ControlErrorCode::kInternal;  // when !ok
  std::string code;  // the wire name of `error` (set with it by failure(); for logs and tests)
  std::string message;

  static Reply success(nlohmann::json r) {
    Reply reply;
    reply.result = std::move(r);
    return reply;
  }
  static Reply failure(control::ControlErrorCode kind, std::string text) {
    Reply reply;
    reply.ok = false;
    reply.error = kind;
    reply.code = std::string(control::to_string(kind));
    reply.message = std::move(text);
    return reply;
  }
  control::ControlReply to_control() const {
    return ok ? control::ControlReply::ok(result) : control::ControlReply::error(error, message);
  }
};

class Daemon {
 public:
  static Result<std::unique_ptr<Daemon>> create(DaemonConfig config, DaemonIo io);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Start-up: boots the CANopen network, checks every node's identity against the config, reads
  // the homing record and checks the pose from the encoders against it (daemon_homing.cc), then
  // enables the drives when start.enable is at-start. It never moves the robot: the RT loop holds
  // the drives' actual positions. A pose that cannot be trusted (no or mismatched record, pose
  // check failed) is said in status "pose" and the log, and motion is refused until `home`.
  // The RT loop must not run yet.
  Status start();
  // The orderly stop's part: persists the drives' counts and the pose held in the homing record
  // (clean_stop), when the pose is trusted and the robot holds still. Before shutdown().
  void persist_stop();
  // The RT cycle (allocation-free).
  // While another thread has the master (the drives' own homing), the cycle does nothing: the
  // master then cycles the bus itself.
  void cycle(can::Timestamp now) noexcept {
    in_cycle_.store(true);
    if (!rt_paused_.load()) rt_->cycle(now);
    in_cycle_.store(false);
  }
  // The supervisor's tick: drains the RT loop's events, follows faults and the hot swap,
  // publishes progress. Call every few milliseconds from one thread.
  void service();
  // A control request (any thread; quick: it never waits for the robot).
  Reply handle(const std::string& cmd, const nlohmann::json& args, const PeerInfo& peer);
  // Events for the control socket's watchers ({"event": ..., "data": ...}).
  void set_event_sink(std::function<void(const nlohmann::json&)> sink);
  // Stops a running sequence, holds, joins the worker. The RT loop may keep cycling.
  void shutdown();
  // Before the RT loop stops (SIGTERM): with holding brakes, the RT loop applies them and
  // disables the drives after the apply delay (RtController::request_disable); waits for that up
  // to `timeout_s` of wall time while the loop runs. Without brakes: nothing (the master's
  // shutdown quick-stops and disables).
  Status apply_brakes_and_disable(double timeout_s);

  DaemonState state() const;
  nlohmann::json status() const;
  RtController& rt() { return *rt_; }
  canopen::Master& master() { return *master_; }
  const StateStore& store() const { return *store_; }
  const DaemonConfig& config() const { return config_; }
  // For the RT loop's figures in status (set by the loop driver).
  void set_loop_figures(nlohmann::json figures);

 private:
  struct Calibration {
    int id = 0;
    CalibrationRunOutcome outcome = CalibrationRunOutcome::kMeasuring;
    int pose = 0, poses = 0;
    double started_s = 0.0, elapsed_s = 0.0, remaining_s = 0.0;
    std::string message;
    bool gates_passed = false;
    nlohmann::json summary;
    std::shared_ptr<const RobotModel> proposed;
    int proposed_version = 0;
    int before_version = 0;
  };
  class SequenceRobot;  // the measuring sequence's view of the daemon (daemon_calibration.cc)
  struct Identified;    // what the identification rounds produce (daemon_calibration.cc)
  using Handler = Reply (Daemon::*)(const nlohmann::json& args, const PeerInfo& peer);

  Daemon(DaemonConfig config, DaemonIo io);
  RtControllerOptions rt_options() const;
  // The safety chain's part of them, and the limits every move and pose is checked against.
  void safety_options(RtControllerOptions& ro) const;
  PathCheckOptions path_check_options() const;
  MotionLimits motion_limits() const;
  Status check_identities();
  Status enable_drives();

  // Homing and the pose check (daemon_homing.cc).
  struct PoseTrust {
    bool trusted = false;
    Pose pose;
    std::string source;  // persisted | encoders | homed (reference | absolute)
    std::string reason;  // why not trusted: what refuses motion
  };
  Status restore_homing();
  PoseTrust verify_pose(const RobotModel& model, const std::array<double, kMaxAxes>& offsets,
                        const std::vector<double>* counts, const Pose* persisted);
  void set_trust(PoseTrust trust, const std::string& why);
  HomingRecord new_record(const std::string& method, const std::array<double, kMaxAxes>& offsets);
  Result<std::array<double, kMaxAxes>> reference_offsets();
  void post_hold(const PoseTrust& trust, bool first = false);
  void persist_hold(const RtSnapshot& s, bool clean_stop);
  std::vector<double> actual_counts();
  std::string motion_refusal() const;  // "" when motion may be commanded
  void follow_enable(const RtSnapshot& s);
  // Start-up: every e-stop source reads closed, else the start is refused naming the open ones.
  Status check_estop();
  // "source 1 (cdprd.yaml:41: safety.estop[0]); ..." for the sources open in `open`.
  std::string estop_sources(std::uint32_t open) const;

  // The one place a state changes: fires `event` in the supervisor table, runs the row's action,
  // logs and publishes the change (a refused event is logged and changes nothing).
  void transition(SupervisorEvent event, const std::string& reason);
  void publish(const std::string& event, nlohmann::json data);
  double now_s() const;
  const Geometry* active_geometry() const;
  int active_version() const;

  // State directory and geometry versions (daemon_state.cc).
  Status load_state();
  Status first_start(Result<int>& active);
  void repair_recordings();
  const Geometry* make_geometry(int version, const RobotModel& model);
  Status activate(int version, const nlohmann::json& why, const PeerInfo* peer);
  void interrupt_swap(const std::string& fault);
  void complete_swap(const RtSnapshot& s);

  // The supervisor's tick (daemon_service.cc).
  void log_rt_events();
  void watch_slack(const RtSnapshot& s);
  void watch_tension_control(const RtSnapshot& s);
  // In-service monitoring (daemon_health.cc): a sample per period while settled, events.
  void watch_health(const RtSnapshot& s);
  double health_speed(const RtSnapshot& s);  // under health_mu_
  // Under health_mu_: the laser's reading for a sample at a settled hold (NaN: none usable).
  double health_laser(const Geometry& g);
  // The largest following error of the drives, as cable length (m).
  static double following_error_m(const RtSnapshot& s, const RobotModel& model);
  Status restart_monitor(const Geometry& g);
  void latch_fault(const RtSnapshot& s);
  void after_fault_reset();

  // Motion (supervisor or worker thread).
  std::uint64_t post(std::unique_ptr<MotionCommand> c, bool first = false);
  void reclaim();
  Status wait_rt(const std::function<bool(const RtSnapshot&)>& done, double timeout_s,
                 const char* what, bool abortable);
  // Plans and checks a move from the commanded pose, posts it; returns its sequence number.
  Result<std::uint64_t> start_move(const Pose& pose, double reference_tension);
  Status move_to(const Pose& pose, double reference_tension, bool abortable);
  Status hold_still(bool abortable);
  Result<Pose> pose_from_encoders(const RobotModel& model);
  // The cable lengths the encoders read in `snap` (the master's before the loop runs) with
  // `offsets`, and the measured tensions (0 without force readings).
  void encoder_lengths(const RtSnapshot& snap, const RobotModel& model,
                       const std::array<double, kMaxAxes>& offsets, Eigen::VectorXd& lengths,
                       Eigen::VectorXd& tensions);

  // The calibration run (worker thread; daemon_calibration.cc).
  void run_calibration(std::vector<Pose> poses, PeerInfo peer);
  Result<std::vector<Pose>> plan_poses(const std::string& poses_csv);
  recording::Recording recording_header(const Geometry& g) const;
  Status regulate_tensions(int pose_index);
  Status sample_pose(recording::RecordedPose& row);
  Status identify_rounds(int id, MeasuringSequence& seq, Identified& result);
  Status measure_more(int id, std::vector<Pose> poses, std::vector<double> pretensions,
                      const std::string& what, MeasuringSequence& seq);
  Result<nlohmann::json> write_report(int id, const Geometry& g, const MeasuringSequence& seq,
                                      const Identified& result, const CalibrationOutcome& out);
  void await_acceptance(int id, const Geometry& g, const CalibrationOutcome& out,
                        nlohmann::json summary, const PeerInfo& peer);
  void finish_calibration(CalibrationRunOutcome outcome, const std::string& message);
  void fail_calibration(const Status& s);

  // Control requests (daemon_commands.cc; status in daemon_status.cc).
  static Handler handler(control::Command command);
  Reply cmd_status(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_calibrate(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_watch(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_abort(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_accept(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_reject(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_geometry_show(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_geometry_diff(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_geometry_history(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_rollback(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_report(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_stop(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_fault_reset(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_move(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_enable(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_disable(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_home(const nlohmann::json& args, const PeerInfo& peer);
  // The drives' own homing (CiA 402 mode 6, methods 35/37) with the platform on its reference:
  // each drive's position actual becomes the active model's counts at home. The RT loop is
  // paused meanwhile; it resumes holding the new counts (untrusted when a drive failed).
  Result<std::array<double, kMaxAxes>> drive_homing();

  // Path runs and the setpoint stream (daemon_motion.cc).
  struct Run {
    std::uint64_t seq = 0;
    std::string file;
    double duration_s = 0.0, length_m = 0.0;
    std::string outcome = "running";  // running | done | aborted | fault
    double reported_s = -1.0;         // robot time of the last progress event
    int reported_line = -1;
  };
  Reply cmd_run(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_stream(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_health(const nlohmann::json& args, const PeerInfo& peer);
  Reply abort_motion(const PeerInfo& peer);
  std::optional<Reply> refuse_motion(const char* what);
  Reply start_stream(const PeerInfo& peer);
  Reply stop_stream(const PeerInfo& peer);
  void follow_motion(const RtSnapshot& s);
  void motion_status(const RtSnapshot& s, nlohmann::json& j) const;  // under mu_
  std::string stream_socket_path() const;

  // Locking rule: the three mutexes are never held together, and none is held while calling the
  // RT controller (except post/command_in_use under motion_mu_), the store, the log or the event
  // sink. A field's group says which mutex guards it.

  // Fixed once the daemon runs: set by create() and start() before any other thread starts; read
  // without a lock (the store and the master are called from one thread at a time: the master by
  // start() then only the RT loop; the store by the supervisor, the worker and the requests, whose
  // writes are atomic files and whose reads follow them).
  DaemonConfig config_;
  DaemonIo io_;
  RobotModel nominal_;
  canopen::MasterConfig network_;
  std::unique_ptr<StateStore> store_;
  std::unique_ptr<canopen::Master> master_;
  std::unique_ptr<CanopenRobotIO> robot_io_;
  std::unique_ptr<RtController> rt_;
  can::Timestamp running_since_{0};  // end of start-up: boot-ups after it are reboots
  LogCoalescer bus_log_;  // the RT loop's CANopen events for the log: service()'s thread only

  // Under mu_: what status shows and the supervisor, requests and worker decide on.
  mutable std::mutex mu_;
  Supervisor supervisor_;  // the state
  std::string state_reason_;
  RtFault last_fault_;
  std::string fault_text_;
  std::set<int> rebooted_nodes_;  // nodes that booted while the daemon ran (need a restart)
  std::string warning_;  // a condition that is named but does not stop the robot (a slack cable)
  TensionControlState tension_state_ = TensionControlState::kOff;  // as last logged
  nlohmann::json loop_figures_ = nlohmann::json::object();
  int active_version_ = 0;
  std::vector<std::unique_ptr<Geometry>> geometries_;  // kept while the RT loop may use them
  const Geometry* active_ = nullptr;
  std::optional<int> swap_target_;  // version being applied
  std::uint64_t swap_seq_ = 0;
  std::string swap_why_;
  std::optional<Calibration> calibration_;
  std::optional<Run> run_;                      // the last path run
  std::uint64_t stream_seq_ = 0;                // the stream command in force (0: none)
  std::shared_ptr<SetpointReceiver> receiver_;  // while a stream runs
  StreamCounters stream_counters_;              // the last stream's, once it ended
  // The pose the daemon holds and whether it may command motion from it; the homing record in
  // force (nullopt: none valid for these drives and this geometry); the encoder offsets of both.
  PoseTrust trust_;
  std::optional<HomingRecord> record_;
  std::array<double, kMaxAxes> offsets_{};
  std::vector<DriveIdentity> identities_;  // the drives as read at boot, in cable order

  // Under motion_mu_: the commands handed to the RT loop (post, reclaim).
  std::mutex motion_mu_;
  std::deque<std::unique_ptr<MotionCommand>> commands_;
  std::uint64_t next_seq_ = 1;

  // Under health_mu_: the in-service monitor of the active geometry (service() feeds it, the
  // health request reads it).
  mutable std::mutex health_mu_;
  std::unique_ptr<Monitor> monitor_;
  int monitor_version_ = -1;  // geometry version it monitors
  // Its model uncertainty and acceptance figure, each {value, source}: the calibration's or the
  // config's (daemon_health.cc monitor_figures).
  nlohmann::json monitor_figures_;
  std::int64_t monitor_start_ns_ = 0;   // robot time it started
  std::int64_t monitor_sample_ns_ = 0;  // of its last sample
  std::int64_t monitor_assess_ns_ = 0;  // of its last assessment
  bool health_alarmed_ = false;         // the alarm event was raised for this geometry
  bool health_alerted_ = false;         // the change event was raised for this geometry
  // The previous supervisor tick's commanded position and time (the platform's speed in moves).
  std::array<double, 3> health_last_position_{};
  std::int64_t health_last_ns_ = -1;
  HealthCounts health_counts_;
  // CLOCK_MONOTONIC (the laser's time base) when the supervisor first saw the current settled
  // hold; -1: not holding settled.
  std::int64_t health_settled_mono_ns_ = -1;

  // Under sink_mu_: where events go.
  std::mutex sink_mu_;
  std::function<void(const nlohmann::json&)> sink_;

  // The calibration worker: the thread object is touched by the control requests (one at a time:
  // the control server calls handle() from one thread) and shutdown(); the flags are atomic.
  std::thread worker_;
  // The RT loop leaves the master to the thread that set rt_paused_ once in_cycle_ reads false
  // (both sequentially consistent: either the cycle sees the pause or the pauser sees the cycle).
  std::atomic<bool> in_cycle_{false};
  std::atomic<bool> rt_paused_{false};
  std::atomic<bool> abort_{false};
  std::atomic<bool> worker_running_{false};
};

}  // namespace cdpr::controller
