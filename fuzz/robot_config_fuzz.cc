// The robot description loader (config::parse_robot_config) on arbitrary text. Besides "never
// crashes", whatever it accepts must survive save_robot_config: the saved text loads again and
// saves to the same text.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "cdpr/config/robot_config.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto model = cdpr::config::parse_robot_config(text, "fuzz.yaml");
  if (!model.ok()) {
    CDPR_FUZZ_CHECK(!model.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  const std::string saved = cdpr::config::save_robot_config(*model);
  auto again = cdpr::config::parse_robot_config(saved, "saved.yaml");
  CDPR_FUZZ_CHECK(again.ok(), "an accepted model saves to a file that loads");
  CDPR_FUZZ_CHECK(cdpr::config::save_robot_config(*again) == saved, "save/load is stable");
  return 0;
}
