// The per-cycle part of cdprd: read -> update -> write against the robot's I/O (RobotIO).
//
//   RtController rt(io, geometry, options);     // non-RT: sizes every buffer once
//   rt.set_encoder_offsets(offsets);             // non-RT, before the loop runs
//   rt.post(command);                            // any thread: a move, or a re-reference
//   loop: rt.cycle(now);                         // RT thread, once per SYNC period
//   RtSnapshot s = rt.snapshot();                // any thread, lock-free
//
// cycle(now) is a list of named stages, each a private function, on this cycle's readings:
//   read_inputs        io.read(now): actual counts, tensions, drive states, bus events
//   take_requests      an operator's quick stop or fault reset (refused while an e-stop input
//                      reads open), a disable or enable (atomics, any thread)
//   watch_faults       drive faults, lost nodes, bus-off, an open e-stop input (or its node
//                      silent or stale), overloaded or slack cables, a stuck force reading: a
//                      fault quick-stops every drive and is latched until fault_reset() (an
//                      e-stop's only once every input reads closed again)
//   take_command       a posted command at the cycle boundary (move, trim, re-reference)
//   sample_trajectory  the pose to command (the active trajectory or path, the setpoint stream,
//                      or the pose held; a stop request decelerates along the path,
//                      rt_controller_motion.cc)
//   control_tensions   tension control in the null space of the structure matrix
//                      (tension_control.hpp): the measured tensions trim the cable targets
//                      towards the band, while holding and moving
//   compute_targets    tension plan (QP, allocation-free) and compensated inverse kinematics
//                      with the active geometry
//   slew_targets       the drive targets: the re-reference slew, or the IK plus the
//                      rate-limited tension-regulation trims
//   check_limits       the commanded pose inside the workspace box, each commanded cable length
//                      (and the actual one, within a tolerance) inside its winch's limits; else a
//                      latched quick stop naming the winch, and this cycle's target is not sent
//   sequence_brakes    each holding brake released only once its drive has been OPERATION_ENABLED
//                      for the release delay; applied at once on a fault, an e-stop or a disable
//                      request, the drives disabled only after the apply delay
//   write_outputs      io.write(command): the targets and the state requests of this cycle
//   update_settle      the stillness window and the averages the sequence asked for
//   publish            the snapshot (seqlock); the bus events go to an SPSC ring
// cycle() allocates, locks, logs and throws nothing (tests prove it).
//
// Geometry hand-over (hot swap): a kReference command carries an immutable Geometry snapshot and
// the pose to hold under it. It is taken only while holding still (settled); the drive targets
// then start exactly where they were and slew (per-axis velocity and acceleration limits) to the
// new geometry's targets for that pose, so the commanded positions do not jump. The caller owns
// Geometry and RtCommand objects; they must outlive their use: see released_up_to().
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>

#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/calibration/slew.hpp"
#include "cdpr/calibration/trajectory.hpp"
#include "cdpr/canopen/events.hpp"
#include "cdpr/controller/motion_command.hpp"
#include "cdpr/controller/robot_io.hpp"
#include "cdpr/controller/spsc_ring.hpp"
#include "cdpr/controller/tension_control.hpp"
#include "cdpr/core/seqlock.hpp"

