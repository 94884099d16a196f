#include "cdpr/can/socketcan_bus.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <net/if_arp.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <ctime>

namespace cdpr::can {
namespace {

// Thread-safe, allocation-free errno text (glibc >= 2.32).
const char* errtext(int err) {
  const char* d = strerrordesc_np(err);
  return d != nullptr ? d : "unknown error";
}

std::int64_t to_ns(const timespec& ts) {
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000LL + ts.tv_nsec;
}

// CLOCK_REALTIME - CLOCK_MONOTONIC, measured between two monotonic reads; of a few tries the one
// with the shortest bracket wins, so a preemption between the reads does not skew it.
std::int64_t measure_realtime_offset() {
  std::int64_t best_offset = 0;
  std::int64_t best_span = INT64_MAX;
  for (int i = 0; i < 5; ++i) {
    timespec m1{};
    timespec real{};
    timespec m2{};
    clock_gettime(CLOCK_MONOTONIC, &m1);
    clock_gettime(CLOCK_REALTIME, &real);
    clock_gettime(CLOCK_MONOTONIC, &m2);
    const std::int64_t span = to_ns(m2) - to_ns(m1);
    if (span < best_span) {
      best_span = span;
      best_offset = to_ns(real) - (to_ns(m1) + span / 2);
    }
  }
  return best_offset;
}

std::int64_t monotonic_now() {
  timespec now{};
  clock_gettime(CLOCK_MONOTONIC, &now);
  return to_ns(now);
}

// Fills ifr_name; the caller has checked the length.
ifreq make_ifreq(const std::string& ifname) {
  ifreq ifr{};
  std::memcpy(ifr.ifr_name, ifname.c_str(), ifname.size() + 1);
  return ifr;
}

class FdCloser {
 public:
  explicit FdCloser(int fd) : fd_(fd) {}
  ~FdCloser() {
    if (fd_ >= 0) ::close(fd_);
  }
  FdCloser(const FdCloser&) = delete;
  FdCloser& operator=(const FdCloser&) = delete;
  int release() {
    const int fd = fd_;
    fd_ = -1;
    return fd;
  }

 private:
  int fd_;
};

}  // namespace

Result<std::unique_ptr<SocketCanBus>> SocketCanBus::open(const std::string& ifname,
                                                         const SocketCanOptions& options) {
  const char* n = ifname.c_str();
  if (ifname.empty() || ifname.size() >= IFNAMSIZ) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "'%s': not a valid interface name (1..%d characters)", n, IFNAMSIZ - 1);
  }
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    const int err = errno;
    if (err == EAFNOSUPPORT || err == EPROTONOSUPPORT || err == ESOCKTNOSUPPORT) {
      return Status::error(ErrorCode::kUnavailable,
                           "%s: this kernel has no SocketCAN support (socket(AF_CAN, CAN_RAW): "
                           "%s); load can/can-raw or use tests/vcan/vcan-run",
                           n, errtext(err));
    }
    return Status::error(ErrorCode::kIoError, "%s: socket(AF_CAN, CAN_RAW): %s", n, errtext(err));
  }
  FdCloser closer(fd);

  // Interface checks through the CAN socket itself (the generic SIOCGIF* ioctls work on any
  // socket), so the messages say exactly what is wrong before bind() gives a vaguer errno.
  ifreq ifr = make_ifreq(ifname);
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
    const int err = errno;
    if (err == ENODEV) {
      return Status::error(ErrorCode::kNotFound, "%s: no such CAN interface", n);
    }
    return Status::error(ErrorCode::kIoError, "%s: SIOCGIFINDEX: %s", n, errtext(err));
  }
  const int ifindex = ifr.ifr_ifindex;

  ifr = make_ifreq(ifname);
  if (::ioctl(fd, SIOCGIFHWADDR, &ifr) == 0 && ifr.ifr_hwaddr.sa_family != ARPHRD_CAN) {
    return Status::error(ErrorCode::kInvalidArgument, "%s is not a CAN interface (link type %u)", n,
                         static_cast<unsigned>(ifr.ifr_hwaddr.sa_family));
  }

  ifr = make_ifreq(ifname);
  if (::ioctl(fd, SIOCGIFFLAGS, &ifr) < 0) {
    return Status::error(ErrorCode::kIoError, "%s: SIOCGIFFLAGS: %s", n, errtext(errno));
  }
  if ((static_cast<unsigned>(ifr.ifr_flags) & IFF_UP) == 0) {
    return Status::error(ErrorCode::kUnavailable, "%s is down (ip link set %s up)", n, n);
  }

  auto set_opt = [&](int level, int opt, const void* value, socklen_t len,
                     const char* what) -> Status {
    if (::setsockopt(fd, level, opt, value, len) < 0) {
      return Status::error(ErrorCode::kIoError, "%s: setsockopt(%s): %s", n, what, errtext(errno));
    }
    return Status::success();
  };

  const can_err_mask_t err_mask = options.error_mask & CAN_ERR_MASK;
  CDPR_RETURN_IF_ERROR(
      set_opt(SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof(err_mask), "CAN_RAW_ERR_FILTER"));
  const int own = options.receive_own ? 1 : 0;
  if (Status s =
          set_opt(SOL_CAN_RAW, CAN_RAW_RECV_OWN_MSGS, &own, sizeof(own), "CAN_RAW_RECV_OWN_MSGS");
      !s.ok()) {
    return s;
  }
  if (options.receive_buffer_bytes > 0) {
    // FORCE needs CAP_NET_ADMIN; without it the plain option still grants up to rmem_max.
    const int want = options.receive_buffer_bytes;
    if (::setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &want, sizeof(want)) < 0) {
      CDPR_RETURN_IF_ERROR(set_opt(SOL_SOCKET, SO_RCVBUF, &want, sizeof(want), "SO_RCVBUF"));
    }
  }
  const int one = 1;
  CDPR_RETURN_IF_ERROR(set_opt(SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof(one), "SO_RXQ_OVFL"));
  CDPR_RETURN_IF_ERROR(set_opt(SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof(one), "SO_TIMESTAMPNS"));
  int granted = 0;
  socklen_t glen = sizeof(granted);
  if (::getsockopt(fd, SOL_SOCKET, SO_RCVBUF, &granted, &glen) < 0) granted = 0;

  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifindex;
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) < 0) {
    const int err = errno;
    if (err == ENETDOWN) {
      return Status::error(ErrorCode::kUnavailable, "%s is down", n);
    }
    if (err == ENODEV) return Status::error(ErrorCode::kNotFound, "%s: no such CAN interface", n);
    return Status::error(ErrorCode::kIoError, "%s: bind: %s", n, errtext(err));
  }
  return std::unique_ptr<SocketCanBus>(new SocketCanBus(closer.release(), ifname, granted));
}

