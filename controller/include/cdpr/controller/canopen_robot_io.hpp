// RobotIO on the CANopen master (drives, force node) and the Modbus laser.
//
//   read(now):  Master::receive (TPDOs in, drive state machines) and the readings of this cycle;
//   write(cmd): the targets and state requests to the drives, then Master::transmit (RPDOs,
//               SYNC), so a target computed from this cycle's readings goes out in this cycle.
//
// Axis k is the master's k-th drive; tension channel k is channel k of its first force node.
#pragma once

#include <array>
#include <cstdint>
#include <memory>

#include "cdpr/canopen/master.hpp"
#include "cdpr/controller/robot_io.hpp"
#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::controller {

class CanopenRobotIO final : public RobotIO {
 public:
  // `laser` may be nullptr (no laser). Both must outlive the object. Not RT.
  static Result<std::unique_ptr<CanopenRobotIO>> create(canopen::Master& master,
                                                        const modbus::LaserSensor* laser);

  Status fits(const RobotModel& model) const override;
  void read(canopen::Timestamp now, RobotReading& reading) noexcept override;
  void write(const RobotCommand& command) noexcept override;

 private:
  CanopenRobotIO(canopen::Master& master, const modbus::LaserSensor* laser);
  void read_drives(RobotReading& r) noexcept;
  void read_tensions(RobotReading& r) noexcept;
  void read_health(RobotReading& r) noexcept;

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

}  // namespace cdpr::controller
