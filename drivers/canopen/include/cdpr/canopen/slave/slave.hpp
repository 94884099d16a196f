// A CANopen slave (CiA 301 subset) for tests and the virtual robot: object dictionary, SDO
// server (expedited and segmented), NMT state machine with boot-up and heartbeat producer,
// master-heartbeat consumer (0x1016), PDOs configured through the dictionary (0x1400/0x1600,
// 0x1800/0x1A00; a change takes effect at once, in any NMT state), synchronous (types 0..240) and
// event-driven TPDOs (254/255: on change and by event timer, with the inhibit time), SYNC handling
// with the SYNC counter check (0x1019), EMCY producer (0x1014) with "error reset" after an error
// is gone. NMT reset communication restores 0x1000..0x1FFF to their defaults, reset node every
// object. The dictionary can come from an EDS (load_eds). Plus a CiA 402 drive model (Drive402)
// and fault injection to test masters against misbehaving nodes.
//
// Single-threaded: the owner calls step(now) to process what the node's bus endpoint received and
// to produce heartbeats. Not real-time (it allocates): it stands in for real devices.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <span>
#include <string>
#include <vector>

#include "cdpr/can/can_bus.hpp"
#include "cdpr/canopen/pdo.hpp"
#include "cdpr/canopen/types.hpp"
#include "cdpr/status.hpp"

namespace cdpr::canopen::eds {
class Eds;
}

namespace cdpr::canopen::slave {

enum class Access : std::uint8_t { kRo, kWo, kRw, kConst };

struct Entry {
  std::vector<std::uint8_t> data;
  std::vector<std::uint8_t> default_data;  // restored by NMT reset (communication or node)
  Access access = Access::kRw;
  bool variable_size = false;  // VISIBLE_STRING / DOMAIN
  bool mappable = true;        // may be mapped into a PDO (EDS PDOMapping)
  // Called before a write is accepted; returns 0 or the SDO abort code.
  std::function<std::uint32_t(std::span<const std::uint8_t>)> validate;
  // Called after a write was stored: every SDO write, and an RPDO write that changed the value
  // (a PDO repeats its values cyclically; a change is the event).
  std::function<void()> on_write;
  // false: on_write is not called for RPDO writes (the device model takes the object from every
  // applied RPDO itself, in on_rpdo_applied: the controlword).
  bool on_write_from_pdo = true;
};

class ObjectDictionary {
 public:
  Entry& add(ObjectAddress a, DataType type, std::int64_t value, Access access = Access::kRw);
  Entry& add_string(ObjectAddress a, std::string_view value, Access access = Access::kRo);
  // An entry of `bytes` raw bytes (types the typed add() does not cover, e.g. UNSIGNED64).
  Entry& add_raw(ObjectAddress a, std::vector<std::uint8_t> bytes, Access access = Access::kRw);
  bool has_index(std::uint16_t index) const;
  Entry* find(ObjectAddress a);
  const Entry* find(ObjectAddress a) const;
  // Typed access for the application (no access checks); 0 if the entry does not exist.
  std::int64_t get(ObjectAddress a, bool is_signed = false) const;
  void set(ObjectAddress a, std::int64_t value);
  // Sets the value and the default it returns to after an NMT reset.
  void set_default(ObjectAddress a, std::int64_t value);
  // Restores the defaults of every entry with an index in [lo, hi].
  void restore_defaults(std::uint16_t lo, std::uint16_t hi);
  // Every entry's address, in order.
  std::vector<ObjectAddress> addresses() const;

  // SDO semantics: 0 or an abort code.
  std::uint32_t read(ObjectAddress a, std::vector<std::uint8_t>& out) const;
  std::uint32_t write(ObjectAddress a, std::span<const std::uint8_t> data);

 private:
  std::map<std::uint32_t, Entry> entries_;
};

// Misbehaviour on demand.
struct Faults {
  int drop_sdo_requests = 0;  // ignore this many SDO requests (to test timeouts/retries)
  bool bad_toggle = false;    // the next segment answer carries the wrong toggle bit
  std::map<std::uint32_t, std::uint32_t> abort_on;  // ObjectAddress::key() -> abort code
  bool silent = false;  // no boot-up, heartbeat or answers at all (dead node)
  // A stalling SDO server: after `delay_sdo_after` more requests were answered normally, the next
  // `delay_sdo_answers` requests are processed (and answered) `sdo_answer_delay` late. Requests
  // arriving meanwhile queue behind them and are processed in order when they are released,
  // so a late answer, and then the answers to what the client sent meanwhile, come in a burst.
  int delay_sdo_answers = 0;
  int delay_sdo_after = 0;
  std::chrono::nanoseconds sdo_answer_delay{0};
};

class SlaveNode {
 public:
  SlaveNode(can::CanBus& bus, NodeId id);
  virtual ~SlaveNode() = default;

  NodeId id() const { return id_; }
  ObjectDictionary& od() { return od_; }
  const ObjectDictionary& od() const { return od_; }
  NmtState nmt_state() const { return state_; }
  Faults& faults() { return faults_; }

