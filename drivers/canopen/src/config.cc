#include "cdpr/canopen/config.hpp"

#include <cstdlib>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <sstream>
#include <type_traits>

#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/eds_check.hpp"
#include "cdpr/config/yaml_reader.hpp"

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

namespace {

struct QuirkInfo {
  const char* name;
  DriveQuirk quirk;
};
// Adding a quirk: one entry here, its bit and comment in config.hpp, its effect where the master
// uses it, a line in docs/canopen.md.
constexpr QuirkInfo kQuirks[] = {
    {"no_mode_display", DriveQuirk::kNoModeDisplay},
    {"no_interpolation_period", DriveQuirk::kNoInterpolationPeriod},
};

}  // namespace

std::string quirk_names() {
  std::string out;
  for (const QuirkInfo& q : kQuirks) out += (out.empty() ? "" : ", ") + std::string(q.name);
  return out;
}

const NodeConfig* MasterConfig::find(NodeId id) const {
  for (const auto& n : nodes) {
    if (n.id == id) return &n;
  }
  return nullptr;
}

namespace {

using config::Sign;
using config::YamlDocument;
using config::YamlField;

// "net.yaml:31: profiles.winch.sdo[0]": the field's place, for errors found after parsing.
std::string where(const YamlField& f) {
  return f.file() + ":" + std::to_string(f.line()) + ": " + f.path();
}

// A duration in milliseconds within 0..max_ms.
Status millis(const YamlField& f, double max_ms, nanoseconds& out) {
  if (!f.present()) return Status::success();
  CDPR_ASSIGN_OR_RETURN(const double v, f.number_in(0.0, max_ms, "ms"));
  out = from_ms(v);
  return Status::success();
}

// "0x6041:00" (index:sub in hexadecimal).
Status address(const YamlField& f, const std::string& s, ObjectAddress& out) {
  const auto colon = s.find(':');
  if (colon == std::string::npos) {
    return f.error("object '" + s + "' is not INDEX:SUB (e.g. 0x6041:00)");
  }
  // Both parts live in named strings: strtoul's end pointers point into them.
  const std::string idx_s = s.substr(0, colon);
  char* end = nullptr;
  const unsigned long idx = std::strtoul(idx_s.c_str(), &end, 16);
  const std::string sub_s = s.substr(colon + 1);
  char* end2 = nullptr;
  const unsigned long sub = std::strtoul(sub_s.c_str(), &end2, 16);
  if (*end != '\0' || *end2 != '\0' || sub_s.empty() || idx > 0xFFFF || sub > 0xFF || colon == 0) {
    return f.error("object '" + s + "' is not INDEX:SUB in hexadecimal");
  }
  out = ObjectAddress{static_cast<std::uint16_t>(idx), static_cast<std::uint8_t>(sub)};
  return Status::success();
}

// "0x6041:00 u16" (index:sub type).
Status mapping(const YamlField& f, PdoEntry& out) {
  if (!f.is_scalar()) return f.error("expected \"0xINDEX:SUB type\", got " + f.describe());
  std::istringstream in(f.scalar());
  std::string addr, type, rest;
  in >> addr >> type >> rest;
  CDPR_RETURN_IF_ERROR(address(f, addr, out.object));
  if (!parse_data_type(type, out.type)) {
    return f.error("type '" + type + "' is not one of i8 u8 i16 u16 i32 u32");
  }
  if (!rest.empty()) return f.error("unexpected '" + rest + "' after the type");
  return Status::success();
}

Status parse_master(const YamlField& m, MasterConfig& c) {
  CDPR_RETURN_IF_ERROR(m.check_keys(
      {"interface", "bitrate", "node_id", "heartbeat_cob_id", "heartbeat_ms", "sync_period_ms",
       "sync_counter_overflow", "boot_timeout_ms", "sdo_timeout_ms", "sdo_retries", "sdo_quiet_ms",
       "bus_off_recovery_ms", "bus_load_warning", "reset_communication", "quick_stop_on_fault"}));
  CDPR_RETURN_IF_ERROR(m.optional("interface", c.interface));
  if (const YamlField f = m["bitrate"]; f.present()) {
    CDPR_ASSIGN_OR_RETURN(c.bitrate, f.number_in(10e3, 1e6, "bit/s"));
  }
  CDPR_RETURN_IF_ERROR(m.optional("node_id", c.master_id, 1, 127));
  CDPR_RETURN_IF_ERROR(m.optional("heartbeat_cob_id", c.master_heartbeat_cob_id, 1, 0x7FF));
  CDPR_RETURN_IF_ERROR(millis(m["heartbeat_ms"], 65535, c.master_heartbeat_period));
  if (const YamlField f = m["sync_period_ms"]; f.present()) {
    CDPR_ASSIGN_OR_RETURN(const double ms, f.number_in(kMinSyncPeriodMs, kMaxSyncPeriodMs, "ms"));
    c.sync_period = from_ms(ms);
  }
  CDPR_RETURN_IF_ERROR(m.optional("sync_counter_overflow", c.sync_counter_overflow, 0, 240));
  if (m["sync_counter_overflow"].present() && c.sync_counter_overflow == 1) {
    return m["sync_counter_overflow"].error("must be 0 (no counter) or 2..240");
  }
  CDPR_RETURN_IF_ERROR(millis(m["boot_timeout_ms"], 600000, c.boot_timeout));
  CDPR_RETURN_IF_ERROR(millis(m["sdo_timeout_ms"], 60000, c.sdo_timeout));
  CDPR_RETURN_IF_ERROR(m.optional("sdo_retries", c.sdo_retries, 0, 10));
  CDPR_RETURN_IF_ERROR(millis(m["sdo_quiet_ms"], 60000, c.sdo_quiet));
  CDPR_RETURN_IF_ERROR(millis(m["bus_off_recovery_ms"], 60000, c.bus_off_recovery));
  if (const YamlField f = m["bus_load_warning"]; f.present()) {
    CDPR_ASSIGN_OR_RETURN(c.bus_load_warning, f.number(Sign::kPositive));
    if (c.bus_load_warning > 1) return f.error("must be within (0, 1]");
  }
  CDPR_RETURN_IF_ERROR(m.optional("reset_communication", c.reset_communication));
  CDPR_RETURN_IF_ERROR(m.optional("quick_stop_on_fault", c.quick_stop_on_fault));
  return Status::success();
}

Status parse_pdo_list(const YamlField& list, PdoDirection dir, std::vector<PdoConfig>& out) {
  CDPR_RETURN_IF_ERROR(list.expect_list("a list of PDOs"));
  out.clear();
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YamlField p = list[i];
    CDPR_RETURN_IF_ERROR(p.check_keys(
        {"number", "cob_id", "transmission", "inhibit_100us", "event_timer_ms", "map"}));
    PdoConfig c;
    c.direction = dir;
    CDPR_ASSIGN_OR_RETURN(const YamlField number, p.required("number"));
    CDPR_ASSIGN_OR_RETURN(const std::int64_t n, number.integer(1, 512));
    c.number = static_cast<int>(n);
    CDPR_RETURN_IF_ERROR(p.optional("cob_id", c.cob_id, 1, 0x7FF));
    if (const YamlField t = p["transmission"]; t.present()) {
      CDPR_ASSIGN_OR_RETURN(const std::int64_t v, t.integer(0, 255));
      if (v > 240 && v < 252) return t.error("241..251 are reserved");
      c.transmission_type = static_cast<std::uint8_t>(v);
    }
    CDPR_RETURN_IF_ERROR(p.optional("inhibit_100us", c.inhibit_time_100us, 0, 65535));
    CDPR_RETURN_IF_ERROR(p.optional("event_timer_ms", c.event_timer_ms, 0, 65535));
    const YamlField map = p["map"];
    CDPR_RETURN_IF_ERROR(map.expect_list("a list of objects"));
    std::size_t bytes = 0;
    for (std::size_t k = 0; k < map.size(); ++k) {
      PdoEntry e;
      CDPR_RETURN_IF_ERROR(mapping(map[k], e));
      bytes += size_of(e.type);
      if (bytes > 8) return map[k].error("the PDO would exceed 8 bytes");
      c.entries.push_back(e);
    }
    out.push_back(std::move(c));
  }
  return Status::success();
}