SocketCanBus::SocketCanBus(int fd, std::string name, int rcvbuf)
    : fd_(fd),
      name_(std::move(name)),
      empty_poll_(Status::error(ErrorCode::kTimeout, "%s: no CAN frame waiting", name_.c_str())),
      rcvbuf_(rcvbuf) {
  realtime_offset_.store(measure_realtime_offset(), std::memory_order_relaxed);
  offset_measured_at_.store(monotonic_now(), std::memory_order_relaxed);
}

SocketCanBus::~SocketCanBus() {
  if (fd_ >= 0) ::close(fd_);
}

Status SocketCanBus::send(const Frame& frame) {
  CDPR_RETURN_IF_ERROR(check_frame(frame, name_));
  can_frame cf{};
  if (frame.error) {
    cf.can_id = CAN_ERR_FLAG | (frame.error_class & CAN_ERR_MASK);
    cf.len = CAN_ERR_DLC;
    std::memcpy(cf.data, frame.data.data(), CAN_ERR_DLC);
  } else {
    cf.can_id = frame.extended ? (frame.id & CAN_EFF_MASK) | CAN_EFF_FLAG : frame.id & CAN_SFF_MASK;
    if (frame.rtr) cf.can_id |= CAN_RTR_FLAG;
    cf.len = frame.dlc;
    // Nothing beyond dlc, and no payload for RTR, goes out (same as the virtual bus).
    if (!frame.rtr) std::memcpy(cf.data, frame.data.data(), frame.dlc);
  }
  const ssize_t w = ::write(fd_, &cf, sizeof(cf));
  if (w == static_cast<ssize_t>(sizeof(cf))) {
    sent_.fetch_add(1, std::memory_order_relaxed);
    return Status::success();
  }
  if (w >= 0) {
    return Status::error(ErrorCode::kIoError, "%s: short write (%zd bytes)", name_.c_str(), w);
  }
  const int err = errno;
  switch (err) {
    case EAGAIN:
    case ENOBUFS:
      return Status::error(ErrorCode::kUnavailable, "%s: transmit queue full", name_.c_str());
    case ENETDOWN:
      return Status::error(ErrorCode::kUnavailable, "%s is down", name_.c_str());
    case EINVAL:
      return Status::error(ErrorCode::kInvalidArgument, "%s: kernel refused the frame: %s",
                           name_.c_str(), errtext(err));
    default:
      return Status::error(ErrorCode::kIoError, "%s: write: %s", name_.c_str(), errtext(err));
  }
}

// The kernel stamps received frames with CLOCK_REALTIME; cdpr works in CLOCK_MONOTONIC. The
// offset between the two is cached and re-measured once a second: measuring it per frame would
// add its measurement noise to every stamp (and could reorder close frames), while a clock step
// or NTP slew shows up within a second.
std::int64_t SocketCanBus::realtime_offset() {
  const std::int64_t now = monotonic_now();
  if (now - offset_measured_at_.load(std::memory_order_relaxed) > 1'000'000'000LL) {
    realtime_offset_.store(measure_realtime_offset(), std::memory_order_relaxed);
    offset_measured_at_.store(now, std::memory_order_relaxed);
  }
  return realtime_offset_.load(std::memory_order_relaxed);
}

