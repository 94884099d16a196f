// A CanBus over a Linux raw CAN socket (SocketCAN), e.g. "can0" or "vcan0".
//
//   auto bus = cdpr::can::SocketCanBus::open("can0", {});
//   if (!bus) return bus.status();     // "unavailable: can0 is down", ...
//   (*bus)->send(frame);
//
// The socket is non-blocking; receive() waits with ppoll(). It asks for a large receive buffer so
// that a slow reader does not lose bursts, counts what the kernel still drops (SO_RXQ_OVFL, in
// stats().rx_dropped), takes the kernel's receive timestamp (SO_TIMESTAMPNS, converted from
// CLOCK_REALTIME to CLOCK_MONOTONIC with an offset re-measured every second) and receives error
// frames selected by an error mask. Nothing allocates after open(); no call throws.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "cdpr/can/can_bus.hpp"

namespace cdpr::can {

struct SocketCanOptions {
  // Requested receive buffer in bytes: SO_RCVBUFFORCE (needs CAP_NET_ADMIN, ignores rmem_max),
  // else SO_RCVBUF (capped by net.core.rmem_max). 0 keeps the kernel default.
  int receive_buffer_bytes = 8 * 1024 * 1024;
  // CAN_ERR_* classes delivered as error frames (CAN_RAW_ERR_FILTER); 0 = no error frames.
  std::uint32_t error_mask = error_class::kAll;
  // Also receive the frames this socket sent (CAN_RAW_RECV_OWN_MSGS). Off, as CanBus promises.
  bool receive_own = false;
};

class SocketCanBus final : public CanBus {
 public:
  // Opens a raw CAN socket bound to `ifname`. Errors name the interface: kUnavailable when the
  // kernel has no AF_CAN or the interface is down, kNotFound when it does not exist,
  // kInvalidArgument when it is not a CAN interface or the name is too long, kIoError otherwise.
  static Result<std::unique_ptr<SocketCanBus>> open(const std::string& ifname,
                                                    const SocketCanOptions& options = {});
  ~SocketCanBus() override;
  SocketCanBus(const SocketCanBus&) = delete;
  SocketCanBus& operator=(const SocketCanBus&) = delete;

  Status send(const Frame& frame) override;
  Status receive(Frame& frame, std::chrono::nanoseconds timeout) override;
  const std::string& name() const override { return name_; }
  BusStats stats() const override;

  // The socket, for callers that multiplex several sources with poll/epoll (readable = frame).
  int fd() const { return fd_; }
  // The receive buffer the kernel granted (getsockopt(SO_RCVBUF), which reports twice the
  // payload size requested because it includes bookkeeping).
  int receive_buffer_bytes() const { return rcvbuf_; }

 private:
  SocketCanBus(int fd, std::string name, int rcvbuf);
  Status read_one(Frame& frame);
  std::int64_t realtime_offset();

  int fd_ = -1;
  std::string name_;
  Status empty_poll_;  // what a poll (timeout 0) that finds no frame returns, made once
  int rcvbuf_ = 0;
  std::atomic<std::uint64_t> sent_{0};
  std::atomic<std::uint64_t> received_{0};
  std::atomic<std::uint64_t> errors_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::int64_t> realtime_offset_{0};     // CLOCK_REALTIME - CLOCK_MONOTONIC, ns
  std::atomic<std::int64_t> offset_measured_at_{0};  // CLOCK_MONOTONIC, ns
};

}  // namespace cdpr::can