// A node's fields: in the node's entry first, then in its profile.
struct NodeFields {
  YamlField node;
  std::optional<YamlField> profile;
  YamlField operator[](const char* key) const {
    const YamlField own = node[key];
    if (own.present() || !profile) return own;
    const YamlField p = (*profile)[key];
    return p.present() ? p : own;
  }
};

// The type of an SDO write without `type:`: the EDS's type of the object.
Status type_from_eds(const YamlField& e, const eds::Eds* device, SdoWrite& w) {
  if (device == nullptr)
    return e.error("needs a type (i8 u8 i16 u16 i32 u32): the node has no EDS");
  const eds::SubObject* s = device->find(w.object);
  if (s == nullptr) {
    return e["object"].error(device->source() + " has no object " + e["object"].scalar() +
                             ": give its type");
  }
  for (DataType t : {DataType::kI8, DataType::kU8, DataType::kI16, DataType::kU16, DataType::kI32,
                     DataType::kU32}) {
    if (eds::same_type(s->data_type, t)) {
      w.type = t;
      return Status::success();
    }
  }
  return e["object"].error(device->where(*s) + " is " + std::string(eds::type_name(s->data_type)) +
                           ": an SDO write takes i8 u8 i16 u16 i32 u32");
}

Status parse_sdo_writes(const YamlField& list, const eds::Eds* device, std::vector<SdoWrite>& out) {
  CDPR_RETURN_IF_ERROR(list.expect_list("a list"));
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YamlField e = list[i];
    CDPR_RETURN_IF_ERROR(e.check_keys({"object", "type", "value"}));
    SdoWrite w;
    const YamlField object = e["object"], type = e["type"], value = e["value"];
    if (!object.present() || !value.present()) return e.error("needs object and value");
    CDPR_RETURN_IF_ERROR(address(object, object.scalar(), w.object));
    if (!type.present()) {
      CDPR_RETURN_IF_ERROR(type_from_eds(e, device, w));
    } else if (!parse_data_type(type.scalar(), w.type)) {
      return type.error("not one of i8 u8 i16 u16 i32 u32");
    }
    const int bits = 8 * size_of(w.type);
    const std::int64_t lo = is_signed(w.type) ? -(std::int64_t{1} << (bits - 1)) : 0;
    const std::int64_t hi =
        is_signed(w.type) ? (std::int64_t{1} << (bits - 1)) - 1 : (std::int64_t{1} << bits) - 1;
    CDPR_ASSIGN_OR_RETURN(w.value, value.integer(lo, hi));
    w.where = where(e);
    out.push_back(w);
  }
  return Status::success();
}

