#include "cdpr/io/bounded_read.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace cdpr::io {

const char* file_type_name(unsigned mode) {
  switch (mode & S_IFMT) {
    case S_IFREG:
      return "a regular file";
    case S_IFDIR:
      return "a directory";
    case S_IFCHR:
      return "a character device";
    case S_IFBLK:
      return "a block device";
    case S_IFIFO:
      return "a FIFO";
    case S_IFSOCK:
      return "a socket";
    default:
      return "not a regular file";
  }
}

Result<std::string> read_regular_file(const std::string& path, std::size_t max_bytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) {
    return Status::error(errno == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIoError,
                         "cannot open %s: %s", path.c_str(), std::strerror(errno));
  }
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat sb {};
  if (::fstat(fd, &sb) != 0) {
    return Status::error(ErrorCode::kIoError, "cannot stat %s: %s", path.c_str(),
                         std::strerror(errno));
  }
  if (!S_ISREG(sb.st_mode)) {
    return Status::error(ErrorCode::kInvalidArgument, "%s is %s, not a regular file", path.c_str(),
                         file_type_name(sb.st_mode));
  }
  const auto too_large = [&](unsigned long long size) {
    return Status::error(ErrorCode::kOutOfRange,
                         "%s is too large: %llu bytes, more than the %zu allowed", path.c_str(),
                         size, max_bytes);
  };
  if (static_cast<unsigned long long>(sb.st_size) > max_bytes) {
    return too_large(static_cast<unsigned long long>(sb.st_size));
  }
  std::string out(static_cast<std::size_t>(sb.st_size), '\0');
  std::size_t got = 0;
  for (;;) {
    if (got == out.size()) {
      if (out.size() > max_bytes) return too_large(out.size());
      out.resize(out.size() + 4096);  // it may have grown since fstat
    }
    const ssize_t n = ::read(fd, out.data() + got, out.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      return Status::error(ErrorCode::kIoError, "cannot read %s: %s", path.c_str(),
                           std::strerror(errno));
    }
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  if (got > max_bytes) return too_large(got);
  out.resize(got);
  return out;
}

}  // namespace cdpr::io
