// The network configuration checked against the devices' EDS files: every object the master
// writes, reads or maps on a node (boot and maintenance, in the order of Master::configure_node)
// must exist in the node's EDS, be writable, readable or mappable as used, and have the type the
// master assumes. Errors name the node, the object and the EDS file and line.
#pragma once

#include <string>
#include <vector>

#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/eds.hpp"

namespace cdpr::canopen {

struct PlannedAccess {
  enum class Kind : std::uint8_t { kWrite, kRead, kMapRpdo, kMapTpdo };
  ObjectAddress object;
  DataType type = DataType::kU8;
  Kind kind = Kind::kWrite;
  const char* what = "";  // "producer heartbeat", "TPDO1 mapping entry", ...
  int pdo = 0;            // PDO number of a mapping access or PDO parameter, else 0
  std::string where;      // the YAML place of a configured write ("net.yaml:31: nodes[2].sdo[0]")
};

// What the master does on `node` of `config`: the boot configuration in order (without the
// disabling of unused PDOs, which depends on what the node has), then the maintenance accesses of
// a cia402 drive (mode switches; homing objects only when the drive's homing is configured,
// DriveConfig::homing), as its quirks change them.
std::vector<PlannedAccess> planned_accesses(const MasterConfig& config, const NodeConfig& node);

// Checks one node against an EDS (the node's own eds_data when `eds` is null).
Status check_against_eds(const MasterConfig& config, const NodeConfig& node, const eds::Eds& eds);

// Checks every node of `config` that names an EDS. Part of parse_config/load_config.
Status check_eds(const MasterConfig& config);

// The PDO numbers a node has, by direction: from its EDS (every 0x1400.. / 0x1800.. object), or
// the four of the pre-defined connection set without one.
std::vector<int> pdo_numbers(const NodeConfig& node, PdoDirection direction);

}  // namespace cdpr::canopen
