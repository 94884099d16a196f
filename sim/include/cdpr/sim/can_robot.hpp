// The virtual robot's CANopen side: m CiA 402 winch drives and the force-sensor node(s) of a
// CANopen network description (drivers/canopen config, e.g. config/canopen-mini.yaml) on one
// CanBus, driven by the physics (physics.hpp) and the scenario's CAN faults.
//
//   CanRobot robot = *CanRobot::create(bus, network, physics, options);
//   robot.power_on(now);                 // boot-ups; scenario time 0
//   for (;;) { robot.wait(1ms); robot.step(clock_now()); }
//
// Nodes: the `cia402` nodes in configuration order are the drives of cables 1..m
// (cdpr_canopen_slave's Drive402); the channels of the `force_sensor` nodes (the values their
// TPDOs map, in node then mapping order) are the force sensors of cables 1..m. A node whose
// configuration names an EDS (`eds:`, e.g. config/eds/cdpr-sim-drive.eds in canopen-mini.yaml)
// has exactly the object dictionary the EDS describes, with its defaults: the drives start with
// their default PDO mappings enabled, as real drives do, and the master must disable what it does
// not use. Without an EDS a node has the model's objects plus every object the configuration maps
// or writes at boot. Every node has the identity object 0x1018 (vendor, product code, revision,
// serial = node id), 0x1008 = "cdpr-sim <name>" and its producer heartbeat 0x1017 preset to the
// configured period (so a node is heard before a master configures it; kept across NMT resets).
//
// On each SYNC: the drives apply their RPDOs (CSP: position actual := target) and send their
// TPDOs (statusword, position actual), then the physics steps with the drives' positions (counts)
// at the scenario time, then the force nodes' mapped objects get the physics' raw force readings
// (rounded, saturated to the mapped type) and the force nodes send their TPDOs.
//
// Scenario faults (scenario.hpp), at scenario time t = seconds since power_on:
//   drive_fault     the cable's drive goes to FAULT and sends EMCY `emcy` (once, at `at`)
//   drive_silent    the cable's drive sends nothing (no heartbeat, no SDO answer) while active
//   sdo_abort       SDO access to object:subindex of the cable's drive is aborted while active
//   bus_off         while active nothing is sent or received; an error frame with the bus-off
//                   class is sent when it starts and one with "restarted" when it ends
//   cable_overload  the physics latches the trip; the cable's drive then faults with EMCY `emcy`
// On demand (tests choose the moment, e.g. the fault matrix): set_bus_off, a force channel stuck
// at its last reading or forced to a raw value (set_force_fault), a cable slipping on its drum
// (set_cable_slip: the physics sees the drive's position plus the slip, the encoder does not), the
// e-stop chain opened and closed (set_estop), and
// through drive()/node() the slaves' own faults (inject_fault, faults().silent, abort_on).
// Single-threaded; not real-time (it allocates), it stands in for devices.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "cdpr/can/can_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/slave/slave.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/status.hpp"

namespace cdpr::sim {

using can::Timestamp;

struct CanRobotOptions {
  // Drive positions at power-on, counts (one per cable; empty: 0).
  std::vector<std::int32_t> initial_counts;
  // Identity object 0x1018.
  std::uint32_t vendor_id = 0x00CD9001;
  std::uint32_t drive_product_code = 0x00000402;
  std::uint32_t force_product_code = 0x00000404;
  std::uint32_t revision = 0x00010000;
  std::uint32_t serial_base = 0x5100'0000;  // serial = serial_base + node id
  // Called with the scenario time and a line of text for what happened (faults applied, drive
  // trips, physics failures). May be empty.
  std::function<void(double, const std::string&)> report;
};

struct CanRobotStats {
  std::uint64_t syncs = 0;             // SYNC frames processed
  std::uint64_t physics_steps = 0;     // successful
  std::uint64_t physics_failures = 0;  // no equilibrium (the previous state was kept)
  std::uint64_t frames_dropped_bus_off = 0;
};

// A force channel's misbehaviour on demand.
enum class ForceChannelFault : std::uint8_t {
  kNone,
  kStuck,  // the channel keeps its last raw reading
  kRaw,    // the channel reads a fixed raw value (e.g. the limit of its type: out of range)
};

class CanRobot {
 public:
  // `network` describes the nodes (validated here: as many cia402 nodes as cables, force
  // channels 0 or m). `physics` must outlive the robot and is stepped only by it.
  static Result<std::unique_ptr<CanRobot>> create(can::CanBus& bus,
                                                  const canopen::MasterConfig& network,
                                                  Physics& physics, CanRobotOptions options = {});
  ~CanRobot();
  CanRobot(const CanRobot&) = delete;
  CanRobot& operator=(const CanRobot&) = delete;

