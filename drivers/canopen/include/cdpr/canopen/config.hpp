// Configuration of the CANopen network: the master's timing and every node (what its PDOs carry,
// heartbeats, drive and force-sensor parameters). Loaded from YAML (see docs/canopen.md and
// config/canopen-mini.yaml); errors name file, line and field. Durations are SI in code.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/canopen/pdo.hpp"
#include "cdpr/canopen/types.hpp"
#include "cdpr/status.hpp"

namespace cdpr::canopen {

namespace eds {
class Eds;
}

using std::chrono::nanoseconds;

enum class NodeKind : std::uint8_t { kGeneric, kCia402Drive, kForceSensor };
std::string_view to_string(NodeKind k);

// CiA 402 modes of operation (0x6060) the master uses.
enum class Mode : std::int8_t {
  kNone = 0,
  kProfilePosition = 1,
  kHoming = 6,
  kCyclicSyncPosition = 8,
};
std::string_view to_string(Mode m);

struct DriveConfig {
  Mode mode = Mode::kCyclicSyncPosition;  // mode set at boot
  double counts_per_unit = 1.0;           // drive position counts per SI unit (m or rad)
  std::string counts_per_unit_where;  // "net.yaml:26: profiles.winch.counts_per_unit"; "": default
  nanoseconds transition_timeout{std::chrono::milliseconds(500)};
  nanoseconds mode_switch_timeout{std::chrono::milliseconds(1000)};
  std::int16_t abort_connection_option =
      3;  // 0x6007: 0 none, 1 fault, 2 disable voltage, 3 quick stop
  std::optional<std::int16_t> quick_stop_option;  // 0x605A, written when set
  std::uint32_t profile_velocity =
      0;  // 0x6081 in counts/s for profile position moves (0: not written)
  std::uint32_t profile_acceleration = 0;  // 0x6083/0x6084 in counts/s^2 (0: not written)
  std::int8_t homing_method = 37;  // 0x6098: 37 (35 in old drives) = current position is home
  // The drive's own homing is configured (`mode: homing` or `homing_method` in the YAML): its
  // EDS must then have 0x6098 and 0x607C. A CSP-only drive needs neither.
  bool homing = false;
  std::uint32_t quirks = 0;  // DriveQuirk bits (`quirks:` in the YAML)
};

// What some drives need beside CiA 402 (`quirks: [name, ...]` on a cia402 node). One table entry
// each (config.cc, kQuirks): its name, its bit, what it changes.
enum class DriveQuirk : std::uint32_t {
  // 0x6061 does not follow 0x6060 (or the drive has no 0x6061): after writing 0x6060 the master
  // reads 0x6060 back instead of waiting for 0x6061.
  kNoModeDisplay = 1u << 0,
  // No 0x60C2 (the drive takes the interpolation period from the SYNC it sees): not written.
  kNoInterpolationPeriod = 1u << 1,
};
constexpr bool has(const DriveConfig& d, DriveQuirk q) {
  return (d.quirks & static_cast<std::uint32_t>(q)) != 0;
}
// The names of the quirks, for documentation and errors ("no_mode_display, ...").
std::string quirk_names();

struct ForceConfig {
  // Channel k is the k-th value the node's TPDOs map, in order. raw = gain * tension + offset.
  std::vector<double> gain;
  std::vector<double> offset;
  std::string gain_where, offset_where;  // "net.yaml:53: profiles.force.gain"; "": the default
};

// A start-up write (`sdo:`). Its type is the YAML's `type`, or the EDS's for the object when the
// YAML gives none; a given type must be the EDS's (check_eds).
struct SdoWrite {
  ObjectAddress object;
  DataType type = DataType::kU8;
  std::int64_t value = 0;
  std::string where;  // "net.yaml:31: profiles.winch.sdo[0]" (file:line: field) for errors
};

struct NodeConfig {
  NodeId id = 0;
  std::string name;
  NodeKind kind = NodeKind::kGeneric;
  nanoseconds heartbeat_period{std::chrono::milliseconds(100)};   // 0x1017 on the node; 0: off
  nanoseconds heartbeat_timeout{std::chrono::milliseconds(300)};  // the master's consumer; 0: off
  nanoseconds master_heartbeat_timeout{0};  // 0x1016:01 on the node watching the master; 0: off
  std::vector<PdoConfig> rpdos;
  std::vector<PdoConfig> tpdos;
  std::vector<SdoWrite> sdo_writes;  // extra start-up writes, after the PDOs
  DriveConfig drive;
  ForceConfig force;
  // The device's EDS/DCF (CiA 306), `eds:` in the YAML, relative to the YAML file's directory;
  // empty: none. Loaded and checked against the configuration at load (eds_check.hpp).
  std::string eds;
  std::shared_ptr<const eds::Eds> eds_data;
};

struct MasterConfig {
  std::string interface = "can0";
  double bitrate = 1e6;
  NodeId master_id = 127;
  std::uint32_t master_heartbeat_cob_id = 0;  // 0: 0x700 + master_id
  nanoseconds master_heartbeat_period{std::chrono::milliseconds(50)};
  nanoseconds sync_period{std::chrono::milliseconds(4)};
  std::uint8_t sync_counter_overflow = 0;
  nanoseconds boot_timeout{std::chrono::seconds(5)};
  nanoseconds sdo_timeout{std::chrono::milliseconds(100)};
  int sdo_retries = 2;
  nanoseconds sdo_quiet{std::chrono::milliseconds(50)};  // after an SDO abort (SdoTiming::quiet)
  nanoseconds bus_off_recovery{std::chrono::milliseconds(500)};
  double bus_load_warning = 0.7;
  bool reset_communication = true;  // boot starts with NMT reset communication to all nodes
  bool quick_stop_on_fault = true;  // a faulted or lost node quick-stops every drive
  // At boot, invalidate every RPDO/TPDO of a node that the configuration does not use (default
  // mappings that real drives ship enabled). Not a YAML field: off only to measure what the
  // defaults cost (docs/canopen.md, bus load).
  bool disable_unused_pdos = true;
  std::vector<NodeConfig> nodes;

  std::uint32_t heartbeat_cob_id() const {
    return master_heartbeat_cob_id != 0 ? master_heartbeat_cob_id : cob::kHeartbeat + master_id;
  }
  const NodeConfig* find(NodeId id) const;
};

// Parses YAML text; `source` names it in errors ("config/canopen-mini.yaml:12: nodes[3].id: ...").
Result<MasterConfig> parse_config(std::string_view yaml, std::string_view source);
Result<MasterConfig> load_config(const std::string& path);

// Checks what parsing cannot: unique node ids and COB-IDs, PDO sizes, drive and force-sensor
// mappings, heartbeat timeouts longer than the producer period. (parse_config also checks every
// node that names an EDS against it: check_eds in eds_check.hpp.)
Status validate(const MasterConfig& config);

// The SYNC periods a network may have: 1 ms to 1 s. Below, a CAN bus cannot carry a cycle of a
// robot's PDOs (a 1 us period was once accepted and failed later as an SDO timeout).
inline constexpr double kMinSyncPeriodMs = 1.0, kMaxSyncPeriodMs = 1000.0;

}  // namespace cdpr::canopen
