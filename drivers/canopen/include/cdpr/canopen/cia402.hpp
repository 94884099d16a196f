// CiA 402 drive profile: the power drive system state machine as pure functions (statusword ->
// state, state + request -> controlword) and a per-drive supervisor that times transitions and
// names drives that do not follow. Nothing here allocates; the RT loop calls step() every cycle.
#pragma once

#include <chrono>
#include <cstdint>
#include <string_view>

#include "cdpr/canopen/types.hpp"
#include "cdpr/status.hpp"

namespace cdpr::canopen::cia402 {

// Objects of the profile used by the master.
namespace obj {
inline constexpr ObjectAddress kAbortConnectionOption{0x6007, 0};
inline constexpr ObjectAddress kControlword{0x6040, 0};
inline constexpr ObjectAddress kStatusword{0x6041, 0};
inline constexpr ObjectAddress kQuickStopOption{0x605A, 0};
inline constexpr ObjectAddress kModesOfOperation{0x6060, 0};
inline constexpr ObjectAddress kModesDisplay{0x6061, 0};
inline constexpr ObjectAddress kPositionActual{0x6064, 0};
inline constexpr ObjectAddress kVelocityActual{0x606C, 0};
inline constexpr ObjectAddress kTargetPosition{0x607A, 0};
inline constexpr ObjectAddress kHomeOffset{0x607C, 0};
inline constexpr ObjectAddress kProfileVelocity{0x6081, 0};
inline constexpr ObjectAddress kProfileAcceleration{0x6083, 0};
inline constexpr ObjectAddress kProfileDeceleration{0x6084, 0};
inline constexpr ObjectAddress kHomingMethod{0x6098, 0};
inline constexpr ObjectAddress kInterpolationPeriodValue{0x60C2, 1};
inline constexpr ObjectAddress kInterpolationPeriodIndex{0x60C2, 2};
}  // namespace obj

enum class State : std::uint8_t {
  kNotReadyToSwitchOn,
  kSwitchOnDisabled,
  kReadyToSwitchOn,
  kSwitchedOn,
  kOperationEnabled,
  kQuickStopActive,
  kFaultReactionActive,
  kFault,
  kUnknown,  // statusword matches no state (should not happen)
};

std::string_view to_string(State s);  // "SWITCH_ON_DISABLED", ...

// Statusword masks (CiA 402, 6.2): the state is in bits 0-3, 5 and 6.
constexpr State decode_state(std::uint16_t sw) {
  if ((sw & 0x4F) == 0x00) return State::kNotReadyToSwitchOn;
  if ((sw & 0x4F) == 0x40) return State::kSwitchOnDisabled;
  if ((sw & 0x6F) == 0x21) return State::kReadyToSwitchOn;
  if ((sw & 0x6F) == 0x23) return State::kSwitchedOn;
  if ((sw & 0x6F) == 0x27) return State::kOperationEnabled;
  if ((sw & 0x6F) == 0x07) return State::kQuickStopActive;
  if ((sw & 0x4F) == 0x0F) return State::kFaultReactionActive;
  if ((sw & 0x4F) == 0x08) return State::kFault;
  return State::kUnknown;
}

// Statusword bits used by the modes.
namespace sw {
inline constexpr std::uint16_t kVoltageEnabled = 1u << 4;
inline constexpr std::uint16_t kWarning = 1u << 7;
inline constexpr std::uint16_t kRemote = 1u << 9;
inline constexpr std::uint16_t kTargetReached = 1u << 10;
inline constexpr std::uint16_t kInternalLimit = 1u << 11;
inline constexpr std::uint16_t kSetPointAcknowledge = 1u << 12;  // PP; homing attained in HM
inline constexpr std::uint16_t kHomingAttained = 1u << 12;
inline constexpr std::uint16_t kFollowingError = 1u << 13;  // PP/CSP; homing error in HM
inline constexpr std::uint16_t kHomingError = 1u << 13;
}  // namespace sw

// Controlword commands (state bits 0-3 and 7) and mode bits.
namespace cw {
inline constexpr std::uint16_t kDisableVoltage = 0x0000;
inline constexpr std::uint16_t kQuickStop = 0x0002;
inline constexpr std::uint16_t kShutdown = 0x0006;
inline constexpr std::uint16_t kSwitchOn = 0x0007;
inline constexpr std::uint16_t kEnableOperation = 0x000F;
inline constexpr std::uint16_t kFaultReset = 0x0080;
inline constexpr std::uint16_t kStateMask = 0x008F;
inline constexpr std::uint16_t kNewSetPoint = 1u << 4;  // PP; homing start in HM
inline constexpr std::uint16_t kStartHoming = 1u << 4;
inline constexpr std::uint16_t kChangeImmediately = 1u << 5;
inline constexpr std::uint16_t kRelative = 1u << 6;
inline constexpr std::uint16_t kHalt = 1u << 8;
}  // namespace cw

// Name of a controlword command for messages ("shutdown", "enable operation", ...).
std::string_view command_name(std::uint16_t controlword);

// What the master wants the drive to be in.
enum class Target : std::uint8_t {
  kSwitchOnDisabled,  // voltage off
  kReadyToSwitchOn,
  kSwitchedOn,
  kOperationEnabled,
  kQuickStop,  // stop on the quick-stop ramp (ends in QUICK_STOP_ACTIVE or SWITCH_ON_DISABLED)
};
std::string_view to_string(Target t);

// True when `state` satisfies `target`.
constexpr bool reached(State state, Target target) {
  switch (target) {
    case Target::kSwitchOnDisabled:
      return state == State::kSwitchOnDisabled;
    case Target::kReadyToSwitchOn:
      return state == State::kReadyToSwitchOn;
    case Target::kSwitchedOn:
      return state == State::kSwitchedOn;
    case Target::kOperationEnabled:
      return state == State::kOperationEnabled;
    case Target::kQuickStop:
      return state == State::kQuickStopActive || state == State::kSwitchOnDisabled;
  }
  return false;
}

// The state machine as a pure function: the controlword (state bits only) that moves a drive in
// state decode_state(statusword) one transition towards `target`. In FAULT it produces the fault
// reset edge when `fault_reset` is set: 0x00 first, then 0x80 (a rising edge of bit 7 needs the
// previous controlword to have bit 7 low), else it holds 0x00.
std::uint16_t next_controlword(std::uint16_t statusword, Target target, bool fault_reset,
                               std::uint16_t previous_controlword);

// Watches one drive: computes its controlword every cycle and reports, once per episode, a drive
// that does not reach the requested state in time or that falls into FAULT.
class Supervisor {
 public:
  Supervisor() = default;
  Supervisor(NodeId node, std::chrono::nanoseconds transition_timeout)
      : node_(node), timeout_(transition_timeout) {}

