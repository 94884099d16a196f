// The CANopen master: boots the network (reset communication, boot-ups, SDO configuration of
// heartbeats, PDOs and drive modes, NMT start, SYNC), then runs cycle(now) from the RT loop: it
// takes in TPDOs, heartbeats, EMCYs and error frames, steps the drives (receive), sends RPDOs, SYNC
// and its own heartbeat (transmit). cycle() never allocates, locks, logs or throws; what it has to
// say goes to events() and to the drives' Status.
//
// Blocking calls (boot, set_mode, wait_for, shutdown) wait through the Hooks: `now` is the clock
// (the RT loop's, or a test's injected one) and `idle` runs whenever nothing is waiting on the bus
// (tests step simulated nodes and advance the clock there). While the master is running, blocking
// calls keep cycling at the SYNC period, so drives stay fed during maintenance SDO traffic.
#pragma once

#include <array>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "cdpr/can/can_bus.hpp"
#include "cdpr/can/can_link.hpp"
#include "cdpr/canopen/bus_supervisor.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/devices.hpp"
#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/events.hpp"
#include "cdpr/canopen/nmt.hpp"
#include "cdpr/canopen/pdo.hpp"
#include "cdpr/canopen/sdo_client.hpp"

namespace cdpr::canopen {

struct MasterHooks {
  std::function<Timestamp()> now;
  std::function<void()> idle;
  std::chrono::nanoseconds receive_timeout{std::chrono::milliseconds(1)};
};

struct MasterStats {
  std::uint64_t cycles = 0;
  std::uint64_t rpdos_sent = 0;
  std::uint64_t tpdos_received = 0;
  std::uint64_t short_pdos = 0;  // TPDOs shorter than their mapping (not processed)
  std::uint64_t emcys = 0;
  std::uint64_t tx_failures = 0;
  std::uint64_t unknown_frames = 0;
  std::uint64_t pdos_disabled = 0;  // unused PDOs found enabled at boot and disabled
  std::uint64_t link_restarts = 0;  // bus-off recoveries through the link (netlink)
  std::uint64_t link_restart_failures = 0;
};

// Bus load of SYNC + all configured PDOs + heartbeats per SYNC period of `config`, without a bus
// (cdprd --check-config refuses a network whose cycle does not fit on the bus).
BusLoad bus_load(const MasterConfig& config);

class Master {
 public:
  // Builds process images, PDO layouts and devices from the configuration (allocates here only).
  static Result<std::unique_ptr<Master>> create(can::CanBus& bus, MasterConfig config,
                                                MasterHooks hooks);

  // Start-up: the master's own boot-up message, reset communication, wait for boot-ups, configure
  // every node, start them, start SYNC. Errors name the node and the step.
  Status boot();
  // Configures one node through SDO (heartbeats, 0x1019 when SYNC carries a counter, 0x6007,
  // disabling of every PDO the configuration does not use, PDOs, mode, extra writes). Part of
  // boot.
  Status configure_node(NodeId id);

  // A DCF (CiA 306) of what the master applied to a node: its EDS (or, without one, the objects
  // written) with ParameterValue = the last value the master wrote. write_dcfs writes one per
  // node, `<dir>/<node name>.dcf`.
  Status write_dcf(NodeId id, const std::string& path) const;
  Status write_dcfs(const std::string& dir) const;
  // Values the master wrote to a node and the node confirmed (ObjectAddress::key() -> value).
  const std::map<std::uint32_t, std::int64_t>* applied(NodeId id) const;
  // The PDOs (comm parameter indices, 0x14xx/0x18xx) the last boot found enabled on a node
  // although the configuration does not use them, and disabled.
  std::vector<std::uint16_t> disabled_pdos(NodeId id) const;

  // Bus-off recovery through the kernel: when the interface (config().interface) has no
  // restart-ms, the master restarts it through rtnetlink once the recovery wait is over
  // (docs/canopen.md, bus-off). Needs CAP_NET_ADMIN for the restart itself.
  Status enable_link_restart();

  // The RT cycle, receive(now) then transmit(now). A controller that reads, computes and writes
  // on this cycle's readings calls the two halves itself, with its update between them:
  //   receive: drains the receive queue (TPDOs into the process images, heartbeats, EMCYs,
  //            error frames), checks heartbeat consumers, steps every drive's state machine on
  //            the statusword that came in (events, the latched fault and its quick stop);
  //   transmit: takes what was asked of the drives since receive (targets, enable, quick stop,
  //            fault reset: Drive::commit), sends RPDOs, SYNC when due, the master heartbeat.
  void cycle(Timestamp now);
  void receive(Timestamp now);
  void transmit(Timestamp now);

