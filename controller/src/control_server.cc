#include "cdpr/controller/control_server.hpp"

#include <fcntl.h>
#include <grp.h>
#include <poll.h>
#include <pwd.h>
#include <spdlog/spdlog.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <deque>
#include <mutex>
#include <thread>
#include <utility>

namespace cdpr::control {

namespace {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr std::size_t kReadChunk = 64 * 1024;
constexpr std::size_t kMaxAcceptsPerRound = 64;

std::string errno_text(int e) {
  return std::string(std::strerror(e)) + " (errno " + std::to_string(e) + ")";
}

Status io_error(const std::string& what, int e) {
  return Status(ErrorCode::kIoError, what + ": " + errno_text(e));
}

bool fill_address(const std::string& path, sockaddr_un& addr) {
  std::memset(&addr, 0, sizeof addr);
  addr.sun_family = AF_UNIX;
  if (path.empty() || path.size() >= sizeof addr.sun_path) return false;
  std::memcpy(addr.sun_path, path.data(), path.size());
  return true;
}

// Whether something accepts connections at `path` (a live daemon) rather than a stale file.
bool someone_listens(const std::string& path) {
  sockaddr_un addr{};
  if (!fill_address(path, addr)) return false;
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  const int rc = ::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr);
  const int e = errno;
  ::close(fd);
  // EAGAIN: a listener whose backlog is full is alive too.
  return rc == 0 || e == EAGAIN || e == EINPROGRESS;
}

struct Chunk {
  std::shared_ptr<const std::string> data;
  std::size_t offset = 0;
};

struct Client {
  int fd = -1;
  PeerCredentials peer;
  std::string in;
  std::size_t in_pos = 0;   // first unprocessed byte of `in`
  bool discarding = false;  // inside a line that was too long: skip to the next '\n'
  bool eof = false;         // the peer shut down its writing side
  bool dead = false;
  bool watching = false;
  std::deque<Chunk> out;
  std::size_t out_bytes = 0;
  std::uint64_t dropped_unannounced = 0;
  std::optional<Clock::time_point> full_since;
};

}  // namespace

struct ControlServer::Impl {
  ControlServerOptions options;
  ControlHandler handler;
  int listen_fd = -1;
  int wake_fd = -1;
  uid_t own_uid = ::geteuid();
  std::optional<gid_t> group_gid;
  dev_t socket_dev = 0;
  ino_t socket_ino = 0;
  std::thread thread;
  std::atomic<bool> stopping{false};
  std::atomic<bool> stopped{false};
  std::mutex stop_mu;

  std::mutex events_mu;
  std::vector<std::shared_ptr<const std::string>> events;  // guarded by events_mu

  std::vector<std::unique_ptr<Client>> clients;                // server thread only
  std::vector<char> read_buf = std::vector<char>(kReadChunk);  // server thread only
  Clock::time_point accept_paused_until{};

  struct {
    std::atomic<std::uint64_t> clients{0}, clients_accepted{0}, clients_rejected{0},
        clients_disconnected_slow{0}, requests{0}, bad_requests{0}, refused{0}, events_published{0},
        events_dropped{0};
  } st;

  ~Impl() {
    if (listen_fd >= 0) ::close(listen_fd);
    if (wake_fd >= 0) ::close(wake_fd);
  }

  // ---- output -------------------------------------------------------------------------------

  bool over_bound(const Client& c) const { return c.out_bytes >= options.max_pending_bytes; }

  void enqueue(Client& c, std::shared_ptr<const std::string> line) {
    c.out_bytes += line->size();
    c.out.push_back(Chunk{std::move(line), 0});
    if (over_bound(c) && !c.full_since) c.full_since = Clock::now();
  }
  void enqueue(Client& c, std::string line) {
    enqueue(c, std::make_shared<const std::string>(std::move(line)));
  }

