#include "cdpr/modbus/register_map.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

namespace cdpr::modbus {
namespace {

// Registers as libmodbus hands them over, from the bytes in wire order.
std::vector<std::uint16_t> from_wire(const std::vector<std::uint8_t>& wire) {
  std::vector<std::uint16_t> regs;
  for (std::size_t i = 0; i + 1 < wire.size(); i += 2) {
    regs.push_back(static_cast<std::uint16_t>((wire[i] << 8) | wire[i + 1]));
  }
  return regs;
}

// Wire bytes of a 32-bit pattern in the named order: "ABCD" lists, for each wire position,
// which byte of the value (A = most significant) goes there.
std::vector<std::uint8_t> wire_of(std::uint32_t bits, const std::string& order) {
  const std::array<std::uint8_t, 4> value_bytes = {
      static_cast<std::uint8_t>(bits >> 24), static_cast<std::uint8_t>(bits >> 16),
      static_cast<std::uint8_t>(bits >> 8), static_cast<std::uint8_t>(bits)};
  std::vector<std::uint8_t> wire;
  for (char c : order) wire.push_back(value_bytes[static_cast<std::size_t>(c - 'A')]);
  return wire;
}

struct Order {
  const char* name;
  WordOrder words;
  ByteOrder bytes;
};
constexpr std::array<Order, 4> kOrders = {{{"ABCD", WordOrder::kHighFirst, ByteOrder::kBig},
                                           {"CDAB", WordOrder::kLowFirst, ByteOrder::kBig},
                                           {"BADC", WordOrder::kHighFirst, ByteOrder::kLittle},
                                           {"DCBA", WordOrder::kLowFirst, ByteOrder::kLittle}}};

std::uint32_t float_bits(float f) {
  std::uint32_t u = 0;
  std::memcpy(&u, &f, sizeof u);
  return u;
}

TEST(Decode, OrderNamesMatchWordAndByteOrder) {
  for (const Order& o : kOrders) EXPECT_EQ(order_name(o.words, o.bytes), o.name);
}

TEST(Decode, U32AllOrders) {
  const std::uint32_t v = 0x89ABCDEFu;
  for (const Order& o : kOrders) {
    const auto regs = from_wire(wire_of(v, o.name));
    EXPECT_EQ(decode_raw(regs, ValueType::kU32, o.words, o.bytes), 2309737967.0) << o.name;
  }
}

TEST(Decode, I32AllOrdersNegative) {
  const std::int32_t v = -123456;
  const auto bits = static_cast<std::uint32_t>(v);
  for (const Order& o : kOrders) {
    const auto regs = from_wire(wire_of(bits, o.name));
    EXPECT_EQ(decode_raw(regs, ValueType::kI32, o.words, o.bytes), -123456.0) << o.name;
  }
}

TEST(Decode, F32AllOrders) {
  for (float f : {1234.5f, -0.001f, 69.743f, 3.0e-7f}) {
    for (const Order& o : kOrders) {
      const auto regs = from_wire(wire_of(float_bits(f), o.name));
      EXPECT_EQ(decode_raw(regs, ValueType::kF32, o.words, o.bytes), static_cast<double>(f))
          << o.name << " " << f;
    }
  }
}

TEST(Decode, F32CdabExampleFromBaumerManual) {
  // OM20/OM30 manual: register 202 = 0x7C37, 203 = 0x428B, "evaluate as 42 8B 7C 37" = 69.743 mm.
  const std::vector<std::uint16_t> regs = {0x7C37, 0x428B};
  const double mm = decode_raw(regs, ValueType::kF32, WordOrder::kLowFirst, ByteOrder::kBig);
  EXPECT_NEAR(mm, 69.743, 5e-4);
  // The same registers read high word first give a different, wrong number.
  EXPECT_GT(
      std::fabs(decode_raw(regs, ValueType::kF32, WordOrder::kHighFirst, ByteOrder::kBig) - 69.743),
      1.0);
}

TEST(Decode, SixteenBitTypesAndByteOrder) {
  const std::vector<std::uint16_t> reg = from_wire({0xAB, 0xCD});
  EXPECT_EQ(decode_raw(reg, ValueType::kU16, WordOrder::kHighFirst, ByteOrder::kBig), 0xABCD);
  EXPECT_EQ(decode_raw(reg, ValueType::kU16, WordOrder::kHighFirst, ByteOrder::kLittle), 0xCDAB);
  const std::vector<std::uint16_t> neg = from_wire({0xFF, 0x38});  // -200 big endian
  EXPECT_EQ(decode_raw(neg, ValueType::kI16, WordOrder::kHighFirst, ByteOrder::kBig), -200.0);
  const std::vector<std::uint16_t> neg_le = from_wire({0x38, 0xFF});
  EXPECT_EQ(decode_raw(neg_le, ValueType::kI16, WordOrder::kLowFirst, ByteOrder::kLittle), -200.0);
  // Word order does not matter for one register.
  EXPECT_EQ(decode_raw(reg, ValueType::kU16, WordOrder::kLowFirst, ByteOrder::kBig), 0xABCD);
}

TEST(Decode, EncodeIsTheInverse) {
  const std::array<std::pair<ValueType, double>, 6> cases = {{{ValueType::kU16, 65535.0},
                                                              {ValueType::kI16, -32768.0},
                                                              {ValueType::kU32, 4294967295.0},
                                                              {ValueType::kI32, -2147483648.0},
                                                              {ValueType::kF32, -12.25},
                                                              {ValueType::kF32, 1.0e6}}};
  for (const auto& [type, raw] : cases) {
    for (const Order& o : kOrders) {
      std::array<std::uint16_t, 2> regs{};
      encode_raw(raw, type, o.words, o.bytes, regs);
      EXPECT_EQ(decode_raw(regs, type, o.words, o.bytes), raw) << to_string(type) << " " << o.name;
    }
  }
  // encode writes the documented wire order.
  std::array<std::uint16_t, 2> regs{};
  encode_raw(2309737967.0, ValueType::kU32, WordOrder::kLowFirst, ByteOrder::kBig, regs);
  EXPECT_EQ(std::vector<std::uint16_t>(regs.begin(), regs.end()),
            from_wire(wire_of(0x89ABCDEFu, "CDAB")));
}

RegisterMap u16_map() {
  RegisterMap m;
  m.name = "test";
  m.table = RegisterTable::kHolding;
  m.address = 10;
  m.type = ValueType::kU16;
  m.scale = 1e-4;  // 0.1 mm
  m.offset = 0.05;
  m.min_m = 0.1;
  m.max_m = 5.0;
  m.no_target_raw = {65535};
  m.error_raw = {65534};
  return m;
}

TEST(Interpret, ScaleAndOffsetGiveMetres) {
  const RegisterMap m = u16_map();
  const std::vector<std::uint16_t> block = {12345};
  const Interpretation in = interpret(m, block);
  EXPECT_EQ(in.status, ReadingStatus::kOk) << in.detail.to_string();
  EXPECT_NEAR(in.distance_m, 12345 * 1e-4 + 0.05, 1e-12);
  EXPECT_EQ(in.raw, 12345.0);
  EXPECT_TRUE(in.detail.ok());
}

TEST(Interpret, SentinelsNameTheValue) {
  const RegisterMap m = u16_map();
  const std::vector<std::uint16_t> no_target = {0xFFFF};
  Interpretation in = interpret(m, no_target);
  EXPECT_EQ(in.status, ReadingStatus::kNoTarget);
  EXPECT_NE(in.detail.message().find("65535"), std::string_view::npos) << in.detail.to_string();
  EXPECT_NE(in.detail.message().find("register 10"), std::string_view::npos);
  const std::vector<std::uint16_t> error = {0xFFFE};
  in = interpret(m, error);
  EXPECT_EQ(in.status, ReadingStatus::kSensorError);
  EXPECT_NE(in.detail.message().find("65534"), std::string_view::npos);
}

TEST(Interpret, RangeIsInclusiveAndChecked) {
  const RegisterMap m = u16_map();
  // 0.1 m = (0.1 - 0.05) / 1e-4 = 500 raw: on the limit, valid.
  EXPECT_EQ(interpret(m, std::vector<std::uint16_t>{500}).status, ReadingStatus::kOk);
  const Interpretation low = interpret(m, std::vector<std::uint16_t>{499});
  EXPECT_EQ(low.status, ReadingStatus::kOutOfRange);
  EXPECT_NEAR(low.distance_m, 0.0999, 1e-12);
  EXPECT_EQ(low.detail.code(), ErrorCode::kOutOfRange);
  RegisterMap neg = m;
  neg.type = ValueType::kI16;
  neg.no_target_raw.clear();
  neg.error_raw.clear();
  EXPECT_EQ(interpret(neg, std::vector<std::uint16_t>{0xFFFF}).status, ReadingStatus::kOutOfRange);
}

TEST(Interpret, FloatNanIsSensorErrorAndFloatSentinelsWork) {
  RegisterMap m;
  m.name = "f";
  m.type = ValueType::kF32;
  m.word_order = WordOrder::kLowFirst;
  m.scale = 1e-3;
  m.min_m = 0.0;
  m.max_m = 1.0;
  m.no_target_raw = {-1.0};
  std::array<std::uint16_t, 2> regs{};
  encode_raw(std::numeric_limits<double>::quiet_NaN(), m.type, m.word_order, m.byte_order, regs);
  EXPECT_EQ(interpret(m, regs).status, ReadingStatus::kSensorError);
  encode_raw(-1.0, m.type, m.word_order, m.byte_order, regs);
  EXPECT_EQ(interpret(m, regs).status, ReadingStatus::kNoTarget);
  encode_raw(250.5, m.type, m.word_order, m.byte_order, regs);
  const Interpretation in = interpret(m, regs);
  EXPECT_EQ(in.status, ReadingStatus::kOk);
  EXPECT_NEAR(in.distance_m, 0.2505, 1e-9);
}

TEST(Interpret, QualityRegisterInBlockAndSeparate) {
  RegisterMap m;
  m.name = "q";
  m.table = RegisterTable::kInput;
  m.address = 202;
  m.type = ValueType::kF32;
  m.word_order = WordOrder::kLowFirst;
  m.scale = 1e-3;
  m.min_m = 0.0;
  m.max_m = 1.0;
  m.quality = QualityRegister{200, 0x00FF, {0, 1}, {2}};
  // Quality two registers below the value: one block 200..203.
  EXPECT_EQ(m.block_start(), 200);
  EXPECT_EQ(m.block_count(), 4);
  EXPECT_TRUE(m.quality_in_block());
  std::array<std::uint16_t, 4> block{};
  encode_raw(120.0, m.type, m.word_order, m.byte_order, std::span(block).subspan(2));
  block[0] = 0x0101;  // masked to 1: weak but valid
  Interpretation in = interpret(m, block);
  EXPECT_EQ(in.status, ReadingStatus::kOk);
  ASSERT_TRUE(in.quality.has_value());
  EXPECT_EQ(*in.quality, 0x0101);
  block[0] = 2;
  EXPECT_EQ(interpret(m, block).status, ReadingStatus::kNoTarget);
  block[0] = 7;
  in = interpret(m, block);
  EXPECT_EQ(in.status, ReadingStatus::kSensorError);
  EXPECT_NE(in.detail.message().find("quality register 200"), std::string_view::npos);

  // Far away: read separately, passed in.
  m.quality->address = 500;
  EXPECT_FALSE(m.quality_in_block());
  EXPECT_EQ(m.block_start(), 202);
  EXPECT_EQ(m.block_count(), 2);
  EXPECT_EQ(interpret(m, std::span(block).subspan(2), std::uint16_t{2}).status,
            ReadingStatus::kNoTarget);
  EXPECT_EQ(interpret(m, std::span(block).subspan(2), std::uint16_t{0}).status, ReadingStatus::kOk);
}

TEST(Interpret, ShortAnswerIsAnErrorNotACrash) {
  RegisterMap m = u16_map();
  m.type = ValueType::kU32;
  EXPECT_EQ(interpret(m, std::vector<std::uint16_t>{1}).status, ReadingStatus::kCommError);
  EXPECT_EQ(interpret(m, std::vector<std::uint16_t>{}).status, ReadingStatus::kCommError);
}

// Found by fuzz/modbus_decode (input kept in fuzz/regressions/modbus_decode/): the value fits in
// a short answer but the quality register after it does not; it was read past the block's end.
TEST(Interpret, ShortAnswerWithoutTheQualityRegisterIsAnErrorNotAnOverread) {
  RegisterMap m = u16_map();
  m.address = 100;
  m.quality = QualityRegister{101, 0xFFFF, {0}, {1}};
  ASSERT_TRUE(m.validate().ok()) << m.validate().to_string();
  ASSERT_TRUE(m.quality_in_block());
  ASSERT_EQ(m.block_count(), 2);
  const std::vector<std::uint16_t> only_the_value{10000};
  const Interpretation in = interpret(m, only_the_value);
  EXPECT_EQ(in.status, ReadingStatus::kCommError);
  EXPECT_NE(in.detail.message().find("quality register"), std::string_view::npos)
      << in.detail.message();
  EXPECT_EQ(interpret(m, std::vector<std::uint16_t>{10000, 0}).status, ReadingStatus::kOk);
}

TEST(RegisterMapValidate, ExplicitBlockAndBase) {
  RegisterMap m = u16_map();
  m.address_base = 1;
  m.address = 1;
  EXPECT_TRUE(m.validate().ok());
  EXPECT_EQ(m.pdu(m.address), 0);
  m.address = 0;
  EXPECT_FALSE(m.validate().ok());
  m.address = 5;
  m.read_start = 1;
  m.read_count = 4;  // 1..4 does not hold register 5
  const Status s = m.validate();
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(s.message().find("not inside"), std::string_view::npos) << s.to_string();
  m.read_count = 5;
  EXPECT_TRUE(m.validate().ok());
  m.read_count = 126;
  EXPECT_FALSE(m.validate().ok());
  RegisterMap r = u16_map();
  r.min_m = 2.0;
  r.max_m = 1.0;
  EXPECT_FALSE(r.validate().ok());
  r = u16_map();
  r.scale = 0.0;
  EXPECT_FALSE(r.validate().ok());
}

TEST(RegisterMapValidate, ResolutionIsOneRawUnit) {
  RegisterMap m = u16_map();
  EXPECT_DOUBLE_EQ(m.resolution_m(), 1e-4);
  m.type = ValueType::kF32;
  EXPECT_EQ(m.resolution_m(), 0.0);
}

}  // namespace
}  // namespace cdpr::modbus
