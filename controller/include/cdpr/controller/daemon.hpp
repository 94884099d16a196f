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
// State machine (status "state"): starting -> holding <-> moving; holding -> measuring ->
// identifying -> awaiting_acceptance -> applying -> holding; fault from every state (a latched
// RT fault, a failed start-up); fault -> holding through fault_reset. Each transition is logged
// with its reason and published as a `state` event.
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
#include "cdpr/can/can_bus.hpp"
#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/master.hpp"
#include "cdpr/controller/daemon_config.hpp"
#include "cdpr/controller/log_coalescer.hpp"
#include "cdpr/controller/rt_controller.hpp"
#include "cdpr/controller/state_store.hpp"
#include "cdpr/modbus/laser_sensor.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/version.hpp"

namespace cdpr::controller {

// `cdprd --version`, and the daemon named in its recordings and reports (cmake/CdprVersion.cmake).
inline constexpr const char* kDaemonVersion = "cdprd " CDPR_VERSION_STRING;

struct DaemonIo {
  can::CanBus* bus = nullptr;            // the master's endpoint
  modbus::LaserSensor* laser = nullptr;  // nullptr: no laser (calibration refused)
  const cdpr::Clock* clock = nullptr;    // CLOCK_MONOTONIC in cdprd, a ManualClock in tests
  std::function<void()> idle;            // while a blocking master call waits (tests step sims)
  // Wall-clock sleep of the supervisor's and the sequence's polling (tests may shorten it).
  std::chrono::microseconds poll{1000};
};

enum class DaemonState {
  kStarting,
  kHolding,
  kMoving,
  kMeasuring,
  kIdentifying,
  kAwaitingAcceptance,
  kApplying,
  kFault,
  kStopped,
};
const char* to_string(DaemonState s);

struct PeerInfo {
  int pid = -1, uid = -1, gid = -1;
};

// The answer to a control request: a result, or a named error (docs/control-protocol.md).
struct Reply {
  bool ok = true;
  nlohmann::json result = nlohmann::json::object();
  std::string code;  // bad_request, invalid_state, not_found, busy, fault, internal
  std::string message;

  static Reply success(nlohmann::json r) { return Reply{true, std::move(r), {}, {}}; }
  static Reply failure(std::string code, std::string message) {
    return Reply{false, nlohmann::json::object(), std::move(code), std::move(message)};
  }
};

class Daemon {
 public:
  static Result<std::unique_ptr<Daemon>> create(DaemonConfig config, DaemonIo io);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Start-up: boots the CANopen network, checks every node's identity against the config,
  // enables the drives (no jump) and homes: with stored encoder offsets the pose comes from the
  // forward kinematics of the encoders; without, the platform stands on the reference platform
  // at home and the offsets are taken and stored. The RT loop must not run yet.
  Status start();
  // The RT cycle (allocation-free).
  void cycle(can::Timestamp now) noexcept { rt_->cycle(now); }
  // The supervisor's tick: drains the RT loop's events, follows faults and the hot swap,
  // publishes progress. Call every few milliseconds from one thread.
  void service();
  // A control request (any thread; quick: it never waits for the robot).
  Reply handle(const std::string& cmd, const nlohmann::json& args, const PeerInfo& peer);
  // Events for the control socket's watchers ({"event": ..., "data": ...}).
  void set_event_sink(std::function<void(const nlohmann::json&)> sink);
  // Stops a running sequence, holds, joins the worker. The RT loop may keep cycling.
  void shutdown();

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
    std::string outcome;  // measuring, identifying, awaiting_acceptance, applied, rejected, failed,
                          // aborted
    int pose = 0, poses = 0;
    double started_s = 0.0, elapsed_s = 0.0, remaining_s = 0.0;
    std::string message;
    bool gates_passed = false;
    nlohmann::json summary;
    std::shared_ptr<const RobotModel> proposed;
    int proposed_version = 0;
    int before_version = 0;
  };

  Daemon(DaemonConfig config, DaemonIo io);
  Status load_state();
  void repair_recordings();
  Status check_identities();
  Status home();
  void set_state(DaemonState s, const std::string& reason);
  void publish(const std::string& event, nlohmann::json data);
  double now_s() const;

  // Motion (supervisor or worker thread).
  std::uint64_t post(std::unique_ptr<MotionCommand> c);
  void reclaim();
  Status wait_rt(const std::function<bool(const RtSnapshot&)>& done, double timeout_s,
                 const char* what, bool abortable);
  // Plans and checks a move from the commanded pose, posts it; returns its sequence number.
  Result<std::uint64_t> start_move(const Pose& pose, double reference_tension);
  Status move_to(const Pose& pose, double reference_tension, bool abortable);
  Status hold_still(bool abortable);
  Result<Pose> pose_from_encoders(const RobotModel& model);
  const Geometry* make_geometry(int version, const RobotModel& model);
  Status activate(int version, const nlohmann::json& why, const PeerInfo* peer);

  // The calibration sequence (worker thread).
  void run_calibration(std::vector<Pose> poses, PeerInfo peer);
  Status measure_pose(const Pose& pose, double reference_tension, recording::RecordedPose& row);
  Status regulate_tensions(int pose_index);
  Result<std::vector<Pose>> plan_poses(const std::string& poses_csv);
  void finish_calibration(const std::string& outcome, const std::string& message);

  Reply cmd_status() const;
  Reply cmd_calibrate(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_accept(const PeerInfo& peer);
  Reply cmd_reject(const PeerInfo& peer);
  Reply cmd_rollback(const nlohmann::json& args, const PeerInfo& peer);
  Reply cmd_geometry_show(const nlohmann::json& args) const;
  Reply cmd_geometry_diff(const nlohmann::json& args) const;
  Reply cmd_geometry_history() const;
  Reply cmd_report(const nlohmann::json& args) const;
  Reply cmd_move(const nlohmann::json& args, const PeerInfo& peer);

  DaemonConfig config_;
  DaemonIo io_;
  RobotModel nominal_;
  canopen::MasterConfig network_;
  std::unique_ptr<StateStore> store_;
  std::unique_ptr<canopen::Master> master_;
  std::unique_ptr<RtController> rt_;

  mutable std::mutex mu_;  // everything below
  DaemonState state_ = DaemonState::kStarting;
  std::string state_reason_;
  int active_version_ = 0;
  std::deque<std::unique_ptr<MotionCommand>> commands_;
  std::uint64_t next_seq_ = 1;
  std::vector<std::unique_ptr<Geometry>> geometries_;  // kept while the RT loop may use them
  const Geometry* active_ = nullptr;
  std::optional<Calibration> calibration_;
  std::optional<int> swap_target_;  // version being applied
  std::uint64_t swap_seq_ = 0;
  std::string swap_why_;
  RtFault last_fault_;
  std::string fault_text_;
  can::Timestamp running_since_{0};  // end of start-up (set once, before the RT loop runs)
  std::set<int> rebooted_nodes_;     // nodes that booted while the daemon ran (need a restart)
  LogCoalescer bus_log_;             // the RT loop's CANopen events, for the log (service())
  std::string warning_;  // a condition that is named but does not stop the robot (a slack cable)
  nlohmann::json loop_figures_ = nlohmann::json::object();
  std::function<void(const nlohmann::json&)> sink_;
  std::thread worker_;
  std::atomic<bool> abort_{false};
  std::atomic<bool> worker_running_{false};
  std::mutex post_mu_;  // one poster at a time
};

}  // namespace cdpr::controller
