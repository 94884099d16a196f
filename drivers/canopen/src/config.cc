#include "cdpr/canopen/config.hpp"

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>

#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/eds_check.hpp"

namespace cdpr::canopen {

std::string_view to_string(NodeKind k) {
  switch (k) {
    case NodeKind::kGeneric:
      return "generic";
    case NodeKind::kCia402Drive:
      return "cia402";
    case NodeKind::kForceSensor:
      return "force_sensor";
  }
  return "?";
}

std::string_view to_string(Mode m) {
  switch (m) {
    case Mode::kNone:
      return "none";
    case Mode::kProfilePosition:
      return "profile_position";
    case Mode::kHoming:
      return "homing";
    case Mode::kCyclicSyncPosition:
      return "cyclic_sync_position";
  }
  return "?";
}

const NodeConfig* MasterConfig::find(NodeId id) const {
  for (const auto& n : nodes) {
    if (n.id == id) return &n;
  }
  return nullptr;
}

namespace {

// Parsing context: every error names source:line: field.
class Parser {
 public:
  explicit Parser(std::string_view source) : source_(source) {}

  Status error(const YAML::Node& at, const std::string& field, const std::string& what) const {
    const int line = at.IsDefined() ? at.Mark().line + 1 : 0;
    if (line > 0) {
      return Status::Error(ErrorCode::kParseError, "%s:%d: %s: %s", source_.c_str(), line,
                           field.c_str(), what.c_str());
    }
    return Status::Error(ErrorCode::kParseError, "%s: %s: %s", source_.c_str(), field.c_str(),
                         what.c_str());
  }

  Status integer(const YAML::Node& n, const std::string& field, std::int64_t lo, std::int64_t hi,
                 std::int64_t& out) const {
    if (!n.IsScalar()) return error(n, field, "expected an integer");
    const std::string s = n.Scalar();
    const char* b = s.c_str();
    bool neg = false;
    if (*b == '-' || *b == '+') neg = *b++ == '-';
    const bool hex = b[0] == '0' && (b[1] == 'x' || b[1] == 'X');
    errno = 0;
    char* end = nullptr;
    const unsigned long long v = std::strtoull(hex ? b + 2 : b, &end, hex ? 16 : 10);
    if (end == b || *end != '\0' || errno != 0 || (hex && end == b + 2)) {
      return error(n, field, "expected an integer, got '" + s + "'");
    }
    const std::int64_t sv = neg ? -static_cast<std::int64_t>(v) : static_cast<std::int64_t>(v);
    if (sv < lo || sv > hi) {
      return error(n, field, s + " is outside " + std::to_string(lo) + ".." + std::to_string(hi));
    }
    out = sv;
    return Status::Ok();
  }

  Status number(const YAML::Node& n, const std::string& field, double& out) const {
    if (!n.IsScalar()) return error(n, field, "expected a number");
    const std::string s = n.Scalar();
    char* end = nullptr;
    const double v = std::strtod(s.c_str(), &end);
    if (end == s.c_str() || *end != '\0' || !std::isfinite(v)) {
      return error(n, field, "expected a number, got '" + s + "'");
    }
    out = v;
    return Status::Ok();
  }

  Status millis(const YAML::Node& n, const std::string& field, double max_ms,
                nanoseconds& out) const {
    double v = 0;
    Status s = number(n, field, v);
    if (!s.ok()) return s;
    if (v < 0 || v > max_ms) {
      return error(n, field,
                   "must be within 0.." + std::to_string(static_cast<long>(max_ms)) + " ms");
    }
    out = from_ms(v);
    return Status::Ok();
  }

  Status boolean(const YAML::Node& n, const std::string& field, bool& out) const {
    if (!n.IsScalar()) return error(n, field, "expected true or false");
    const std::string& s = n.Scalar();
    if (s == "true" || s == "yes" || s == "on") {
      out = true;
    } else if (s == "false" || s == "no" || s == "off") {
      out = false;
    } else {
      return error(n, field, "expected true or false, got '" + s + "'");
    }
    return Status::Ok();
  }

