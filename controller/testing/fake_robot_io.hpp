// A RobotIO for unit tests of the RT cycle, without a CANopen network: the test scripts what the
// robot reads (positions, tensions, faults, bus events) and the fake records what the controller
// writes. Each enabled drive follows its target as a first-order lag (time constant tau_s) over
// the time between two read() calls; the tension sensor reads `tension` with a one raw unit
// dither (a live reading changes), unless its channel is frozen. Drive state requests take
// effect at once: quick stop leaves OPERATION_ENABLED, fault reset clears FAULT, enable enters
// OPERATION_ENABLED, disable leaves it. With `brakes`, a drive whose holding brake is applied
// (release_brake not set in the last command) does not move. read() and write() allocate nothing.
#pragma once

#include <array>
#include <cstdint>

#include "cdpr/controller/robot_io.hpp"

namespace cdpr::controller::testing {

class FakeRobotIO final : public RobotIO {
 public:
  enum class DriveState : std::uint8_t { kDisabled, kEnabled, kQuickStop, kFault };

  explicit FakeRobotIO(int axes, bool with_tensions = true);

  // The script (change it between cycles).
  std::array<double, kMaxAxes> position{};   // counts
  std::array<DriveState, kMaxAxes> state{};  // every drive starts enabled
  std::array<double, kMaxAxes> tension{};    // N, what the sensor measures
  std::array<bool, kMaxAxes> frozen{};       // the channel's raw value stays where it is
  double gain = 10.0;                        // raw units per N
  double tau_s = 0.01;                       // the drives' response
  bool tensions_arrive = true;               // false: no fresh tension reading
  bool master_faulted = false;               // the bus's latched fault (cleared by fault reset)
  int safety_inputs = 0;                     // e-stop / STO sources
  std::uint32_t safety_open = 0;             // bit j: source j reads open
  bool brakes = false;                       // each winch has a holding brake
  // A drive falls into FAULT (with the bus's latched fault and its events, as the master
  // reports them: a drive fault, then the EMCY).
  void fault(int axis, std::uint16_t emcy_code);
  // An event for the next read() (heartbeat lost, bus-off, ...).
  void push_event(const canopen::Event& e);

  // What the controller wrote.
  const RobotCommand& last() const { return last_; }
  int writes() const { return writes_; }
  int quick_stops() const { return quick_stops_; }
  int fault_resets() const { return fault_resets_; }
  bool brake_released(int axis) const {
    return last_.release_brake[static_cast<std::size_t>(axis)];
  }
  std::array<std::int32_t, kMaxAxes> target() const { return target_; }

  Status fits(const RobotModel& model) const override;
  void read(canopen::Timestamp now, RobotReading& reading) noexcept override;
  void write(const RobotCommand& command) noexcept override;

 private:
  int n_ = 0;
  bool with_tensions_ = true;
  bool have_time_ = false;
  canopen::Timestamp now_{0};
  std::array<std::int32_t, kMaxAxes> target_{};
  std::array<bool, kMaxAxes> has_target_{};  // false: the target follows the position
  std::array<std::int64_t, kMaxAxes> raw_{};
  std::array<std::uint16_t, kMaxAxes> emcy_{};
  std::uint64_t tension_updates_ = 0;
  std::array<canopen::Event, RobotReading::kMaxEvents> pending_{};
  int num_pending_ = 0;
  RobotCommand last_;
  int writes_ = 0, quick_stops_ = 0, fault_resets_ = 0;
};

}  // namespace cdpr::controller::testing
