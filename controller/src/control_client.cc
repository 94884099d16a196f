#include "cdpr/controller/control_client.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace cdpr::control {

namespace {

using json = nlohmann::json;

// The longest single poll() slice, so that `cancel` is seen even without a signal.
constexpr int kSliceMs = 100;

std::string errno_text(int e) {
  return std::string(std::strerror(e)) + " (errno " + std::to_string(e) + ")";
}

// Milliseconds to wait in one poll() slice; -2 when the deadline has passed.
int slice_ms(const ControlClient::Deadline& deadline) {
  if (!deadline) return kSliceMs;
  const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
      *deadline - ControlClient::Clock::now());
  if (left.count() < 0) return -2;
  return static_cast<int>(std::min<std::int64_t>(left.count() + 1, kSliceMs));
}

// Waits for `events` on fd; ok when ready.
Status wait_fd(int fd, short events, const ControlClient::Deadline& deadline,
               const std::atomic<bool>* cancel, const char* what) {
  for (;;) {
    if (cancel != nullptr && cancel->load()) return Status(ErrorCode::kAborted, "interrupted");
    const int ms = slice_ms(deadline);
    if (ms == -2) {
      return Status::error(ErrorCode::kTimeout, "no %s from cdprd before the timeout", what);
    }
    pollfd p{fd, events, 0};
    const int rc = ::poll(&p, 1, ms);
    if (rc < 0) {
      if (errno == EINTR) continue;
      return Status(ErrorCode::kIoError, "poll: " + errno_text(errno));
    }
    if (rc > 0) return Status::success();
  }
}

}  // namespace

ControlClient::Deadline deadline_after(double seconds) {
  if (!(seconds > 0)) return std::nullopt;
  return ControlClient::Clock::now() + std::chrono::duration_cast<ControlClient::Clock::duration>(
                                           std::chrono::duration<double>(seconds));
}

Result<ControlClient> ControlClient::connect(const std::string& path, Deadline deadline) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (path.empty() || path.size() >= sizeof addr.sun_path) {
    return Status(ErrorCode::kInvalidArgument, "socket path '" + path + "' is empty or too long");
  }
  std::memcpy(addr.sun_path, path.data(), path.size());
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return Status(ErrorCode::kIoError, "socket: " + errno_text(errno));
  for (;;) {
    if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) == 0) break;
    const int e = errno;
    if (e == EINTR) continue;
    if (e == EAGAIN) {  // the listener's backlog is full: try again until the deadline
      const int ms = slice_ms(deadline);
      if (ms == -2) {
        ::close(fd);
        return Status(ErrorCode::kTimeout, "cdprd did not accept the connection on " + path +
                                               " before the timeout (backlog full)");
      }
      ::usleep(static_cast<useconds_t>(std::min(ms, 10)) * 1000u);
      continue;
    }
    ::close(fd);
    switch (e) {
      case ENOENT:
      case ENOTDIR:
        return Status(ErrorCode::kNotFound, "no socket at " + path);
      case ECONNREFUSED:
      case ENOTSOCK:
        return Status(ErrorCode::kUnavailable,
                      "nothing accepts connections at " + path + " (" + errno_text(e) + ")");
      case EACCES:
      case EPERM:
        return Status(ErrorCode::kFailedPrecondition,
                      "permission denied on " + path + " (" + errno_text(e) + ")");
      default:
        return Status(ErrorCode::kIoError, "connect to " + path + ": " + errno_text(e));
    }
  }
  return ControlClient(fd, path);
}

ControlClient::ControlClient(ControlClient&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)),
      path_(std::move(other.path_)),
      in_(std::move(other.in_)),
      next_id_(other.next_id_),
      events_(std::move(other.events_)) {}

ControlClient& ControlClient::operator=(ControlClient&& other) noexcept {
  if (this != &other) {
    close_fd();
    fd_ = std::exchange(other.fd_, -1);
    path_ = std::move(other.path_);
    in_ = std::move(other.in_);
    next_id_ = other.next_id_;
    events_ = std::move(other.events_);
  }
  return *this;
}

