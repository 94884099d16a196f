// The PDO layout compiler and decoder (canopen::PdoLayout) on arbitrary mappings and frames:
// compile refuses what does not fit in 8 bytes; decode takes exactly the frames at least as long
// as the mapping, and then each variable holds its bytes (sign-extended for signed types), so
// that encoding the image again gives the same bytes when no object is mapped twice.
#include <fuzzer/FuzzedDataProvider.h>

#include <cstddef>
#include <cstdint>
#include <set>

#include "cdpr/canopen/pdo.hpp"
#include "fuzz_util.hpp"

namespace co = cdpr::canopen;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider in(data, size);
  co::PdoConfig config;
  config.direction = in.ConsumeBool() ? co::PdoDirection::kTpdo : co::PdoDirection::kRpdo;
  config.number = in.ConsumeIntegralInRange<int>(0, 600);
  config.cob_id = in.ConsumeBool() ? 0 : in.ConsumeIntegral<std::uint32_t>();
  const int entries = in.ConsumeIntegralInRange<int>(0, 10);
  std::set<std::uint32_t> objects;
  bool distinct = true;
  for (int i = 0; i < entries; ++i) {
    co::PdoEntry e;
    e.object.index = in.ConsumeIntegral<std::uint16_t>() % 4;  // few objects: some repeat
    e.object.sub = in.ConsumeIntegral<std::uint8_t>() % 2;
    e.type = static_cast<co::DataType>(in.ConsumeIntegralInRange<int>(0, 5));
    distinct = objects.insert(e.object.key()).second && distinct;
    config.entries.push_back(e);
  }
  const co::NodeId node = in.ConsumeIntegralInRange<co::NodeId>(1, co::kMaxNodeId);
  co::ProcessImage image;
  auto layout = co::PdoLayout::compile(config, node, image);
  const bool fits = config.entries.size() <= 8 && config.byte_size() <= 8;
  if (!layout.ok()) {
    CDPR_FUZZ_CHECK(!layout.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  CDPR_FUZZ_CHECK(fits, "a compiled layout fits in one frame");
  CDPR_FUZZ_CHECK(layout->dlc() == config.byte_size(), "dlc is the mapping's size");
  while (in.remaining_bytes() > 0) {
    cdpr::can::Frame f;
    f.id = layout->cob_id() & cdpr::can::kMaxStandardId;
    f.dlc = in.ConsumeIntegralInRange<std::uint8_t>(0, cdpr::can::kMaxDlc);
    for (auto& b : f.data) b = in.ConsumeIntegral<std::uint8_t>();
    const bool decoded = layout->decode(f, image);
    CDPR_FUZZ_CHECK(decoded == (f.dlc >= layout->dlc()), "decodes exactly the long frames");
    if (!decoded) continue;
    // An object mapped twice shares one variable: the last field wins, so the ranges and the
    // round trip are only checked when every object is mapped once.
    if (!distinct) continue;
    for (const auto& field : layout->fields()) {
      const std::int64_t v = image.get(field.slot);
      if (field.is_signed) {
        const std::int64_t half = std::int64_t{1} << (8 * field.size - 1);
        CDPR_FUZZ_CHECK(v >= -half && v < half, "a signed value is in its type's range");
      } else {
        CDPR_FUZZ_CHECK(v >= 0 && v < (std::int64_t{1} << (8 * field.size)),
                        "an unsigned value is in its type's range");
      }
    }
    cdpr::can::Frame out;
    layout->encode(image, out);
    CDPR_FUZZ_CHECK(out.dlc == layout->dlc(), "encode writes the mapping's size");
    for (std::size_t i = 0; i < layout->dlc(); ++i) {
      CDPR_FUZZ_CHECK(out.data[i] == f.data[i], "decode then encode gives the same bytes");
    }
  }
  return 0;
}