  // "0x6041:00 u16" (index:sub type).
  Status mapping(const YAML::Node& n, const std::string& field, PdoEntry& out) const {
    if (!n.IsScalar()) return error(n, field, "expected \"0xINDEX:SUB type\"");
    const std::string s = n.Scalar();
    std::istringstream in(s);
    std::string addr, type, rest;
    in >> addr >> type >> rest;
    Status st = address(n, field, addr, out.object);
    if (!st.ok()) return st;
    if (!parse_data_type(type, out.type)) {
      return error(n, field, "type '" + type + "' is not one of i8 u8 i16 u16 i32 u32");
    }
    if (!rest.empty()) return error(n, field, "unexpected '" + rest + "' after the type");
    return Status::Ok();
  }

  Status address(const YAML::Node& n, const std::string& field, const std::string& s,
                 ObjectAddress& out) const {
    const auto colon = s.find(':');
    if (colon == std::string::npos) {
      return error(n, field, "object '" + s + "' is not INDEX:SUB (e.g. 0x6041:00)");
    }
    // Both parts live in named strings: strtoul's end pointers point into them.
    const std::string idx_s = s.substr(0, colon);
    char* end = nullptr;
    const unsigned long idx = std::strtoul(idx_s.c_str(), &end, 16);
    const std::string sub_s = s.substr(colon + 1);
    char* end2 = nullptr;
    const unsigned long sub = std::strtoul(sub_s.c_str(), &end2, 16);
    if (*end != '\0' || *end2 != '\0' || sub_s.empty() || idx > 0xFFFF || sub > 0xFF ||
        colon == 0) {
      return error(n, field, "object '" + s + "' is not INDEX:SUB in hexadecimal");
    }
    out = ObjectAddress{static_cast<std::uint16_t>(idx), static_cast<std::uint8_t>(sub)};
    return Status::Ok();
  }

  Status check_keys(const YAML::Node& map, const std::string& field,
                    const std::set<std::string>& allowed) const {
    if (!map.IsMap()) return error(map, field, "expected a mapping");
    for (const auto& kv : map) {
      const std::string k = kv.first.Scalar();
      if (allowed.count(k) == 0) return error(kv.first, field + "." + k, "unknown field");
    }
    return Status::Ok();
  }

