#include "cdpr/canopen/eds_check.hpp"

#include <cstdio>
#include <string>

#include "cdpr/canopen/cia402.hpp"

namespace cdpr::canopen {

namespace {

using Kind = PlannedAccess::Kind;

void add(std::vector<PlannedAccess>& v, ObjectAddress a, DataType t, Kind k, const char* what,
         int pdo = 0) {
  v.push_back(PlannedAccess{a, t, k, what, pdo, {}});
}

std::string node_name(const NodeConfig& n) {
  return "node " + std::to_string(n.id) + " (" + n.name + ")";
}

std::string addr(ObjectAddress a) {
  char b[16];
  std::snprintf(b, sizeof b, "0x%04X:%02X", unsigned{a.index}, unsigned{a.sub});
  return b;
}

std::string use(const PlannedAccess& a) {
  char b[96];
  switch (a.kind) {
    case Kind::kWrite:
      std::snprintf(b, sizeof b, "writes %s (%s) as %s", addr(a.object).c_str(), a.what,
                    to_string(a.type).data());
      break;
    case Kind::kRead:
      std::snprintf(b, sizeof b, "reads %s (%s) as %s", addr(a.object).c_str(), a.what,
                    to_string(a.type).data());
      break;
    case Kind::kMapRpdo:
      std::snprintf(b, sizeof b, "maps %s as %s in RPDO%d", addr(a.object).c_str(),
                    to_string(a.type).data(), a.pdo);
      break;
    case Kind::kMapTpdo:
      std::snprintf(b, sizeof b, "maps %s as %s in TPDO%d", addr(a.object).c_str(),
                    to_string(a.type).data(), a.pdo);
      break;
  }
  return b;
}

}  // namespace

std::vector<PlannedAccess> planned_accesses(const MasterConfig& config, const NodeConfig& c) {
  std::vector<PlannedAccess> v;
  namespace o = cia402::obj;
  if (c.heartbeat_period.count() > 0) {
    add(v, {0x1017, 0}, DataType::kU16, Kind::kWrite, "producer heartbeat time");
  }
  if (c.master_heartbeat_timeout.count() > 0) {
    add(v, {0x1016, 1}, DataType::kU32, Kind::kWrite, "consumer heartbeat time of the master");
  }
  if (config.sync_counter_overflow >= 2) {
    add(v, {0x1019, 0}, DataType::kU8, Kind::kWrite, "synchronous counter overflow value");
  }
  const bool drive = c.kind == NodeKind::kCia402Drive;
  if (drive) {
    add(v, o::kAbortConnectionOption, DataType::kI16, Kind::kWrite, "abort connection option");
    if (c.drive.quick_stop_option) {
      add(v, o::kQuickStopOption, DataType::kI16, Kind::kWrite, "quick stop option");
    }
  }
  for (const auto* list : {&c.rpdos, &c.tpdos}) {
    for (const PdoConfig& p : *list) {
      const std::uint16_t comm = p.comm_index(), map = p.mapping_index();
      const bool tpdo = p.direction == PdoDirection::kTpdo;
      add(v, {comm, 1}, DataType::kU32, Kind::kWrite, tpdo ? "TPDO COB-ID" : "RPDO COB-ID",
          p.number);
      add(v, {map, 0}, DataType::kU8, Kind::kWrite, "PDO mapping count", p.number);
      for (std::size_t i = 0; i < p.entries.size(); ++i) {
        add(v, {map, static_cast<std::uint8_t>(i + 1)}, DataType::kU32, Kind::kWrite,
            "PDO mapping entry", p.number);
      }
      add(v, {comm, 2}, DataType::kU8, Kind::kWrite, "PDO transmission type", p.number);
      if (tpdo && p.inhibit_time_100us != 0) {
        add(v, {comm, 3}, DataType::kU16, Kind::kWrite, "TPDO inhibit time", p.number);
      }
      if (tpdo && p.event_timer_ms != 0) {
        add(v, {comm, 5}, DataType::kU16, Kind::kWrite, "TPDO event timer", p.number);
      }
      for (const PdoEntry& e : p.entries) {
        add(v, e.object, e.type, tpdo ? Kind::kMapTpdo : Kind::kMapRpdo, "mapped object", p.number);
      }
    }
  }
  if (drive) {
    if (c.drive.profile_velocity != 0) {
      add(v, o::kProfileVelocity, DataType::kU32, Kind::kWrite, "profile velocity");
    }
    if (c.drive.profile_acceleration != 0) {
      add(v, o::kProfileAcceleration, DataType::kU32, Kind::kWrite, "profile acceleration");
      add(v, o::kProfileDeceleration, DataType::kU32, Kind::kWrite, "profile deceleration");
    }
  }
  for (const SdoWrite& w : c.sdo_writes) {
    add(v, w.object, w.type, Kind::kWrite, "sdo write");
    v.back().where = w.where;
  }
  if (drive) {
    // Mode switches (boot and set_mode).
    if (!has(c.drive, DriveQuirk::kNoInterpolationPeriod)) {
      add(v, o::kInterpolationPeriodValue, DataType::kU8, Kind::kWrite,
          "interpolation time period value");
      add(v, o::kInterpolationPeriodIndex, DataType::kI8, Kind::kWrite, "interpolation time index");
    }
    add(v, o::kModesOfOperation, DataType::kI8, Kind::kWrite, "modes of operation");
    if (has(c.drive, DriveQuirk::kNoModeDisplay)) {
      add(v, o::kModesOfOperation, DataType::kI8, Kind::kRead, "modes of operation (read back)");
    } else {
      add(v, o::kModesDisplay, DataType::kI8, Kind::kRead, "modes of operation display");
    }
  }
  if (drive && c.drive.homing) {
    // The drive's own homing (boot in homing mode, set_actual_position).
    add(v, o::kHomingMethod, DataType::kI8, Kind::kWrite, "homing method");
    add(v, o::kHomeOffset, DataType::kI32, Kind::kWrite, "home offset");
  }
  return v;
}

Status check_against_eds(const MasterConfig& config, const NodeConfig& node, const eds::Eds& e) {
  auto fail = [&](const PlannedAccess& a, const std::string& why) {
    return Status::error(ErrorCode::kInvalidArgument, "%s%s%s: the master %s, but %s",
                         a.where.c_str(), a.where.empty() ? "" : ": ", node_name(node).c_str(),
                         use(a).c_str(), why.c_str());
  };
  for (const PlannedAccess& a : planned_accesses(config, node)) {
    const eds::SubObject* s = e.find(a.object);
    if (s == nullptr) {
      const bool index = e.object(a.object.index) != nullptr;
      return fail(a,
                  e.source() + (index ? " has no sub-index " : " has no object ") + addr(a.object));
    }
    if (!eds::same_type(s->data_type, a.type)) {
      return fail(a, e.where(*s) + " is " + std::string(eds::type_name(s->data_type)));
    }
    switch (a.kind) {
      case Kind::kWrite:
        if (!eds::writable(s->access)) {
          return fail(a, e.where(*s) + " is " + std::string(eds::to_string(s->access)));
        }
        break;
      case Kind::kRead:
        if (!eds::readable(s->access)) return fail(a, e.where(*s) + " is write-only");
        break;
      case Kind::kMapRpdo:
      case Kind::kMapTpdo:
        if (!s->pdo_mapping) return fail(a, e.where(*s) + " is not mappable (PDOMapping=0)");
        if (a.kind == Kind::kMapRpdo && !eds::writable(s->access)) {
          return fail(a, e.where(*s) + " is " + std::string(eds::to_string(s->access)) +
                             ": an RPDO cannot write it");
        }
        if (a.kind == Kind::kMapTpdo && !eds::readable(s->access)) {
          return fail(a, e.where(*s) + " is write-only: a TPDO cannot read it");
        }
        break;
    }
  }
  // Every PDO the EDS has and the configuration does not use gets disabled at boot: its COB-ID
  // must be writable.
  for (PdoDirection d : {PdoDirection::kRpdo, PdoDirection::kTpdo}) {
    for (int n : pdo_numbers(node, d)) {
      PdoConfig p;
      p.direction = d;
      p.number = n;
      const eds::SubObject* s = e.find({p.comm_index(), 1});
      if (s == nullptr) continue;
      if (!eds::writable(s->access)) {
        PlannedAccess a{
            {p.comm_index(), 1}, DataType::kU32, Kind::kWrite, "COB-ID of an unused PDO", n, {}};
        return fail(a, e.where(*s) + " is " + std::string(eds::to_string(s->access)));
      }
    }
  }
  return Status::success();
}

Status check_eds(const MasterConfig& config) {
  for (const NodeConfig& n : config.nodes) {
    if (!n.eds_data) continue;
    CDPR_RETURN_IF_ERROR(check_against_eds(config, n, *n.eds_data));
  }
  return Status::success();
}

std::vector<int> pdo_numbers(const NodeConfig& node, PdoDirection direction) {
  std::vector<int> out;
  const std::uint16_t base = direction == PdoDirection::kRpdo ? 0x1400 : 0x1800;
  if (!node.eds_data) {
    for (int n = 1; n <= 4; ++n) out.push_back(n);
    return out;
  }
  for (const auto& [index, object] : node.eds_data->objects()) {
    if (index >= base && index < base + 0x200) out.push_back(index - base + 1);
  }
  return out;
}

}  // namespace cdpr::canopen