  // Powers the node on: sends its boot-up and enters PRE-OPERATIONAL.
  void power_on(Timestamp now);
  // Processes received frames and produces heartbeats.
  void step(Timestamp now);
  // Sends an EMCY on the COB-ID of 0x1014 (nothing while it is invalid) and sets 0x1001.
  void send_emcy(std::uint16_t code, std::uint8_t error_register,
                 std::array<std::uint8_t, 5> manufacturer = {});
  // The error is gone: 0x1001 := 0 and EMCY 0x0000 "error reset / no error" (CiA 301, 7.2.7.1).
  void clear_errors();
  // The application acknowledges errors (a CiA 402 fault reset): a pending communication error
  // (EMCY 0x8210 short RPDO, 0x8240 unexpected SYNC length) is cleared with clear_errors().
  void acknowledge_communication_error();
  bool communication_error() const { return comm_error_; }

  // Makes the dictionary the one an EDS describes: every EDS entry exists with the EDS's type
  // size, access, PDO mapping flag and default value ($NODEID resolved); entries the device model
  // defines keep their behaviour. Fails naming the object if an EDS entry's size contradicts the
  // model or the model needs an object the EDS does not describe. Call before power_on().
  Status load_eds(const eds::Eds& eds);

  std::uint64_t syncs() const { return syncs_; }
  std::uint64_t sdo_requests() const { return sdo_requests_; }  // processed (not dropped/held)
  std::uint64_t rpdos_applied() const { return rpdos_applied_; }
  std::uint64_t tpdos_sent() const { return tpdos_sent_; }
  std::uint64_t emcys_sent() const { return emcys_sent_; }
  // RPDO values a mapped object's check refused (e.g. an unsupported 0x6060 mode): not stored.
  std::uint64_t rpdo_values_refused() const { return rpdo_values_refused_; }
  bool master_lost() const { return master_lost_; }

 protected:
  // Hooks for device models.
  virtual void on_sync(Timestamp) {}
  virtual void on_rpdo_applied(Timestamp) {}
  virtual void on_master_lost(Timestamp) {}
  virtual void on_reset_application() {}
  // Called at the end of every step(now).
  virtual void on_step(Timestamp) {}
  // Time of the step() being processed (for hooks without a time argument).
  Timestamp now() const { return now_; }

 private:
  void handle(const can::Frame& f, Timestamp now);
  void receive_sdo(const can::Frame& f, Timestamp now);
  void handle_sdo(const can::Frame& f);
  void sdo_abort(ObjectAddress a, std::uint32_t code);
  void sdo_send(can::Frame& f);
  void reset_communication(Timestamp now);
  void apply_rpdo(std::size_t i, Timestamp now);
  void send_sync_tpdos();
  void send_event_tpdos(Timestamp now);
  void refresh_pdo(bool tpdo, int n);
  void refresh_pdos();
  void send(const can::Frame& f);

  struct Pdo {
    bool valid = false;
    std::uint32_t cob_id = 0;
    std::uint8_t type = 0;
    std::chrono::nanoseconds inhibit{0};      // TPDO: at least this between two transmissions
    std::chrono::nanoseconds event_timer{0};  // TPDO 254/255: at least one frame per period
    std::vector<std::pair<ObjectAddress, std::uint8_t>> map;  // object, bytes
    std::array<std::uint8_t, 8> pending{};
    bool has_pending = false;
    std::uint32_t sync_count = 0;
    // TPDO: what was sent last and when (event-driven and type 0 send on change).
    bool sent = false;
    std::array<std::uint8_t, 8> last{};
    std::uint8_t last_dlc = 0;
    Timestamp last_time{0};
  };
  static constexpr int kPdos = 4;
  std::uint8_t tpdo_data(const Pdo& p, std::array<std::uint8_t, 8>& out) const;
  void transmit_tpdo(Pdo& p, const std::array<std::uint8_t, 8>& data, std::uint8_t dlc,
                     Timestamp now);

