// The Modbus register decoding (modbus::decode_raw, modbus::interpret) on arbitrary register maps
// and answers. decode_raw of integer types must be undone exactly by encode_raw; interpret must
// never crash or read outside the block, and a reading it calls valid is a finite distance inside
// the map's range (anything else carries a reason).
#include <fuzzer/FuzzedDataProvider.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "cdpr/modbus/register_map.hpp"
#include "fuzz_util.hpp"

namespace mb = cdpr::modbus;

namespace {

double consume_double(FuzzedDataProvider& in) {
  // Mostly ordinary numbers, sometimes any bit pattern (NaN, infinities, denormals).
  if (in.ConsumeBool()) return in.ConsumeFloatingPoint<double>();
  return in.ConsumeFloatingPointInRange<double>(-1e4, 1e4);
}

std::vector<std::uint16_t> consume_u16s(FuzzedDataProvider& in, std::size_t max) {
  std::vector<std::uint16_t> v(in.ConsumeIntegralInRange<std::size_t>(0, max));
  for (auto& x : v) x = in.ConsumeIntegral<std::uint16_t>();
  return v;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider in(data, size);

  // decode_raw / encode_raw on every type and order.
  const auto type = static_cast<mb::ValueType>(in.ConsumeIntegralInRange<int>(0, 4));
  const auto words = in.ConsumeBool() ? mb::WordOrder::kLowFirst : mb::WordOrder::kHighFirst;
  const auto bytes = in.ConsumeBool() ? mb::ByteOrder::kLittle : mb::ByteOrder::kBig;
  const std::uint16_t regs[2] = {in.ConsumeIntegral<std::uint16_t>(),
                                 in.ConsumeIntegral<std::uint16_t>()};
  const double raw = mb::decode_raw(regs, type, words, bytes);
  if (type != mb::ValueType::kF32) {
    std::uint16_t back[2] = {0, 0};
    mb::encode_raw(raw, type, words, bytes, std::span<std::uint16_t>(back, 2));
    for (int i = 0; i < mb::register_count(type); ++i) {
      CDPR_FUZZ_CHECK(back[i] == regs[i], "encode_raw undoes decode_raw for integers");
    }
  }

  // A register map and an answer.
  mb::RegisterMap map;
  map.name = "fuzz";
  map.table = in.ConsumeBool() ? mb::RegisterTable::kHolding : mb::RegisterTable::kInput;
  map.address_base = in.ConsumeIntegralInRange<int>(-1, 2);
  map.address = in.ConsumeIntegral<std::uint16_t>();
  map.type = static_cast<mb::ValueType>(in.ConsumeIntegralInRange<int>(0, 4));
  map.word_order = in.ConsumeBool() ? mb::WordOrder::kLowFirst : mb::WordOrder::kHighFirst;
  map.byte_order = in.ConsumeBool() ? mb::ByteOrder::kLittle : mb::ByteOrder::kBig;
  map.scale = consume_double(in);
  map.offset = consume_double(in);
  map.min_m = consume_double(in);
  map.max_m = consume_double(in);
  for (int i = in.ConsumeIntegralInRange<int>(0, 3); i > 0; --i) {
    map.no_target_raw.push_back(consume_double(in));
  }
  for (int i = in.ConsumeIntegralInRange<int>(0, 3); i > 0; --i) {
    map.error_raw.push_back(consume_double(in));
  }
  if (in.ConsumeBool()) {
    mb::QualityRegister q;
    q.address = in.ConsumeIntegral<std::uint16_t>();
    q.mask = in.ConsumeIntegral<std::uint16_t>();
    q.ok_values = consume_u16s(in, 3);
    q.no_target_values = consume_u16s(in, 3);
    map.quality = q;
  }
  if (in.ConsumeBool()) map.read_start = in.ConsumeIntegral<std::uint16_t>();
  if (in.ConsumeBool()) map.read_count = in.ConsumeIntegral<std::uint16_t>();
  if (!map.validate().ok()) return 0;

  // The block as the sensor answered (usually the requested length; sometimes not).
  std::size_t n = map.block_count();
  if (in.ConsumeBool()) n = in.ConsumeIntegralInRange<std::size_t>(0, 130);
  std::vector<std::uint16_t> block(n);
  for (auto& r : block) r = in.ConsumeIntegral<std::uint16_t>();
  std::optional<std::uint16_t> quality;
  if (in.ConsumeBool()) quality = in.ConsumeIntegral<std::uint16_t>();
  const mb::Interpretation r = mb::interpret(map, block, quality);
  CDPR_FUZZ_CHECK(r.status != mb::ReadingStatus::kNone, "every answer gets a status");
  if (r.status == mb::ReadingStatus::kOk) {
    CDPR_FUZZ_CHECK(std::isfinite(r.distance_m), "a valid distance is finite");
    CDPR_FUZZ_CHECK(r.distance_m >= map.min_m && r.distance_m <= map.max_m,
                    "a valid distance is inside the range");
  } else {
    CDPR_FUZZ_CHECK(!r.detail.ok() && !r.detail.message().empty(),
                    "an invalid reading names its reason");
  }
  return 0;
}
