// Service notifications to systemd (Type=notify in cdprd.service), over libsystemd's sd_notify.
//
//   cdpr::controller::SystemdNotifier notify;
//   notify.status("configuring the CAN bus");        // while starting
//   notify.ready("holding, 8 drives, geometry v3");    // READY=1 + STATUS=
//   if (auto wd = notify.watchdog_interval()) ...    // WatchdogSec= of the unit, or nullopt
//   notify.watchdog();                                // WATCHDOG=1, every *wd / 2
//   notify.stopping();                                // STOPPING=1 on shutdown
//
// Without NOTIFY_SOCKET in the environment (started by hand, or in a test) every call is a no-op
// that returns Ok. The calls send one datagram each; they are for the daemon's non-RT threads
// (never the RT loop). Feed the watchdog only while the RT loop is alive: call watchdog() only
// after checking that RtLoop::cycles() advanced since the previous call, so a stuck loop gets
// the service restarted (Restart=on-failure).
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "cdpr/status.hpp"

namespace cdpr::controller {

class SystemdNotifier {
 public:
  // True when NOTIFY_SOCKET is set (the process runs under a service manager that listens).
  static bool enabled();

  // "READY=1\nSTATUS=<status>" (STATUS left out when status is empty).
  Status ready(std::string_view status = {});
  // "STATUS=<text>": one line shown by `systemctl status cdprd`.
  Status status(std::string_view text);
  // "WATCHDOG=1".
  Status watchdog();
  // "STOPPING=1" (optionally with a STATUS).
  Status stopping(std::string_view status = {});
  // "EXTEND_TIMEOUT_USEC=<us>": more time for a long start-up or shutdown step.
  Status extend_timeout(std::chrono::microseconds more);

  // The watchdog interval systemd expects (WATCHDOG_USEC for this process), or nullopt when the
  // unit has no watchdog. Feed it at least twice per interval.
  static std::optional<std::chrono::microseconds> watchdog_interval();

  // Sends an assignment list as is ("A=1\nB=2"). Error: the message could not be sent
  // (message names the errno).
  static Status send(const std::string& state);

 private:
  // STATUS= must be one line: newlines become spaces.
  static std::string one_line(std::string_view text);
};

// Feeds the watchdog only while a progress counter advances (RtLoop::cycles()): a loop that
// stopped cycling stops the feeding, and systemd restarts the service after WatchdogSec=.
//
//   WatchdogFeeder feeder(notifier);
//   every watchdog_interval() / 2 on a non-RT thread: feeder.feed_if_advanced(loop.cycles());
class WatchdogFeeder {
 public:
  explicit WatchdogFeeder(SystemdNotifier& notifier) : notifier_(notifier) {}
  // Sends WATCHDOG=1 when `progress` is larger than at the previous call (and than 0 at the
  // first). Returns whether it was sent; an error when sending failed.
  Result<bool> feed_if_advanced(std::uint64_t progress);
  // Calls in a row that found no progress.
  std::uint64_t stalled_checks() const { return stalled_; }

 private:
  SystemdNotifier& notifier_;
  std::uint64_t last_ = 0;
  std::uint64_t stalled_ = 0;
};

}  // namespace cdpr::controller
