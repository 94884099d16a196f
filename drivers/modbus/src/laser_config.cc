// Reads a LaserConfig (link settings, poll rate, register map) from YAML.
#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "cdpr/modbus/laser_sensor.hpp"
#include "yaml_fields.hpp"

namespace cdpr::modbus {

namespace {

using detail::YamlFields;

Status parse_config(const YamlFields& f, const YAML::Node& root, std::string_view base_dir,
                    LaserConfig& c) {
  if (!root.IsMap()) return f.error(root, "<top level>", "must be a mapping of laser fields");
  CDPR_RETURN_IF_ERROR(
      f.only_known(root, "",
                   {"name", "transport", "device", "baud", "parity", "data_bits", "stop_bits",
                    "rs485", "host", "port", "slave_id", "response_timeout", "byte_timeout",
                    "retries", "reconnect_delay", "poll_rate", "register_map"}));
  CDPR_RETURN_IF_ERROR(f.get_string(root, "name", "", c.name, false));
  int transport = 0;
  CDPR_RETURN_IF_ERROR(f.get_choice(root, "transport", "", {"rtu", "tcp"}, transport, true));
  if (transport == 0) {
    RtuSettings rtu;
    CDPR_RETURN_IF_ERROR(f.get_string(root, "device", "", rtu.device, true));
    long long v = rtu.baud;
    CDPR_RETURN_IF_ERROR(f.get_int(root, "baud", "", 300, 4000000, v, false));
    rtu.baud = static_cast<int>(v);
    int parity = 1;
    CDPR_RETURN_IF_ERROR(f.get_choice(root, "parity", "", {"none", "even", "odd"}, parity, false));
    rtu.parity = parity == 0 ? 'N' : (parity == 1 ? 'E' : 'O');
    v = rtu.data_bits;
    CDPR_RETURN_IF_ERROR(f.get_int(root, "data_bits", "", 5, 8, v, false));
    rtu.data_bits = static_cast<int>(v);
    v = rtu.stop_bits;
    CDPR_RETURN_IF_ERROR(f.get_int(root, "stop_bits", "", 1, 2, v, false));
    rtu.stop_bits = static_cast<int>(v);
    CDPR_RETURN_IF_ERROR(f.get_bool(root, "rs485", "", rtu.rs485));
    for (const char* k : {"host", "port"}) {
      if (root[k]) return f.error(root[k], k, "only for transport: tcp");
    }
    c.link.transport = rtu;
  } else {
    TcpSettings tcp;
    CDPR_RETURN_IF_ERROR(f.get_string(root, "host", "", tcp.host, true));
    long long v = tcp.port;
    CDPR_RETURN_IF_ERROR(f.get_int(root, "port", "", 1, 65535, v, false));
    tcp.port = static_cast<int>(v);
    for (const char* k : {"device", "baud", "parity", "data_bits", "stop_bits", "rs485"}) {
      if (root[k]) return f.error(root[k], k, "only for transport: rtu");
    }
    c.link.transport = tcp;
  }
  long long v = c.link.slave_id;
  CDPR_RETURN_IF_ERROR(
      f.get_int(root, "slave_id", "", transport == 0 ? 1 : 0, transport == 0 ? 247 : 255, v, true));
  c.link.slave_id = static_cast<int>(v);
  CDPR_RETURN_IF_ERROR(
      f.get_double(root, "response_timeout", "", c.link.response_timeout_s, false));
  CDPR_RETURN_IF_ERROR(f.get_double(root, "byte_timeout", "", c.link.byte_timeout_s, false));
  v = c.link.retries;
  CDPR_RETURN_IF_ERROR(f.get_int(root, "retries", "", 0, 10, v, false));
  c.link.retries = static_cast<int>(v);
  CDPR_RETURN_IF_ERROR(f.get_double(root, "reconnect_delay", "", c.link.reconnect_delay_s, false));
  CDPR_RETURN_IF_ERROR(f.get_double(root, "poll_rate", "", c.poll_rate_hz, false));

  const YAML::Node map = root["register_map"];
  if (!map) return f.error(root, "register_map", "is missing (a file path or a mapping)");
  if (map.IsScalar()) {
    std::filesystem::path p(map.Scalar());
    if (p.is_relative() && !base_dir.empty()) p = std::filesystem::path(base_dir) / p;
    Result<RegisterMap> m = load_register_map(p.string());
    if (!m.ok()) {
      Status s = m.status();
      return with_context(f.error(map, "register_map", "").message(), s);
    }
    c.map = std::move(*m);
  } else if (map.IsMap()) {
    CDPR_RETURN_IF_ERROR(detail::parse_register_map_node(f, map, c.map));
  } else {
    return f.error(map, "register_map", "must be a file path or a mapping");
  }

  // Range checks with the field names (validate() repeats them without positions).
  if (!(c.link.response_timeout_s >= 0.001 && c.link.response_timeout_s <= 10.0)) {
    return f.error(root["response_timeout"], "response_timeout", "must be 0.001..10 s");
  }
  if (!(c.link.byte_timeout_s >= 0.0001 && c.link.byte_timeout_s <= 10.0)) {
    return f.error(root["byte_timeout"], "byte_timeout", "must be 0.0001..10 s");
  }
  if (!(c.link.reconnect_delay_s >= 0.0 && c.link.reconnect_delay_s <= 60.0)) {
    return f.error(root["reconnect_delay"], "reconnect_delay", "must be 0..60 s");
  }
  if (!(c.poll_rate_hz >= 0.1 && c.poll_rate_hz <= 1000.0)) {
    return f.error(root["poll_rate"], "poll_rate", "must be 0.1..1000 Hz");
  }
  return c.validate();
}

}  // namespace

Result<LaserConfig> parse_laser_config(std::string_view yaml_text, std::string_view file,
                                       std::string_view base_dir) {
  YamlFields f(file);
  LaserConfig c;
  try {
    const YAML::Node root = YAML::Load(std::string(yaml_text));
    Status s = parse_config(f, root, base_dir, c);
    if (!s.ok()) return s;
  } catch (const YAML::Exception& e) {
    return Status::Error(ErrorCode::kParseError, "%.*s:%d:%d: YAML syntax: %s",
                         static_cast<int>(file.size()), file.data(), e.mark.line + 1,
                         e.mark.column + 1, e.msg.c_str());
  }
  return c;
}

Result<LaserConfig> load_laser_config(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    return Status::Error(ErrorCode::kNotFound, "laser config %s: cannot open: %s", path.c_str(),
                         std::strerror(errno));
  }
  std::ostringstream text;
  text << in.rdbuf();
  return parse_laser_config(text.str(), path, std::filesystem::path(path).parent_path().string());
}

}  // namespace cdpr::modbus
