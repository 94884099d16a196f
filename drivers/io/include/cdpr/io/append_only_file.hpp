// A file that grows by whole records, each made durable (fdatasync) before append() returns: a
// crash loses at most the record being written, which may then be left torn (part of it, without
// its end) at the end of the file. Its reader skips or cuts such a tail (the recording's rows:
// cdpr/recording/recording.hpp RecordingAppender; the state directory's history).
//
//   io::AppendOnlyFile f;
//   CDPR_RETURN_IF_ERROR(f.open("history.jsonl", /*truncate=*/false));
//   CDPR_RETURN_IF_ERROR(f.append("{...}\n"));
//
// Errors are kIoError (kNotFound for a missing directory) naming the path and the reason. Not for
// the RT path.
#pragma once

#include <string>
#include <string_view>

#include "cdpr/status.hpp"

namespace cdpr::io {

class AppendOnlyFile {
 public:
  AppendOnlyFile() = default;
  ~AppendOnlyFile();
  AppendOnlyFile(const AppendOnlyFile&) = delete;
  AppendOnlyFile& operator=(const AppendOnlyFile&) = delete;
  AppendOnlyFile(AppendOnlyFile&& other) noexcept;
  AppendOnlyFile& operator=(AppendOnlyFile&& other) noexcept;

  // Creates (or, with `truncate` false, continues) the file; the directory entry is made durable.
  Status open(const std::string& path, bool truncate);
  Status append(std::string_view record);
  void close();
  bool is_open() const { return fd_ >= 0; }
  const std::string& path() const { return path_; }

 private:
  int fd_ = -1;
  std::string path_;
};

}  // namespace cdpr::io
