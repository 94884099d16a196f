#include "cdpr/canopen/cia402.hpp"

namespace cdpr::canopen::cia402 {

std::string_view to_string(State s) {
  switch (s) {
    case State::kNotReadyToSwitchOn:
      return "NOT_READY_TO_SWITCH_ON";
    case State::kSwitchOnDisabled:
      return "SWITCH_ON_DISABLED";
    case State::kReadyToSwitchOn:
      return "READY_TO_SWITCH_ON";
    case State::kSwitchedOn:
      return "SWITCHED_ON";
    case State::kOperationEnabled:
      return "OPERATION_ENABLED";
    case State::kQuickStopActive:
      return "QUICK_STOP_ACTIVE";
    case State::kFaultReactionActive:
      return "FAULT_REACTION_ACTIVE";
    case State::kFault:
      return "FAULT";
    case State::kUnknown:
      return "UNKNOWN";
  }
  return "INVALID";
}

std::string_view to_string(Target t) {
  switch (t) {
    case Target::kSwitchOnDisabled:
      return "SWITCH_ON_DISABLED";
    case Target::kReadyToSwitchOn:
      return "READY_TO_SWITCH_ON";
    case Target::kSwitchedOn:
      return "SWITCHED_ON";
    case Target::kOperationEnabled:
      return "OPERATION_ENABLED";
    case Target::kQuickStop:
      return "QUICK_STOP";
  }
  return "INVALID";
}

std::string_view command_name(std::uint16_t controlword) {
  switch (controlword & cw::kStateMask) {
    case cw::kDisableVoltage:
      return "disable voltage";
    case cw::kQuickStop:
      return "quick stop";
    case cw::kShutdown:
      return "shutdown";
    case cw::kSwitchOn:
      return "switch on";
    case cw::kEnableOperation:
      return "enable operation";
    default:
      break;
  }
  if (controlword & cw::kFaultReset) return "fault reset";
  return "other command";
}

std::uint16_t next_controlword(std::uint16_t statusword, Target target, bool fault_reset,
                               std::uint16_t previous_controlword) {
  switch (decode_state(statusword)) {
    case State::kNotReadyToSwitchOn:   // the drive leaves it by itself (T1)
    case State::kFaultReactionActive:  // the drive goes to FAULT by itself (T14)
    case State::kUnknown:
      return cw::kDisableVoltage;
    case State::kFault:
      if (!fault_reset) return cw::kDisableVoltage;
      // T15 needs a rising edge of bit 7: first a word with bit 7 low, then 0x80.
      return previous_controlword == cw::kDisableVoltage ? cw::kFaultReset : cw::kDisableVoltage;
    case State::kSwitchOnDisabled:
      if (target == Target::kSwitchOnDisabled || target == Target::kQuickStop) {
        return cw::kDisableVoltage;
      }
      return cw::kShutdown;  // T2
    case State::kReadyToSwitchOn:
      switch (target) {
        case Target::kSwitchOnDisabled:
          return cw::kDisableVoltage;  // T7
        case Target::kQuickStop:
          return cw::kQuickStop;  // T7
        case Target::kReadyToSwitchOn:
          return cw::kShutdown;
        case Target::kSwitchedOn:
        case Target::kOperationEnabled:
          return cw::kSwitchOn;  // T3
      }
      break;
    case State::kSwitchedOn:
      switch (target) {
        case Target::kSwitchOnDisabled:
          return cw::kDisableVoltage;  // T10
        case Target::kQuickStop:
          return cw::kQuickStop;  // T10
        case Target::kReadyToSwitchOn:
          return cw::kShutdown;  // T6
        case Target::kSwitchedOn:
          return cw::kSwitchOn;  // stay
        case Target::kOperationEnabled:
          return cw::kEnableOperation;  // T4
      }
      break;
    case State::kOperationEnabled:
      switch (target) {
        case Target::kSwitchOnDisabled:
          return cw::kDisableVoltage;  // T9
        case Target::kQuickStop:
          return cw::kQuickStop;  // T11
        case Target::kReadyToSwitchOn:
          return cw::kShutdown;  // T8
        case Target::kSwitchedOn:
          return cw::kSwitchOn;  // T5
        case Target::kOperationEnabled:
          return cw::kEnableOperation;  // stay
      }
      break;
    case State::kQuickStopActive:
      // Hold the quick stop while it is wanted; otherwise leave through T12 (disable voltage),
      // which every drive supports (T16 back to enabled depends on the quick-stop option code).
      return target == Target::kQuickStop ? cw::kQuickStop : cw::kDisableVoltage;
  }
  return cw::kDisableVoltage;
}

void Supervisor::request(Target t) {
  if (t == target_ && !stuck_) return;
  target_ = t;
  stuck_ = false;
  started_ = false;  // restart the transition timer at the next step
}

std::uint16_t Supervisor::step(std::uint16_t statusword, Timestamp now) {
  became_stuck_ = false;
  became_faulted_ = false;
  const State s = decode_state(statusword);
  if (s != state_ || !started_) {
    if ((s == State::kFault || s == State::kFaultReactionActive) && !in_fault()) {
      became_faulted_ = true;
      error_ = Status::error(ErrorCode::kUnavailable, "node %u: drive in %s (statusword 0x%04X)",
                             unsigned{node_}, to_string(s).data(), unsigned{statusword});
    }
    state_ = s;
    since_ = now;
    started_ = true;
  }
  if (s != State::kFault) fault_reset_ = fault_reset_ && s == State::kFaultReactionActive;
  const std::uint16_t c = next_controlword(statusword, target_, fault_reset_, last_cw_);
  if (c != last_cw_) {
    last_command_ = c;
  }
  last_cw_ = c;

  // A drive in FAULT without a reset request is reported as faulted, not as stuck.
  const bool waiting = !cia402::reached(s, target_) && !(s == State::kFault && !fault_reset_);
  if (waiting && !stuck_ && now - since_ >= timeout_) {
    stuck_ = true;
    became_stuck_ = true;
    const std::string_view cmd =
        s == State::kFault ? std::string_view("fault reset") : command_name(last_command_);
    error_ = Status::error(ErrorCode::kTimeout, "node %u: stuck in %s for %.0f ms after %.*s",
                           unsigned{node_}, to_string(s).data(), to_ms(now - since_),
                           static_cast<int>(cmd.size()), cmd.data());
  }
  return c;
}

}  // namespace cdpr::canopen::cia402