// EDS files named by the network, parsed once per file (profiles share them).
using EdsCache = std::map<std::string, std::shared_ptr<const eds::Eds>>;

// `eds:` names the device's EDS/DCF, relative to the YAML file's directory.
Status device_eds(const YamlField& field, EdsCache& cache, NodeConfig& c) {
  CDPR_ASSIGN_OR_RETURN(std::string path, field.text());
  const std::string& source = field.file();
  const auto slash = source.rfind('/');
  if (path.front() != '/' && slash != std::string::npos) path = source.substr(0, slash + 1) + path;
  auto& cached = cache[path];
  if (!cached) {
    auto e = eds::Eds::load(path);
    if (!e.ok()) return field.error(std::string(e.status().message()));
    cached = std::make_shared<const eds::Eds>(std::move(*e));
  }
  c.eds = path;
  c.eds_data = cached;
  return Status::success();
}

Status parse_quirks(const YamlField& list, std::uint32_t& out) {
  CDPR_RETURN_IF_ERROR(list.expect_list("a list of quirk names (" + quirk_names() + ")"));
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YamlField q = list[i];
    const QuirkInfo* found = nullptr;
    for (const QuirkInfo& k : kQuirks) {
      if (q.is_scalar() && q.scalar() == k.name) found = &k;
    }
    if (found == nullptr) {
      const std::string what = q.is_scalar() ? "'" + q.scalar() + "'" : q.describe();
      return q.error(what + " is not a quirk (" + quirk_names() + ")");
    }
    out |= static_cast<std::uint32_t>(found->quirk);
  }
  return Status::success();
}

