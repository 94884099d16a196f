#include "cdpr/controller/sd_notify.hpp"

#include <systemd/sd-daemon.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>

namespace cdpr::controller {

bool SystemdNotifier::enabled() {
  const char* s = std::getenv("NOTIFY_SOCKET");
  return s != nullptr && s[0] != '\0';
}

std::string SystemdNotifier::one_line(std::string_view text) {
  std::string s(text);
  for (char& c : s) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  return s;
}

Status SystemdNotifier::send(const std::string& state) {
  if (!enabled()) return Status::success();
  const int r = sd_notify(0, state.c_str());
  if (r < 0) {
    const char* socket = std::getenv("NOTIFY_SOCKET");
    const char* name = strerrorname_np(-r);
    return Status::error(ErrorCode::kIoError, "sd_notify to NOTIFY_SOCKET=%s failed: %s (%s)",
                         socket != nullptr ? socket : "", name != nullptr ? name : "?",
                         std::strerror(-r));
  }
  return Status::success();
}

Status SystemdNotifier::ready(std::string_view status) {
  std::string msg = "READY=1";
  if (!status.empty()) msg += "\nSTATUS=" + one_line(status);
  return send(msg);
}

Status SystemdNotifier::status(std::string_view text) {
  return send("STATUS=" + one_line(text));
}

Status SystemdNotifier::watchdog() {
  return send("WATCHDOG=1");
}

Status SystemdNotifier::stopping(std::string_view status) {
  std::string msg = "STOPPING=1";
  if (!status.empty()) msg += "\nSTATUS=" + one_line(status);
  return send(msg);
}

Status SystemdNotifier::extend_timeout(std::chrono::microseconds more) {
  return send("EXTEND_TIMEOUT_USEC=" + std::to_string(more.count() < 0 ? 0 : more.count()));
}

std::optional<std::chrono::microseconds> SystemdNotifier::watchdog_interval() {
  std::uint64_t usec = 0;
  if (sd_watchdog_enabled(0, &usec) > 0 && usec > 0) {
    return std::chrono::microseconds{static_cast<std::int64_t>(usec)};
  }
  return std::nullopt;
}

Result<bool> WatchdogFeeder::feed_if_advanced(std::uint64_t progress) {
  if (progress <= last_) {
    ++stalled_;
    return false;
  }
  last_ = progress;
  stalled_ = 0;
  if (Status st = notifier_.watchdog(); !st) return st;
  return true;
}

}  // namespace cdpr::controller
