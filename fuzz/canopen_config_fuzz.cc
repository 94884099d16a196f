// The CANopen network description (canopen::parse_config) on arbitrary text: never crashes, and
// what it accepts passes validate() (the checks the master relies on).
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "cdpr/canopen/config.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto config = cdpr::canopen::parse_config(text, "fuzz.yaml");
  if (!config.ok()) {
    CDPR_FUZZ_CHECK(!config.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  CDPR_FUZZ_CHECK(cdpr::canopen::validate(*config).ok(), "an accepted network validates");
  return 0;
}