  Status master(const YAML::Node& m, MasterConfig& c) const {
    Status s = check_keys(m, "master",
                          {"interface", "bitrate", "node_id", "heartbeat_cob_id", "heartbeat_ms",
                           "sync_period_ms", "sync_counter_overflow", "boot_timeout_ms",
                           "sdo_timeout_ms", "sdo_retries", "sdo_quiet_ms", "bus_off_recovery_ms",
                           "bus_load_warning", "reset_communication", "quick_stop_on_fault"});
    if (!s.ok()) return s;
    std::int64_t v = 0;
    if (m["interface"]) c.interface = m["interface"].Scalar();
    if (m["bitrate"]) {
      if (!(s = number(m["bitrate"], "master.bitrate", c.bitrate)).ok()) return s;
      if (c.bitrate < 10e3 || c.bitrate > 1e6) {
        return error(m["bitrate"], "master.bitrate", "must be within 10000..1000000 bit/s");
      }
    }
    if (m["node_id"]) {
      if (!(s = integer(m["node_id"], "master.node_id", 1, 127, v)).ok()) return s;
      c.master_id = static_cast<NodeId>(v);
    }
    if (m["heartbeat_cob_id"]) {
      if (!(s = integer(m["heartbeat_cob_id"], "master.heartbeat_cob_id", 1, 0x7FF, v)).ok()) {
        return s;
      }
      c.master_heartbeat_cob_id = static_cast<std::uint32_t>(v);
    }
    if (m["heartbeat_ms"] &&
        !(s = millis(m["heartbeat_ms"], "master.heartbeat_ms", 65535, c.master_heartbeat_period))
             .ok()) {
      return s;
    }
    if (m["sync_period_ms"]) {
      if (!(s = millis(m["sync_period_ms"], "master.sync_period_ms", 1000, c.sync_period)).ok()) {
        return s;
      }
      if (c.sync_period.count() <= 0) {
        return error(m["sync_period_ms"], "master.sync_period_ms", "must be > 0");
      }
    }
    if (m["sync_counter_overflow"]) {
      if (!(s = integer(m["sync_counter_overflow"], "master.sync_counter_overflow", 0, 240, v))
               .ok()) {
        return s;
      }
      if (v == 1) {
        return error(m["sync_counter_overflow"], "master.sync_counter_overflow",
                     "must be 0 (no counter) or 2..240");
      }
      c.sync_counter_overflow = static_cast<std::uint8_t>(v);
    }
    if (m["boot_timeout_ms"] &&
        !(s = millis(m["boot_timeout_ms"], "master.boot_timeout_ms", 600000, c.boot_timeout))
             .ok()) {
      return s;
    }
    if (m["sdo_timeout_ms"] &&
        !(s = millis(m["sdo_timeout_ms"], "master.sdo_timeout_ms", 60000, c.sdo_timeout)).ok()) {
      return s;
    }
    if (m["sdo_retries"]) {
      if (!(s = integer(m["sdo_retries"], "master.sdo_retries", 0, 10, v)).ok()) return s;
      c.sdo_retries = static_cast<int>(v);
    }
    if (m["sdo_quiet_ms"] &&
        !(s = millis(m["sdo_quiet_ms"], "master.sdo_quiet_ms", 60000, c.sdo_quiet)).ok()) {
      return s;
    }
    if (m["bus_off_recovery_ms"] &&
        !(s = millis(m["bus_off_recovery_ms"], "master.bus_off_recovery_ms", 60000,
                     c.bus_off_recovery))
             .ok()) {
      return s;
    }
    if (m["bus_load_warning"]) {
      if (!(s = number(m["bus_load_warning"], "master.bus_load_warning", c.bus_load_warning))
               .ok()) {
        return s;
      }
      if (c.bus_load_warning <= 0 || c.bus_load_warning > 1) {
        return error(m["bus_load_warning"], "master.bus_load_warning", "must be within (0, 1]");
      }
    }
    if (m["reset_communication"] &&
        !(s = boolean(m["reset_communication"], "master.reset_communication",
                      c.reset_communication))
             .ok()) {
      return s;
    }
    if (m["quick_stop_on_fault"] &&
        !(s = boolean(m["quick_stop_on_fault"], "master.quick_stop_on_fault",
                      c.quick_stop_on_fault))
             .ok()) {
      return s;
    }
    return Status::Ok();
  }