// The fields of a node entry; a profile has the same but the node's identity.
Status check_node_fields(const YamlField& y, bool entry) {
  CDPR_RETURN_IF_ERROR(y.check_keys({"id",
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
                                     "quirks",
                                     "gain",
                                     "offset",
                                     "eds"}));
  if (entry) return Status::success();
  for (const char* key : {"id", "name", "profile"}) {
    if (const YamlField k = y[key]; k.present()) return k.error("belongs to a node, not a profile");
  }
  return Status::success();
}

Status parse_node(const NodeFields& f, EdsCache& eds_cache, NodeConfig& c) {
  CDPR_RETURN_IF_ERROR(check_node_fields(f.node, /*entry=*/true));
  if (const YamlField kind = f["kind"]; kind.present()) {
    CDPR_ASSIGN_OR_RETURN(const int k, kind.choice({"generic", "cia402", "force_sensor"}));
    constexpr NodeKind kKinds[] = {NodeKind::kGeneric, NodeKind::kCia402Drive,
                                   NodeKind::kForceSensor};
    c.kind = kKinds[k];
  }
  CDPR_RETURN_IF_ERROR(millis(f["heartbeat_ms"], 65535, c.heartbeat_period));
  CDPR_RETURN_IF_ERROR(millis(f["heartbeat_timeout_ms"], 65535, c.heartbeat_timeout));
  CDPR_RETURN_IF_ERROR(millis(f["master_heartbeat_timeout_ms"], 65535, c.master_heartbeat_timeout));
  if (const YamlField rpdo = f["rpdo"]; rpdo.present()) {
    CDPR_RETURN_IF_ERROR(parse_pdo_list(rpdo, PdoDirection::kRpdo, c.rpdos));
  }
  if (const YamlField tpdo = f["tpdo"]; tpdo.present()) {
    CDPR_RETURN_IF_ERROR(parse_pdo_list(tpdo, PdoDirection::kTpdo, c.tpdos));
  }
  // The EDS first: an SDO write without a type takes the EDS's.
  if (const YamlField e = f["eds"]; e.present()) CDPR_RETURN_IF_ERROR(device_eds(e, eds_cache, c));
  if (const YamlField sdo = f["sdo"]; sdo.present()) {
    CDPR_RETURN_IF_ERROR(parse_sdo_writes(sdo, c.eds_data.get(), c.sdo_writes));
  }
  DriveConfig& d = c.drive;
  if (const YamlField mode = f["mode"]; mode.present()) {
    CDPR_ASSIGN_OR_RETURN(const int m, mode.choice({"csp", "pp", "homing"}));
    constexpr Mode kModes[] = {Mode::kCyclicSyncPosition, Mode::kProfilePosition, Mode::kHoming};
    d.mode = kModes[m];
  }
  if (const YamlField cpu = f["counts_per_unit"]; cpu.present()) {
    CDPR_ASSIGN_OR_RETURN(d.counts_per_unit, cpu.number(Sign::kNonZero, "counts per unit"));
    d.counts_per_unit_where = where(cpu);
  }
  CDPR_RETURN_IF_ERROR(millis(f["transition_timeout_ms"], 60000, d.transition_timeout));
  CDPR_RETURN_IF_ERROR(millis(f["mode_switch_timeout_ms"], 60000, d.mode_switch_timeout));
  const auto integer = [&](const char* key, auto& out, std::int64_t lo, std::int64_t hi) {
    const YamlField v = f[key];
    if (!v.present()) return Status::success();
    Result<std::int64_t> r = v.integer(lo, hi);
    if (!r.ok()) return r.status();
    out = static_cast<std::remove_reference_t<decltype(out)>>(*r);
    return Status::success();
  };
  CDPR_RETURN_IF_ERROR(
      integer("abort_connection_option", d.abort_connection_option, -32768, 32767));
  CDPR_RETURN_IF_ERROR(integer("quick_stop_option", d.quick_stop_option, -32768, 32767));
  CDPR_RETURN_IF_ERROR(integer("profile_velocity", d.profile_velocity, 0, 0xFFFFFFFF));
  CDPR_RETURN_IF_ERROR(integer("profile_acceleration", d.profile_acceleration, 0, 0xFFFFFFFF));
  CDPR_RETURN_IF_ERROR(integer("homing_method", d.homing_method, -128, 127));
  d.homing = d.mode == Mode::kHoming || f["homing_method"].present();
  if (const YamlField q = f["quirks"]; q.present()) {
    CDPR_RETURN_IF_ERROR(parse_quirks(q, d.quirks));
  }
  // One value for every channel (expanded in parse_config) or one per channel.
  if (const YamlField gain = f["gain"]; gain.present()) {
    CDPR_ASSIGN_OR_RETURN(c.force.gain, gain.numbers(Sign::kAny, "", /*scalar_allowed=*/true));
    c.force.gain_where = where(gain);
  }
  if (const YamlField offset = f["offset"]; offset.present()) {
    CDPR_ASSIGN_OR_RETURN(c.force.offset, offset.numbers(Sign::kAny, "", /*scalar_allowed=*/true));
    c.force.offset_where = where(offset);
  }
  return Status::success();
}