namespace cdpr::controller {

enum class RtMode : std::uint8_t {
  kDisabled,       // drives not (yet) enabled, or stopped after a fault: targets follow the actuals
  kHolding,        // holding a pose
  kMoving,         // following a trajectory
  kSlewing,        // re-referenced: the targets slew to the geometry's targets for the hold pose
  kHoldingCounts,  // holding the drives' counts as they were, without kinematics (pose unknown)
};
const char* to_string(RtMode m);

enum class FaultKind : std::uint8_t {
  kNone,
  kDriveFault,   // a drive reported FAULT (EMCY code in `code`)
  kNodeLost,     // heartbeat lost
  kBusOff,       // the CAN controller went bus-off
  kSlackCable,   // a measured tension fell below the slack limit
  kOverload,     // a measured tension exceeded the overload limit
  kCommand,      // the inverse kinematics or the tension planner failed at the commanded pose
  kQuickStop,    // an operator's quick stop
  kForceSensor,  // no force readings while they are required
  kForceStuck,   // a force reading did not change while its cable's tension was made to change
  kEStop,        // an e-stop / STO input open, silent or stale (`code`: the source, from 1)
  kCableLimit,   // a commanded or actual cable length outside its winch's limits (`value`, m)
  kWorkspace,    // the commanded platform position outside the workspace box (`code`: axis 0..2)
};
const char* to_string(FaultKind f);

struct RtFault {
  FaultKind kind = FaultKind::kNone;
  int node = 0;            // CANopen node, 0 when none
  int cable = -1;          // 0-based cable, -1 when none
  std::uint16_t code = 0;  // EMCY code
  double value = 0.0;      // the tension that tripped, N
  std::int64_t time_ns = 0;
};

// An array with every axis set to `v`.
constexpr std::array<double, kMaxAxes> axes_filled(double v) {
  std::array<double, kMaxAxes> a{};
  for (double& x : a) x = v;
  return a;
}

struct RtControllerOptions {
  double slack_below = 1.0;        // N
  double overload_above = 0.0;     // N; 0: 1.1 x f_max of each cable
  int watch_cycles = 5;            // consecutive cycles before a tension fault
  double cycle_s = 0.004;          // SYNC period, s
  int settle_cycles = 50;          // window of the stillness test
  double settle_counts = 10.0;     // spread of each encoder in the window, counts
  double settle_tension = 1.0;     // spread of each tension in the window, N
  double slew_velocity = 0.2;      // m/s of cable, re-reference slew
  double slew_acceleration = 1.0;  // m/s^2
  double trim_velocity = 0.002;    // m/s of cable, rate of a tension-regulation trim
  // Stuck force reading: a channel whose raw value stays the same while its cable's planned
  // tension spans more than `stuck_raw_units` raw units (or, while holding, its tension-regulation
  // trims are worth 2 times that by the cable's stiffness), for `stuck_confirm_cycles` cycles
  // (the cable's response lags the command). 0: off.
  double stuck_raw_units = 12.0;
  int stuck_confirm_cycles = 50;
  // Holding brakes (one per winch): none to sequence when false (release_brake is always set).
  bool brakes = false;
  int brake_release_cycles = 25;  // a drive enabled this long holds torque: its brake releases
  int brake_apply_cycles = 25;    // the brakes applied this long before the drives are disabled
  // Kinematic cable lengths allowed to each winch (frame anchor to platform anchor, m), and how
  // far an actual length may lie beyond them (the drives' following error).
  std::array<double, kMaxAxes> min_cable_length{};
  std::array<double, kMaxAxes> max_cable_length =
      axes_filled(std::numeric_limits<double>::infinity());
  double cable_length_tolerance = 0.002;
  // Allowed commanded positions of the platform origin (world, m); off when !workspace_box.
  bool workspace_box = false;
  std::array<double, 3> box_min{}, box_max{};
  // Tension control in the null space (gain 0: off; tension_control.hpp).
  TensionControlOptions tension_control;
  // A stopped move or path (request_motion_stop) slows down along its path: its time runs at a
  // rate r going from 1 to 0 on a double-S profile with dr/dt <= a / v, d2r/dt2 <= j / v and
  // d3r/dt3 <= j^2 / (a v) (the tighter of the linear and the angular class), which adds at most
  // a to the acceleration and j to the jerk the path has at that point. The setpoint stream's
  // smooth hold uses the linear and angular acceleration and jerk limits.
  MotionLimits stop_limits;
  // The setpoint stream: a setpoint further than these from the commanded pose is refused (the
  // stream ends, the robot holds); none newer for this many cycles: the robot holds (smoothly)
  // until one comes within the step limit again.
  double stream_max_step = 0.002;       // m
  double stream_max_step_angle = 0.01;  // rad
  int stream_deadline_cycles = 3;
};

// The setpoint stream as the RT loop sees it (RtSnapshot::stream).
enum class StreamState : std::uint8_t {
  kOff,        // no stream command active
  kFollowing,  // the last setpoint is applied
  kHolding,    // late or missing setpoints: decelerated, waiting for one within the step limit
  kStopping,   // ending (stop request, refused setpoint): decelerating, then the robot holds
};
const char* to_string(StreamState s);

enum class StreamEnd : std::uint8_t {
  kNone,
  kStopped,      // the operator's stop
  kStepRefused,  // a setpoint too far from the commanded pose (value: its distance, m or rad)
  // The first setpoint from rest (the stream's start, after a hold) further from the held pose
  // than the acceleration limit covers in one cycle from rest (value: its distance, m or rad).
  kResumeRefused,
  kRefused,  // the receiver refused a setpoint (box, tensions, cable lengths)
  kFault,    // a fault ended it
};
const char* to_string(StreamEnd e);

struct StreamStatus {
  StreamState state = StreamState::kOff;
  StreamEnd end = StreamEnd::kNone;  // why the last stream ended
  std::uint64_t end_seq = 0;         // the setpoint that ended it (refusals)
  double end_value = 0.0;      // kStepRefused, kResumeRefused: the step, m (or rad when angular)
  std::uint64_t applied = 0;   // setpoints applied
  std::uint64_t last_seq = 0;  // of the last applied setpoint
  std::uint64_t holds = 0;     // times the deadline passed without a setpoint
  // Latency of the last applied setpoint: sender timestamp to the cycle that applied it, ns (on
  // one machine, both CLOCK_MONOTONIC); and receive to apply.
  std::int64_t latency_ns = 0;
  std::int64_t queue_ns = 0;
  // Over every applied setpoint since the stream started: count, sum and sum of squares (ns,
  // ns^2: mean and standard deviation, the jitter), smallest and largest latency.
  std::uint64_t latency_count = 0;
  double latency_sum = 0.0, latency_sum_sq = 0.0;
  std::int64_t latency_min_ns = 0, latency_max_ns = 0;
};

// What the RT loop reports about the move in progress (a move or a path run).
struct MoveProgress {
  double elapsed_s = 0.0;   // path time reached (it runs slower while stopping)
  double duration_s = 0.0;  // of the whole move
  int line = 0;             // path file line at the current point (0: none)
  bool stopping = false;    // a stop request is being carried out
  bool stopped = false;     // the last move ended by a stop request, not at its end
};

// What any thread may read about the loop (trivially copyable, published every cycle).
struct RtSnapshot {
  std::uint64_t cycle = 0;
  std::int64_t now_ns = 0;
  RtMode mode = RtMode::kDisabled;
  RtFault fault;
  bool all_enabled = false;
  // The safety chain: inputs read open (bit j: source j), every holding brake released, the
  // drives disabled on request (request_disable) with their brakes applied.
  std::uint32_t safety_open = 0;
  bool brakes_released = false;
  bool disabled = false;
  std::uint64_t command_taken = 0;  // sequence number of the active command
  std::uint64_t command_done = 0;   // of the last command that finished (move ended, slew done)
  int geometry_version = 0;
  bool settled = false;
  std::array<double, 6> pose_vector{};  // commanded pose: x, y, z (m), roll, pitch, yaw (rad)
  Pose pose() const {
    return Pose{Eigen::Vector3d(pose_vector[0], pose_vector[1], pose_vector[2]),
                Eigen::Vector3d(pose_vector[3], pose_vector[4], pose_vector[5])};
  }
  double reference_tension = 0.0;  // N, pretension of the tension planner now
  int num_cables = 0;
  bool have_tensions = false;
  std::array<double, kMaxAxes> tensions{};       // measured, N
  std::array<double, kMaxAxes> planned{};        // planned, N
  std::array<double, kMaxAxes> actual_counts{};  // drive position actual
  std::array<double, kMaxAxes> target_counts{};  // drive target sent
  std::array<double, kMaxAxes> trim_counts{};    // tension-regulation trims in force
  TensionControlStatus tension_control;          // the null-space stage and its trims
  std::array<int, kMaxAxes> slack_cycles{};      // consecutive cycles below the slack limit
  // Stuck-reading watch: how far each cable's tension was made to change since its raw reading
  // last changed, in units of the watch's threshold (above 1: evidence of a stuck reading).
  std::array<double, kMaxAxes> unchanged_span{};
  // Averages over the cycles since the last request_average() while settled.
  std::uint64_t average_id = 0;
  int average_cycles = 0;
  std::array<double, kMaxAxes> average_counts{};
  std::array<double, kMaxAxes> average_tensions{};
  // Largest change of any drive target from one cycle to the next: over the last move, and
  // over the last re-reference (hot swap) — counts.
  double largest_move_step = 0.0;
  double largest_reference_step = 0.0;
  std::uint64_t overruns = 0;  // filled by the loop driver
  MoveProgress move;
  StreamStatus stream;
};

struct RtEvent {
  canopen::Event event;
};

class RtController {
 public:
  // Trims count against this many times the stuck-reading threshold (see watch_stuck).
  static constexpr double kStuckTrimFactor = 2.0;
  // Drives the robot through `io` (axis k = cable k, tension channel k = cable k), which must
  // outlive the controller. Allocates here only.
  static Result<std::unique_ptr<RtController>> create(RobotIO& io, const Geometry& initial,
                                                      const RtControllerOptions& options);