  Status pdo_list(const YAML::Node& list, const std::string& field, PdoDirection dir,
                  std::vector<PdoConfig>& out) const {
    if (!list.IsSequence()) return error(list, field, "expected a list of PDOs");
    out.clear();
    for (std::size_t i = 0; i < list.size(); ++i) {
      const YAML::Node p = list[i];
      const std::string f = field + "[" + std::to_string(i) + "]";
      Status s = check_keys(
          p, f, {"number", "cob_id", "transmission", "inhibit_100us", "event_timer_ms", "map"});
      if (!s.ok()) return s;
      PdoConfig c;
      c.direction = dir;
      std::int64_t v = 0;
      if (!p["number"]) return error(p, f + ".number", "missing");
      if (!(s = integer(p["number"], f + ".number", 1, 512, v)).ok()) return s;
      c.number = static_cast<int>(v);
      if (p["cob_id"]) {
        if (!(s = integer(p["cob_id"], f + ".cob_id", 1, 0x7FF, v)).ok()) return s;
        c.cob_id = static_cast<std::uint32_t>(v);
      }
      if (p["transmission"]) {
        if (!(s = integer(p["transmission"], f + ".transmission", 0, 255, v)).ok()) return s;
        if (v > 240 && v < 252) {
          return error(p["transmission"], f + ".transmission", "241..251 are reserved");
        }
        c.transmission_type = static_cast<std::uint8_t>(v);
      }
      if (p["inhibit_100us"]) {
        if (!(s = integer(p["inhibit_100us"], f + ".inhibit_100us", 0, 65535, v)).ok()) return s;
        c.inhibit_time_100us = static_cast<std::uint16_t>(v);
      }
      if (p["event_timer_ms"]) {
        if (!(s = integer(p["event_timer_ms"], f + ".event_timer_ms", 0, 65535, v)).ok()) return s;
        c.event_timer_ms = static_cast<std::uint16_t>(v);
      }
      const YAML::Node map = p["map"];
      if (!map || !map.IsSequence()) return error(p, f + ".map", "expected a list of objects");
      std::size_t bytes = 0;
      for (std::size_t k = 0; k < map.size(); ++k) {
        PdoEntry e;
        const std::string fe = f + ".map[" + std::to_string(k) + "]";
        if (!(s = mapping(map[k], fe, e)).ok()) return s;
        bytes += size_of(e.type);
        if (bytes > 8) return error(map[k], fe, "the PDO would exceed 8 bytes");
        c.entries.push_back(e);
      }
      out.push_back(std::move(c));
    }
    return Status::Ok();
  }

  // Looks a field up in the node first, then in its profile.
  struct Fields {
    YAML::Node node;
    YAML::Node profile;
    std::string node_field;
    std::string profile_field;
    YAML::Node get(const std::string& k) const {
      if (node[k]) return node[k];
      if (profile && profile.IsMap() && profile[k]) return profile[k];
      return YAML::Node(YAML::NodeType::Undefined);  // a default Node is a defined null
    }
    std::string name(const std::string& k) const {
      return (node[k] ? node_field : profile_field) + "." + k;
    }
  };

