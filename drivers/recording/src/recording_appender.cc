// RecordingAppender: a recording written row by row (recording.hpp).
#include <filesystem>
#include <system_error>

#include "cdpr/recording/recording.hpp"
#include "csv.hpp"

namespace cdpr::recording {

RecordingAppender::RecordingAppender(std::string path, Recording header)
    : file_path_(std::move(path)), recording_(std::move(header)) {
  recording_.poses.clear();
}

Status RecordingAppender::append(const RecordedPose& row) {
  if (!recording_.poses.empty() && row.index <= recording_.poses.back().index) {
    return Status::error(ErrorCode::kInvalidArgument, "pose index %lld does not increase",
                         static_cast<long long>(row.index));
  }
  CDPR_ASSIGN_OR_RETURN(std::string text, format_recording_row(recording_, row));
  if (!file_.is_open()) {
    CDPR_ASSIGN_OR_RETURN(const std::string head, format_recording_header(recording_));
    CDPR_RETURN_IF_ERROR(file_.open(file_path_, /*truncate=*/true));
    CDPR_RETURN_IF_ERROR(file_.append(head));
  }
  CDPR_RETURN_IF_ERROR(file_.append(text));
  recording_.poses.push_back(row);
  return Status::success();
}

Result<std::size_t> RecordingAppender::cut_torn_row(const std::string& path) {
  auto text = detail::read_file(path);
  if (!text.ok()) {
    if (text.status().code() == ErrorCode::kNotFound) return std::size_t{0};
    return text.status();
  }
  if (text->empty() || text->back() == '\n') return std::size_t{0};
  const std::size_t keep = text->rfind('\n') + 1;  // npos + 1 == 0: nothing whole
  std::error_code ec;
  std::filesystem::resize_file(path, keep, ec);
  if (ec) {
    return Status::error(ErrorCode::kIoError,
                         "%s: torn last row (%zu bytes) could not be cut off: %s", path.c_str(),
                         text->size() - keep, ec.message().c_str());
  }
  return text->size() - keep;
}

}  // namespace cdpr::recording
