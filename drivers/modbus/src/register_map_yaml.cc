// Reads a RegisterMap from YAML. The fields are described in docs/modbus-laser.md.
#include "register_map_yaml.hpp"

#include <cstdint>
#include <vector>

#include "cdpr/modbus/register_map.hpp"

namespace cdpr::modbus {

using config::Sign;
using config::YamlDocument;
using config::YamlField;

namespace {

// An optional list of 16-bit register values.
Status read_u16_list(const YamlField& f, std::vector<std::uint16_t>& out) {
  if (!f.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(f.expect_list("a list of integers, e.g. [0, 1]"));
  for (std::size_t i = 0; i < f.size(); ++i) {
    CDPR_ASSIGN_OR_RETURN(const std::int64_t v, f[i].integer(0, 0xFFFF));
    out.push_back(static_cast<std::uint16_t>(v));
  }
  return Status::success();
}

// An optional list of raw values, e.g. [0xFFFF, -1.5].
Status read_raw_list(const YamlField& f, std::vector<double>& out) {
  if (!f.present()) return Status::success();
  CDPR_ASSIGN_OR_RETURN(out, f.numbers(Sign::kAny, "raw values", /*scalar_allowed=*/false));
  return Status::success();
}

}  // namespace

namespace detail {

Status parse_register_map_node(const YamlField& root, RegisterMap& m) {
  CDPR_RETURN_IF_ERROR(root.expect_map("a mapping of register map fields"));
  CDPR_RETURN_IF_ERROR(root.check_keys({"name", "source", "table", "address_base", "value", "range",
                                        "no_target", "error", "quality", "trigger", "read"}));
  CDPR_ASSIGN_OR_RETURN(m.name, root["name"].text());
  CDPR_ASSIGN_OR_RETURN(m.source, root["source"].text());
  CDPR_ASSIGN_OR_RETURN(const int table, root["table"].choice({"input", "holding"}));
  m.table = table == 0 ? RegisterTable::kInput : RegisterTable::kHolding;
  CDPR_RETURN_IF_ERROR(root.optional("address_base", m.address_base, 0, 1));
  const std::int64_t base = m.address_base;
  const std::int64_t max_addr = 0xFFFF + base;

  CDPR_ASSIGN_OR_RETURN(const YamlField value, root.required("value"));
  CDPR_RETURN_IF_ERROR(value.expect_map());
  CDPR_RETURN_IF_ERROR(value.check_keys(
      {"register", "type", "order", "word_order", "byte_order", "scale", "offset"}));
  CDPR_ASSIGN_OR_RETURN(const std::int64_t reg, value["register"].integer(base, max_addr));
  m.address = static_cast<std::uint16_t>(reg);
  CDPR_ASSIGN_OR_RETURN(const int type, value["type"].choice({"u16", "i16", "u32", "i32", "f32"}));
  m.type = static_cast<ValueType>(type);
  if (const YamlField order_field = value["order"]; order_field.present()) {
    if (value["word_order"].present() || value["byte_order"].present()) {
      return order_field.error("give either order or word_order/byte_order, not both");
    }
    CDPR_ASSIGN_OR_RETURN(const int order, order_field.choice({"ABCD", "CDAB", "BADC", "DCBA"}));
    m.word_order = (order == 0 || order == 2) ? WordOrder::kHighFirst : WordOrder::kLowFirst;
    m.byte_order = (order == 0 || order == 1) ? ByteOrder::kBig : ByteOrder::kLittle;
  } else {
    int w = 0;
    int b = 0;
    CDPR_RETURN_IF_ERROR(value.optional_choice("word_order", w, {"high_first", "low_first"}));
    CDPR_RETURN_IF_ERROR(value.optional_choice("byte_order", b, {"big", "little"}));
    m.word_order = w == 0 ? WordOrder::kHighFirst : WordOrder::kLowFirst;
    m.byte_order = b == 0 ? ByteOrder::kBig : ByteOrder::kLittle;
  }
  CDPR_ASSIGN_OR_RETURN(m.scale, value["scale"].number(Sign::kNonZero, "metres per unit"));
  CDPR_RETURN_IF_ERROR(value.optional("offset", m.offset, Sign::kAny, "m"));

  CDPR_ASSIGN_OR_RETURN(const YamlField range, root.required("range"));
  CDPR_RETURN_IF_ERROR(range.expect_map());
  CDPR_RETURN_IF_ERROR(range.check_keys({"min", "max"}));
  CDPR_ASSIGN_OR_RETURN(m.min_m, range["min"].number(Sign::kAny, "m"));
  CDPR_ASSIGN_OR_RETURN(m.max_m, range["max"].number(Sign::kAny, "m"));
  if (!(m.min_m < m.max_m)) return range.error("min must be below max (metres)");

  CDPR_RETURN_IF_ERROR(read_raw_list(root["no_target"], m.no_target_raw));
  CDPR_RETURN_IF_ERROR(read_raw_list(root["error"], m.error_raw));

  if (const YamlField q = root["quality"]; q.present()) {
    CDPR_RETURN_IF_ERROR(q.expect_map());
    CDPR_RETURN_IF_ERROR(q.check_keys({"register", "mask", "ok", "no_target"}));
    QualityRegister qr;
    CDPR_ASSIGN_OR_RETURN(const std::int64_t address, q["register"].integer(base, max_addr));
    qr.address = static_cast<std::uint16_t>(address);
    qr.mask = 0xFFFF;
    CDPR_RETURN_IF_ERROR(q.optional("mask", qr.mask, 1, 0xFFFF));
    CDPR_ASSIGN_OR_RETURN(const YamlField ok,
                          q.required("ok", "list the values of a good reading"));
    CDPR_RETURN_IF_ERROR(read_u16_list(ok, qr.ok_values));
    if (qr.ok_values.empty()) return ok.error("must not be empty");
    CDPR_RETURN_IF_ERROR(read_u16_list(q["no_target"], qr.no_target_values));
    m.quality = qr;
  }

  if (const YamlField t = root["trigger"]; t.present()) {
    CDPR_RETURN_IF_ERROR(t.expect_map());
    CDPR_RETURN_IF_ERROR(t.check_keys({"register", "value", "settle"}));
    TriggerWrite tw;
    CDPR_ASSIGN_OR_RETURN(const std::int64_t address, t["register"].integer(base, max_addr));
    tw.address = static_cast<std::uint16_t>(address);
    CDPR_ASSIGN_OR_RETURN(const std::int64_t v, t["value"].integer(0, 0xFFFF));
    tw.value = static_cast<std::uint16_t>(v);
    CDPR_RETURN_IF_ERROR(t.optional("settle", tw.settle_s, Sign::kAny, "s"));
    if (!(tw.settle_s >= 0.0 && tw.settle_s <= 1.0)) {
      return t["settle"].error("must be 0..1 s");
    }
    m.trigger = tw;
  }

  if (const YamlField r = root["read"]; r.present()) {
    CDPR_RETURN_IF_ERROR(r.expect_map());
    CDPR_RETURN_IF_ERROR(r.check_keys({"start", "count"}));
    CDPR_ASSIGN_OR_RETURN(const std::int64_t start, r["start"].integer(base, max_addr));
    m.read_start = static_cast<std::uint16_t>(start);
    CDPR_ASSIGN_OR_RETURN(const std::int64_t count, r["count"].integer(1, 125));
    m.read_count = static_cast<std::uint16_t>(count);
    if (m.address < *m.read_start ||
        m.address + register_count(m.type) > *m.read_start + *m.read_count) {
      return r.error("the block must contain value.register and its registers");
    }
  }

  Status s = m.validate();
  if (!s.ok()) return with_context(root.file() + ": ", s);
  return Status::success();
}

}  // namespace detail

Result<RegisterMap> parse_register_map(std::string_view yaml_text, std::string_view file) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::parse(yaml_text, file));
  RegisterMap m;
  CDPR_RETURN_IF_ERROR(detail::parse_register_map_node(doc.root(), m));
  return m;
}

Result<RegisterMap> load_register_map(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::load(path, "register map"));
  RegisterMap m;
  CDPR_RETURN_IF_ERROR(detail::parse_register_map_node(doc.root(), m));
  return m;
}

}  // namespace cdpr::modbus