  // Powers every node on (boot-up messages); `now` is scenario time 0. Steps the physics once
  // with the initial counts, so the force nodes hold readings before the first SYNC.
  void power_on(Timestamp now);
  // Waits up to `timeout` for a frame (kept for the next step). Returns true if one came.
  bool wait(std::chrono::nanoseconds timeout);
  // Applies the faults due at `now`, takes in every received frame and runs the nodes.
  void step(Timestamp now);

  // On-demand faults (see the file comment).
  void set_bus_off(bool on);
  void set_force_fault(int cable, ForceChannelFault fault, double raw = 0.0);
  void set_cable_slip(int cable, double counts);
  // The e-stop / STO chain, wired through every drive: open clears the safety bit of each drive's
  // digital inputs (0x60FD bit Drive402::kSafetyInputBit), closed sets it. A drive's holding
  // brake (0x60FE:01 bit 0, as its RPDO sets it) keeps its winch from turning.
  void set_estop(bool open);

  double scenario_time(Timestamp now) const;
  int num_cables() const { return static_cast<int>(drives_.size()); }
  canopen::slave::Drive402& drive(int cable) { return *drives_[static_cast<std::size_t>(cable)]; }
  canopen::slave::SlaveNode& node(canopen::NodeId id);
  const Physics& physics() const { return physics_; }
  const CanRobotStats& stats() const { return stats_; }
  bool bus_off() const { return bus_off_; }

  class Port;  // one node's view of the shared bus

 private:
  struct ForceChannel {
    canopen::slave::SlaveNode* node = nullptr;
    canopen::ObjectAddress object;
    canopen::DataType type = canopen::DataType::kI16;
  };

  CanRobot(can::CanBus& bus, Physics& physics, CanRobotOptions options);
  void apply_faults(double t);
  void deliver(const can::Frame& f);
  void on_sync(Timestamp now);
  void step_physics(double t);
  void say(double t, const std::string& what);

  can::CanBus& bus_;
  Physics& physics_;
  CanRobotOptions options_;
  std::vector<std::unique_ptr<Port>> ports_;
  std::vector<std::unique_ptr<canopen::slave::SlaveNode>> nodes_;
  std::vector<canopen::slave::Drive402*> drives_;        // per cable
  std::vector<canopen::slave::SlaveNode*> force_nodes_;  // in configuration order
  std::vector<ForceChannel> force_channels_;             // per cable (or none)
  std::vector<std::uint16_t> overload_emcy_;             // per cable: 0 = no overload fault
  std::vector<bool> overload_tripped_;                   // per cable
  std::vector<bool> fault_applied_;                      // per scenario fault (one-shots)
  std::vector<bool> fault_active_;                       // per scenario fault (windows)
  std::vector<ForceChannelFault> force_fault_;           // per cable (on demand)
  std::vector<double> force_fault_raw_;                  // per cable, for kRaw
  std::vector<double> slip_counts_;                      // per cable (on demand)
  std::deque<can::Frame> waiting_;                       // received by wait()
  Timestamp t0_{0};
  double last_t_ = 0.0;
  bool powered_ = false;
  bool bus_off_ = false;
  bool physics_failing_ = false;
  CanRobotStats stats_;
};

}  // namespace cdpr::sim
