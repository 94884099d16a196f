#include "cdpr/can/can_bus.hpp"

namespace cdpr::can {

Status check_frame(const Frame& frame, std::string_view where) {
  const int wn = static_cast<int>(where.size());
  if (frame.dlc > kMaxDlc) {
    return Status::error(ErrorCode::kInvalidArgument, "%.*s: dlc %u > 8 (classic CAN)", wn,
                         where.data(), static_cast<unsigned>(frame.dlc));
  }
  if (frame.error) {
    if (frame.error_class == 0 || frame.error_class > error_class::kAll) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%.*s: error frame with invalid error class 0x%X", wn, where.data(),
                           static_cast<unsigned>(frame.error_class));
    }
    return Status::success();
  }
  const std::uint32_t max_id = frame.extended ? kMaxExtendedId : kMaxStandardId;
  if (frame.id > max_id) {
    return Status::error(ErrorCode::kInvalidArgument, "%.*s: %s id 0x%X exceeds 0x%X", wn,
                         where.data(), frame.extended ? "29-bit" : "11-bit",
                         static_cast<unsigned>(frame.id), static_cast<unsigned>(max_id));
  }
  return Status::success();
}

}  // namespace cdpr::can
