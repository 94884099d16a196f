// Latency and jitter of the setpoint stream's channel, measured with the real clock: a sender
// thread sends one setpoint datagram per period (CLOCK_MONOTONIC send time in the record, as
// tools/cdpr-stream.py does) to cdprd's SetpointReceiver on a UNIX datagram socket; the receiver
// thread decodes it and hands it through the RT loop's ring (SpscRing, as RtController's) to a
// loop that wakes every period on its own phase, drains the ring and applies the newest, as the
// RT cycle does. Printed: the receive latency (send -> the receiver's decode) and the apply
// latency (send -> the cycle that applied it: what `cdprctl status` reports as
// stream.latency_us), p50 / p99 / max, over the run. Not included: the receiver's pose check
// (here accepts all) and the rest of the RT cycle's compute. Nothing is asserted.
//
//   stream_latency_bench [--seconds S] [--period-ms P]
//     S: seconds of streaming (default 20), P: the sender's and the loop's period (default 4 ms)
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/controller/setpoint_stream.hpp"
#include "cdpr/controller/spsc_ring.hpp"
#include "cdpr/core/clock.hpp"

namespace {

using cdpr::controller::SetpointReceiver;
using cdpr::controller::SpscRing;
using cdpr::controller::StreamSetpoint;
using SteadyTime = std::chrono::steady_clock;

std::int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(SteadyTime::now().time_since_epoch())
      .count();
}

void print(const char* what, std::vector<std::int64_t> v) {
  if (v.empty()) {
    std::printf("  %-40s no samples\n", what);
    return;
  }
  std::sort(v.begin(), v.end());
  auto at = [&](double q) {
    return static_cast<double>(v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))]) *
           1e-3;
  };
  std::printf("  %-40s %7zu  p50 %8.1f us  p99 %8.1f us  max %8.1f us\n", what, v.size(), at(0.5),
              at(0.99), static_cast<double>(v.back()) * 1e-3);
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 20.0, period_ms = 4.0;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string a = argv[i];
    if (a == "--seconds") {
      seconds = std::atof(argv[i + 1]);
    } else if (a == "--period-ms") {
      period_ms = std::atof(argv[i + 1]);
    } else {
      std::fprintf(stderr, "usage: %s [--seconds S] [--period-ms P]\n", argv[0]);
      return 2;
    }
  }
  if (!(seconds > 0.0) || !(period_ms > 0.0)) {
    std::fprintf(stderr, "stream_latency_bench: --seconds and --period-ms must be > 0\n");
    return 2;
  }
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("cdpr-stream-bench-" + std::to_string(::getpid()) + ".sock"))
                               .string();
  SpscRing<StreamSetpoint, 64> ring;
  cdpr::SteadyClock clock;
  std::vector<std::int64_t> received;
  received.reserve(static_cast<std::size_t>(seconds * 1000.0 / period_ms) + 16);
  auto receiver = SetpointReceiver::open(
      path, [](const cdpr::Pose&) { return cdpr::Status::success(); },
      [&](const StreamSetpoint& sp) { return ring.push(sp); }, clock);
  if (!receiver.ok()) {
    std::fprintf(stderr, "stream_latency_bench: %s\n", receiver.status().to_string().c_str());
    return 1;
  }
  const auto period = std::chrono::nanoseconds(static_cast<std::int64_t>(period_ms * 1e6));
  const auto end =
      SteadyTime::now() + std::chrono::nanoseconds(static_cast<std::int64_t>(seconds * 1e9));
  std::atomic<bool> done{false};

  // The application: its own period and phase, one datagram each.
  std::thread sender([&] {
    const int fd = ::socket(AF_UNIX, SOCK_DGRAM, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path.c_str(), sizeof(addr.sun_path) - 1);
    cdpr::Pose pose;
    auto next = SteadyTime::now() + period / 3;  // a phase of its own
    for (std::uint64_t seq = 1; SteadyTime::now() < end; ++seq) {
      std::this_thread::sleep_until(next);
      next += period;
      const auto bytes = cdpr::controller::encode_setpoint(seq, now_ns(), pose);
      (void)::sendto(fd, bytes.data(), bytes.size(), 0, reinterpret_cast<const sockaddr*>(&addr),
                     sizeof(addr));
    }
    ::close(fd);
    done = true;
  });

  // The cycle: drain the ring, apply the newest.
  std::vector<std::int64_t> applied;
  applied.reserve(received.capacity());
  auto next = SteadyTime::now();
  while (!done.load()) {
    next += period;
    std::this_thread::sleep_until(next);
    const std::int64_t t = now_ns();
    StreamSetpoint sp, newest;
    bool any = false;
    while (ring.pop(sp)) {
      received.push_back(sp.received_ns - sp.sent_ns);
      newest = sp;
      any = true;
    }
    if (any) applied.push_back(t - newest.sent_ns);
  }
  sender.join();
  const auto c = (*receiver)->counters();
  std::printf("setpoint stream, %.0f s at a %.1f ms period (sender and loop on their own phases)\n",
              seconds, period_ms);
  print("send -> received (socket, receiver thread)", received);
  print("send -> applied by the cycle", applied);
  std::printf("  received %llu, malformed %llu, gaps %llu, overflow %llu\n",
              static_cast<unsigned long long>(c.received),
              static_cast<unsigned long long>(c.malformed), static_cast<unsigned long long>(c.gaps),
              static_cast<unsigned long long>(c.overflow));
  return 0;
}
