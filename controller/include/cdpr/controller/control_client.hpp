// A client of the control socket (docs/control-protocol.md), used by cdprctl and by tests: one
// connection, requests with increasing integer ids, replies matched by id, events kept in arrival
// order. Every wait has a deadline; nothing blocks without one unless the caller asks for it.
// Not thread-safe (one thread per client).
#pragma once

#include <atomic>
#include <chrono>
#include <deque>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>

#include "cdpr/controller/control_protocol.hpp"
#include "cdpr/status.hpp"

namespace cdpr::control {

struct ControlEvent {
  std::string type;  // state, progress, fault, calibration, log, dropped
  nlohmann::json data;
};

class ControlClient {
 public:
  using Clock = std::chrono::steady_clock;
  using Deadline = std::optional<Clock::time_point>;  // nullopt: wait as long as it takes
  // Longest line accepted from the daemon (a report with its HTML page is one line).
  static constexpr std::size_t kMaxReplyLine = 64u << 20;

  // Status codes, which cdprctl maps to its exit codes:
  //   kNotFound            no socket at `path` (the daemon is not running)
  //   kUnavailable         nobody accepts at `path` (stale socket), or the daemon closed the
  //                        connection
  //   kFailedPrecondition  permission denied on the socket (EACCES/EPERM)
  //   kTimeout             the deadline passed
  //   kAborted             *cancel became true
  //   kProtocolError       the daemon sent something that is not a reply or an event
  //   kIoError             anything else the system refused (errno in the message)
  static Result<ControlClient> connect(const std::string& path, Deadline deadline = {});

  ControlClient(ControlClient&& other) noexcept;
  ControlClient& operator=(ControlClient&& other) noexcept;
  ControlClient(const ControlClient&) = delete;
  ControlClient& operator=(const ControlClient&) = delete;
  ~ControlClient();

  // Sends {"id": n, "cmd": cmd, "args": args} and waits for the reply with id n (or a reply with a
  // null id: the server's answer to a line it could not read, or "busy" on connect). A refused
  // command is an ok Result holding an error ControlReply; the Status is for the transport.
  Result<ControlReply> call(std::string_view cmd,
                            const nlohmann::json& args = nlohmann::json::object(),
                            Deadline deadline = {}, const std::atomic<bool>* cancel = nullptr);

  // The next event (after a successful `watch`), in arrival order.
  Result<ControlEvent> next_event(Deadline deadline = {},
                                  const std::atomic<bool>* cancel = nullptr);

  // Raw access for tests: writes bytes as they are; reads one line without its '\n'.
  Status send_raw(std::string_view bytes, Deadline deadline = {});
  Result<std::string> read_line(Deadline deadline = {}, const std::atomic<bool>* cancel = nullptr);

  int fd() const { return fd_; }
  const std::string& path() const { return path_; }

 private:
  ControlClient(int fd, std::string path) : fd_(fd), path_(std::move(path)) {}
  void close_fd();

  int fd_ = -1;
  std::string path_;
  std::string in_;
  std::int64_t next_id_ = 1;
  std::deque<ControlEvent> events_;
};

// Deadline `seconds` from now; nullopt when seconds <= 0 (no bound).
ControlClient::Deadline deadline_after(double seconds);

}  // namespace cdpr::control
