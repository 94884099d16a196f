// Reads a LaserConfig (link settings, poll rate, register map) from YAML.
#include <cstdint>
#include <filesystem>

#include "cdpr/modbus/laser_sensor.hpp"
#include "register_map_yaml.hpp"

namespace cdpr::modbus {

namespace {

using config::Sign;
using config::YamlDocument;
using config::YamlField;

Status parse_config(const YamlField& root, std::string_view base_dir, LaserConfig& c) {
  CDPR_RETURN_IF_ERROR(root.expect_map("a mapping of laser fields"));
  CDPR_RETURN_IF_ERROR(
      root.check_keys({"name", "transport", "device", "baud", "parity", "data_bits", "stop_bits",
                       "rs485", "host", "port", "slave_id", "response_timeout", "byte_timeout",
                       "retries", "reconnect_delay", "poll_rate", "register_map"}));
  CDPR_RETURN_IF_ERROR(root.optional("name", c.name));
  CDPR_ASSIGN_OR_RETURN(const int transport, root["transport"].choice({"rtu", "tcp"}));
  if (transport == 0) {
    RtuSettings rtu;
    CDPR_ASSIGN_OR_RETURN(rtu.device, root["device"].text());
    CDPR_RETURN_IF_ERROR(root.optional("baud", rtu.baud, 300, 4000000));
    int parity = 1;
    CDPR_RETURN_IF_ERROR(root.optional_choice("parity", parity, {"none", "even", "odd"}));
    rtu.parity = parity == 0 ? 'N' : (parity == 1 ? 'E' : 'O');
    CDPR_RETURN_IF_ERROR(root.optional("data_bits", rtu.data_bits, 5, 8));
    CDPR_RETURN_IF_ERROR(root.optional("stop_bits", rtu.stop_bits, 1, 2));
    CDPR_RETURN_IF_ERROR(root.optional("rs485", rtu.rs485));
    for (const char* k : {"host", "port"}) {
      if (root[k].present()) return root[k].error("only for transport: tcp");
    }
    c.link.transport = rtu;
  } else {
    TcpSettings tcp;
    CDPR_ASSIGN_OR_RETURN(tcp.host, root["host"].text());
    CDPR_RETURN_IF_ERROR(root.optional("port", tcp.port, 1, 65535));
    for (const char* k : {"device", "baud", "parity", "data_bits", "stop_bits", "rs485"}) {
      if (root[k].present()) return root[k].error("only for transport: rtu");
    }
    c.link.transport = tcp;
  }
  CDPR_ASSIGN_OR_RETURN(
      const std::int64_t slave_id,
      root["slave_id"].integer(transport == 0 ? 1 : 0, transport == 0 ? 247 : 255));
  c.link.slave_id = static_cast<int>(slave_id);
  CDPR_RETURN_IF_ERROR(
      root.optional("response_timeout", c.link.response_timeout_s, Sign::kAny, "s"));
  CDPR_RETURN_IF_ERROR(root.optional("byte_timeout", c.link.byte_timeout_s, Sign::kAny, "s"));
  CDPR_RETURN_IF_ERROR(root.optional("retries", c.link.retries, 0, 10));
  CDPR_RETURN_IF_ERROR(root.optional("reconnect_delay", c.link.reconnect_delay_s, Sign::kAny, "s"));
  CDPR_RETURN_IF_ERROR(root.optional("poll_rate", c.poll_rate_hz, Sign::kAny, "Hz"));

  const YamlField map = root["register_map"];
  if (!map.present()) return map.error("missing (a file path or a mapping)");
  if (map.is_scalar()) {
    std::filesystem::path p(map.scalar());
    if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
    Result<RegisterMap> m = load_register_map(p.string());
    if (!m.ok()) {
      const std::string where = map.file() + ":" + std::to_string(map.line()) + ": register_map: ";
      return with_context(where, m.status());
    }
    c.map = std::move(*m);
  } else if (map.is_map()) {
    CDPR_RETURN_IF_ERROR(detail::parse_register_map_node(map, c.map));
  } else {
    return map.error("must be a file path or a mapping");
  }

  // Range checks with the field names (validate() repeats them without positions).
  if (!(c.link.response_timeout_s >= 0.001 && c.link.response_timeout_s <= 10.0)) {
    return root["response_timeout"].error("must be 0.001..10 s");
  }
  if (!(c.link.byte_timeout_s >= 0.0001 && c.link.byte_timeout_s <= 10.0)) {
    return root["byte_timeout"].error("must be 0.0001..10 s");
  }
  if (!(c.link.reconnect_delay_s >= 0.0 && c.link.reconnect_delay_s <= 60.0)) {
    return root["reconnect_delay"].error("must be 0..60 s");
  }
  if (!(c.poll_rate_hz >= 0.1 && c.poll_rate_hz <= 1000.0)) {
    return root["poll_rate"].error("must be 0.1..1000 Hz");
  }
  return c.validate();
}

}  // namespace

Result<LaserConfig> parse_laser_config(std::string_view yaml_text, std::string_view file,
                                       std::string_view base_dir) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::parse(yaml_text, file));
  LaserConfig c;
  CDPR_RETURN_IF_ERROR(parse_config(doc.root(), base_dir, c));
  return c;
}

Result<LaserConfig> load_laser_config(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::load(path, "laser config"));
  LaserConfig c;
  CDPR_RETURN_IF_ERROR(
      parse_config(doc.root(), std::filesystem::path(path).parent_path().string(), c));
  return c;
}

}  // namespace cdpr::modbus
