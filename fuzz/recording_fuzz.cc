// The recording CSV reader (recording::parse_recording) on arbitrary text: never crashes, and a
// recording it accepts formats to text that it reads back into the same text.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "cdpr/recording/recording.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto rec = cdpr::recording::parse_recording(text, "fuzz.csv");
  if (!rec.ok()) {
    CDPR_FUZZ_CHECK(!rec.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  auto formatted = cdpr::recording::format_recording(*rec);
  if (!formatted.ok()) return 0;  // a refusal to write is a value, not a crash
  auto again = cdpr::recording::parse_recording(*formatted, "formatted.csv");
  CDPR_FUZZ_CHECK(again.ok(), "a formatted recording reads back");
  auto formatted_again = cdpr::recording::format_recording(*again);
  CDPR_FUZZ_CHECK(formatted_again.ok() && *formatted_again == *formatted, "format/read is stable");
  return 0;
}