  void request(Target t);
  // Clears a fault on the next cycles (edge on bit 7), then continues towards the target.
  void request_fault_reset() { fault_reset_ = true; }
  bool fault_reset_pending() const { return fault_reset_; }
  Target target() const { return target_; }

  // Feed the latest statusword; returns the controlword state bits to send this cycle.
  std::uint16_t step(std::uint16_t statusword, Timestamp now);

  State state() const { return state_; }
  bool reached() const { return cia402::reached(state_, target_); }
  bool in_fault() const { return state_ == State::kFault || state_ == State::kFaultReactionActive; }
  // Set once when the drive did not follow; cleared by the next request().
  bool stuck() const { return stuck_; }
  // Newly stuck / newly faulted in the last step (edge flags for event reporting).
  bool became_stuck() const { return became_stuck_; }
  bool became_faulted() const { return became_faulted_; }
  const Status& error() const { return error_; }
  std::uint16_t last_controlword() const { return last_cw_; }

 private:
  NodeId node_ = 0;
  std::chrono::nanoseconds timeout_{std::chrono::milliseconds(500)};
  Target target_ = Target::kSwitchOnDisabled;
  State state_ = State::kUnknown;
  bool fault_reset_ = false;
  bool stuck_ = false;
  bool became_stuck_ = false;
  bool became_faulted_ = false;
  bool started_ = false;
  Timestamp since_{0};  // time of the last state change or request
  std::uint16_t last_cw_ = cw::kDisableVoltage;
  std::uint16_t last_command_ = cw::kDisableVoltage;  // last command that differed
  Status error_;
};

}  // namespace cdpr::canopen::cia402
