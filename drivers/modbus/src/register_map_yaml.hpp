// Reading a register map from a YAML mapping (register_map_yaml.cc), shared with the laser
// configuration, which may hold its map inline. Internal to cdpr_modbus.
#pragma once

#include "cdpr/config/yaml_reader.hpp"
#include "cdpr/modbus/register_map.hpp"
#include "cdpr/status.hpp"

namespace cdpr::modbus::detail {

Status parse_register_map_node(const config::YamlField& root, RegisterMap& m);

}  // namespace cdpr::modbus::detail