  void flush(Client& c) {
    while (!c.out.empty() && !c.dead) {
      Chunk& ch = c.out.front();
      const std::size_t left = ch.data->size() - ch.offset;
      const ssize_t n = ::send(c.fd, ch.data->data() + ch.offset, left, MSG_NOSIGNAL);
      if (n < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) break;
        c.dead = true;  // EPIPE, ECONNRESET: the peer is gone
        break;
      }
      ch.offset += static_cast<std::size_t>(n);
      c.out_bytes -= static_cast<std::size_t>(n);
      if (ch.offset == ch.data->size()) c.out.pop_front();
    }
    if (c.out_bytes <= options.max_pending_bytes / 2) c.full_since.reset();
  }

  void fan_out(const std::vector<std::shared_ptr<const std::string>>& batch) {
    for (const auto& ev : batch) {
      for (auto& cp : clients) {
        Client& c = *cp;
        if (!c.watching || c.dead) continue;
        if (c.dropped_unannounced > 0 && !over_bound(c)) {
          enqueue(c, encode_event("dropped", {{"count", c.dropped_unannounced}}));
          c.dropped_unannounced = 0;
        }
        if (c.out_bytes + ev->size() > options.max_pending_bytes) {
          ++c.dropped_unannounced;
          st.events_dropped.fetch_add(1, std::memory_order_relaxed);
          if (!c.full_since) c.full_since = Clock::now();
          continue;
        }
        enqueue(c, ev);
      }
    }
  }

  void drain_events() {
    std::vector<std::shared_ptr<const std::string>> batch;
    {
      std::lock_guard lock(events_mu);
      batch.swap(events);
    }
    if (!batch.empty()) fan_out(batch);
  }

  // ---- requests -----------------------------------------------------------------------------

  std::string permission_message(const std::string& cmd) const {
    std::string m =
        cmd + " moves the robot or changes the geometry: it needs root, the daemon's user";
    if (!options.group.empty()) m += " or membership of group '" + options.group + "'";
    return m;
  }

  void handle_line(Client& c, std::string_view line) {
    st.requests.fetch_add(1, std::memory_order_relaxed);
    ParsedRequest p = parse_request(line);
    if (!p.request) {
      st.bad_requests.fetch_add(1, std::memory_order_relaxed);
      enqueue(c, encode_reply(p.id, ControlReply::error(p.error_code, p.error_message)));
      return;
    }
    ControlRequest& req = *p.request;
    req.peer = c.peer;
    if (is_privileged(req.cmd)) {
      if (!c.peer.privileged_allowed) {
        st.refused.fetch_add(1, std::memory_order_relaxed);
        spdlog::warn("control: refused {} from pid {} uid {} gid {}: not permitted", req.cmd,
                     c.peer.pid, c.peer.uid, c.peer.gid);
        enqueue(c, encode_reply(req.id, ControlReply::error(ControlErrorCode::kNotPermitted,
                                                            permission_message(req.cmd))));
        return;
      }
      spdlog::info("control: {} from pid {} uid {} gid {}", req.cmd, c.peer.pid, c.peer.uid,
                   c.peer.gid);
    }
    ControlReply reply = ControlReply::error(ControlErrorCode::kInternal, "no reply");
    try {
      reply = handler(req);
    } catch (const std::exception& e) {
      reply = ControlReply::error(ControlErrorCode::kInternal,
                                  std::string("the daemon failed on ") + req.cmd + ": " + e.what());
    } catch (...) {
      reply = ControlReply::error(ControlErrorCode::kInternal,
                                  std::string("the daemon failed on ") + req.cmd);
    }
    enqueue(c, encode_reply(req.id, reply));
    if (req.cmd == "watch" && reply.is_ok()) c.watching = true;
  }

  void too_long(Client& c) {
    st.requests.fetch_add(1, std::memory_order_relaxed);
    st.bad_requests.fetch_add(1, std::memory_order_relaxed);
    enqueue(c, encode_reply(nullptr,
                            ControlReply::error(ControlErrorCode::kBadRequest,
                                                "request line longer than " +
                                                    std::to_string(options.max_line) + " bytes")));
  }

  // Serves up to max_lines_per_turn complete lines of `c`. True when complete lines are left.
  bool serve_lines(Client& c) {
    std::size_t served = 0;
    while (served < options.max_lines_per_turn && !over_bound(c) && !c.dead) {
      const std::size_t nl = c.in.find('\n', c.in_pos);
      if (c.discarding) {
        if (nl == std::string::npos) {
          c.in_pos = c.in.size();
          break;
        }
        c.in_pos = nl + 1;
        c.discarding = false;
        continue;
      }
      if (nl == std::string::npos) {
        if (c.in.size() - c.in_pos > options.max_line) {
          too_long(c);
          ++served;
          c.discarding = true;
          c.in_pos = c.in.size();
        }
        break;
      }
      std::string_view line(c.in.data() + c.in_pos, nl - c.in_pos);
      c.in_pos = nl + 1;
      if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
      if (line.size() > options.max_line) {
        too_long(c);
        ++served;
        continue;
      }
      if (line.find_first_not_of(" \t") == std::string_view::npos) continue;  // blank line
      handle_line(c, line);
      ++served;
    }
    if (c.in_pos > 0) {
      c.in.erase(0, c.in_pos);
      c.in_pos = 0;
    }
    if (c.in.empty() && c.in.capacity() > 2 * kReadChunk) c.in.shrink_to_fit();
    return !c.discarding && c.in.find('\n') != std::string::npos;
  }

  // Reads once from `c` (when it has no complete line waiting).
  void read_from(Client& c) {
    const ssize_t n = ::recv(c.fd, read_buf.data(), read_buf.size(), 0);
    if (n > 0) {
      c.in.append(read_buf.data(), static_cast<std::size_t>(n));
      return;
    }
    if (n == 0) {
      c.eof = true;
      // A last request without its '\n' still counts.
      if (!c.discarding && c.in.size() > c.in_pos) c.in.push_back('\n');
    } else if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
      c.dead = true;
    }
  }

  // ---- connections --------------------------------------------------------------------------

  void accept_clients() {
    for (std::size_t k = 0; k < kMaxAcceptsPerRound; ++k) {
      const int fd = ::accept4(listen_fd, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) {
        if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
          spdlog::warn("control: cannot accept a client: {}", errno_text(errno));
          accept_paused_until = Clock::now() + std::chrono::milliseconds(100);
        }
        return;
      }
      if (clients.size() >= options.max_clients) {
        const std::string busy = encode_reply(
            nullptr,
            ControlReply::error(ControlErrorCode::kBusy,
                                "too many clients (" + std::to_string(options.max_clients) + ")"));
        st.clients_rejected.fetch_add(1, std::memory_order_relaxed);
        (void)!::send(fd, busy.data(), busy.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
        ::close(fd);
        continue;
      }
      auto c = std::make_unique<Client>();
      c->fd = fd;
      ucred cred{};
      socklen_t len = sizeof cred;
      if (::getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) == 0) {
        c->peer.pid = cred.pid;
        c->peer.uid = cred.uid;
        c->peer.gid = cred.gid;
        const bool trivially = cred.uid == 0 || (options.allow_own_uid && cred.uid == own_uid);
        c->peer.privileged_allowed =
            trivially ||
            peer_may_run_privileged(cred.uid, cred.gid, own_uid, options.allow_own_uid, group_gid,
                                    group_gid ? groups_of_uid(cred.uid) : std::vector<gid_t>{});
      }  // else: unknown peer, never privileged
      clients.push_back(std::move(c));
      st.clients_accepted.fetch_add(1, std::memory_order_relaxed);
    }
  }

  void run() {
    std::vector<pollfd> fds;
    std::vector<std::size_t> owner;  // fds[i] -> clients index (from 2 on)
    bool backlog = false;            // some client has complete lines waiting
    while (!stopping.load()) {
      fds.clear();
      const auto now = Clock::now();
      const bool accept_ok = now >= accept_paused_until;
      fds.push_back({listen_fd, static_cast<short>(accept_ok ? POLLIN : 0), 0});
      fds.push_back({wake_fd, POLLIN, 0});
      int timeout_ms = backlog ? 0 : -1;
      if (!accept_ok) timeout_ms = timeout_ms < 0 ? 100 : timeout_ms;
      for (const auto& cp : clients) {
        const Client& c = *cp;
        short ev = 0;
        const bool has_line = c.in.find('\n', c.in_pos) != std::string::npos;
        if (!c.eof && !over_bound(c) && !has_line) ev |= POLLIN;
        if (!c.out.empty()) ev |= POLLOUT;
        fds.push_back({c.fd, ev, 0});
        if (c.full_since) {
          const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
              *c.full_since + options.stall_timeout - now);
          const int ms = static_cast<int>(std::max<std::int64_t>(left.count() + 1, 0));
          timeout_ms = timeout_ms < 0 ? ms : std::min(timeout_ms, ms);
        }
      }
      const int rc = ::poll(fds.data(), fds.size(), timeout_ms);
      if (rc < 0 && errno != EINTR) {
        spdlog::error("control: poll failed: {}", errno_text(errno));
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
      if (stopping.load()) break;
      if (fds[1].revents & POLLIN) {
        std::uint64_t v;
        (void)!::read(wake_fd, &v, sizeof v);
      }
      drain_events();
      const std::size_t n_polled = fds.size() - 2;
      for (std::size_t i = 0; i < n_polled; ++i) {
        Client& c = *clients[i];
        const short re = fds[i + 2].revents;
        if (re & POLLNVAL) c.dead = true;
        if (re & (POLLIN | POLLHUP | POLLERR)) {
          if (fds[i + 2].events & POLLIN) {
            read_from(c);
          } else if (re & POLLERR) {
            c.dead = true;
          } else if ((re & POLLHUP) && c.out.empty()) {
            c.eof = true;
          }
        }
      }
      backlog = false;
      for (auto& cp : clients) {
        Client& c = *cp;
        if (c.dead) continue;
        if (serve_lines(c) && !over_bound(c)) backlog = true;
        if (!c.out.empty()) flush(c);
      }
      if (fds[0].revents & POLLIN) accept_clients();
      // Disconnect the stalled, close the finished, drop the dead.
      const auto t = Clock::now();
      for (auto& cp : clients) {
        Client& c = *cp;
        if (c.full_since && c.out_bytes <= options.max_pending_bytes / 2) c.full_since.reset();
        if (!c.dead && c.full_since && t - *c.full_since >= options.stall_timeout) {
          spdlog::warn("control: disconnected pid {} uid {}: it read nothing for {} ms", c.peer.pid,
                       c.peer.uid, options.stall_timeout.count());
          st.clients_disconnected_slow.fetch_add(1, std::memory_order_relaxed);
          c.dead = true;
        }
        // Half-closed and all answered: done.
        if (c.eof && c.out.empty() && c.in.find('\n') == std::string::npos) c.dead = true;
      }
      std::erase_if(clients, [](const std::unique_ptr<Client>& c) {
        if (c->dead) ::close(c->fd);
        return c->dead;
      });
      st.clients.store(clients.size(), std::memory_order_relaxed);
    }
    drain_events();
    for (auto& c : clients) {
      flush(*c);  // best effort: what fits in the socket now (the daemon is shutting down)
      ::close(c->fd);
    }
    clients.clear();
    st.clients.store(0);
  }
};

