// Every file cdprd reads, checked before the CAN bus is opened (`cdprd --check-config`, and every
// start of cdprd before it touches the bus): the daemon configuration, the robot description
// (loaded and plausible: a file in millimetres is refused), the CANopen network (its EDS/DCF files
// and their types), the laser, and what holds only between files or against the host: cables and
// drives, counts per metre and force-sensor gains (in the robot and the network file: they must
// agree), the SYNC period on the bus, the tension settings against f_min/f_max, the control
// socket's directory and group, the state directory.
//
//   std::vector<Status> errors = check_daemon_files("/etc/cdpr/cdprd.yaml");  // empty: valid
//
// Each error names its file, line and field where the file has them ("mini.yaml:52:
// cables[0].frame_anchor: ..."). Adding a check: one entry in kChecks (config_check.cc) and a
// line in docs/daemon.md.
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/controller/daemon_config.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

// What a check looks at: the daemon configuration and the files it names, each loaded or null
// (its load error is already among the errors).
struct LoadedFiles {
  const DaemonConfig* daemon = nullptr;
  const canopen::MasterConfig* network = nullptr;
  const RobotModel* robot = nullptr;
};

// The checks between files and against the host, in order; each appends what it finds.
std::vector<Status> check_loaded_files(const LoadedFiles& files);

// Loads every file from the daemon configuration at `path` and checks it: every error found.
std::vector<Status> check_daemon_files(const std::string& path);

}  // namespace cdpr::controller