  can::CanBus& bus_;
  NodeId id_;
  ObjectDictionary od_;
  Faults faults_;
  NmtState state_ = NmtState::kUnknown;  // off until power_on
  Timestamp next_heartbeat_{0};
  Timestamp master_last_{0};
  bool master_heard_ = false;
  bool master_lost_ = false;
  bool comm_error_ = false;  // EMCY 0x8210/0x8240 sent and not yet cleared
  std::uint64_t rpdo_values_refused_ = 0;
  std::array<Pdo, kPdos> rpdos_{}, tpdos_{};
  std::uint64_t syncs_ = 0, rpdos_applied_ = 0, sdo_requests_ = 0, tpdos_sent_ = 0, emcys_sent_ = 0;
  Timestamp now_{0};
  struct HeldRequest {
    Timestamp due;
    can::Frame frame;
  };
  std::deque<HeldRequest> held_sdo_;  // requests of a stalling server (Faults::delay_sdo_*)
  // SDO server state.
  enum class SdoState { kIdle, kDownload, kUpload } sdo_state_ = SdoState::kIdle;
  ObjectAddress sdo_addr_{};
  std::vector<std::uint8_t> sdo_buf_;
  std::size_t sdo_offset_ = 0;
  bool sdo_toggle_ = false;
};

// CiA 402 drive model: state machine driven by 0x6040, statusword 0x6041, modes 0x6060/0x6061,
// CSP (actual follows 0x607A at each SYNC), profile position (moves at 0x6081 per second, new
// set-point handshake), homing (method 35/37: current position becomes 0x607C, on the rising edge
// of bit 4), delayed or missing 0x6061 confirmation, quick stop,
// fault injection with EMCY (and EMCY 0x0000 after the fault reset), 0x6007 reaction to a lost
// master. Statusword bit 12 in CSP: target position used (1 while OPERATION_ENABLED). 0x6502
// lists the modes it supports (PP, HM, CSP). Digital inputs 0x60FD: bit kSafetyInputBit is the
// e-stop / STO chain's status (1: closed, at power-on). Digital outputs 0x60FE:01: bit 0 is
// CiA 402's "set brake" (1: the holding brake is applied and the shaft does not turn).
class Drive402 : public SlaveNode {
 public:
  static constexpr int kSafetyInputBit = 16;

  Drive402(can::CanBus& bus, NodeId id, std::int32_t initial_position = 0);

  // Sets or clears a bit of the digital inputs 0x60FD.
  void set_digital_input(int bit, bool on);
  bool brake_applied() const;
  // SYNCs at which the brake held the shaft against a target that would have moved it.
  std::uint64_t braked_syncs() const { return braked_syncs_; }

  // Goes to FAULT (through FAULT_REACTION_ACTIVE) and sends an EMCY with `emcy_code`.
  void inject_fault(std::uint16_t emcy_code);
  // A drive that ignores the controlword (to test the master's supervisor).
  void set_ignore_controlword(bool v) { ignore_cw_ = v; }
  // Moves the shaft by hand (the model's actual position, in the drive's counts) while not
  // enabled.
  void set_actual_position(std::int32_t p) { position_ = p; }
  // 0x6061 follows a write of 0x6060 only after `d` (0: at once), or never.
  void set_mode_display_delay(std::chrono::nanoseconds d) { mode_delay_ = d; }
  void set_ignore_mode_switch(bool v) { ignore_mode_switch_ = v; }
  // Homing (mode 6) starts on a rising edge of controlword bit 4 while OPERATION_ENABLED and
  // clears "homing attained"; methods 35/37 set the position to 0x607C after `d` (0: at the
  // edge) without turning the shaft (the drive's counts shift against the shaft), other methods
  // end with "homing error".
  void set_homing_duration(std::chrono::nanoseconds d) { homing_duration_ = d; }
  std::uint32_t homings() const { return homings_; }

  std::uint16_t statusword() const { return statusword_; }
  // Position actual (0x6064) in the drive's counts, and the shaft's own position (what turns
  // the drum: the position less the shift homing gave the counts).
  std::int32_t position() const { return position_; }
  std::int64_t shaft() const { return std::int64_t{position_} - home_shift_; }
  // Largest |position change| in one SYNC seen right at a transition into OPERATION_ENABLED.
  std::int64_t max_jump_on_enable() const { return max_jump_on_enable_; }
  std::uint32_t enable_count() const { return enable_count_; }
  std::uint16_t last_controlword() const { return last_cw_; }

 protected:
  void on_rpdo_applied(Timestamp now) override;
  void on_sync(Timestamp now) override;
  void on_master_lost(Timestamp now) override;
  void on_reset_application() override;
  void on_step(Timestamp now) override;

 private:
  enum class S : std::uint8_t {
    kNotReady,
    kSwitchOnDisabled,
    kReady,
    kSwitchedOn,
    kEnabled,
    kQuickStop,
    kFaultReaction,
    kFault
  };
  void apply_controlword(std::uint16_t cw);
  void publish();
  void home_here();

  S s_ = S::kNotReady;
  std::uint16_t last_cw_ = 0;
  std::uint16_t statusword_ = 0;
  std::int32_t position_ = 0;
  std::int64_t home_shift_ = 0;  // position_ - shaft, changed by homing only
  bool ignore_cw_ = false;
  bool set_point_ack_ = false;
  bool homing_attained_ = false;
  bool homing_error_ = false;
  bool homing_running_ = false;
  Timestamp homing_until_{0};
  std::chrono::nanoseconds homing_duration_{0};
  std::uint32_t homings_ = 0;
  std::chrono::nanoseconds mode_delay_{0};
  bool ignore_mode_switch_ = false;
  bool mode_pending_ = false;
  Timestamp mode_due_{0};
  std::int32_t pp_target_ = 0;
  bool pp_moving_ = false;
  std::int64_t max_jump_on_enable_ = 0;
  std::uint32_t enable_count_ = 0;
  bool enable_sync_pending_ = false;
  int fault_reaction_syncs_ = 0;
  double sync_period_s_ = 0.004;
  std::uint64_t braked_syncs_ = 0;
};

}  // namespace cdpr::canopen::slave
