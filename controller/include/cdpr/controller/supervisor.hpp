// cdprd's state machine as a table (docs/architecture.md "The daemon's supervisor"): a pure object
// (no I/O, no clock, no threads) that answers, for the daemon's state and an event, the next state
// and the action the daemon takes on the way, or refuses the event with a reason.
//
//   Supervisor sup;                                   // starts in `starting`
//   Transition t = sup.fire(SupervisorEvent::kStarted);
//   if (!t.accepted) log(t.refusal);                  // "event 'started' is not accepted in ..."
//
// The daemon owns one Supervisor under its state lock; Daemon::transition is the one place that
// fires events, runs the action, logs and publishes the change (docs/daemon.md "States").
#pragma once

#include <span>
#include <string>
#include <string_view>

namespace cdpr::controller {

// The daemon's state (status "state").
enum class DaemonState {
  kStarting,
  kHolding,
  kMoving,
  kMeasuring,
  kIdentifying,
  kAwaitingAcceptance,
  kApplying,
  kFault,
  kStopped,   // named in the protocol; no event leads to it
  kDisabled,  // the drives are disabled (after start-up until `enable`, or after `disable`)
};
const char* to_string(DaemonState s);

// What a calibration came to (status "calibration.outcome", `calibration` events). It stays
// `measuring` while the worker identifies (the state says which); `applying` after accept until
// the hot swap completes.
enum class CalibrationRunOutcome {
  kMeasuring,
  kAwaitingAcceptance,
  kApplying,
  kApplied,
  kRejected,
  kFailed,
  kAborted,
};
const char* to_string(CalibrationRunOutcome o);

enum class SupervisorEvent {
  kBoot,                // start(): the network is being booted
  kStartFailed,         // boot, identities, enable or homing failed
  kStarted,             // started with the drives enabled, holding where they are
  kStartedDisabled,     // started with the drives disabled (start.enable: operator)
  kEnabled,             // the operator enabled the drives; the RT loop holds where they are
  kDisable,             // the operator disabled the drives
  kHomed,               // `home` wrote a homing record; the pose is known again
  kMoveRequested,       // a `move` was accepted
  kRtMoving,            // the RT loop runs a trajectory (no sequence running)
  kRtHolding,           // the RT loop holds (no sequence running)
  kCalibrationStarted,  // the worker begins measuring
  kMeasured,            // a round of poses measured: identify
  kMorePoses,           // poses to measure again or extra poses
  kIdentified,          // the result awaits acceptance
  kCalibrationEnded,    // the sequence failed or was aborted, the robot is not in fault
  kRejected,            // the operator rejected the result
  kApply,               // a hot swap begins (accept, rollback)
  kApplyFailed,         // accept could not start the hot swap
  kApplied,             // the hot swap completed
  kFaultLatched,        // the RT loop latched a fault
  kFaultCleared,        // after fault_reset: holding where the platform stopped
  kFaultResetFailed,    // after fault_reset: the pose could not be derived
};
const char* to_string(SupervisorEvent e);

// What the daemon does on a transition, before the new state is visible.
enum class SupervisorAction {
  kNone,
  kStopSequence,   // tell a running sequence to stop (its waits return kAborted)
  kReleaseWorker,  // the worker's part is over: a request that follows the new state at once
                   // (a script's next `calibrate`) must not find the worker still running
};
const char* to_string(SupervisorAction a);

struct SupervisorRow {
  DaemonState from;
  SupervisorEvent event;
  DaemonState to;
  SupervisorAction action;
};

// Every row of the table, grouped by event.
std::span<const SupervisorRow> supervisor_table();

// The table as the Markdown of docs/architecture.md (a test checks the doc against it).
std::string supervisor_table_markdown();

struct Transition {
  bool accepted = false;
  DaemonState from = DaemonState::kStarting;
  DaemonState to = DaemonState::kStarting;
  SupervisorAction action = SupervisorAction::kNone;
  std::string refusal;  // why not, when !accepted
};

class Supervisor {
 public:
  explicit Supervisor(DaemonState initial = DaemonState::kStarting) : state_(initial) {}

  DaemonState state() const { return state_; }
  // The row for (state, event): the state moves to its `to`. Without a row the state stays and
  // the refusal names the event and the state.
  Transition fire(SupervisorEvent event);
  // The row for (from, event), or nullptr.
  static const SupervisorRow* find(DaemonState from, SupervisorEvent event);

 private:
  DaemonState state_;
};

}  // namespace cdpr::controller
