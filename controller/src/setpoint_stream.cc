#include "cdpr/controller/setpoint_stream.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>

namespace cdpr::controller {

namespace {

static_assert(std::endian::native == std::endian::little, "the record is little-endian");

template <typename T>
void put(std::array<std::byte, kSetpointBytes>& b, std::size_t at, T v) {
  std::memcpy(b.data() + at, &v, sizeof v);
}
template <typename T>
T get(std::span<const std::byte> b, std::size_t at) {
  T v;
  std::memcpy(&v, b.data() + at, sizeof v);
  return v;
}

constexpr int kPollMs = 50;  // how often the thread looks at its stop flag

}  // namespace

std::array<std::byte, kSetpointBytes> encode_setpoint(std::uint64_t seq, std::int64_t sent_ns,
                                                      const Pose& pose) {
  std::array<std::byte, kSetpointBytes> b{};
  put(b, 0, kSetpointMagic);
  put(b, 4, kSetpointVersion);
  put(b, 6, std::uint16_t{0});
  put(b, 8, seq);
  put(b, 16, sent_ns);
  for (int j = 0; j < 3; ++j) {
    put(b, 24 + 8 * static_cast<std::size_t>(j), pose.position(j));
    put(b, 48 + 8 * static_cast<std::size_t>(j), pose.rpy(j));
  }
  return b;
}

Result<StreamSetpoint> decode_setpoint(std::span<const std::byte> bytes) {
  if (bytes.size() != kSetpointBytes) {
    return Status::error(ErrorCode::kInvalidArgument, "setpoint of %zu bytes (%zu expected)",
                         bytes.size(), kSetpointBytes);
  }
  if (get<std::uint32_t>(bytes, 0) != kSetpointMagic) {
    return Status::error(ErrorCode::kInvalidArgument, "setpoint magic is not CDPS");
  }
  if (get<std::uint16_t>(bytes, 4) != kSetpointVersion || get<std::uint16_t>(bytes, 6) != 0) {
    return Status::error(ErrorCode::kInvalidArgument, "setpoint version %u flags %u (1, 0 known)",
                         unsigned{get<std::uint16_t>(bytes, 4)},
                         unsigned{get<std::uint16_t>(bytes, 6)});
  }
  StreamSetpoint sp;
  sp.seq = get<std::uint64_t>(bytes, 8);
  sp.sent_ns = get<std::int64_t>(bytes, 16);
  for (std::size_t j = 0; j < 6; ++j) {
    sp.pose[j] = get<double>(bytes, 24 + 8 * j);
    if (!std::isfinite(sp.pose[j])) {
      return Status::error(ErrorCode::kInvalidArgument, "setpoint %llu: pose value %zu not finite",
                           static_cast<unsigned long long>(sp.seq), j + 1);
    }
  }
  return sp;
}

Result<std::unique_ptr<SetpointReceiver>> SetpointReceiver::open(const std::string& path,
                                                                 Check check, Sink sink,
                                                                 const cdpr::Clock& clock) {
  sockaddr_un addr{};
  if (path.empty() || path.size() >= sizeof addr.sun_path) {
    return Status::error(ErrorCode::kInvalidArgument, "stream socket path '%s' is too long",
                         path.c_str());
  }
  const int fd = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    return Status::error(ErrorCode::kIoError, "stream socket: %s", std::strerror(errno));
  }
  addr.sun_family = AF_UNIX;
  std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
  (void)::unlink(path.c_str());
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0 ||
      ::chmod(path.c_str(), 0660) != 0) {
    const int e = errno;
    ::close(fd);
    return Status::error(ErrorCode::kIoError, "stream socket %s: %s", path.c_str(),
                         std::strerror(e));
  }
  std::unique_ptr<SetpointReceiver> r(
      new SetpointReceiver(path, fd, std::move(check), std::move(sink), clock));
  r->thread_ = std::thread([p = r.get()] { p->run(); });
  return r;
}

SetpointReceiver::SetpointReceiver(std::string path, int fd, Check check, Sink sink,
                                   const cdpr::Clock& clock)
    : path_(std::move(path)),
      fd_(fd),
      check_(std::move(check)),
      sink_(std::move(sink)),
      clock_(clock) {}

SetpointReceiver::~SetpointReceiver() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  ::close(fd_);
  (void)::unlink(path_.c_str());
}

StreamCounters SetpointReceiver::counters() const {
  return {received_.load(),  malformed_.load(), gaps_.load(),
          reordered_.load(), refused_.load(),   overflow_.load()};
}

void SetpointReceiver::run() {
  std::array<std::byte, kSetpointBytes + 1> buf{};  // one more: a longer datagram is seen as such
  while (!stop_.load()) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, kPollMs) <= 0) continue;
    const ssize_t n = ::recv(fd_, buf.data(), buf.size(), MSG_DONTWAIT);
    if (n < 0) continue;
    handle(std::span<const std::byte>(buf.data(), static_cast<std::size_t>(n)));
  }
}

void SetpointReceiver::handle(std::span<const std::byte> bytes) {
  const std::int64_t now = clock_.now().count();
  auto sp = decode_setpoint(bytes);
  if (!sp.ok()) {
    ++malformed_;
    return;
  }
  if (have_seq_ && sp->seq <= last_seq_) {
    ++reordered_;
    return;
  }
  if (have_seq_ && sp->seq > last_seq_ + 1) gaps_ += sp->seq - last_seq_ - 1;
  have_seq_ = true;
  last_seq_ = sp->seq;
  sp->received_ns = now;
  const Pose pose{Eigen::Vector3d(sp->pose[0], sp->pose[1], sp->pose[2]),
                  Eigen::Vector3d(sp->pose[3], sp->pose[4], sp->pose[5])};
  if (!check_(pose).ok()) {
    ++refused_;
    sp->verdict = StreamSetpoint::Verdict::kRefused;
  }
  if (!sink_(*sp)) {
    ++overflow_;
    return;
  }
  ++received_;
}

}  // namespace cdpr::controller