  // Blocking helpers (start-up/maintenance).
  Status nmt(NmtCommand cmd, NodeId node);  // node 0 = all
  // 0x6060, then polls 0x6061 until it matches (mode_switch_timeout, error names the node).
  // While running, the drive is held (target = actual, Drive mode kNone) during the switch and
  // stays held if the drive never confirms.
  Status set_mode(NodeId node, Mode mode);
  // Reference platform: with the platform held at its reference pose, makes the drive's position
  // actual read `position` (SI units) without moving it: homing method 37 (35 if configured)
  // with 0x607C = position in counts, then back to the previous mode. The drive must be
  // OPERATION_ENABLED (homing starts only there); the master must be running.
  Status set_actual_position(NodeId node, double position, std::chrono::nanoseconds timeout);
  // The same in the drive's counts.
  Status set_actual_counts(NodeId node, std::int32_t counts, std::chrono::nanoseconds timeout);
  // Cycles (or pumps) until done() or the timeout; `what` names the wait in the error.
  Status wait_for(const std::function<bool()>& done, std::chrono::nanoseconds timeout,
                  const char* what);
  // Requests OPERATION_ENABLED on every drive and waits; fails with the drive supervisor's
  // message ("node 4: stuck in SWITCH_ON_DISABLED for 500 ms after shutdown").
  Status enable_all(std::chrono::nanoseconds timeout);
  // Quick stop to every drive, wait for it, disable voltage, 0x1016:01 = 0 on every node that
  // consumes the master's heartbeat (so none applies 0x6007 when the master is gone), stop SYNC,
  // NMT pre-operational. Goes through every step; returns the first error.
  Status shutdown(std::chrono::nanoseconds timeout);

  // Quick stop to every drive (RT-safe; taken at the next cycle).
  void quick_stop_all();
  // Latched by a drive fault or a lost node when quick_stop_on_fault is set.
  bool faulted() const { return faulted_; }
  void clear_fault() { faulted_ = false; }

  bool running() const { return running_; }
  Drive* drive(NodeId id);
  ForceSensor* force_sensor(NodeId id);
  std::span<Drive> drives() { return drives_; }
  std::span<ForceSensor> force_sensors() { return forces_; }
  SdoClient* sdo(NodeId id);
  ProcessImage* image(NodeId id);
  // When a TPDO of the node was last decoded (0: none since the master was created).
  Timestamp last_tpdo(NodeId id) const { return id <= kMaxNodeId ? last_tpdo_[id] : Timestamp{0}; }
  // The last TPDO of a drive that carried its statusword or position actual.
  Timestamp last_state_tpdo(NodeId id) const {
    return id <= kMaxNodeId ? last_state_tpdo_[id] : Timestamp{0};
  }
  Pump& pump() { return pump_; }
  Events& events() { return events_; }
  const NodeMonitor& nodes() const { return monitor_; }
  const BusSupervisor& bus() const { return bus_sup_; }
  BusSupervisor& bus() { return bus_sup_; }
  const SyncProducer& sync() const { return sync_; }
  const MasterStats& stats() const { return stats_; }
  const MasterConfig& config() const { return config_; }
  // Bus load of SYNC + all configured PDOs + heartbeats per SYNC period (canopen::bus_load).
  BusLoad bus_load() const;

 private:
  struct NodeRt {
    NodeConfig config;
    ProcessImage image;
    std::vector<PdoLayout> rpdos;
    std::vector<PdoLayout> tpdos;
    std::unique_ptr<SdoClient> sdo;
    int drive = -1;
    int force = -1;
    std::map<std::uint32_t, std::int64_t> applied;  // confirmed downloads (for the DCF)
    std::map<std::uint32_t, std::uint8_t> applied_size;
    std::vector<std::uint16_t> disabled;  // comm indices of PDOs disabled at boot
    // Without an EDS: 0x1000 and 0x1018:01..04 as the node answered at boot (for the DCF).
    std::map<std::uint32_t, std::int64_t> identity;
  };
  Status disable_unused_pdos(NodeRt& n);
  void read_identity(NodeRt& n);
  eds::Eds describe_without_eds(const NodeRt& n) const;
  Status stop_heartbeat_consumers();
  static void restart_link(void* self);

  class MasterPump final : public Pump {
   public:
    explicit MasterPump(Master& m) : m_(m) {}
    Timestamp now() override { return m_.hooks_.now(); }
    void step() override { m_.pump_step(); }

   private:
    Master& m_;
  };

  Master(can::CanBus& bus, MasterConfig config, MasterHooks hooks);
  void dispatch(const can::Frame& f, Timestamp now);
  void background(Timestamp now);  // heartbeat, consumer checks, SDO timeouts
  void pump_step();
  void send(const can::Frame& f, Timestamp now);
  NodeRt* node(NodeId id) { return node_index_[id] < 0 ? nullptr : nodes_[node_index_[id]].get(); }

  can::CanBus& bus_;
  MasterConfig config_;
  MasterHooks hooks_;
  MasterPump pump_{*this};
  std::vector<std::unique_ptr<NodeRt>> nodes_;
  std::array<int, kMaxNodeId + 1> node_index_{};
  // COB-ID -> (node, TPDO) for O(1) dispatch in the cycle.
  struct TpdoRef {
    std::int16_t node = -1;
    std::int16_t pdo = -1;
  };
  std::array<TpdoRef, 0x800> tpdo_table_{};
  std::array<Timestamp, kMaxNodeId + 1> last_tpdo_{};
  std::array<Timestamp, kMaxNodeId + 1> last_state_tpdo_{};
  std::vector<Drive> drives_;
  std::vector<ForceSensor> forces_;
  NodeMonitor monitor_;
  SyncProducer sync_;
  HeartbeatProducer heartbeat_;
  BusSupervisor bus_sup_;
  Events events_;
  MasterStats stats_;
  NmtState own_state_ = NmtState::kPreOperational;
  bool running_ = false;
  bool faulted_ = false;
  Timestamp next_cycle_{0};
  std::unique_ptr<can::CanLink> link_;  // enable_link_restart()
};

}  // namespace cdpr::canopen