  // Non-RT set-up, before the loop runs (or while it is disabled).
  void set_encoder_offsets(const std::array<double, kMaxAxes>& offsets) { offsets_ = offsets; }
  const std::array<double, kMaxAxes>& encoder_offsets() const { return offsets_; }

  // Any thread: hand a command to the next cycle. Returns the command replaced before the RT
  // loop took it (the caller may free it), or nullptr.
  MotionCommand* post(MotionCommand* command) noexcept {
    return inbox_.exchange(command, std::memory_order_acq_rel);
  }
  // The same for a hold of the actual counts that the next cycle takes before the inbox's
  // command (after the loop was paused while the drives' counts changed: a move posted meanwhile
  // must not replace it).
  MotionCommand* post_first(MotionCommand* command) noexcept {
    return first_.exchange(command, std::memory_order_acq_rel);
  }
  // Any thread: the move, path or stream with a sequence number up to `seq` stops smoothly
  // (RtControllerOptions::stop_limits) and the robot holds where it came to rest; such a command
  // not taken yet is never started.
  void request_motion_stop(std::uint64_t seq) noexcept {
    std::uint64_t cur = stop_seq_.load(std::memory_order_acquire);
    while (cur < seq && !stop_seq_.compare_exchange_weak(cur, seq, std::memory_order_acq_rel)) {
    }
  }
  // The stream's receiving thread (one producer): the next setpoint; false when the ring is full
  // (the RT loop takes every setpoint waiting at each cycle and applies the newest).
  bool push_setpoint(const StreamSetpoint& sp) noexcept { return stream_in_.push(sp); }
  // Any thread: requests (taken at the next cycle).
  void request_quick_stop() noexcept { quick_stop_.store(true, std::memory_order_release); }
  // A fault reset is refused (the fault stays latched) while an e-stop input reads open.
  void request_fault_reset() noexcept { fault_reset_.store(true, std::memory_order_release); }
  // The operator's disable and enable. Disable: the holding brakes are applied, then
  // (brake_apply_cycles later) every drive goes to SWITCH_ON_DISABLED and the loop stays disabled
  // (not a fault) until request_enable(). Enable: every drive towards OPERATION_ENABLED, the
  // brakes released once each holds torque; the loop stays disabled (targets = actual) until a
  // hold_actual reference is taken.
  void request_disable() noexcept { disable_.store(true, std::memory_order_release); }
  void request_enable() noexcept { enable_.store(true, std::memory_order_release); }
  // Starts a new average of encoder counts and tensions; returns its id (see RtSnapshot).
  // Any thread: the tension control's trims stay where they are while `hold` (the measuring
  // sequence, while a pose is averaged: the trims must not move the drives then).
  void hold_tension_trims(bool hold) noexcept {
    hold_tension_trims_.store(hold, std::memory_order_release);
  }
  std::uint64_t request_average() noexcept {
    return average_request_.fetch_add(1, std::memory_order_acq_rel) + 1;
  }

