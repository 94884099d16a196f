#include "cdpr/controller/supervisor.hpp"

#include <array>

namespace cdpr::controller {

namespace {

using S = DaemonState;
using E = SupervisorEvent;
using A = SupervisorAction;

// The daemon's state machine: one row per (state, event) it accepts, grouped by event.
constexpr std::array<SupervisorRow, 35> kTable{{
    {S::kStarting, E::kBoot, S::kStarting, A::kNone},
    {S::kStarting, E::kStartFailed, S::kFault, A::kNone},
    {S::kStarting, E::kStarted, S::kHolding, A::kNone},
    {S::kStarting, E::kStartedDisabled, S::kDisabled, A::kNone},
    {S::kDisabled, E::kEnabled, S::kHolding, A::kNone},
    {S::kHolding, E::kDisable, S::kDisabled, A::kNone},
    {S::kHolding, E::kHomed, S::kHolding, A::kNone},
    {S::kDisabled, E::kHomed, S::kDisabled, A::kNone},
    {S::kHolding, E::kMoveRequested, S::kMoving, A::kNone},
    {S::kHolding, E::kRtMoving, S::kMoving, A::kNone},
    {S::kMoving, E::kRtMoving, S::kMoving, A::kNone},
    {S::kHolding, E::kRtHolding, S::kHolding, A::kNone},
    {S::kMoving, E::kRtHolding, S::kHolding, A::kNone},
    {S::kHolding, E::kCalibrationStarted, S::kMeasuring, A::kNone},
    {S::kMeasuring, E::kMeasured, S::kIdentifying, A::kNone},
    {S::kIdentifying, E::kMorePoses, S::kMeasuring, A::kNone},
    {S::kIdentifying, E::kIdentified, S::kAwaitingAcceptance, A::kReleaseWorker},
    // (from `fault`: the fault was reset while the worker was still running)
    {S::kMeasuring, E::kCalibrationEnded, S::kHolding, A::kReleaseWorker},
    {S::kIdentifying, E::kCalibrationEnded, S::kHolding, A::kReleaseWorker},
    {S::kFault, E::kCalibrationEnded, S::kHolding, A::kReleaseWorker},
    {S::kAwaitingAcceptance, E::kRejected, S::kHolding, A::kNone},
    {S::kAwaitingAcceptance, E::kApply, S::kApplying, A::kNone},
    {S::kHolding, E::kApply, S::kApplying, A::kNone},
    {S::kAwaitingAcceptance, E::kApplyFailed, S::kHolding, A::kNone},
    {S::kApplying, E::kApplied, S::kHolding, A::kNone},
    {S::kHolding, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kMoving, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kMeasuring, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kIdentifying, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kAwaitingAcceptance, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kApplying, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kStopped, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kDisabled, E::kFaultLatched, S::kFault, A::kStopSequence},
    {S::kFault, E::kFaultCleared, S::kHolding, A::kNone},
    {S::kFault, E::kFaultResetFailed, S::kFault, A::kNone},
}};

}  // namespace

const char* to_string(DaemonState s) {
  switch (s) {
    case S::kStarting:
      return "starting";
    case S::kHolding:
      return "holding";
    case S::kMoving:
      return "moving";
    case S::kMeasuring:
      return "measuring";
    case S::kIdentifying:
      return "identifying";
    case S::kAwaitingAcceptance:
      return "awaiting_acceptance";
    case S::kApplying:
      return "applying";
    case S::kFault:
      return "fault";
    case S::kStopped:
      return "stopped";
    case S::kDisabled:
      return "disabled";
  }
  return "?";
}

const char* to_string(CalibrationRunOutcome o) {
  switch (o) {
    case CalibrationRunOutcome::kMeasuring:
      return "measuring";
    case CalibrationRunOutcome::kAwaitingAcceptance:
      return "awaiting_acceptance";
    case CalibrationRunOutcome::kApplying:
      return "applying";
    case CalibrationRunOutcome::kApplied:
      return "applied";
    case CalibrationRunOutcome::kRejected:
      return "rejected";
    case CalibrationRunOutcome::kFailed:
      return "failed";
    case CalibrationRunOutcome::kAborted:
      return "aborted";
  }
  return "?";
}

const char* to_string(SupervisorEvent e) {
  switch (e) {
    case E::kBoot:
      return "boot";
    case E::kStartFailed:
      return "start_failed";
    case E::kStarted:
      return "started";
    case E::kStartedDisabled:
      return "started_disabled";
    case E::kEnabled:
      return "enabled";
    case E::kDisable:
      return "disable";
    case E::kHomed:
      return "homed";
    case E::kMoveRequested:
      return "move_requested";
    case E::kRtMoving:
      return "rt_moving";
    case E::kRtHolding:
      return "rt_holding";
    case E::kCalibrationStarted:
      return "calibration_started";
    case E::kMeasured:
      return "measured";
    case E::kMorePoses:
      return "more_poses";
    case E::kIdentified:
      return "identified";
    case E::kCalibrationEnded:
      return "calibration_ended";
    case E::kRejected:
      return "rejected";
    case E::kApply:
      return "apply";
    case E::kApplyFailed:
      return "apply_failed";
    case E::kApplied:
      return "applied";
    case E::kFaultLatched:
      return "fault_latched";
    case E::kFaultCleared:
      return "fault_cleared";
    case E::kFaultResetFailed:
      return "fault_reset_failed";
  }
  return "?";
}

const char* to_string(SupervisorAction a) {
  switch (a) {
    case A::kNone:
      return "-";
    case A::kStopSequence:
      return "stop_sequence";
    case A::kReleaseWorker:
      return "release_worker";
  }
  return "?";
}

std::span<const SupervisorRow> supervisor_table() {
  return kTable;
}

std::string supervisor_table_markdown() {
  std::string md = "| state | event | next state | action |\n| --- | --- | --- | --- |\n";
  for (const SupervisorRow& r : kTable) {
    md += std::string("| `") + to_string(r.from) + "` | " + to_string(r.event) + " | `" +
          to_string(r.to) + "` | " + to_string(r.action) + " |\n";
  }
  return md;
}

const SupervisorRow* Supervisor::find(DaemonState from, SupervisorEvent event) {
  for (const SupervisorRow& r : kTable) {
    if (r.from == from && r.event == event) return &r;
  }
  return nullptr;
}

Transition Supervisor::fire(SupervisorEvent event) {
  Transition t;
  t.from = state_;
  const SupervisorRow* row = find(state_, event);
  if (row == nullptr) {
    t.to = state_;
    t.refusal = std::string("event '") + to_string(event) + "' is not accepted in state '" +
                to_string(state_) + "'";
    return t;
  }
  t.accepted = true;
  t.to = row->to;
  t.action = row->action;
  state_ = row->to;
  return t;
}

}  // namespace cdpr::controller