Status parse_document(const YamlField& root, MasterConfig& c) {
  EdsCache eds_cache;
  CDPR_RETURN_IF_ERROR(root.check_keys({"master", "profiles", "nodes"}));
  if (const YamlField m = root["master"]; m.present()) CDPR_RETURN_IF_ERROR(parse_master(m, c));
  const YamlField profiles = root["profiles"];
  if (profiles.present()) CDPR_RETURN_IF_ERROR(profiles.expect_map("a mapping"));
  const YamlField nodes = root["nodes"];
  if (!nodes.is_list() || nodes.size() == 0) {
    return nodes.error("expected a non-empty list of nodes");
  }
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    const YamlField n = nodes[i];
    CDPR_RETURN_IF_ERROR(n.expect_map("a mapping"));
    NodeConfig nc;
    CDPR_ASSIGN_OR_RETURN(const YamlField id_field, n.required("id"));
    CDPR_ASSIGN_OR_RETURN(const std::int64_t id, id_field.integer(1, 127));
    nc.id = static_cast<NodeId>(id);
    nc.name = "node" + std::to_string(id);
    CDPR_RETURN_IF_ERROR(n.optional("name", nc.name));
    NodeFields f{n, std::nullopt};
    if (const YamlField profile = n["profile"]; profile.present()) {
      const YamlField p = profiles[profile.scalar()];
      if (!p.present()) {
        return profile.error("no profile '" + profile.scalar() + "' in profiles");
      }
      CDPR_RETURN_IF_ERROR(check_node_fields(p, /*entry=*/false));
      f.profile = p;
    }
    CDPR_RETURN_IF_ERROR(parse_node(f, eds_cache, nc));
    c.nodes.push_back(std::move(nc));
  }
  return Status::success();
}

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
      return Status::error(ErrorCode::kInvalidArgument, "node %u (%s): id not in 1..127",
                           unsigned{n.id}, n.name.c_str());
    }
    if (n.id == c.master_id) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "node %u (%s): id is the master's own node id", unsigned{n.id},
                           n.name.c_str());
    }
    if (!ids.insert(n.id).second) {
      return Status::error(ErrorCode::kInvalidArgument, "node %u (%s): id used twice",
                           unsigned{n.id}, n.name.c_str());
    }
    for (const auto* list : {&n.rpdos, &n.tpdos}) {
      for (const auto& p : *list) {
        const char* dir = p.direction == PdoDirection::kRpdo ? "RPDO" : "TPDO";
        if (p.cob_id == 0 && p.number > 4) {
          return Status::error(ErrorCode::kInvalidArgument,
                               "node %u (%s): %s%d needs a cob_id (defaults exist for 1..4)",
                               unsigned{n.id}, n.name.c_str(), dir, p.number);
        }
        if (p.entries.empty()) continue;
        if (!cob_ids.insert(p.effective_cob_id(n.id)).second) {
          return Status::error(ErrorCode::kInvalidArgument,
                               "node %u (%s): %s%d COB-ID 0x%03X is used twice", unsigned{n.id},
                               n.name.c_str(), dir, p.number, unsigned{p.effective_cob_id(n.id)});
        }
      }
    }
    if (n.heartbeat_timeout.count() > 0 && n.heartbeat_period.count() > 0 &&
        n.heartbeat_timeout <= n.heartbeat_period) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "node %u (%s): heartbeat timeout %.0f ms must exceed its period %.0f ms",
                           unsigned{n.id}, n.name.c_str(), to_ms(n.heartbeat_timeout),
                           to_ms(n.heartbeat_period));
    }
    if (n.master_heartbeat_timeout.count() > 0 &&
        n.master_heartbeat_timeout <= c.master_heartbeat_period) {
      return Status::error(
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
          return Status::error(ErrorCode::kInvalidArgument,
                               "node %u (%s): a cia402 drive needs 0x%04X:%02X in its %ss",
                               unsigned{n.id}, n.name.c_str(), unsigned{obj.index},
                               unsigned{obj.sub}, where);
        }
      }
    }
    if (n.kind == NodeKind::kForceSensor) {
      const std::size_t ch = mapped_count(n.tpdos);
      if (ch == 0) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "node %u (%s): a force sensor needs its channels in TPDOs",
                             unsigned{n.id}, n.name.c_str());
      }
      for (const auto* v : {&n.force.gain, &n.force.offset}) {
        if (v->size() != 1 && v->size() != ch) {
          return Status::error(ErrorCode::kInvalidArgument,
                               "node %u (%s): %s has %zu values for %zu channels", unsigned{n.id},
                               n.name.c_str(), v == &n.force.gain ? "gain" : "offset", v->size(),
                               ch);
        }
      }
      for (double g : n.force.gain) {
        if (g == 0) {
          return Status::error(ErrorCode::kInvalidArgument, "node %u (%s): a gain is 0",
                               unsigned{n.id}, n.name.c_str());
        }
      }
    }
  }
  return Status::success();
}

