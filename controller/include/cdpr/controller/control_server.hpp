// The daemon's control socket (docs/control-protocol.md): a Unix stream socket served by one
// thread with poll() and non-blocking sockets. The daemon plugs in a handler; the server does the
// transport, the parsing and validation (control_protocol.hpp), the permission check of privileged
// commands (SO_PEERCRED) and the fan-out of events to watchers.
//
// Under abuse (docs/control-protocol.md, "Limits"): lines longer than max_line are answered with
// bad_request and skipped up to the next newline; each client has a bounded output queue; a client
// whose queue is over max_pending_bytes is not read from (its requests wait), gets events dropped
// (counted, and announced with a `dropped` event once it reads again), and is disconnected when the
// queue stays over the bound for stall_timeout; a client is served at most max_lines_per_turn
// requests per poll round, so a flood does not starve the others; beyond max_clients a new client
// gets one busy error line and is closed. Nothing a client does blocks the server or publish().
#pragma once

#include <sys/types.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/controller/control_protocol.hpp"
#include "cdpr/status.hpp"

namespace cdpr::control {

// Runs on the server thread for every valid request (known command, valid args), privileged ones
// only when the peer is allowed. Must be quick (read snapshots, post commands) and must not call
// ControlServer::stop(). An exception escaping it is answered with `internal`.
// For `watch`, an ok reply subscribes the client to events (the reply is sent before any event).
using ControlHandler = std::function<ControlReply(const ControlRequest&)>;

struct ControlServerOptions {
  std::string path;   // socket path (at most 107 bytes)
  std::string group;  // group of the socket and of the peers allowed privileged commands; "" none
  unsigned mode = 0660;
  std::size_t max_line = kDefaultMaxLine;         // longest request line, bytes without '\n'
  std::size_t max_clients = 128;                  // connections served at once
  std::size_t max_pending_bytes = 1 << 20;        // per-client output queue bound
  std::chrono::milliseconds stall_timeout{5000};  // queue over the bound this long: disconnect
  std::size_t max_lines_per_turn = 16;            // requests served per client per poll round
  std::size_t max_queued_events = 4096;  // published, not yet fanned out (the server is late)
  // The daemon's own uid may run privileged commands (tests set false to simulate an outsider
  // without a second uid; the daemon keeps true).
  bool allow_own_uid = true;
};

struct ControlServerStats {
  std::uint64_t clients = 0;                    // connected now
  std::uint64_t clients_accepted = 0;           // since start
  std::uint64_t clients_rejected = 0;           // turned away: max_clients reached
  std::uint64_t clients_disconnected_slow = 0;  // queue stayed full for stall_timeout
  std::uint64_t requests = 0;                   // lines answered (valid or not)
  std::uint64_t bad_requests = 0;               // answered bad_request or unknown_command
  std::uint64_t refused = 0;                    // privileged commands refused with not_permitted
  std::uint64_t events_published = 0;
  std::uint64_t events_dropped = 0;  // per watcher: not queued because its queue was full
};

class ControlServer {
 public:
  // Creates the socket (mode and group set before it listens: bound under a temporary name, then
  // renamed into place), then starts the server thread. Refuses with kUnavailable when a daemon
  // answers at `path`, kFailedPrecondition when `path` exists and is not a socket, kNotFound when
  // the group does not exist, kIoError (with errno) when the system refuses.
  static Result<std::unique_ptr<ControlServer>> start(ControlServerOptions options,
                                                      ControlHandler handler);
  ~ControlServer();
  ControlServer(const ControlServer&) = delete;
  ControlServer& operator=(const ControlServer&) = delete;

  // Sends {"event": type, "data": data} to every watcher. Thread-safe; serialises on the calling
  // thread, holds a mutex only to append to a queue and never waits for a client or for the
  // server thread. Not for the RT thread (it allocates). After stop(): does nothing.
  void publish(std::string_view type, const nlohmann::json& data);
  // The same with the whole event object {"event": "<type>", "data": {...}}.
  void publish(const nlohmann::json& event);

  // Closes every connection, removes the socket (when it is still ours) and joins the thread.
  // Idempotent.
  void stop();

  ControlServerStats stats() const;
  const std::string& path() const;

  struct Impl;

 private:
  explicit ControlServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Whether a peer may run privileged commands: root, `daemon_uid` (when allow_own_uid), or a member
// of `group` by its primary gid or by the supplementary groups of its passwd entry.
bool peer_may_run_privileged(uid_t uid, gid_t gid, uid_t daemon_uid, bool allow_own_uid,
                             std::optional<gid_t> group, const std::vector<gid_t>& supplementary);
// The supplementary groups of the passwd entry of `uid` (getgrouplist); empty when it has none.
std::vector<gid_t> groups_of_uid(uid_t uid);

}  // namespace cdpr::control
