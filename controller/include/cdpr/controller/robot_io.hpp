// What the RT cycle reads from the robot and writes to it, one call each per cycle:
//
//   io.read(now, reading);    // this cycle's state: drives, tensions, laser, bus, master events
//   ... update: the controller computes its command from `reading` ...
//   io.write(command);        // targets and state requests, sent in this same cycle
//
// Plain fixed-size structs: read and write allocate, lock, log and throw nothing. The CANopen +
// Modbus implementation is CanopenRobotIO (canopen_robot_io.hpp); unit tests use a fake
// (controller/testing/fake_robot_io.hpp).
#pragma once

#include <array>
#include <cstdint>
#include <limits>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/canopen/events.hpp"
#include "cdpr/canopen/types.hpp"
#include "cdpr/controller/motion_command.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

// One drive (axis k drives cable k) as read this cycle.
struct DriveReading {
  int node = 0;           // its CANopen node (0: none)
  bool received = false;  // its status is known (a TPDO arrived since start-up)
  bool enabled = false;   // OPERATION_ENABLED
  bool fault = false;     // FAULT or FAULT_REACTION_ACTIVE
  std::uint16_t statusword = 0;
  std::uint16_t emcy_code = 0;  // last EMCY code of its node (0: none since the last fault reset)
  std::int32_t actual_counts = 0;
  double velocity = 0.0;  // counts/s, from this reading and the previous one
};

struct RobotReading {
  static constexpr int kMaxEvents = 64;

  canopen::Timestamp now{0};  // the time read() was called with
  int num_axes = 0;
  std::array<DriveReading, kMaxAxes> drives{};
  // Cable tensions (channel k measures cable k).
  bool have_tensions = false;
  bool tensions_fresh = false;               // a reading arrived since the previous read()
  std::uint64_t tension_updates = 0;         // readings received so far (moves when one is fresh)
  canopen::Timestamp tensions_time{0};       // when the last fresh one was read
  std::array<double, kMaxAxes> tensions{};   // N
  std::array<std::int64_t, kMaxAxes> raw{};  // raw = gain * tension + offset
  std::array<double, kMaxAxes> gain{};       // raw units per N
  // The laser distance sensor (its latest reading; polled in its own thread).
  bool have_laser = false;
  bool laser_valid = false;
  double laser_m = std::numeric_limits<double>::quiet_NaN();
  std::int64_t laser_stamp_ns = 0;  // CLOCK_MONOTONIC
  // Bus health.
  bool master_faulted = false;  // latched by a drive fault or a lost node until a fault reset
  bool bus_off = false;         // the CAN controller is bus-off (transmission suspended)
  int lost_node = 0;            // a node whose heartbeat is lost (0: none)
  // The safety chain: the e-stop / STO inputs (the configured sources, in order). Bit j of
  // safety_open is set while source j reads open, or its node is silent or its reading stale.
  int num_safety_inputs = 0;
  std::uint32_t safety_open = 0;
  // Events of the bus and the drives since the previous read(), oldest first (more than
  // kMaxEvents wait for the next read()).
  int num_events = 0;
  std::array<canopen::Event, kMaxEvents> events{};
};

struct RobotCommand {
  int num_axes = 0;
  // Drive targets (cyclic synchronous position); taken by enabled drives only.
  bool send_targets = false;
  std::array<std::int32_t, kMaxAxes> target_counts{};
  // State requests of this cycle, applied in this order: fault reset (the latched fault and
  // each drive in FAULT), enable (every drive towards OPERATION_ENABLED), quick stop (every
  // drive), disable (every drive towards SWITCH_ON_DISABLED; sent only once the holding brakes
  // are applied).
  bool fault_reset = false;
  bool enable = false;
  bool quick_stop = false;
  bool disable = false;
  // Holding brakes: release_brake[k] releases winch k's brake; false applies it. An I/O whose
  // brakes the drives manage themselves (or that has none) ignores it.
  std::array<bool, kMaxAxes> release_brake{};
};

class RobotIO {
 public:
  virtual ~RobotIO() = default;
  // Whether this I/O drives `model` (one axis per cable, one tension channel per cable when it
  // measures tensions); the error names what differs. Not RT.
  virtual Status fits(const RobotModel& model) const = 0;
  // RT: fills `reading` with this cycle's state.
  virtual void read(canopen::Timestamp now, RobotReading& reading) noexcept = 0;
  // RT: sends `command` (the cycle read() started).
  virtual void write(const RobotCommand& command) noexcept = 0;
};

}  // namespace cdpr::controller
