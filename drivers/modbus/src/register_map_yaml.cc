// Reads a RegisterMap from YAML. The fields are described in docs/modbus-laser.md.
#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>

#include "cdpr/modbus/register_map.hpp"
#include "yaml_fields.hpp"

namespace cdpr::modbus {

namespace {

using detail::YamlFields;

Status read_u16_list(const YamlFields& f, const YAML::Node& parent, const char* key,
                     const std::string& prefix, std::vector<std::uint16_t>& out) {
  const YAML::Node n = parent[key];
  if (!n) return Status::Ok();
  const std::string field = YamlFields::join(prefix, key);
  if (!n.IsSequence()) return f.error(n, field, "must be a list of integers, e.g. [0, 1]");
  for (std::size_t i = 0; i < n.size(); ++i) {
    long long v = 0;
    CDPR_RETURN_IF_ERROR(f.to_int(n[i], field + "[" + std::to_string(i) + "]", 0, 0xFFFF, v));
    out.push_back(static_cast<std::uint16_t>(v));
  }
  return Status::Ok();
}

Status read_raw_list(const YamlFields& f, const YAML::Node& parent, const char* key,
                     std::vector<double>& out) {
  const YAML::Node n = parent[key];
  if (!n) return Status::Ok();
  if (!n.IsSequence()) return f.error(n, key, "must be a list of raw values, e.g. [0xFFFF]");
  for (std::size_t i = 0; i < n.size(); ++i) {
    double v = 0.0;
    CDPR_RETURN_IF_ERROR(f.to_double(n[i], std::string(key) + "[" + std::to_string(i) + "]", v));
    out.push_back(v);
  }
  return Status::Ok();
}

}  // namespace

namespace detail {

Status parse_register_map_node(const YamlFields& f, const YAML::Node& root, RegisterMap& m) {
  if (!root.IsMap())
    return f.error(root, "<top level>", "must be a mapping of register map fields");
  CDPR_RETURN_IF_ERROR(f.only_known(root, "",
                                    {"name", "source", "table", "address_base", "value", "range",
                                     "no_target", "error", "quality", "trigger", "read"}));
  CDPR_RETURN_IF_ERROR(f.get_string(root, "name", "", m.name, true));
  CDPR_RETURN_IF_ERROR(f.get_string(root, "source", "", m.source, true));
  int table = 0;
  CDPR_RETURN_IF_ERROR(f.get_choice(root, "table", "", {"input", "holding"}, table, true));
  m.table = table == 0 ? RegisterTable::kInput : RegisterTable::kHolding;
  long long base = 0;
  CDPR_RETURN_IF_ERROR(f.get_int(root, "address_base", "", 0, 1, base, false));
  m.address_base = static_cast<int>(base);
  const long long max_addr = 0xFFFF + base;

  const YAML::Node value = root["value"];
  CDPR_RETURN_IF_ERROR(f.require_map(root, value, "value"));
  CDPR_RETURN_IF_ERROR(
      f.only_known(value, "value",
                   {"register", "type", "order", "word_order", "byte_order", "scale", "offset"}));
  long long reg = 0;
  CDPR_RETURN_IF_ERROR(f.get_int(value, "register", "value", base, max_addr, reg, true));
  m.address = static_cast<std::uint16_t>(reg);
  int type = 0;
  CDPR_RETURN_IF_ERROR(
      f.get_choice(value, "type", "value", {"u16", "i16", "u32", "i32", "f32"}, type, true));
  m.type = static_cast<ValueType>(type);
  if (value["order"]) {
    if (value["word_order"] || value["byte_order"]) {
      return f.error(value["order"], "value.order",
                     "give either order or word_order/byte_order, not both");
    }
    int order = 0;
    CDPR_RETURN_IF_ERROR(
        f.get_choice(value, "order", "value", {"ABCD", "CDAB", "BADC", "DCBA"}, order, true));
    m.word_order = (order == 0 || order == 2) ? WordOrder::kHighFirst : WordOrder::kLowFirst;
    m.byte_order = (order == 0 || order == 1) ? ByteOrder::kBig : ByteOrder::kLittle;
  } else {
    int w = 0;
    int b = 0;
    CDPR_RETURN_IF_ERROR(
        f.get_choice(value, "word_order", "value", {"high_first", "low_first"}, w, false));
    CDPR_RETURN_IF_ERROR(f.get_choice(value, "byte_order", "value", {"big", "little"}, b, false));
    m.word_order = w == 0 ? WordOrder::kHighFirst : WordOrder::kLowFirst;
    m.byte_order = b == 0 ? ByteOrder::kBig : ByteOrder::kLittle;
  }
  CDPR_RETURN_IF_ERROR(f.get_double(value, "scale", "value", m.scale, true));
  if (!std::isfinite(m.scale) || m.scale == 0.0) {
    return f.error(value["scale"], "value.scale", "must be finite and non-zero (metres per unit)");
  }
  CDPR_RETURN_IF_ERROR(f.get_double(value, "offset", "value", m.offset, false));

  const YAML::Node range = root["range"];
  CDPR_RETURN_IF_ERROR(f.require_map(root, range, "range"));
  CDPR_RETURN_IF_ERROR(f.only_known(range, "range", {"min", "max"}));
  CDPR_RETURN_IF_ERROR(f.get_double(range, "min", "range", m.min_m, true));
  CDPR_RETURN_IF_ERROR(f.get_double(range, "max", "range", m.max_m, true));
  if (!(m.min_m < m.max_m)) return f.error(range, "range", "min must be below max (metres)");

  CDPR_RETURN_IF_ERROR(read_raw_list(f, root, "no_target", m.no_target_raw));
  CDPR_RETURN_IF_ERROR(read_raw_list(f, root, "error", m.error_raw));

  if (const YAML::Node q = root["quality"]) {
    CDPR_RETURN_IF_ERROR(f.require_map(root, q, "quality"));
    CDPR_RETURN_IF_ERROR(f.only_known(q, "quality", {"register", "mask", "ok", "no_target"}));
    QualityRegister qr;
    long long v = 0;
    CDPR_RETURN_IF_ERROR(f.get_int(q, "register", "quality", base, max_addr, v, true));
    qr.address = static_cast<std::uint16_t>(v);
    v = 0xFFFF;
    CDPR_RETURN_IF_ERROR(f.get_int(q, "mask", "quality", 1, 0xFFFF, v, false));
    qr.mask = static_cast<std::uint16_t>(v);
    if (!q["ok"]) return f.error(q, "quality.ok", "is missing (list the values of a good reading)");
    CDPR_RETURN_IF_ERROR(read_u16_list(f, q, "ok", "quality", qr.ok_values));
    if (qr.ok_values.empty()) return f.error(q["ok"], "quality.ok", "must not be empty");
    CDPR_RETURN_IF_ERROR(read_u16_list(f, q, "no_target", "quality", qr.no_target_values));
    m.quality = qr;
  }

  if (const YAML::Node t = root["trigger"]) {
    CDPR_RETURN_IF_ERROR(f.require_map(root, t, "trigger"));
    CDPR_RETURN_IF_ERROR(f.only_known(t, "trigger", {"register", "value", "settle"}));
    TriggerWrite tw;
    long long v = 0;
    CDPR_RETURN_IF_ERROR(f.get_int(t, "register", "trigger", base, max_addr, v, true));
    tw.address = static_cast<std::uint16_t>(v);
    CDPR_RETURN_IF_ERROR(f.get_int(t, "value", "trigger", 0, 0xFFFF, v, true));
    tw.value = static_cast<std::uint16_t>(v);
    CDPR_RETURN_IF_ERROR(f.get_double(t, "settle", "trigger", tw.settle_s, false));
    if (!(tw.settle_s >= 0.0 && tw.settle_s <= 1.0)) {
      return f.error(t["settle"], "trigger.settle", "must be 0..1 s");
    }
    m.trigger = tw;
  }

  if (const YAML::Node r = root["read"]) {
    CDPR_RETURN_IF_ERROR(f.require_map(root, r, "read"));
    CDPR_RETURN_IF_ERROR(f.only_known(r, "read", {"start", "count"}));
    long long v = 0;
    CDPR_RETURN_IF_ERROR(f.get_int(r, "start", "read", base, max_addr, v, true));
    m.read_start = static_cast<std::uint16_t>(v);
    CDPR_RETURN_IF_ERROR(f.get_int(r, "count", "read", 1, 125, v, true));
    m.read_count = static_cast<std::uint16_t>(v);
    if (m.address < *m.read_start ||
        m.address + register_count(m.type) > *m.read_start + *m.read_count) {
      return f.error(r, "read", "the block must contain value.register and its registers");
    }
  }

  Status s = m.validate();
  if (!s.ok()) return with_context(f.file() + ": ", s);
  return Status::Ok();
}

}  // namespace detail

Result<RegisterMap> parse_register_map(std::string_view yaml_text, std::string_view file) {
  YamlFields f(file);
  RegisterMap m;
  try {
    const YAML::Node root = YAML::Load(std::string(yaml_text));
    Status s = detail::parse_register_map_node(f, root, m);
    if (!s.ok()) return s;
  } catch (const YAML::Exception& e) {
    return Status::Error(ErrorCode::kParseError, "%.*s:%d:%d: YAML syntax: %s",
                         static_cast<int>(file.size()), file.data(), e.mark.line + 1,
                         e.mark.column + 1, e.msg.c_str());
  }
  return m;
}

Result<RegisterMap> load_register_map(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    return Status::Error(ErrorCode::kNotFound, "register map %s: cannot open: %s", path.c_str(),
                         std::strerror(errno));
  }
  std::ostringstream text;
  text << in.rdbuf();
  return parse_register_map(text.str(), path);
}

}  // namespace cdpr::modbus