Result<MasterConfig> parse_config(std::string_view yaml, std::string_view source) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::parse(yaml, source));
  MasterConfig c;
  CDPR_RETURN_IF_ERROR(parse_document(doc.root(), c));
  // A single gain/offset applies to every channel.
  for (auto& n : c.nodes) {
    if (n.kind != NodeKind::kForceSensor) continue;
    const std::size_t ch = mapped_count(n.tpdos);
    if (n.force.gain.empty()) n.force.gain.assign(ch, 1.0);
    if (n.force.offset.empty()) n.force.offset.assign(ch, 0.0);
    if (n.force.gain.size() == 1) n.force.gain.assign(ch, n.force.gain[0]);
    if (n.force.offset.size() == 1) n.force.offset.assign(ch, n.force.offset[0]);
  }
  Status s = validate(c);
  if (s.ok()) s = check_eds(c);
  // An error that names its own place (file:line: field) is left as it is.
  if (!s.ok() && s.message().rfind(std::string(source) + ":", 0) == 0) return s;
  if (!s.ok()) {
    return Status::error(s.code(), "%.*s: %.*s", static_cast<int>(source.size()), source.data(),
                         static_cast<int>(s.message().size()), s.message().data());
  }
  return c;
}

Result<MasterConfig> load_config(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    return Status::error(ErrorCode::kNotFound, "%s: cannot open the CANopen configuration",
                         path.c_str());
  }
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_config(ss.str(), path);
}

}  // namespace cdpr::canopen
