#include "cdpr/can/can_link.hpp"

#include <linux/can/netlink.h>
#include <linux/if_link.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>
#include <net/if.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace cdpr::can {

namespace {

// The netlink macros (NLMSG_*, RTA_*) cast in C style; these helpers do the same arithmetic.
constexpr std::size_t align4(std::size_t n) {
  return (n + 3) & ~std::size_t{3};
}
constexpr std::size_t kNlHdr = align4(sizeof(nlmsghdr));
constexpr std::size_t kRtaHdr = align4(sizeof(rtattr));
constexpr std::size_t kIfiLen = align4(sizeof(ifinfomsg));
template <typename T>
T* payload(nlmsghdr* nh) {
  return reinterpret_cast<T*>(reinterpret_cast<std::uint8_t*>(nh) + kNlHdr);
}
template <typename T>
const T* payload(const nlmsghdr* nh) {
  return reinterpret_cast<const T*>(reinterpret_cast<const std::uint8_t*>(nh) + kNlHdr);
}

const char* errtext(int err) {
  const char* d = strerrordesc_np(err);
  return d != nullptr ? d : "unknown error";
}

// Appends an attribute at `off` (aligned); returns the new offset, 0 if it does not fit.
std::size_t put_attr(std::uint8_t* buf, std::size_t size, std::size_t off, std::uint16_t type,
                     const void* data, std::size_t len) {
  const std::size_t need = align4(kRtaHdr + len);
  if (off + need > size) return 0;
  auto* rta = reinterpret_cast<rtattr*>(buf + off);
  rta->rta_type = type;
  rta->rta_len = static_cast<unsigned short>(kRtaHdr + len);
  if (len > 0) std::memcpy(buf + off + kRtaHdr, data, len);
  std::memset(buf + off + kRtaHdr + len, 0, need - kRtaHdr - len);
  return off + need;
}

// Walks the attributes in [p, p + len), calling fn(type, data, len) for each.
template <typename Fn>
void for_each_attr(const std::uint8_t* p, std::size_t len, Fn&& fn) {
  std::size_t off = 0;
  while (len - off >= sizeof(rtattr)) {
    const auto* rta = reinterpret_cast<const rtattr*>(p + off);
    if (rta->rta_len < sizeof(rtattr) || rta->rta_len > len - off) break;
    fn(static_cast<std::uint16_t>(rta->rta_type & ~NLA_F_NESTED), p + off + kRtaHdr,
       static_cast<std::size_t>(rta->rta_len) - kRtaHdr);
    off += align4(rta->rta_len);
    if (off > len) break;
  }
}

std::size_t begin_request(std::uint8_t* buf, std::size_t size, std::uint16_t type,
                          std::uint16_t flags, int ifindex, std::uint32_t seq) {
  const std::size_t head = kNlHdr + kIfiLen;
  if (size < head) return 0;
  std::memset(buf, 0, head);
  auto* nh = reinterpret_cast<nlmsghdr*>(buf);
  nh->nlmsg_type = type;
  nh->nlmsg_flags = flags;
  nh->nlmsg_seq = seq;
  auto* ifi = payload<ifinfomsg>(nh);
  ifi->ifi_family = AF_UNSPEC;
  ifi->ifi_index = ifindex;
  return head;
}

}  // namespace

const char* to_string(RecoveryOutcome::Action a) {
  switch (a) {
    case RecoveryOutcome::Action::kNone:
      return "none";
    case RecoveryOutcome::Action::kKernelRestarts:
      return "the kernel restarts it (restart-ms)";
    case RecoveryOutcome::Action::kRestarted:
      return "controller restarted";
    case RecoveryOutcome::Action::kNotBusOff:
      return "not bus-off any more";
    case RecoveryOutcome::Action::kLinkCycled:
      return "interface taken down and up";
    case RecoveryOutcome::Action::kFailed:
      return "failed";
  }
  return "?";
}

std::size_t CanLink::build_restart_request(std::uint8_t* buf, std::size_t size, int ifindex,
                                           std::uint32_t seq) {
  std::size_t off = begin_request(buf, size, RTM_NEWLINK, NLM_F_REQUEST | NLM_F_ACK, ifindex, seq);
  if (off == 0) return 0;
  // IFLA_LINKINFO { IFLA_INFO_KIND "can", IFLA_INFO_DATA { IFLA_CAN_RESTART = 1 } }
  const std::size_t linkinfo = off;
  off = put_attr(buf, size, off, IFLA_LINKINFO, nullptr, 0);
  if (off == 0) return 0;
  off = put_attr(buf, size, off, IFLA_INFO_KIND, "can", 4);
  if (off == 0) return 0;
  const std::size_t data = off;
  off = put_attr(buf, size, off, IFLA_INFO_DATA, nullptr, 0);
  if (off == 0) return 0;
  const std::uint32_t one = 1;
  off = put_attr(buf, size, off, IFLA_CAN_RESTART, &one, sizeof(one));
  if (off == 0) return 0;
  reinterpret_cast<rtattr*>(buf + data)->rta_len = static_cast<unsigned short>(off - data);
  reinterpret_cast<rtattr*>(buf + linkinfo)->rta_len = static_cast<unsigned short>(off - linkinfo);
  reinterpret_cast<nlmsghdr*>(buf)->nlmsg_len = static_cast<std::uint32_t>(off);
  return off;
}

