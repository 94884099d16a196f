// Control of a SocketCAN interface through rtnetlink (NETLINK_ROUTE), what `ip link` does:
//
//   auto link = cdpr::can::CanLink::open("can0");    // allocates; errors name the interface
//   LinkInfo info; link->query(info);                // kind "can"/"vcan", controller state,
//                                                    // restart-ms, bitrate, up
//   link->recover(outcome);                          // after bus-off: the recovery policy below
//
// The kernel restarts a bus-off CAN controller by itself only when restart-ms is set
// (`ip link set can0 type can restart-ms 100`). Otherwise someone must restart it: recover()
// does nothing when restart-ms is set, else asks for a controller restart (IFLA_CAN_RESTART, as
// `ip link set can0 type can restart`); where the kernel refuses that (the interface is no CAN
// controller, e.g. vcan, or the driver cannot restart) it takes the interface down and up again,
// which resets the controller. Restart and down/up need CAP_NET_ADMIN.
//
// After open(), query/restart/set_up/recover use fixed buffers: they never allocate or throw, so
// the RT cycle may call recover() from the bus-off hook (it makes two or three netlink calls).
// The low-level calls return 0 or an errno; the Status wrappers are for start-up code.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "cdpr/status.hpp"

namespace cdpr::can {

// Controller states (enum can_state of linux/can/netlink.h).
enum class ControllerState : std::uint32_t {
  kErrorActive = 0,
  kErrorWarning = 1,
  kErrorPassive = 2,
  kBusOff = 3,
  kStopped = 4,
  kSleeping = 5,
  kUnknown = 0xFF,  // not a CAN controller (vcan) or not reported
};

struct LinkInfo {
  int ifindex = 0;
  bool up = false;              // administratively up (IFF_UP)
  std::array<char, 16> kind{};  // IFLA_INFO_KIND: "can" for controllers, "vcan", ...
  bool controller = false;      // kind "can": has a state, restart-ms, bit timing
  ControllerState state = ControllerState::kUnknown;
  std::uint32_t restart_ms = 0;  // kernel auto-restart after bus-off; 0 = off
  std::uint32_t bitrate = 0;     // bit/s, controllers only
};

// What recover() did.
struct RecoveryOutcome {
  enum class Action : std::uint8_t {
    kNone,            // nothing tried yet
    kKernelRestarts,  // restart-ms is set: the kernel restarts the controller itself
    kRestarted,       // IFLA_CAN_RESTART accepted
    kNotBusOff,       // the controller was no longer bus-off (EBUSY): nothing to do
    kLinkCycled,      // restart refused (errno in restart_error); down and up again
    kFailed,          // nothing worked; error is the errno of the last attempt
  };
  Action action = Action::kNone;
  int restart_error = 0;  // errno of a refused IFLA_CAN_RESTART (EOPNOTSUPP on vcan)
  int error = 0;          // errno when kFailed
};
const char* to_string(RecoveryOutcome::Action a);

class CanLink {
 public:
  // Opens a netlink socket for `ifname`; kNotFound when there is no such interface, kIoError
  // when netlink is unavailable.
  static Result<std::unique_ptr<CanLink>> open(const std::string& ifname);
  ~CanLink();
  CanLink(const CanLink&) = delete;
  CanLink& operator=(const CanLink&) = delete;

  const std::string& name() const { return name_; }
  int ifindex() const { return ifindex_; }

  // Allocation-free calls: 0 or an errno.
  int query_errno(LinkInfo& out);
  int restart_errno();
  int set_up_errno(bool up);
  // The recovery policy above. Returns the outcome; never allocates.
  RecoveryOutcome recover();

  // Status wrappers (messages name the interface and the reason).
  Status query(LinkInfo& out);
  Status restart();
  Status set_up(bool up);

  // The RTM_NEWLINK request IFLA_CAN_RESTART sends (exposed for tests): writes it into `buf`
  // and returns its length (0 if `size` is too small).
  static std::size_t build_restart_request(std::uint8_t* buf, std::size_t size, int ifindex,
                                           std::uint32_t seq);

 private:
  CanLink(int fd, std::string name, int ifindex)
      : fd_(fd), name_(std::move(name)), ifindex_(ifindex) {}
  // Sends a request of `len` bytes from buf_ and waits for its answer; for RTM_GETLINK the
  // answer stays in buf_ (`answer_len`). 0 or an errno.
  int transact(std::size_t len, std::size_t* answer_len);

  int fd_ = -1;
  std::string name_;
  int ifindex_ = 0;
  std::uint32_t seq_ = 0;
  alignas(8) std::array<std::uint8_t, 16384> buf_{};
};

}  // namespace cdpr::can