  Status node(const Fields& f, NodeConfig& c) const {
    static const std::set<std::string> kNodeKeys{"id",
                                                 "name",
                                                 "profile",
                                                 "kind",
                                                 "heartbeat_ms",
                                                 "heartbeat_timeout_ms",
                                                 "master_heartbeat_timeout_ms",
                                                 "rpdo",
                                                 "tpdo",
                                                 "sdo",
                                                 "mode",
                                                 "counts_per_unit",
                                                 "transition_timeout_ms",
                                                 "mode_switch_timeout_ms",
                                                 "abort_connection_option",
                                                 "quick_stop_option",
                                                 "profile_velocity",
                                                 "profile_acceleration",
                                                 "homing_method",
                                                 "gain",
                                                 "offset",
                                                 "eds"};
    Status s = check_keys(f.node, f.node_field, kNodeKeys);
    if (!s.ok()) return s;
    std::int64_t v = 0;
    if (const YAML::Node n = f.get("kind"); n) {
      const std::string k = n.Scalar();
      if (k == "cia402") {
        c.kind = NodeKind::kCia402Drive;
      } else if (k == "force_sensor") {
        c.kind = NodeKind::kForceSensor;
      } else if (k == "generic") {
        c.kind = NodeKind::kGeneric;
      } else {
        return error(n, f.name("kind"), "'" + k + "' is not cia402, force_sensor or generic");
      }
    }
    if (const YAML::Node n = f.get("heartbeat_ms");
        n && !(s = millis(n, f.name("heartbeat_ms"), 65535, c.heartbeat_period)).ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("heartbeat_timeout_ms");
        n && !(s = millis(n, f.name("heartbeat_timeout_ms"), 65535, c.heartbeat_timeout)).ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("master_heartbeat_timeout_ms");
        n &&
        !(s = millis(n, f.name("master_heartbeat_timeout_ms"), 65535, c.master_heartbeat_timeout))
             .ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("rpdo");
        n && !(s = pdo_list(n, f.name("rpdo"), PdoDirection::kRpdo, c.rpdos)).ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("tpdo");
        n && !(s = pdo_list(n, f.name("tpdo"), PdoDirection::kTpdo, c.tpdos)).ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("sdo"); n) {
      if (!n.IsSequence()) return error(n, f.name("sdo"), "expected a list");
      for (std::size_t i = 0; i < n.size(); ++i) {
        const std::string fe = f.name("sdo") + "[" + std::to_string(i) + "]";
        if (!(s = check_keys(n[i], fe, {"object", "type", "value"})).ok()) return s;
        SdoWrite w;
        if (!n[i]["object"] || !n[i]["type"] || !n[i]["value"]) {
          return error(n[i], fe, "needs object, type and value");
        }
        if (!(s = address(n[i]["object"], fe + ".object", n[i]["object"].Scalar(), w.object))
                 .ok()) {
          return s;
        }
        if (!parse_data_type(n[i]["type"].Scalar(), w.type)) {
          return error(n[i]["type"], fe + ".type", "not one of i8 u8 i16 u16 i32 u32");
        }
        const int bits = 8 * size_of(w.type);
        const std::int64_t lo = is_signed(w.type) ? -(std::int64_t{1} << (bits - 1)) : 0;
        const std::int64_t hi =
            is_signed(w.type) ? (std::int64_t{1} << (bits - 1)) - 1 : (std::int64_t{1} << bits) - 1;
        if (!(s = integer(n[i]["value"], fe + ".value", lo, hi, w.value)).ok()) return s;
        c.sdo_writes.push_back(w);
      }
    }
    DriveConfig& d = c.drive;
    if (const YAML::Node n = f.get("mode"); n) {
      const std::string m = n.Scalar();
      if (m == "csp") {
        d.mode = Mode::kCyclicSyncPosition;
      } else if (m == "pp") {
        d.mode = Mode::kProfilePosition;
      } else if (m == "homing") {
        d.mode = Mode::kHoming;
      } else {
        return error(n, f.name("mode"), "'" + m + "' is not csp, pp or homing");
      }
    }
    if (const YAML::Node n = f.get("counts_per_unit"); n) {
      if (!(s = number(n, f.name("counts_per_unit"), d.counts_per_unit)).ok()) return s;
      if (d.counts_per_unit == 0) return error(n, f.name("counts_per_unit"), "must not be 0");
    }
    if (const YAML::Node n = f.get("transition_timeout_ms");
        n && !(s = millis(n, f.name("transition_timeout_ms"), 60000, d.transition_timeout)).ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("mode_switch_timeout_ms");
        n &&
        !(s = millis(n, f.name("mode_switch_timeout_ms"), 60000, d.mode_switch_timeout)).ok()) {
      return s;
    }
    if (const YAML::Node n = f.get("abort_connection_option"); n) {
      if (!(s = integer(n, f.name("abort_connection_option"), -32768, 32767, v)).ok()) return s;
      d.abort_connection_option = static_cast<std::int16_t>(v);
    }
    if (const YAML::Node n = f.get("quick_stop_option"); n) {
      if (!(s = integer(n, f.name("quick_stop_option"), -32768, 32767, v)).ok()) return s;
      d.quick_stop_option = static_cast<std::int16_t>(v);
    }
    if (const YAML::Node n = f.get("profile_velocity"); n) {
      if (!(s = integer(n, f.name("profile_velocity"), 0, 0xFFFFFFFF, v)).ok()) return s;
      d.profile_velocity = static_cast<std::uint32_t>(v);
    }
    if (const YAML::Node n = f.get("profile_acceleration"); n) {
      if (!(s = integer(n, f.name("profile_acceleration"), 0, 0xFFFFFFFF, v)).ok()) return s;
      d.profile_acceleration = static_cast<std::uint32_t>(v);
    }
    if (const YAML::Node n = f.get("homing_method"); n) {
      if (!(s = integer(n, f.name("homing_method"), -128, 127, v)).ok()) return s;
      d.homing_method = static_cast<std::int8_t>(v);
    }
    if (const YAML::Node n = f.get("eds"); n) {
      if (!(s = device_eds(n, f.name("eds"), c)).ok()) return s;
    }
    for (const char* key : {"gain", "offset"}) {
      const YAML::Node n = f.get(key);
      if (!n) continue;
      std::vector<double>& dst = std::string(key) == "gain" ? c.force.gain : c.force.offset;
      dst.clear();
      if (n.IsSequence()) {
        for (std::size_t i = 0; i < n.size(); ++i) {
          double x = 0;
          if (!(s = number(n[i], f.name(key) + "[" + std::to_string(i) + "]", x)).ok()) return s;
          dst.push_back(x);
        }
      } else {
        double x = 0;
        if (!(s = number(n, f.name(key), x)).ok()) return s;
        dst.push_back(x);  // one value for every channel; expanded in validate()
      }
    }
    return Status::Ok();
  }