Result<std::unique_ptr<CanLink>> CanLink::open(const std::string& ifname) {
  if (ifname.empty() || ifname.size() >= IFNAMSIZ) {
    return Status::error(ErrorCode::kInvalidArgument, "'%s': not a valid interface name",
                         ifname.c_str());
  }
  const unsigned index = if_nametoindex(ifname.c_str());
  if (index == 0) {
    return Status::error(ErrorCode::kNotFound, "%s: no such interface (%s)", ifname.c_str(),
                         errtext(errno));
  }
  const int fd = ::socket(AF_NETLINK, SOCK_RAW | SOCK_CLOEXEC, NETLINK_ROUTE);
  if (fd < 0) {
    return Status::error(ErrorCode::kIoError, "%s: netlink socket: %s", ifname.c_str(),
                         errtext(errno));
  }
  // Answers come at once; a bounded wait keeps a lost answer from blocking the caller.
  timeval tv{0, 200000};
  (void)::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  sockaddr_nl local{};
  local.nl_family = AF_NETLINK;
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&local), sizeof(local)) < 0) {
    const int err = errno;
    ::close(fd);
    return Status::error(ErrorCode::kIoError, "%s: netlink bind: %s", ifname.c_str(), errtext(err));
  }
  return std::unique_ptr<CanLink>(new CanLink(fd, ifname, static_cast<int>(index)));
}

CanLink::~CanLink() {
  if (fd_ >= 0) ::close(fd_);
}

int CanLink::transact(std::size_t len, std::size_t* answer_len) {
  auto* req = reinterpret_cast<nlmsghdr*>(buf_.data());
  const std::uint32_t seq = req->nlmsg_seq;
  sockaddr_nl kernel{};
  kernel.nl_family = AF_NETLINK;
  if (::sendto(fd_, buf_.data(), len, 0, reinterpret_cast<const sockaddr*>(&kernel),
               sizeof(kernel)) < 0) {
    return errno;
  }
  for (;;) {
    const ssize_t r = ::recv(fd_, buf_.data(), buf_.size(), 0);
    if (r < 0) {
      if (errno == EINTR) continue;
      return errno == EAGAIN ? ETIMEDOUT : errno;
    }
    const auto total = static_cast<std::size_t>(r);
    std::size_t off = 0;
    while (total - off >= sizeof(nlmsghdr)) {
      auto* nh = reinterpret_cast<nlmsghdr*>(buf_.data() + off);
      if (nh->nlmsg_len < sizeof(nlmsghdr) || nh->nlmsg_len > total - off) break;
      if (nh->nlmsg_seq == seq) {
        if (nh->nlmsg_type == NLMSG_ERROR) return -payload<nlmsgerr>(nh)->error;  // 0: ack
        if (answer_len != nullptr) {
          // Move the answer to the start of the buffer.
          const std::uint32_t n = nh->nlmsg_len;
          if (off != 0) std::memmove(buf_.data(), buf_.data() + off, n);
          *answer_len = n;
          return 0;
        }
      }
      // Otherwise an answer to an earlier, timed-out request: skip it.
      off += align4(nh->nlmsg_len);
    }
  }
}

int CanLink::query_errno(LinkInfo& out) {
  out = LinkInfo{};
  std::size_t len =
      begin_request(buf_.data(), buf_.size(), RTM_GETLINK, NLM_F_REQUEST, ifindex_, ++seq_);
  reinterpret_cast<nlmsghdr*>(buf_.data())->nlmsg_len = static_cast<std::uint32_t>(len);
  std::size_t answer = 0;
  const int err = transact(len, &answer);
  if (err != 0) return err;
  const auto* nh = reinterpret_cast<const nlmsghdr*>(buf_.data());
  if (nh->nlmsg_type != RTM_NEWLINK) return EPROTO;
  if (answer < kNlHdr + kIfiLen) return EPROTO;
  const auto* ifi = payload<ifinfomsg>(nh);
  out.ifindex = ifi->ifi_index;
  out.up = (ifi->ifi_flags & IFF_UP) != 0;
  const auto* attrs = buf_.data() + kNlHdr + kIfiLen;
  const std::size_t attrs_len = answer - kNlHdr - kIfiLen;
  for_each_attr(attrs, attrs_len, [&](std::uint16_t type, const std::uint8_t* p, std::size_t n) {
    if (type != IFLA_LINKINFO) return;
    for_each_attr(p, n, [&](std::uint16_t t, const std::uint8_t* q, std::size_t m) {
      if (t == IFLA_INFO_KIND) {
        const std::size_t k = m < out.kind.size() - 1 ? m : out.kind.size() - 1;
        std::memcpy(out.kind.data(), q, k);
        out.kind[k] = '\0';
        out.controller = std::strcmp(out.kind.data(), "can") == 0;
      } else if (t == IFLA_INFO_DATA) {
        for_each_attr(q, m, [&](std::uint16_t c, const std::uint8_t* d, std::size_t dn) {
          std::uint32_t v = 0;
          if (dn >= sizeof(v)) std::memcpy(&v, d, sizeof(v));
          if (c == IFLA_CAN_STATE) out.state = static_cast<ControllerState>(v);
          if (c == IFLA_CAN_RESTART_MS) out.restart_ms = v;
          if (c == IFLA_CAN_BITTIMING) out.bitrate = v;  // can_bittiming starts with bitrate
        });
      }
    });
  });
  return 0;
}

