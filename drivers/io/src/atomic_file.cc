#include "cdpr/io/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <utility>

#include "cdpr/io/append_only_file.hpp"

namespace cdpr::io {
namespace {

Status os_error(int err, const char* what, const std::string& path) {
  return Status::error(err == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIoError,
                       "cannot %s %s: %s", what, path.c_str(), std::strerror(err));
}

// The directory of `path` ("." for a bare file name).
std::string directory_of(const std::string& path) {
  const std::string dir = std::filesystem::path(path).parent_path().string();
  return dir.empty() ? std::string(".") : dir;
}

// ".<name>.tmp-<pid>-<n>" beside the target.
std::string temp_name(const std::string& path) {
  static std::atomic<unsigned> counter{0};
  const std::filesystem::path p(path);
  const std::string name = "." + p.filename().string() + ".tmp-" + std::to_string(::getpid()) +
                           "-" + std::to_string(counter.fetch_add(1));
  return (p.parent_path() / name).string();
}

bool all_digits(std::string_view s) {
  if (s.empty() || s.size() > 18) return false;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
  }
  return true;
}

Status write_all(int fd, std::string_view contents, const std::string& temp) {
  const char* p = contents.data();
  std::size_t left = contents.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      return os_error(errno, "write", temp);
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  return Status::success();
}

Status fsync_directory(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return os_error(errno, "open the directory", dir);
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  // Some file systems cannot sync a directory (EINVAL); the rename itself is still atomic.
  if (rc != 0 && err != EINVAL) return os_error(err, "flush the directory", dir);
  return Status::success();
}

// Writes and flushes a new temporary beside `path`; returns its name.
Result<std::string> write_temporary(const std::string& path, std::string_view contents) {
  if (path.empty())
    return Status(ErrorCode::kInvalidArgument, "cannot write a file without a name");
  std::string temp;
  int fd = -1;
  for (int attempt = 0; attempt < 100 && fd < 0; ++attempt) {
    temp = temp_name(path);
    fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd < 0 && errno != EEXIST) return os_error(errno, "create", path);
  }
  if (fd < 0) return os_error(EEXIST, "create a temporary file for", path);
  Status s = write_all(fd, contents, temp);
  if (s.ok() && ::fsync(fd) != 0) s = os_error(errno, "flush", temp);
  if (::close(fd) != 0 && s.ok()) s = os_error(errno, "close", temp);
  if (!s.ok()) {
    ::unlink(temp.c_str());
    return s;
  }
  return temp;
}

}  // namespace

namespace {
std::atomic<BeforeRenameHook> g_before_rename{nullptr};
}  // namespace

void set_before_rename_hook(BeforeRenameHook hook) {
  g_before_rename.store(hook);
}

Status write_file_atomically(const std::string& path, std::string_view contents) {
  AtomicFileSet one;
  CDPR_RETURN_IF_ERROR(one.stage(path, contents));
  return one.commit();
}

AtomicFileSet::~AtomicFileSet() {
  abandon();
}

Status AtomicFileSet::stage(const std::string& path, std::string_view contents) {
  Result<std::string> temp = write_temporary(path, contents);
  if (!temp.ok()) {
    abandon();
    return temp.status();
  }
  files_.push_back({path, std::move(*temp)});
  return Status::success();
}

Status AtomicFileSet::commit() {
  std::vector<std::string> directories;
  for (std::size_t k = 0; k < files_.size(); ++k) {
    if (BeforeRenameHook hook = g_before_rename.load(); hook != nullptr) hook(files_[k].target);
    if (::rename(files_[k].temp.c_str(), files_[k].target.c_str()) != 0) {
      const Status s = os_error(errno, "replace", files_[k].target);
      files_.erase(files_.begin(), files_.begin() + static_cast<std::ptrdiff_t>(k));
      abandon();
      return s;
    }
    const std::string dir = directory_of(files_[k].target);
    bool seen = false;
    for (const std::string& d : directories) seen = seen || d == dir;
    if (!seen) directories.push_back(dir);
  }
  files_.clear();
  for (const std::string& dir : directories) CDPR_RETURN_IF_ERROR(fsync_directory(dir));
  return Status::success();
}

void AtomicFileSet::abandon() {
  for (const Staged& f : files_) ::unlink(f.temp.c_str());
  files_.clear();
}

bool is_temporary_name(std::string_view file_name, int* writer_pid) {
  // "." + name + ".tmp-" + pid + "-" + n, with a non-empty name.
  if (file_name.size() < 2 || file_name.front() != '.') return false;
  const std::size_t tag = file_name.rfind(".tmp-");
  if (tag == std::string_view::npos || tag < 2) return false;
  const std::string_view numbers = file_name.substr(tag + 5);
  const std::size_t dash = numbers.find('-');
  if (dash == std::string_view::npos) return false;
  const std::string_view pid = numbers.substr(0, dash), n = numbers.substr(dash + 1);
  if (!all_digits(pid) || !all_digits(n) || pid.size() > 9) return false;
  if (writer_pid != nullptr) {
    int v = 0;
    for (char c : pid) v = v * 10 + (c - '0');
    *writer_pid = v;
  }
  return true;
}

// ---- AppendOnlyFile --------------------------------------------------------------------------

AppendOnlyFile::~AppendOnlyFile() {
  close();
}

AppendOnlyFile::AppendOnlyFile(AppendOnlyFile&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)), path_(std::move(other.path_)) {}

AppendOnlyFile& AppendOnlyFile::operator=(AppendOnlyFile&& other) noexcept {
  if (this != &other) {
    close();
    fd_ = std::exchange(other.fd_, -1);
    path_ = std::move(other.path_);
  }
  return *this;
}

Status AppendOnlyFile::open(const std::string& path, bool truncate) {
  close();
  const int flags = O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC | (truncate ? O_TRUNC : 0);
  fd_ = ::open(path.c_str(), flags, 0644);
  if (fd_ < 0) return os_error(errno, "open", path);
  path_ = path;
  return fsync_directory(directory_of(path));
}

Status AppendOnlyFile::append(std::string_view record) {
  if (fd_ < 0) return Status(ErrorCode::kFailedPrecondition, "append to a closed file");
  if (Status s = write_all(fd_, record, path_); !s.ok()) return s;
  if (::fdatasync(fd_) != 0) return os_error(errno, "flush", path_);
  return Status::success();
}

void AppendOnlyFile::close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

}  // namespace cdpr::io
