// The master's view of its devices, bound to slots of the node's process image: a CiA 402 drive
// (state supervision, no-jump targets, CSP/PP/homing handshakes) and a force-sensor node (raw
// channels to tensions). update() runs in the RT cycle: no allocation, no locks.
#pragma once

#include <cstdint>
#include <vector>

#include "cdpr/canopen/cia402.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/pdo.hpp"

namespace cdpr::canopen {

class Drive {
 public:
  // Binds to the image slots of controlword/target (RPDO) and statusword/actual (TPDO).
  static Result<Drive> bind(const NodeConfig& config, ProcessImage& image);

  NodeId node() const { return node_; }

  // Requests (taken at the next cycle).
  void enable() { sup_.request(cia402::Target::kOperationEnabled); }
  void disable() { sup_.request(cia402::Target::kSwitchOnDisabled); }
  void switch_on() { sup_.request(cia402::Target::kSwitchedOn); }
  void quick_stop() { sup_.request(cia402::Target::kQuickStop); }
  void reset_fault() { sup_.request_fault_reset(); }

  // Position commands in SI units (counts / counts_per_unit) or raw counts. In CSP they are only
  // taken while OPERATION_ENABLED; otherwise the target follows the actual position, so enabling
  // never jumps. Returns false when the target was not taken.
  bool set_target(double position) { return set_target_counts(to_counts(position)); }
  bool set_target_counts(std::int32_t counts);
  // Profile position move (new set-point handshake with set-point acknowledge).
  bool move_to(double position) { return move_to_counts(to_counts(position)); }
  bool move_to_counts(std::int32_t counts);
  bool move_done() const { return !pp_pending_ && !pp_bit4_ && pp_reached_; }
  // Homing (method from the configuration; 37/35 = "the current position is home"). Bit 4 gets
  // a rising edge (one cycle low first if it is still high), and the statusword is judged only
  // from the second cycle on: a "homing attained" left from an earlier homing is not taken.
  void start_homing() {
    homing_requested_ = true;
    homing_done_ = homing_error_ = false;
    homing_cycles_ = (controlword_ & cia402::cw::kStartHoming) ? -1 : 0;
  }
  bool homing_done() const { return homing_done_; }
  bool homing_error() const { return homing_error_; }

  // RT: read statusword/actual from the image, step the supervisor, write controlword/target.
  // Until the first TPDO arrived (on_pdo), nothing is known: the supervisor does not run.
  void update(Timestamp now);
  // RT, after update and before the RPDOs are encoded: a CSP target set since update goes into
  // the image, and a state request made since update (enable, disable, quick stop, fault reset)
  // is stepped into this cycle's controlword instead of waiting for the next update.
  void commit(Timestamp now);
  void on_pdo() { received_ = true; }
  bool received() const { return received_; }
  // Whether a TPDO writing `slot` carries the drive's state (statusword or position actual): only
  // such a TPDO makes the drive known (one carrying only its digital inputs does not).
  bool carries_state(std::uint16_t slot) const { return slot == sw_slot_ || slot == actual_slot_; }

  Mode mode() const { return mode_; }
  // After the master switched the drive (0x6060/0x6061); kNone holds the position (the target
  // follows the actual position) while a switch is under way. Commands of the old mode are
  // dropped: a CSP target or a move from before a homing would be in the old coordinates.
  void set_mode(Mode m);

  cia402::State state() const { return sup_.state(); }
  const cia402::Supervisor& supervisor() const { return sup_; }
  std::uint16_t statusword() const { return statusword_; }
  std::uint16_t controlword() const { return controlword_; }
  std::int32_t actual_counts() const { return actual_; }
  std::int32_t target_counts() const { return target_; }
  double actual_position() const { return actual_ / counts_per_unit_; }
  double target_position() const { return target_ / counts_per_unit_; }
  bool enabled() const { return sup_.state() == cia402::State::kOperationEnabled; }
  // Number of transitions into OPERATION_ENABLED and the largest |target - actual| seen at them.
  std::uint32_t enable_count() const { return enable_count_; }
  std::int64_t max_enable_error() const { return max_enable_error_; }

  // SI units to counts (rounded, saturated to int32).
  std::int32_t to_counts(double x) const;

 private:
  NodeId node_ = 0;
  ProcessImage* image_ = nullptr;
  std::uint16_t cw_slot_ = 0, target_slot_ = 0, sw_slot_ = 0, actual_slot_ = 0;
  double counts_per_unit_ = 1.0;
  Mode mode_ = Mode::kNone;
  cia402::Supervisor sup_;
  std::uint16_t statusword_ = 0;
  std::uint16_t controlword_ = 0;
  std::int32_t actual_ = 0;
  std::int32_t target_ = 0;
  std::int32_t user_target_ = 0;
  bool user_target_valid_ = false;
  bool was_enabled_ = false;
  bool received_ = false;
  // The supervisor's request as update() stepped it (commit() steps again if it changed).
  cia402::Target stepped_target_ = cia402::Target::kSwitchOnDisabled;
  bool stepped_reset_ = false;
  bool stepped_stuck_ = false;
  std::uint32_t enable_count_ = 0;
  std::int64_t max_enable_error_ = 0;
  // Profile position handshake.
  std::int32_t pp_target_ = 0;
  bool pp_pending_ = false;
  bool pp_bit4_ = false;
  bool pp_reached_ = true;
  // Homing.
  bool homing_requested_ = false;
  bool homing_done_ = false;
  bool homing_error_ = false;
  int homing_cycles_ = 0;  // cycles bit 4 was sent (-1: one cycle low first)
};

class ForceSensor {
 public:
  static Result<ForceSensor> bind(const NodeConfig& config, const ProcessImage& image);
  NodeId node() const { return node_; }
  std::size_t channels() const { return slots_.size(); }
  std::int64_t raw(std::size_t ch) const { return image_->get(slots_[ch]); }
  // Tension in N: raw = gain * tension + offset.
  double tension(std::size_t ch) const {
    return (static_cast<double>(raw(ch)) - offset_[ch]) / gain_[ch];
  }
  // Raw units per N.
  double gain(std::size_t ch) const { return gain_[ch]; }
  // TPDOs of this node decoded so far (a reading is fresh when this count moved).
  void on_pdo() { ++pdos_; }
  std::uint64_t pdos_received() const { return pdos_; }

 private:
  NodeId node_ = 0;
  const ProcessImage* image_ = nullptr;
  std::vector<std::uint16_t> slots_;
  std::vector<double> gain_, offset_;
  std::uint64_t pdos_ = 0;
};

}  // namespace cdpr::canopen
