#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "cdpr/modbus/register_map.hpp"

namespace cdpr::modbus {
namespace {

constexpr const char* kGood = R"(name: t
source: "unit test"
table: input
address_base: 1
value:
  register: 3
  type: f32
  order: CDAB
  scale: 0.001
  offset: -0.01
range: {min: 0.0, max: 2.0}
no_target: [0xFFFF, -1.5]
error: [7]
quality: {register: 1, mask: 0x0F, ok: [0, 1], no_target: [2]}
trigger: {register: 10, value: 0x55, settle: 0.002}
read: {start: 1, count: 4}
)";

// Replaces the first occurrence of `from` in kGood.
std::string good_with(const std::string& from, const std::string& to) {
  std::string s = kGood;
  const auto pos = s.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  if (pos != std::string::npos) s.replace(pos, from.size(), to);
  return s;
}

void expect_error(const std::string& yaml, const std::string& needle1, const std::string& needle2) {
  const Result<RegisterMap> r = parse_register_map(yaml, "maps/x.yaml");
  ASSERT_FALSE(r.ok()) << "expected an error containing " << needle1;
  const std::string msg(r.status().message());
  EXPECT_NE(msg.find("maps/x.yaml"), std::string::npos) << msg;
  EXPECT_NE(msg.find(needle1), std::string::npos) << msg;
  EXPECT_NE(msg.find(needle2), std::string::npos) << msg;
}

TEST(RegisterMapYaml, ParsesEveryField) {
  const Result<RegisterMap> r = parse_register_map(kGood, "good.yaml");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  const RegisterMap& m = *r;
  EXPECT_EQ(m.name, "t");
  EXPECT_EQ(m.source, "unit test");
  EXPECT_EQ(m.table, RegisterTable::kInput);
  EXPECT_EQ(m.address_base, 1);
  EXPECT_EQ(m.address, 3);
  EXPECT_EQ(m.pdu(m.address), 2);
  EXPECT_EQ(m.type, ValueType::kF32);
  EXPECT_EQ(m.word_order, WordOrder::kLowFirst);
  EXPECT_EQ(m.byte_order, ByteOrder::kBig);
  EXPECT_DOUBLE_EQ(m.scale, 0.001);
  EXPECT_DOUBLE_EQ(m.offset, -0.01);
  EXPECT_DOUBLE_EQ(m.max_m, 2.0);
  ASSERT_EQ(m.no_target_raw.size(), 2u);
  EXPECT_EQ(m.no_target_raw[0], 65535.0);
  EXPECT_EQ(m.no_target_raw[1], -1.5);
  ASSERT_EQ(m.error_raw.size(), 1u);
  ASSERT_TRUE(m.quality.has_value());
  EXPECT_EQ(m.quality->address, 1);
  EXPECT_EQ(m.quality->mask, 0x0F);
  EXPECT_EQ(m.quality->ok_values.size(), 2u);
  ASSERT_TRUE(m.trigger.has_value());
  EXPECT_EQ(m.trigger->value, 0x55);
  EXPECT_DOUBLE_EQ(m.trigger->settle_s, 0.002);
  EXPECT_EQ(m.block_start(), 1);
  EXPECT_EQ(m.block_count(), 4);
  EXPECT_TRUE(m.quality_in_block());
}

TEST(RegisterMapYaml, SeparateWordAndByteOrder) {
  const Result<RegisterMap> r = parse_register_map(
      good_with("order: CDAB", "word_order: low_first\n  byte_order: little"), "x.yaml");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(order_name(r->word_order, r->byte_order), "DCBA");
}

TEST(RegisterMapYaml, ErrorsNameFileLineAndField) {
  // line 7 is "  type: f32"
  expect_error(good_with("type: f32", "type: f64"), "x.yaml:7:", "value.type");
  expect_error(good_with("type: f32", "type: f64"), "f64", "u16, i16, u32, i32, f32");
  expect_error(good_with("  register: 3\n", ""), "value.register", "missing");
  expect_error(good_with("scale: 0.001", "scael: 0.001"), "value.scael", "unknown field");
  expect_error(good_with("table: input", "table: coils"), "x.yaml:3:", "table");
  expect_error(good_with("order: CDAB", "order: CDAB\n  word_order: high_first"), "value.order",
               "not both");
  expect_error(good_with("order: CDAB", "order: ACBD"), "value.order", "ACBD");
  expect_error(good_with("address_base: 1", "address_base: 2"), "address_base", "0..1");
  expect_error(good_with("register: 3", "register: 0"), "value.register", "outside");
  expect_error(good_with("register: 3", "register: 70000"), "value.register", "outside");
  expect_error(good_with("register: 3", "register: three"), "value.register", "not an integer");
  expect_error(good_with("scale: 0.001", "scale: 0"), "value.scale", "non-zero");
  expect_error(good_with("range: {min: 0.0, max: 2.0}", "range: {min: 2.0, max: 1.0}"), "range",
               "below max");
  expect_error(good_with("{min: 0.0, max: 2.0}", "{min: 0.0}"), "range.max", "missing");
  expect_error(good_with("no_target: [0xFFFF, -1.5]", "no_target: 5"), "no_target", "list");
  expect_error(good_with("ok: [0, 1]", "ok: []"), "quality.ok", "empty");
  expect_error(good_with("ok: [0, 1]", "ok: [70000]"), "quality.ok[0]", "outside");
  expect_error(good_with("{start: 1, count: 4}", "{start: 1, count: 2}"), "read", "value.register");
  expect_error(good_with("{start: 1, count: 4}", "{start: 1, count: 200}"), "read.count",
               "outside");
  expect_error(good_with("settle: 0.002", "settle: 5"), "trigger.settle", "0..1");
  expect_error(good_with("name: t\n", ""), "name", "missing");
  expect_error("value: [1, 2", "x.yaml:", "YAML syntax");
  expect_error("- just\n- a list\n", "top level", "mapping");
}

TEST(RegisterMapYaml, MissingFileIsNotFound) {
  const Result<RegisterMap> r = load_register_map("/nonexistent/dir/laser.yaml");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kNotFound);
  EXPECT_NE(r.status().message().find("/nonexistent/dir/laser.yaml"), std::string_view::npos);
}

TEST(RegisterMapYaml, ShippedMapsLoadAndSayWhatTheyRestOn) {
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(CDPR_LASER_MAP_DIR)) {
    if (e.path().extension() != ".yaml") continue;
    const Result<RegisterMap> r = load_register_map(e.path().string());
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    EXPECT_FALSE(r->source.empty()) << e.path();
    EXPECT_TRUE(r->validate().ok()) << e.path();
    ++n;
  }
  EXPECT_GE(n, 3);
  const Result<RegisterMap> baumer =
      load_register_map(std::string(CDPR_LASER_MAP_DIR) + "/baumer-om20-om30.yaml");
  ASSERT_TRUE(baumer.ok()) << baumer.status().to_string();
  EXPECT_EQ(baumer->type, ValueType::kF32);
  EXPECT_EQ(order_name(baumer->word_order, baumer->byte_order), "CDAB");
  EXPECT_EQ(baumer->table, RegisterTable::kInput);
  // The manual's example registers decode to 69.743 mm through the shipped map.
  std::array<std::uint16_t, 13> block{};
  block[2] = 0x7C37;
  block[3] = 0x428B;
  const Interpretation in = interpret(*baumer, block);
  EXPECT_EQ(in.status, ReadingStatus::kOk) << in.detail.to_string();
  EXPECT_NEAR(in.distance_m, 0.069743, 5e-7);
}

}  // namespace
}  // namespace cdpr::modbus