  Status document(const YAML::Node& root, MasterConfig& c) const {
    Status s = check_keys(root, "(top level)", {"master", "profiles", "nodes"});
    if (!s.ok()) return s;
    if (root["master"] && !(s = master(root["master"], c)).ok()) return s;
    const YAML::Node profiles = root["profiles"];
    if (profiles && !profiles.IsMap()) return error(profiles, "profiles", "expected a mapping");
    const YAML::Node nodes = root["nodes"];
    if (!nodes || !nodes.IsSequence() || nodes.size() == 0) {
      return error(root, "nodes", "expected a non-empty list of nodes");
    }
    for (std::size_t i = 0; i < nodes.size(); ++i) {
      const YAML::Node n = nodes[i];
      const std::string field = "nodes[" + std::to_string(i) + "]";
      if (!n.IsMap()) return error(n, field, "expected a mapping");
      NodeConfig nc;
      std::int64_t v = 0;
      if (!n["id"]) return error(n, field + ".id", "missing");
      if (!(s = integer(n["id"], field + ".id", 1, 127, v)).ok()) return s;
      nc.id = static_cast<NodeId>(v);
      nc.name = n["name"] ? n["name"].Scalar() : "node" + std::to_string(v);
      Fields f{n, YAML::Node(YAML::NodeType::Undefined), field, field};
      if (n["profile"]) {
        const std::string p = n["profile"].Scalar();
        if (!profiles || !profiles[p]) {
          return error(n["profile"], field + ".profile", "no profile '" + p + "' in profiles");
        }
        f.profile = profiles[p];
        f.profile_field = "profiles." + p;
        Status ps = check_keys(
            f.profile, f.profile_field,
            {"kind", "heartbeat_ms", "heartbeat_timeout_ms", "master_heartbeat_timeout_ms", "rpdo",
             "tpdo", "sdo", "mode", "counts_per_unit", "transition_timeout_ms",
             "mode_switch_timeout_ms", "abort_connection_option", "quick_stop_option",
             "profile_velocity", "profile_acceleration", "homing_method", "gain", "offset", "eds"});
        if (!ps.ok()) return ps;
      }
      if (!(s = node(f, nc)).ok()) return s;
      c.nodes.push_back(std::move(nc));
    }
    return Status::Ok();
  }

  const std::string& source() const { return source_; }

