// What the master applied to its nodes: the confirmed SDO downloads, the PDOs it disabled at
// boot, and the DCF (CiA 306) of each node written from them (docs/canopen.md).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>

#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/master.hpp"
#include "cdpr/io/atomic_file.hpp"

namespace cdpr::canopen {

namespace {

eds::SubObject entry(ObjectAddress a, std::string name, std::uint16_t type, eds::Access access) {
  eds::SubObject s;
  s.address = a;
  s.name = std::move(name);
  s.data_type = type;
  s.access = access;
  return s;
}

// Adds (or replaces) one entry; an object with sub-indices other than 0 becomes a RECORD with its
// sub-index 0 (highest sub-index supported).
void put_entry(eds::Eds& d, eds::SubObject sub, const char* object_name) {
  const std::uint16_t index = sub.address.index;
  const eds::Object* existing = d.object(index);
  eds::Object o = existing != nullptr ? *existing : eds::Object{};
  o.index = index;
  if (o.name.empty()) o.name = object_name;
  std::erase_if(o.subs, [&](const eds::SubObject& x) { return x.address.sub == sub.address.sub; });
  o.subs.push_back(std::move(sub));
  std::sort(o.subs.begin(), o.subs.end(), [](const eds::SubObject& x, const eds::SubObject& y) {
    return x.address.sub < y.address.sub;
  });
  if (o.subs.size() == 1 && o.subs.front().address.sub == 0) {
    o.code = eds::ObjectCode::kVar;
  } else {
    o.code = eds::ObjectCode::kRecord;
    if (o.subs.front().address.sub != 0) {
      o.subs.insert(o.subs.begin(), entry({index, 0}, "Highest sub-index supported",
                                          eds::type::kUnsigned8, eds::Access::kRo));
    }
    o.subs.front().default_value = std::to_string(o.subs.back().address.sub);
  }
  d.put(std::move(o));
}

std::string hex32(std::int64_t v) {
  char b[16];
  std::snprintf(b, sizeof b, "0x%08X", static_cast<unsigned>(v));
  return b;
}

}  // namespace

// Without an EDS the master describes what it knows: the mandatory objects of CiA 301 (0x1000,
// 0x1001, 0x1018; the values the node answered at boot as defaults), every object it wrote
// (typed by its size), and a [DeviceInfo] with every key CiA 306 requires, filled from the
// identity, the configuration and the bit rate.
const std::map<std::uint32_t, std::int64_t>* Master::applied(NodeId id) const {
  if (node_index_[id] < 0) return nullptr;
  return &nodes_[static_cast<std::size_t>(node_index_[id])]->applied;
}

std::vector<std::uint16_t> Master::disabled_pdos(NodeId id) const {
  if (node_index_[id] < 0) return {};
  return nodes_[static_cast<std::size_t>(node_index_[id])]->disabled;
}

eds::Eds Master::describe_without_eds(const NodeRt& n) const {
  eds::Eds d;
  const auto known = [&](ObjectAddress a) -> std::optional<std::int64_t> {
    auto it = n.identity.find(a.key());
    if (it == n.identity.end()) return std::nullopt;
    return it->second;
  };
  auto put_read = [&](ObjectAddress a, const char* name, std::uint16_t type, const char* object) {
    eds::SubObject s = entry(a, name, type, eds::Access::kRo);
    if (auto v = known(a)) s.default_value = hex32(*v);
    put_entry(d, std::move(s), object);
  };
  put_read({0x1000, 0}, "Device type", eds::type::kUnsigned32, "Device type");
  put_entry(d, entry({0x1001, 0}, "Error register", eds::type::kUnsigned8, eds::Access::kRo),
            "Error register");
  const char* id_names[] = {"Vendor-ID", "Product code", "Revision number", "Serial number"};
  for (std::uint8_t sub = 1; sub <= 4; ++sub) {
    if (sub > 1 && !known({0x1018, sub})) continue;  // only Vendor-ID is mandatory
    put_read({0x1018, sub}, id_names[sub - 1], eds::type::kUnsigned32, "Identity object");
  }
  for (const auto& [key, size] : n.applied_size) {
    const ObjectAddress a{static_cast<std::uint16_t>(key >> 8),
                          static_cast<std::uint8_t>(key & 0xFF)};
    char name[32], object[32];
    std::snprintf(name, sizeof name, "0x%04X:%02X", unsigned{a.index}, unsigned{a.sub});
    std::snprintf(object, sizeof object, "Object 0x%04X", unsigned{a.index});
    const std::uint16_t type = size == 1   ? eds::type::kUnsigned8
                               : size == 2 ? eds::type::kUnsigned16
                                           : eds::type::kUnsigned32;
    put_entry(d, entry(a, name, type, eds::Access::kRw), object);
  }
  const auto id_value = [&](std::uint8_t sub) {
    const auto v = known({0x1018, sub});
    return v ? hex32(*v) : std::string("0");
  };
  std::size_t rx = 0, tx = 0;
  for (const auto& p : n.config.rpdos) rx += p.entries.empty() ? 0 : 1;
  for (const auto& p : n.config.tpdos) tx += p.entries.empty() ? 0 : 1;
  eds::Section info = {
      {"VendorName", "unknown (no EDS; identity read from 0x1018)"},
      {"VendorNumber", id_value(1)},
      {"ProductName", n.config.name + " (" + std::string(to_string(n.config.kind)) + ")"},
      {"ProductNumber", id_value(2)},
      {"RevisionNumber", id_value(3)},
      {"OrderCode", ""}};
  const int rates[] = {10, 20, 50, 125, 250, 500, 800, 1000};
  const long kbit = std::lround(config_.bitrate / 1000.0);
  for (int r : rates) info.push_back({"BaudRate_" + std::to_string(r), r == kbit ? "1" : "0"});
  info.insert(info.end(), {{"SimpleBootUpMaster", "0"},
                           {"SimpleBootUpSlave", "1"},
                           {"Granularity", "8"},
                           {"DynamicChannelsSupported", "0"},
                           {"GroupMessaging", "0"},
                           {"NrOfRXPDO", std::to_string(rx)},
                           {"NrOfTXPDO", std::to_string(tx)},
                           {"LSS_Supported", "0"}});
  d.set_device_info(std::move(info));
  d.set_source("(no EDS: the mandatory objects and the objects written by the master)");
  return d;
}

// Best effort, for the DCF of a node without EDS: a node lacking an optional identity entry
// answers with an abort and the entry is left out.
void Master::read_identity(NodeRt& n) {
  n.identity.clear();
  const ObjectAddress entries[] = {{0x1000, 0}, {0x1018, 1}, {0x1018, 2}, {0x1018, 3}, {0x1018, 4}};
  for (const ObjectAddress a : entries) {
    auto r = n.sdo->read<std::uint32_t>(a, pump_);
    if (r.ok()) n.identity[a.key()] = *r;
  }
}

Status Master::write_dcf(NodeId id, const std::string& path) const {
  if (node_index_[id] < 0) {
    return Status::error(ErrorCode::kNotFound, "node %u: not in the configuration", unsigned{id});
  }
  const NodeRt& n = *nodes_[static_cast<std::size_t>(node_index_[id])];
  const eds::Eds description = n.config.eds_data ? *n.config.eds_data : describe_without_eds(n);
  eds::Commissioning c;
  c.node_id = id;
  c.node_name = n.config.name;
  c.bitrate = config_.bitrate;
  c.network_name = config_.interface;
  return io::write_file_atomically(path, eds::to_dcf(description, c, n.applied));
}

Status Master::write_dcfs(const std::string& dir) const {
  for (const auto& n : nodes_) {
    CDPR_RETURN_IF_ERROR(write_dcf(n->config.id, dir + "/" + n->config.name + ".dcf"));
  }
  return Status::success();
}

}  // namespace cdpr::canopen