  // The RT cycle.
  void cycle(canopen::Timestamp now) noexcept;

  RtSnapshot snapshot() const noexcept { return published_.load(); }
  bool pop_event(RtEvent& e) noexcept { return events_.pop(e); }
  // Commands and geometries older than the active ones are no longer referenced by the loop.
  std::uint64_t command_in_use() const noexcept {
    return in_use_command_.load(std::memory_order_acquire);
  }
  int geometry_in_use() const noexcept { return in_use_geometry_.load(std::memory_order_acquire); }
  void set_overruns(std::uint64_t n) noexcept { overruns_ = n; }

 private:
  RtController(RobotIO& io, const Geometry& initial, const RtControllerOptions& options);
  // The stages of cycle(), in order.
  void read_inputs(canopen::Timestamp now) noexcept;
  void take_requests(canopen::Timestamp now) noexcept;
  void watch_faults(canopen::Timestamp now) noexcept;
  void take_command(canopen::Timestamp now) noexcept;
  void sample_trajectory(canopen::Timestamp now) noexcept;
  void control_tensions() noexcept;
  void compute_targets(canopen::Timestamp now) noexcept;
  void slew_targets() noexcept;
  void check_limits(canopen::Timestamp now) noexcept;
  void sequence_brakes() noexcept;
  void write_outputs() noexcept;
  void update_settle() noexcept;
  void publish(canopen::Timestamp now) noexcept;
  // Parts of the stages.
  void watch_events(canopen::Timestamp now) noexcept;
  void watch_tensions(canopen::Timestamp now) noexcept;
  void watch_stuck(canopen::Timestamp now) noexcept;
  void watch_safety(canopen::Timestamp now) noexcept;
  void take_enable_requests() noexcept;
  double stuck_evidence(int i) noexcept;
  void reset_stuck_watch() noexcept { stuck_valid_.fill(false); }
  void start_move(const MotionCommand& c, canopen::Timestamp now) noexcept;
  void start_reference(const MotionCommand& c, canopen::Timestamp now) noexcept;
  // Moves, paths and the stream (rt_controller_motion.cc).
  bool stop_requested() const noexcept {
    return active_ != nullptr && active_->seq <= stop_seq_.load(std::memory_order_acquire);
  }
  double move_time(canopen::Timestamp now) noexcept;
  double move_duration() const noexcept;
  void sample_move(double t) noexcept;
  void start_stream(const MotionCommand& c, canopen::Timestamp now) noexcept;
  void sample_stream(canopen::Timestamp now) noexcept;
  bool take_setpoint(canopen::Timestamp now) noexcept;
  void decelerate(double dt) noexcept;
  void end_stream(StreamEnd why, std::uint64_t seq, double value) noexcept;
  void hold_actual(const MotionCommand& c) noexcept;
  void step_trims() noexcept;
  void update_average() noexcept;
  void set_fault(const RtFault& f) noexcept;
  void hold_fault(const RtFault& f) noexcept;
  bool solve(const Pose& pose) noexcept;
  void follow_plan_reference(double margin) noexcept;
  bool active() const noexcept {
    return mode_ == RtMode::kMoving || mode_ == RtMode::kHolding || mode_ == RtMode::kSlewing ||
           mode_ == RtMode::kHoldingCounts;
  }
  double cable_counts_per_metre(int i) const noexcept;

