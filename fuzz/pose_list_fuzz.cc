// The pose list reader (recording::parse_pose_list) on arbitrary text: never crashes, and a list
// it accepts formats to text that it reads back into the same text.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "cdpr/recording/recording.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto list = cdpr::recording::parse_pose_list(text, "fuzz.csv");
  if (!list.ok()) {
    CDPR_FUZZ_CHECK(!list.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  auto formatted = cdpr::recording::format_pose_list(*list);
  if (!formatted.ok()) return 0;
  auto again = cdpr::recording::parse_pose_list(*formatted, "formatted.csv");
  CDPR_FUZZ_CHECK(again.ok(), "a formatted pose list reads back");
  auto formatted_again = cdpr::recording::format_pose_list(*again);
  CDPR_FUZZ_CHECK(formatted_again.ok() && *formatted_again == *formatted, "format/read is stable");
  return 0;
}
