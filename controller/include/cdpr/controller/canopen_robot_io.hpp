// RobotIO on the CANopen master (drives, force node) and the Modbus laser.
//
//   read(now):  Master::receive (TPDOs in, drive state machines) and the readings of this cycle;
//   write(cmd): the targets and state requests to the drives, then Master::transmit (RPDOs,
//               SYNC), so a target computed from this cycle's readings goes out in this cycle.
//
// Axis k is the master's k-th drive; tension channel k is channel k of its first force node.
// The safety chain (safety_config.hpp): each e-stop source is a bit of an object in its node's
// process image (a TPDO maps it), open when the bit is clear, the node lost or no TPDO of it came
// for stale_s; with brakes by output, bit `bit` of the brake object in each drive's image (an RPDO
// maps it) is set while the brake is to be applied.
#pragma once

#include <array>
#include <cstdint>
#include <memory>

#include "cdpr/canopen/master.hpp"
#include "cdpr/controller/robot_io.hpp"
#include "cdpr/controller/safety_config.hpp"
#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::controller {

class CanopenRobotIO final : public RobotIO {
 public:
  // `laser` may be nullptr (no laser). Both must outlive the object. Not RT.
  static Result<std::unique_ptr<CanopenRobotIO>> create(canopen::Master& master,
                                                        const modbus::LaserSensor* laser,
                                                        const SafetySettings& safety = {});

  Status fits(const RobotModel& model) const override;
  void read(canopen::Timestamp now, RobotReading& reading) noexcept override;
  // The e-stop sources that read open, silent or stale at `now` (bit j: source j), without
  // taking anything from the master (start-up, before the RT loop runs).
  std::uint32_t safety_open(canopen::Timestamp now) const noexcept;
  void write(const RobotCommand& command) noexcept override;

 private:
  CanopenRobotIO(canopen::Master& master, const modbus::LaserSensor* laser);
  void read_drives(RobotReading& r) noexcept;
  void read_tensions(RobotReading& r) noexcept;
  void read_health(RobotReading& r) noexcept;
  void read_safety(RobotReading& r) noexcept;
  Status bind_safety(const SafetySettings& safety);

  struct SafetyInput {
    int node = 0;
    const canopen::ProcessImage* image = nullptr;
    std::uint16_t slot = 0;
    int bit = 0;
    canopen::Timestamp stale{0};
  };
  std::array<SafetyInput, 32> safety_{};
  int num_safety_ = 0;
  std::array<canopen::ProcessImage*, kMaxAxes> brake_image_{};  // nullptr: not by output
  std::array<std::uint16_t, kMaxAxes> brake_slot_{};
  int brake_bit_ = 0;

  canopen::Master& master_;
  const modbus::LaserSensor* laser_ = nullptr;
  int n_ = 0;
  std::array<canopen::Drive*, kMaxAxes> drives_{};
  canopen::ForceSensor* force_ = nullptr;
  canopen::Timestamp now_{0};
  canopen::Timestamp previous_{0};
  bool have_previous_ = false;
  std::array<std::int32_t, kMaxAxes> previous_counts_{};
  std::uint64_t force_pdos_ = 0;
  canopen::Timestamp tensions_time_{0};
  std::array<std::uint16_t, kMaxAxes> emcy_{};
};

// The safety chain's sources and brake output against the network (no bus needed): each source's
// node exists (a CiA 402 drive where its kind needs one) and a TPDO of it maps the object; with
// brakes by output, an RPDO of every drive maps the brake object. Errors name the YAML field.
Status check_safety_io(const SafetySettings& safety, const canopen::MasterConfig& network);

}  // namespace cdpr::controller