  RobotIO& io_;
  RobotReading in_;   // this cycle's readings
  RobotCommand out_;  // this cycle's command
  RtControllerOptions options_;
  int m_ = 0;
  const Geometry* geometry_ = nullptr;
  CommandData command_data_;
  std::array<double, kMaxAxes> offsets_{};
  std::array<double, kMaxAxes> target_{};   // sent (fractional counts)
  std::array<double, kMaxAxes> desired_{};  // from the IK this cycle
  SlewLimiter slew_;
  TensionControl tension_;

  std::atomic<MotionCommand*> inbox_{nullptr};
  std::atomic<MotionCommand*> first_{nullptr};  // taken before inbox_'s
  MotionCommand* active_ = nullptr;
  std::atomic<std::uint64_t> in_use_command_{0};
  std::atomic<int> in_use_geometry_{0};
  std::atomic<bool> quick_stop_{false};
  std::atomic<bool> fault_reset_{false};
  std::atomic<bool> disable_{false};
  std::atomic<bool> enable_{false};
  std::atomic<std::uint64_t> average_request_{0};
  std::atomic<bool> hold_tension_trims_{false};
  std::uint64_t average_taken_ = 0;

  RtMode mode_ = RtMode::kDisabled;
  RtFault fault_;
  double ref_tension_ = 0.0, ref_start_ = 0.0, ref_goal_ = 0.0;  // planner pretension, N
  // The reference the plan is made at (solve): it follows the planner's choice (1x, 2x or 4x
  // ref_tension_) at a bounded rate, so the plan and its elongation compensation never step;
  // NaN: none yet (taken as it is at the next solve).
  double plan_reference_ = std::numeric_limits<double>::quiet_NaN();
  // What the last solve was made from: the same pose, pretension and geometry with the plan's
  // reference settled give the same plan and counts (a hold solves once, not every cycle).
  struct Solved {
    bool valid = false;
    Pose pose;
    double reference = 0.0;
    const Geometry* geometry = nullptr;
  } solved_;
  Pose hold_pose_;
  Pose pose_;
  canopen::Timestamp move_start_{0};
  std::uint64_t done_ = 0;
  std::array<double, kMaxAxes> trim_{}, trim_goal_{}, trim_at_move_{};
  // The trims fading out during the current move, worth their length times their cable's
  // stiffness, summed over the cables (N): what they may change any cable's tension by (0 when
  // not moving).
  double fading_trim_worth_ = 0.0;
  std::array<int, kMaxAxes> slack_count_{}, overload_count_{};
  // Stuck-reading watch: the raw value seen last, the range of the expected tension since it
  // changed, and for how many cycles that range has been too wide.
  std::array<bool, kMaxAxes> stuck_valid_{};
  std::array<std::int64_t, kMaxAxes> stuck_raw_{};
  std::array<double, kMaxAxes> plan_min_{}, plan_max_{}, trim_min_{}, trim_max_{};
  // Set when a move with fading trims ends: the watch's plan window starts again.
  bool restart_plan_window_ = false;
  std::array<int, kMaxAxes> stuck_count_{};
  std::uint64_t force_pdos_ = 0;  // the tension readings' count the watch saw last
  // Safety chain: disabled on request; cycles each drive has been enabled; cycles since the
  // brakes were applied for a disable.
  bool disable_requested_ = false;
  std::array<int, kMaxAxes> enabled_cycles_{};
  int applied_cycles_ = 0;

