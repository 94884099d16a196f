// What the master applied to its nodes: the confirmed SDO downloads, the PDOs it disabled at
// boot, and the DCF (CiA 306) of each node written from them.
#include <algorithm>
#include <cstdio>
#include <string>

#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/master.hpp"

namespace cdpr::canopen {

const std::map<std::uint32_t, std::int64_t>* Master::applied(NodeId id) const {
  if (node_index_[id] < 0) return nullptr;
  return &nodes_[static_cast<std::size_t>(node_index_[id])]->applied;
}

std::vector<std::uint16_t> Master::disabled_pdos(NodeId id) const {
  if (node_index_[id] < 0) return {};
  return nodes_[static_cast<std::size_t>(node_index_[id])]->disabled;
}

Status Master::write_dcf(NodeId id, const std::string& path) const {
  if (node_index_[id] < 0) {
    return Status::error(ErrorCode::kNotFound, "node %u: not in the configuration", unsigned{id});
  }
  const NodeRt& n = *nodes_[static_cast<std::size_t>(node_index_[id])];
  eds::Eds description;
  if (n.config.eds_data) {
    description = *n.config.eds_data;
  } else {
    // No EDS: a description of the objects the master wrote, typed by their size.
    auto e = eds::Eds::parse(
        "[MandatoryObjects]\nSupportedObjects=0\n[OptionalObjects]\nSupportedObjects=0\n"
        "[ManufacturerObjects]\nSupportedObjects=0\n[1000]\nParameterName=Device type\n"
        "DataType=0x0007\nAccessType=ro\n",
        "(no EDS: objects written by the master)");
    if (!e.ok()) return e.status();
    description = std::move(*e);
    for (const auto& [key, size] : n.applied_size) {
      const ObjectAddress a{static_cast<std::uint16_t>(key >> 8),
                            static_cast<std::uint8_t>(key & 0xFF)};
      const eds::Object* existing = description.object(a.index);
      eds::Object o = existing != nullptr ? *existing : eds::Object{};
      o.index = a.index;
      char name[32];
      std::snprintf(name, sizeof name, "Object 0x%04X", unsigned{a.index});
      if (o.name.empty()) o.name = name;
      eds::SubObject sub;
      sub.address = a;
      std::snprintf(name, sizeof name, "0x%04X:%02X", unsigned{a.index}, unsigned{a.sub});
      sub.name = name;
      sub.data_type = size == 1   ? eds::type::kUnsigned8
                      : size == 2 ? eds::type::kUnsigned16
                                  : eds::type::kUnsigned32;
      sub.access = eds::Access::kRw;
      std::erase_if(o.subs, [&](const eds::SubObject& x) { return x.address.sub == a.sub; });
      o.subs.push_back(sub);
      std::sort(o.subs.begin(), o.subs.end(), [](const eds::SubObject& x, const eds::SubObject& y) {
        return x.address.sub < y.address.sub;
      });
      if (o.subs.size() == 1 && a.sub == 0) {
        o.code = eds::ObjectCode::kVar;
      } else {
        o.code = eds::ObjectCode::kRecord;
        // A record needs its sub-index 0 (highest sub-index supported).
        if (o.subs.front().address.sub != 0) {
          eds::SubObject count;
          count.address = {a.index, 0};
          count.name = "Highest sub-index supported";
          count.data_type = eds::type::kUnsigned8;
          count.access = eds::Access::kRo;
          o.subs.insert(o.subs.begin(), count);
        }
        o.subs.front().default_value = std::to_string(o.subs.back().address.sub);
      }
      description.put(std::move(o));
    }
  }
  eds::Commissioning c;
  c.node_id = id;
  c.node_name = n.config.name;
  c.bitrate = config_.bitrate;
  c.network_name = config_.interface;
  return eds::write_text_file(path, eds::to_dcf(description, c, n.applied));
}

Status Master::write_dcfs(const std::string& dir) const {
  for (const auto& n : nodes_) {
    CDPR_RETURN_IF_ERROR(write_dcf(n->config.id, dir + "/" + n->config.name + ".dcf"));
  }
  return Status::success();
}

}  // namespace cdpr::canopen
