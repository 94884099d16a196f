// The path file reader (parse_path_program) and the path planner on arbitrary text: never crash;
// a refusal names its reason, and a path it plans samples to finite poses.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "cdpr/calibration/path_program.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto segments = cdpr::parse_path_program(text, "fuzz.path", cdpr::Pose{});
  if (!segments.ok()) {
    CDPR_FUZZ_CHECK(!segments.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  auto path = cdpr::Path::plan(cdpr::Pose{}, *segments, cdpr::PathLimits{}, nullptr, "fuzz.path");
  if (!path.ok()) {
    CDPR_FUZZ_CHECK(!path.status().message().empty(), "a refusal names its reason");
    return 0;
  }
  for (int k = 0; k <= 16; ++k) {
    cdpr::Pose p;
    path->sample(path->duration() * k / 16.0, p);
    CDPR_FUZZ_CHECK(p.position.allFinite() && p.rpy.allFinite(), "samples are finite");
  }
  return 0;
}
