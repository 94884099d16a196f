// Reading a file that nobody vouches for (a path a client names, a file in a directory others
// may write): regular files only, at most `max_bytes`, and never a blocking open.
//
//   CDPR_ASSIGN_OR_RETURN(std::string csv, io::read_regular_file(path, 64 * 1024));
//
// The file is opened non-blocking (a FIFO does not wait for a writer), then refused unless it is
// a regular file ("/dev/zero is a character device, not a regular file"), refused when larger
// than `max_bytes` (by its size, before reading; and if it grew while read), and read in full.
// Errors name the path: kNotFound (cannot open), kInvalidArgument (not a regular file),
// kOutOfRange (too large), kIoError (read failed). Not for the RT path.
#pragma once

#include <cstddef>
#include <string>

#include "cdpr/status.hpp"

namespace cdpr::io {

Result<std::string> read_regular_file(const std::string& path, std::size_t max_bytes);

// "a FIFO", "a character device", "a directory", ... for a stat mode (messages).
const char* file_type_name(unsigned mode);

}  // namespace cdpr::io