int CanLink::restart_errno() {
  const std::size_t len = build_restart_request(buf_.data(), buf_.size(), ifindex_, ++seq_);
  if (len == 0) return ENOBUFS;
  return transact(len, nullptr);
}

int CanLink::set_up_errno(bool up) {
  const std::size_t len = begin_request(buf_.data(), buf_.size(), RTM_NEWLINK,
                                        NLM_F_REQUEST | NLM_F_ACK, ifindex_, ++seq_);
  auto* nh = reinterpret_cast<nlmsghdr*>(buf_.data());
  auto* ifi = payload<ifinfomsg>(nh);
  ifi->ifi_flags = up ? IFF_UP : 0;
  ifi->ifi_change = IFF_UP;
  nh->nlmsg_len = static_cast<std::uint32_t>(len);
  return transact(len, nullptr);
}

RecoveryOutcome CanLink::recover() {
  RecoveryOutcome o;
  LinkInfo info;
  if (query_errno(info) == 0 && info.controller && info.restart_ms > 0) {
    o.action = RecoveryOutcome::Action::kKernelRestarts;
    return o;
  }
  const int err = restart_errno();
  if (err == 0) {
    o.action = RecoveryOutcome::Action::kRestarted;
    return o;
  }
  if (err == EBUSY) {  // can_restart_now(): the controller is not bus-off
    o.action = RecoveryOutcome::Action::kNotBusOff;
    return o;
  }
  o.restart_error = err;
  if (err == EPERM || err == EACCES) {  // no CAP_NET_ADMIN: down/up is refused as well
    o.action = RecoveryOutcome::Action::kFailed;
    o.error = err;
    return o;
  }
  int e = set_up_errno(false);
  if (e == 0) e = set_up_errno(true);
  if (e != 0) {
    o.action = RecoveryOutcome::Action::kFailed;
    o.error = e;
    (void)set_up_errno(true);  // never leave it down
    return o;
  }
  o.action = RecoveryOutcome::Action::kLinkCycled;
  return o;
}

Status CanLink::query(LinkInfo& out) {
  const int err = query_errno(out);
  if (err == 0) return Status::success();
  return Status::error(ErrorCode::kIoError, "%s: netlink query: %s", name_.c_str(), errtext(err));
}

Status CanLink::restart() {
  const int err = restart_errno();
  if (err == 0) return Status::success();
  switch (err) {
    case EOPNOTSUPP:
      return Status::error(ErrorCode::kUnavailable,
                           "%s: the kernel refuses a CAN controller restart (%s): not a CAN "
                           "controller (vcan?)",
                           name_.c_str(), errtext(err));
    case EINVAL:
      return Status::error(ErrorCode::kFailedPrecondition,
                           "%s: restart refused (%s): restart-ms is set, the kernel restarts it",
                           name_.c_str(), errtext(err));
    case EBUSY:
      return Status::error(ErrorCode::kFailedPrecondition,
                           "%s: restart refused (%s): the controller is not bus-off", name_.c_str(),
                           errtext(err));
    case EPERM:
    case EACCES:
      return Status::error(ErrorCode::kUnavailable, "%s: restart refused (%s): needs CAP_NET_ADMIN",
                           name_.c_str(), errtext(err));
    default:
      return Status::error(ErrorCode::kIoError, "%s: restart: %s", name_.c_str(), errtext(err));
  }
}

Status CanLink::set_up(bool up) {
  const int err = set_up_errno(up);
  if (err == 0) return Status::success();
  return Status::error(
      err == EPERM || err == EACCES ? ErrorCode::kUnavailable : ErrorCode::kIoError,
      "%s: set %s: %s", name_.c_str(), up ? "up" : "down", errtext(err));
}

}  // namespace cdpr::can