ControlClient::~ControlClient() {
  close_fd();
}

void ControlClient::close_fd() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

Status ControlClient::send_raw(std::string_view bytes, Deadline deadline) {
  while (!bytes.empty()) {
    const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
    if (n >= 0) {
      bytes.remove_prefix(static_cast<std::size_t>(n));
      continue;
    }
    if (errno == EINTR) continue;
    if (errno == EAGAIN || errno == EWOULDBLOCK) {
      if (Status st = wait_fd(fd_, POLLOUT, deadline, nullptr, "room to send"); !st.ok()) {
        return st;
      }
      continue;
    }
    if (errno == EPIPE || errno == ECONNRESET) {
      return Status(ErrorCode::kUnavailable, "cdprd closed the connection");
    }
    return Status(ErrorCode::kIoError, "send: " + errno_text(errno));
  }
  return Status::success();
}

Result<std::string> ControlClient::read_line(Deadline deadline, const std::atomic<bool>* cancel) {
  for (;;) {
    if (const auto nl = in_.find('\n'); nl != std::string::npos) {
      std::string line = in_.substr(0, nl);
      in_.erase(0, nl + 1);
      return line;
    }
    if (in_.size() > kMaxReplyLine) {
      return Status(ErrorCode::kProtocolError,
                    "cdprd sent a line longer than " + std::to_string(kMaxReplyLine) + " bytes");
    }
    if (Status st = wait_fd(fd_, POLLIN, deadline, cancel, "answer"); !st.ok()) return st;
    char buf[65536];
    const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
    if (n > 0) {
      in_.append(buf, static_cast<std::size_t>(n));
      continue;
    }
    if (n == 0) return Status(ErrorCode::kUnavailable, "cdprd closed the connection");
    if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) continue;
    if (errno == ECONNRESET) return Status(ErrorCode::kUnavailable, "cdprd closed the connection");
    return Status(ErrorCode::kIoError, "recv: " + errno_text(errno));
  }
}

Result<ControlReply> ControlClient::call(std::string_view cmd, const nlohmann::json& args,
                                         Deadline deadline, const std::atomic<bool>* cancel) {
  const std::int64_t id = next_id_++;
  if (Status st = send_raw(encode_request(id, cmd, args), deadline); !st.ok()) {
    // The server may have said why before it closed (busy: too many clients).
    if (st.code() != ErrorCode::kUnavailable) return st;
    Result<std::string> last = read_line(deadline_after(0.5), cancel);
    if (!last.ok()) return st;
    Result<ServerMessage> msg = parse_server_message(*last);
    if (!msg.ok() || msg->is_event) return st;
    return std::move(msg->reply);
  }
  for (;;) {
    Result<std::string> line = read_line(deadline, cancel);
    if (!line.ok()) return line.status();
    Result<ServerMessage> msg = parse_server_message(*line);
    if (!msg.ok()) return Status(ErrorCode::kProtocolError, msg.status().message());
    if (msg->is_event) {
      events_.push_back(ControlEvent{std::move(msg->event), std::move(msg->data)});
      continue;
    }
    if (msg->id.is_null() || msg->id == json(id)) return std::move(msg->reply);
    // A late reply to an earlier request that timed out: not ours.
  }
}

Result<ControlEvent> ControlClient::next_event(Deadline deadline, const std::atomic<bool>* cancel) {
  for (;;) {
    if (!events_.empty()) {
      ControlEvent ev = std::move(events_.front());
      events_.pop_front();
      return ev;
    }
    Result<std::string> line = read_line(deadline, cancel);
    if (!line.ok()) return line.status();
    Result<ServerMessage> msg = parse_server_message(*line);
    if (!msg.ok()) return Status(ErrorCode::kProtocolError, msg.status().message());
    if (msg->is_event) return ControlEvent{std::move(msg->event), std::move(msg->data)};
  }
}

}  // namespace cdpr::control