Status SocketCanBus::read_one(Frame& frame) {
  can_frame cf{};
  iovec iov{&cf, sizeof(cf)};
  // Room for a timespec and the drop counter; aligned like cmsghdr.
  alignas(cmsghdr) unsigned char
      control[CMSG_SPACE(sizeof(timespec)) + CMSG_SPACE(sizeof(std::uint32_t))];
  msghdr msg{};
  msg.msg_iov = &iov;
  msg.msg_iovlen = 1;
  msg.msg_control = control;
  msg.msg_controllen = sizeof(control);
  const ssize_t r = ::recvmsg(fd_, &msg, MSG_DONTWAIT);
  if (r < 0) {
    const int err = errno;
    if (err == EAGAIN || err == EINTR) return Status(ErrorCode::kTimeout, "");
    if (err == ENETDOWN) {
      return Status::error(ErrorCode::kUnavailable, "%s is down", name_.c_str());
    }
    return Status::error(ErrorCode::kIoError, "%s: recvmsg: %s", name_.c_str(), errtext(err));
  }
  if (r != static_cast<ssize_t>(sizeof(cf))) {
    return Status::error(ErrorCode::kProtocolError, "%s: unexpected %zd-byte CAN frame (CAN FD?)",
                         name_.c_str(), r);
  }
  std::int64_t stamp = 0;
  for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
    if (c->cmsg_level != SOL_SOCKET) continue;
    if (c->cmsg_type == SO_TIMESTAMPNS) {
      timespec ts{};
      std::memcpy(&ts, CMSG_DATA(c), sizeof(ts));
      stamp = to_ns(ts) - realtime_offset();
    } else if (c->cmsg_type == SO_RXQ_OVFL) {
      // The kernel reports the socket's running total of drops.
      std::uint32_t drops = 0;
      std::memcpy(&drops, CMSG_DATA(c), sizeof(drops));
      dropped_.store(drops, std::memory_order_relaxed);
    }
  }
  if (stamp == 0) stamp = monotonic_now();

  frame = Frame{};
  frame.timestamp = Timestamp{stamp};
  frame.dlc = cf.len > CAN_MAX_DLEN ? CAN_MAX_DLEN : cf.len;
  if ((cf.can_id & CAN_ERR_FLAG) != 0) {
    frame.error = true;
    frame.error_class = cf.can_id & CAN_ERR_MASK;
    std::memcpy(frame.data.data(), cf.data, CAN_ERR_DLC);
    errors_.fetch_add(1, std::memory_order_relaxed);
  } else {
    frame.extended = (cf.can_id & CAN_EFF_FLAG) != 0;
    frame.rtr = (cf.can_id & CAN_RTR_FLAG) != 0;
    frame.id = cf.can_id & (frame.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
    if (!frame.rtr) std::memcpy(frame.data.data(), cf.data, frame.dlc);
  }
  received_.fetch_add(1, std::memory_order_relaxed);
  return Status::success();
}

Status SocketCanBus::receive(Frame& frame, std::chrono::nanoseconds timeout) {
  timespec start{};
  clock_gettime(CLOCK_MONOTONIC, &start);
  const std::int64_t deadline = to_ns(start) + (timeout.count() > 0 ? timeout.count() : 0);
  for (;;) {
    Status s = read_one(frame);
    if (s.code() != ErrorCode::kTimeout) return s;
    timespec now{};
    clock_gettime(CLOCK_MONOTONIC, &now);
    const std::int64_t left = deadline - to_ns(now);
    if (left <= 0) {
      // A poll (timeout 0, the RT cycle's reads until empty) gets the message made at
      // construction: formatting one costs more than the rest of the read.
      if (timeout.count() <= 0) return empty_poll_;
      return Status::error(ErrorCode::kTimeout, "%s: no CAN frame within %lld us", name_.c_str(),
                           static_cast<long long>(timeout.count() / 1000));
    }
    pollfd p{fd_, POLLIN, 0};
    const timespec wait{static_cast<time_t>(left / 1'000'000'000LL),
                        static_cast<long>(left % 1'000'000'000LL)};
    const int pr = ::ppoll(&p, 1, &wait, nullptr);
    if (pr < 0 && errno != EINTR) {
      return Status::error(ErrorCode::kIoError, "%s: poll: %s", name_.c_str(), errtext(errno));
    }
    if (pr > 0 && (p.revents & (POLLERR | POLLNVAL)) != 0 && (p.revents & POLLIN) == 0) {
      return Status::error(ErrorCode::kIoError, "%s: socket error while waiting", name_.c_str());
    }
  }
}

BusStats SocketCanBus::stats() const {
  BusStats s;
  s.frames_sent = sent_.load(std::memory_order_relaxed);
  s.frames_received = received_.load(std::memory_order_relaxed);
  s.error_frames = errors_.load(std::memory_order_relaxed);
  s.rx_dropped = dropped_.load(std::memory_order_relaxed);
  return s;
}

}  // namespace cdpr::can