ControlServer::ControlServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

ControlServer::~ControlServer() {
  stop();
}

Result<std::unique_ptr<ControlServer>> ControlServer::start(ControlServerOptions options,
                                                            ControlHandler handler) {
  if (!handler) return Status(ErrorCode::kInvalidArgument, "control server needs a handler");
  auto impl = std::make_unique<Impl>();
  const std::string tmp = options.path + ".tmp" + std::to_string(::getpid());
  sockaddr_un addr{};
  if (!fill_address(tmp, addr)) {
    return Status(
        ErrorCode::kInvalidArgument,
        "control socket path '" + options.path + "' is empty or too long (at most " +
            std::to_string(sizeof addr.sun_path - 1 - (tmp.size() - options.path.size())) +
            " bytes)");
  }
  if (!options.group.empty()) {
    group grp{}, *found = nullptr;
    std::vector<char> buf(16384);
    int e = 0;
    while ((e = ::getgrnam_r(options.group.c_str(), &grp, buf.data(), buf.size(), &found)) ==
               ERANGE &&
           buf.size() < (1u << 22)) {
      buf.resize(buf.size() * 2);
    }
    if (found == nullptr) {
      return Status(ErrorCode::kNotFound,
                    "control socket group '" + options.group + "' does not exist" +
                        (e != 0 ? " (" + errno_text(e) + ")" : std::string()));
    }
    impl->group_gid = grp.gr_gid;
  }
  struct stat sb {};
  if (::lstat(options.path.c_str(), &sb) == 0) {
    if (!S_ISSOCK(sb.st_mode)) {
      return Status(ErrorCode::kFailedPrecondition,
                    "control socket path '" + options.path +
                        "' exists and is not a socket; not replacing it");
    }
    if (someone_listens(options.path)) {
      return Status(ErrorCode::kUnavailable,
                    "a daemon is already answering on control socket '" + options.path + "'");
    }
    // A stale socket from a daemon that died: replaced by the rename below.
  }
  (void)::unlink(tmp.c_str());
  impl->listen_fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (impl->listen_fd < 0) return io_error("control socket: socket()", errno);
  if (::bind(impl->listen_fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    return io_error("control socket: bind to '" + tmp + "'", errno);
  }
  auto fail = [&](const std::string& what) -> Status {
    const int e = errno;
    (void)::unlink(tmp.c_str());
    return io_error(what, e);
  };
  if (::chmod(tmp.c_str(), options.mode) != 0) return fail("control socket: chmod '" + tmp + "'");
  if (impl->group_gid && ::chown(tmp.c_str(), static_cast<uid_t>(-1), *impl->group_gid) != 0) {
    return fail("control socket: chown '" + tmp + "' to group '" + options.group + "'");
  }
  if (::listen(impl->listen_fd, SOMAXCONN) != 0) return fail("control socket: listen");
  if (::rename(tmp.c_str(), options.path.c_str()) != 0) {
    return fail("control socket: rename '" + tmp + "' to '" + options.path + "'");
  }
  if (::stat(options.path.c_str(), &sb) == 0) {
    impl->socket_dev = sb.st_dev;
    impl->socket_ino = sb.st_ino;
  }
  impl->wake_fd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (impl->wake_fd < 0) {
    const int e = errno;
    (void)::unlink(options.path.c_str());
    return io_error("control socket: eventfd", e);
  }
  impl->options = std::move(options);
  impl->handler = std::move(handler);
  Impl* raw = impl.get();
  impl->thread = std::thread([raw] { raw->run(); });
  spdlog::info("control: listening on {} (mode {:o}{}{})", raw->options.path, raw->options.mode,
               raw->options.group.empty() ? "" : ", group ", raw->options.group);
  return std::unique_ptr<ControlServer>(new ControlServer(std::move(impl)));
}

void ControlServer::stop() {
  if (!impl_) return;
  std::lock_guard lock(impl_->stop_mu);
  if (impl_->stopped.load()) return;
  impl_->stopping.store(true);
  const std::uint64_t one = 1;
  (void)!::write(impl_->wake_fd, &one, sizeof one);
  if (impl_->thread.joinable()) impl_->thread.join();
  // Connections still in the backlog (never accepted) see the end now, not at destruction.
  if (impl_->listen_fd >= 0) ::close(impl_->listen_fd);
  impl_->listen_fd = -1;
  struct stat sb {};
  if (::stat(impl_->options.path.c_str(), &sb) == 0 && sb.st_dev == impl_->socket_dev &&
      sb.st_ino == impl_->socket_ino) {
    (void)::unlink(impl_->options.path.c_str());
  }
  impl_->stopped.store(true);
}

void ControlServer::publish(std::string_view type, const nlohmann::json& data) {
  if (!impl_ || impl_->stopping.load()) return;
  auto line = std::make_shared<const std::string>(encode_event(type, data));
  impl_->st.events_published.fetch_add(1, std::memory_order_relaxed);
  {
    std::lock_guard lock(impl_->events_mu);
    if (impl_->events.size() >= impl_->options.max_queued_events) {
      impl_->st.events_dropped.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    impl_->events.push_back(std::move(line));
  }
  const std::uint64_t one = 1;
  (void)!::write(impl_->wake_fd, &one, sizeof one);
}

void ControlServer::publish(const nlohmann::json& event) {
  const auto type = event.is_object() ? event.find("event") : event.end();
  if (!event.is_object() || type == event.end() || !type->is_string()) {
    spdlog::error("control: publish() needs {{\"event\": <type>, \"data\": {{...}}}}");
    return;
  }
  const auto data = event.find("data");
  publish(type->get_ref<const std::string&>(), data == event.end() ? json::object() : *data);
}

ControlServerStats ControlServer::stats() const {
  ControlServerStats s;
  const auto& a = impl_->st;
  s.clients = a.clients.load();
  s.clients_accepted = a.clients_accepted.load();
  s.clients_rejected = a.clients_rejected.load();
  s.clients_disconnected_slow = a.clients_disconnected_slow.load();
  s.requests = a.requests.load();
  s.bad_requests = a.bad_requests.load();
  s.refused = a.refused.load();
  s.events_published = a.events_published.load();
  s.events_dropped = a.events_dropped.load();
  return s;
}

const std::string& ControlServer::path() const {
  return impl_->options.path;
}

bool peer_may_run_privileged(uid_t uid, gid_t gid, uid_t daemon_uid, bool allow_own_uid,
                             std::optional<gid_t> group, const std::vector<gid_t>& supplementary) {
  if (uid == 0) return true;
  if (allow_own_uid && uid == daemon_uid) return true;
  if (!group) return false;
  if (gid == *group) return true;
  return std::find(supplementary.begin(), supplementary.end(), *group) != supplementary.end();
}

std::vector<gid_t> groups_of_uid(uid_t uid) {
  passwd pw{}, *found = nullptr;
  std::vector<char> buf(16384);
  while (::getpwuid_r(uid, &pw, buf.data(), buf.size(), &found) == ERANGE &&
         buf.size() < (1u << 22)) {
    buf.resize(buf.size() * 2);
  }
  if (found == nullptr) return {};
  int n = 64;
  std::vector<gid_t> groups(static_cast<std::size_t>(n));
  for (int attempt = 0; attempt < 8; ++attempt) {
    int count = n;
    if (::getgrouplist(pw.pw_name, pw.pw_gid, groups.data(), &count) >= 0) {
      groups.resize(static_cast<std::size_t>(count));
      return groups;
    }
    n = std::max(count, n * 2);
    groups.resize(static_cast<std::size_t>(n));
  }
  return {};
}

}  // namespace cdpr::control
