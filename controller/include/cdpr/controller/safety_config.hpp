// The safety chain's configuration (cdprd.yaml `safety`, docs/config.md): the e-stop / STO inputs
// read from the bus, the holding brakes, the software limits of each winch and the workspace box.
//
//   safety:
//     estop:                        # every source must read closed; one open, silent or stale
//       - {kind: drive_input, node: 1, bit: 16}           # latches a quick stop
//     brakes: {control: output, bit: 0, release_delay_s: 0.2, apply_delay_s: 0.2}
//     cable_length: {min: 0.05, max: [2.1, 2.1, 2.1, 2.1, 2.1, 2.1, 2.1, 2.1]}
//     workspace: {min: [-0.3, -0.3, -0.2], max: [0.3, 0.3, 0.4]}
//
// A kind of e-stop source is one row of estop_source_kinds(). The sources and the brake output
// are checked against the CANopen network when cdprd binds them (check_safety_io,
// canopen_robot_io.hpp); the limits against the robot (check_safety_limits).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::config {
class YamlField;
}

namespace cdpr::controller {

// How an e-stop source is read: the object (0 = given in the YAML as `index`/`sub`) and whether
// the node must be one of the network's CiA 402 drives.
struct EStopSourceKind {
  const char* name;
  std::uint16_t index;
  std::uint8_t sub;
  bool drive;
  const char* what;  // for docs/config.md and errors
};
std::span<const EStopSourceKind> estop_source_kinds();

// One input of the chain: bit `bit` of object index:sub, which a TPDO of `node` maps. Set (1) is
// closed; clear is open. No TPDO of the node for `stale_s`, or its heartbeat lost: open too.
struct EStopSource {
  int kind = 0;  // row of estop_source_kinds()
  int node = 0;
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  int bit = 0;
  double stale_s = 0.1;
  std::string where;  // "cdprd.yaml:41: safety.estop[0]"
};

enum class BrakeControl : std::uint8_t {
  kNone,    // no holding brakes
  kDrive,   // each drive applies its own brake on disable and fault (the delays still apply)
  kOutput,  // a digital output of each drive (bit of index:sub, 0x60FE:01 by default), set =
            // brake applied (CiA 402 "set brake"); a drive's RPDO must map it
};

struct BrakeSettings {
  BrakeControl control = BrakeControl::kNone;
  std::uint16_t index = 0x60FE;
  std::uint8_t sub = 1;
  int bit = 0;
  double release_delay_s = 0.2;  // the drive holds torque this long before its brake releases
  double apply_delay_s = 0.2;    // the brakes are applied this long before the drives disable
  std::string where;
};

struct SafetySettings {
  std::vector<EStopSource> estop;
  BrakeSettings brakes;
  // Kinematic cable length of each winch (m): one entry per cable, or one for all; empty: none.
  std::vector<double> min_cable_length, max_cable_length;
  double cable_length_tolerance = 0.002;  // m an actual length may lie beyond them
  std::string cable_length_where;
  bool workspace = false;  // the platform origin's box (world, m)
  std::array<double, 3> workspace_min{}, workspace_max{};
};

// Reads `safety` (absent: no chain, no limits); errors name file, line and field.
Status read_safety_settings(const config::YamlField& node, SafetySettings& out);
// The limits fit a robot of `num_cables` cables (one length each, or one for all).
Status check_safety_limits(const SafetySettings& s, int num_cables);
// The limit of cable i (m): min (lower) or max, +-infinity when none.
double cable_length_limit(const SafetySettings& s, int cable, bool upper);

}  // namespace cdpr::controller