  // Stillness window: ring of the last settle_cycles actual counts and tensions.
  static constexpr int kMaxWindow = 512;
  std::array<std::array<double, kMaxAxes>, kMaxWindow> win_counts_{};
  std::array<std::array<double, kMaxAxes>, kMaxWindow> win_tensions_{};
  int win_size_ = 0, win_head_ = 0;
  bool settled_ = false;

  RtSnapshot snap_;
  cdpr::SeqLock<RtSnapshot> published_;
  SpscRing<RtEvent, 256> events_;
  std::uint64_t overruns_ = 0;

  // Moves and paths: the stop request, the path time while stopping (rt_controller_motion.cc).
  std::atomic<std::uint64_t> stop_seq_{0};
  DoubleSProfile stop_profile_;  // the rate r = 1 - s(t) of a stopping move
  bool stopping_ = false;
  canopen::Timestamp stop_start_{0}, last_now_{0};
  double move_t_ = 0.0;
  // The stream: setpoints from the receiving thread; the commanded pose's velocity (linear m/s,
  // rpy rad/s) and the deceleration reached while holding.
  SpscRing<StreamSetpoint, 64> stream_in_;
  bool streaming_ = false;
  canopen::Timestamp last_setpoint_{0}, stream_start_{0};
  Eigen::Matrix<double, 6, 1> stream_velocity_ = Eigen::Matrix<double, 6, 1>::Zero();
  double decel_linear_ = 0.0, decel_angular_ = 0.0;
  Eigen::Matrix<double, 6, 1> last_applied_ = Eigen::Matrix<double, 6, 1>::Zero();
  bool st_resumed_ = true;  // no setpoint applied since the start or a hold
};

}  // namespace cdpr::controller
