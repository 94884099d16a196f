#include "cdpr/config/path_file.hpp"

#include "cdpr/calibration/path_program.hpp"
#include "cdpr/io/bounded_read.hpp"

namespace cdpr {

Result<std::vector<PathSegment>> load_path_file(const std::string& path, const Pose& start) {
  auto text = io::read_regular_file(path, kMaxPathFileBytes);
  if (!text.ok()) return text.status();
  return parse_path_program(*text, path, start);
}

}  // namespace cdpr