 private:
  // `eds:` names the device's EDS/DCF, relative to the YAML file's directory; loaded once per
  // file (profiles share it).
  Status device_eds(const YAML::Node& n, const std::string& field, NodeConfig& c) const {
    if (!n.IsScalar() || n.Scalar().empty()) return error(n, field, "expected a file name");
    std::string path = n.Scalar();
    const auto slash = source_.rfind('/');
    if (path.front() != '/' && slash != std::string::npos) {
      path = source_.substr(0, slash + 1) + path;
    }
    auto& cached = eds_cache_[path];
    if (!cached) {
      auto e = eds::Eds::load(path);
      if (!e.ok()) return error(n, field, std::string(e.status().message()));
      cached = std::make_shared<const eds::Eds>(std::move(*e));
    }
    c.eds = path;
    c.eds_data = cached;
    return Status::Ok();
  }

  std::string source_;
  mutable std::map<std::string, std::shared_ptr<const eds::Eds>> eds_cache_;
};

std::size_t mapped_count(const std::vector<PdoConfig>& pdos) {
  std::size_t n = 0;
  for (const auto& p : pdos) n += p.entries.size();
  return n;
}

bool maps(const std::vector<PdoConfig>& pdos, ObjectAddress a) {
  for (const auto& p : pdos) {
    for (const auto& e : p.entries) {
      if (e.object == a) return true;
    }
  }
  return false;
}

}  // namespace

Status validate(const MasterConfig& c) {
  std::set<int> ids;
  std::set<std::uint32_t> cob_ids{cob::kNmt, cob::kSync, c.heartbeat_cob_id()};
  for (const auto& n : c.nodes) {
    if (!valid_node_id(n.id)) {
      return Status::Error(ErrorCode::kInvalidArgument, "node %u (%s): id not in 1..127",
                           unsigned{n.id}, n.name.c_str());
    }
    if (n.id == c.master_id) {
      return Status::Error(ErrorCode::kInvalidArgument,
                           "node %u (%s): id is the master's own node id", unsigned{n.id},
                           n.name.c_str());
    }
    if (!ids.insert(n.id).second) {
      return Status::Error(ErrorCode::kInvalidArgument, "node %u (%s): id used twice",
                           unsigned{n.id}, n.name.c_str());
    }
    for (const auto* list : {&n.rpdos, &n.tpdos}) {
      for (const auto& p : *list) {
        const char* dir = p.direction == PdoDirection::kRpdo ? "RPDO" : "TPDO";
        if (p.cob_id == 0 && p.number > 4) {
          return Status::Error(ErrorCode::kInvalidArgument,
                               "node %u (%s): %s%d needs a cob_id (defaults exist for 1..4)",
                               unsigned{n.id}, n.name.c_str(), dir, p.number);
        }
        if (p.entries.empty()) continue;
        if (!cob_ids.insert(p.effective_cob_id(n.id)).second) {
          return Status::Error(ErrorCode::kInvalidArgument,
                               "node %u (%s): %s%d COB-ID 0x%03X is used twice", unsigned{n.id},
                               n.name.c_str(), dir, p.number, unsigned{p.effective_cob_id(n.id)});
        }
      }
    }
    if (n.heartbeat_timeout.count() > 0 && n.heartbeat_period.count() > 0 &&
        n.heartbeat_timeout <= n.heartbeat_period) {
      return Status::Error(ErrorCode::kInvalidArgument,
                           "node %u (%s): heartbeat timeout %.0f ms must exceed its period %.0f ms",
                           unsigned{n.id}, n.name.c_str(), to_ms(n.heartbeat_timeout),
                           to_ms(n.heartbeat_period));
    }
    if (n.master_heartbeat_timeout.count() > 0 &&
        n.master_heartbeat_timeout <= c.master_heartbeat_period) {
      return Status::Error(
          ErrorCode::kInvalidArgument,
          "node %u (%s): master heartbeat timeout %.0f ms must exceed the master's "
          "heartbeat period %.0f ms",
          unsigned{n.id}, n.name.c_str(), to_ms(n.master_heartbeat_timeout),
          to_ms(c.master_heartbeat_period));
    }
    if (n.kind == NodeKind::kCia402Drive) {
      using A = ObjectAddress;
      const std::pair<A, const char*> need[] = {{A{0x6041, 0}, "TPDO"},
                                                {A{0x6064, 0}, "TPDO"},
                                                {A{0x6040, 0}, "RPDO"},
                                                {A{0x607A, 0}, "RPDO"}};
      for (const auto& [obj, where] : need) {
        const auto& list = std::string_view(where) == "TPDO" ? n.tpdos : n.rpdos;
        if (!maps(list, obj)) {
          return Status::Error(ErrorCode::kInvalidArgument,
                               "node %u (%s): a cia402 drive needs 0x%04X:%02X in its %ss",
                               unsigned{n.id}, n.name.c_str(), unsigned{obj.index},
                               unsigned{obj.sub}, where);
        }
      }
    }
    if (n.kind == NodeKind::kForceSensor) {
      const std::size_t ch = mapped_count(n.tpdos);
      if (ch == 0) {
        return Status::Error(ErrorCode::kInvalidArgument,
                             "node %u (%s): a force sensor needs its channels in TPDOs",
                             unsigned{n.id}, n.name.c_str());
      }
      for (const auto* v : {&n.force.gain, &n.force.offset}) {
        if (v->size() != 1 && v->size() != ch) {
          return Status::Error(ErrorCode::kInvalidArgument,
                               "node %u (%s): %s has %zu values for %zu channels", unsigned{n.id},
                               n.name.c_str(), v == &n.force.gain ? "gain" : "offset", v->size(),
                               ch);
        }
      }
      for (double g : n.force.gain) {
        if (g == 0) {
          return Status::Error(ErrorCode::kInvalidArgument, "node %u (%s): a gain is 0",
                               unsigned{n.id}, n.name.c_str());
        }
      }
    }
  }
  return Status::Ok();
}

Result<MasterConfig> parse_config(std::string_view yaml, std::string_view source) {
  Parser p(source);
  YAML::Node root;
  try {
    root = YAML::Load(std::string(yaml));
  } catch (const YAML::Exception& e) {
    return Status::Error(ErrorCode::kParseError, "%.*s:%d: %s", static_cast<int>(source.size()),
                         source.data(), e.mark.line + 1, e.msg.c_str());
  }
  MasterConfig c;
  Status s;
  try {
    s = p.document(root, c);
  } catch (const YAML::Exception& e) {
    return Status::Error(ErrorCode::kParseError, "%.*s:%d: %s", static_cast<int>(source.size()),
                         source.data(), e.mark.line + 1, e.msg.c_str());
  }
  if (!s.ok()) return s;
  // A single gain/offset applies to every channel.
  for (auto& n : c.nodes) {
    if (n.kind != NodeKind::kForceSensor) continue;
    const std::size_t ch = mapped_count(n.tpdos);
    if (n.force.gain.empty()) n.force.gain.assign(ch, 1.0);
    if (n.force.offset.empty()) n.force.offset.assign(ch, 0.0);
    if (n.force.gain.size() == 1) n.force.gain.assign(ch, n.force.gain[0]);
    if (n.force.offset.size() == 1) n.force.offset.assign(ch, n.force.offset[0]);
  }
  s = validate(c);
  if (s.ok()) s = check_eds(c);
  if (!s.ok()) {
    return Status::Error(s.code(), "%.*s: %.*s", static_cast<int>(source.size()), source.data(),
                         static_cast<int>(s.message().size()), s.message().data());
  }
  return c;
}

Result<MasterConfig> load_config(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    return Status::Error(ErrorCode::kNotFound, "%s: cannot open the CANopen configuration",
                         path.c_str());
  }
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_config(ss.str(), path);
}

}  // namespace cdpr::canopen
