// Path files (docs/motion.md "Path files"): read with the bounds of a file a client names, then
// parsed by the path program reader (cdpr/calibration/path_program.hpp).
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/path.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// Reads and parses a path file whose program starts at `start`. Only a regular file of at most
// kMaxPathFileBytes is read (never a blocking open: a FIFO is refused): kNotFound (cannot open),
// kInvalidArgument (not a regular file), kOutOfRange (too large), kIoError, each naming the
// file; kParseError "<file>:<line>: <word>: <reason>" on the first bad line.
Result<std::vector<PathSegment>> load_path_file(const std::string& path, const Pose& start);

}  // namespace cdpr
