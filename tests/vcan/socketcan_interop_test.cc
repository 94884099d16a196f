// SocketCanBus against independent peers on a kernel vcan bus (run through tests/vcan/vcan-run):
// can-utils cansend/candump, python3-can and the kernel's own checks (interface down, drops).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "cdpr/can/socketcan_bus.hpp"

extern char** environ;

namespace cdpr::can {
namespace {

using std::chrono::milliseconds;

// A child process with stdout+stderr on a pipe we read (posix_spawn, no shell).
class Child {
 public:
  explicit Child(const std::vector<std::string>& argv) {
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0) return;
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, fds[1], STDOUT_FILENO);
    posix_spawn_file_actions_adddup2(&fa, fds[1], STDERR_FILENO);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    if (posix_spawnp(&pid_, args[0], &fa, nullptr, args.data(), environ) != 0) pid_ = -1;
    posix_spawn_file_actions_destroy(&fa);
    ::close(fds[1]);
    out_ = fds[0];
  }
  ~Child() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      wait();
    }
    if (out_ >= 0) ::close(out_);
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;

  bool started() const { return pid_ > 0; }

  // Reads until `pred(output)` holds, the child closes its output, or the timeout passes.
  template <typename Pred>
  bool read_until(Pred pred, milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    char buf[4096];
    while (!pred(output_)) {
      const auto left =
          std::chrono::duration_cast<milliseconds>(end - std::chrono::steady_clock::now());
      if (left.count() <= 0) return false;
      pollfd p{out_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
      const ssize_t n = ::read(out_, buf, sizeof(buf));
      if (n <= 0) return pred(output_);
      output_.append(buf, static_cast<std::size_t>(n));
    }
    return true;
  }

  // Waits for exit and returns the exit status (-1 if it did not exit normally).
  int wait() {
    if (pid_ <= 0) return -1;
    int st = 0;
    while (::waitpid(pid_, &st, 0) < 0 && errno == EINTR) {
    }
    pid_ = -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  }
  int finish(milliseconds timeout) {
    read_until([](const std::string&) { return false; }, timeout);
    return wait();
  }
  void stop() {
    if (pid_ > 0) ::kill(pid_, SIGTERM);
  }
  const std::string& output() const { return output_; }

 private:
  pid_t pid_ = -1;
  int out_ = -1;
  std::string output_;
};

const char* vcan() {
  const char* e = std::getenv("CDPR_VCAN");
  return e != nullptr ? e : "vcan0";
}

std::unique_ptr<SocketCanBus> open_or_fail(const std::string& ifname, SocketCanOptions o = {}) {
  auto bus = SocketCanBus::open(ifname, o);
  EXPECT_TRUE(bus.ok()) << bus.status().to_string();
  return bus.ok() ? std::move(*bus) : nullptr;
}

int run(const std::vector<std::string>& argv, std::string* out = nullptr) {
  Child c(argv);
  if (!c.started()) return -1;
  const int rc = c.finish(milliseconds(20000));
  if (out != nullptr) *out = c.output();
  return rc;
}

struct Expect {
  const char* cansend;  // what cansend is given
  std::uint32_t id;
  bool extended;
  bool rtr;
  std::uint8_t dlc;
  std::vector<std::uint8_t> data;
};

const std::vector<Expect>& cases() {
  static const std::vector<Expect> k = {
      {"123#DEADBEEF", 0x123, false, false, 4, {0xDE, 0xAD, 0xBE, 0xEF}},
      {"7FF#0102030405060708", 0x7FF, false, false, 8, {1, 2, 3, 4, 5, 6, 7, 8}},
      {"1F334455#1122334455667788",
       0x1F334455,
       true,
       false,
       8,
       {0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88}},
      {"00000123#AA", 0x123, true, false, 1, {0xAA}},  // 8 hex digits: extended even if small
      {"080#", 0x080, false, false, 0, {}},
      {"701#R", 0x701, false, true, 0, {}},
      {"00000701#R3", 0x701, true, true, 3, {}},
  };
  return k;
}

TEST(SocketCanInterop, PrintsThePath) {
  const char* path = std::getenv("CDPR_VCAN_PATH");
  std::printf("socketcan_interop: kernel CAN path: %s\n", path != nullptr ? path : "unknown");
  auto bus = open_or_fail(vcan());
  ASSERT_NE(bus, nullptr);
  std::printf("socketcan_interop: %s receive buffer granted: %d bytes\n", vcan(),
              bus->receive_buffer_bytes());
  EXPECT_GE(bus->receive_buffer_bytes(), 8 * 1024 * 1024) << "8 MiB asked, SO_RCVBUFFORCE as root";
}

TEST(SocketCanInterop, CansendFramesReachUs) {
  auto bus = open_or_fail(vcan());
  ASSERT_NE(bus, nullptr);
  for (const Expect& e : cases()) {
    ASSERT_EQ(run({"cansend", vcan(), e.cansend}), 0) << "cansend " << e.cansend;
    Frame f;
    Status s = bus->receive(f, milliseconds(5000));
    ASSERT_TRUE(s.ok()) << e.cansend << ": " << s.to_string();
    EXPECT_EQ(f.id, e.id) << e.cansend;
    EXPECT_EQ(f.extended, e.extended) << e.cansend;
    EXPECT_EQ(f.rtr, e.rtr) << e.cansend;
    EXPECT_FALSE(f.error) << e.cansend;
    EXPECT_EQ(f.dlc, e.dlc) << e.cansend;
    for (std::size_t i = 0; i < e.data.size(); ++i) EXPECT_EQ(f.data[i], e.data[i]) << e.cansend;
  }
  EXPECT_EQ(bus->stats().frames_received, cases().size());
}

// candump -L prints "(time) vcan0 ID#DATA"; that ID#DATA text is compared with cansend syntax.
TEST(SocketCanInterop, CandumpSeesOurFrames) {
  auto bus = open_or_fail(vcan());
  ASSERT_NE(bus, nullptr);
  Child dump({"candump", "-L", vcan()});
  ASSERT_TRUE(dump.started());
  // candump needs a moment to bind: send a marker until it shows up.
  Frame marker;
  marker.id = 0x5EE;
  bool seen = false;
  std::uint64_t markers = 0;
  for (int i = 0; i < 300 && !seen; ++i) {  // candump may start late: up to 30 s
    ASSERT_TRUE(bus->send(marker).ok());
    ++markers;
    seen = dump.read_until([](const std::string& o) { return o.find("5EE#") != std::string::npos; },
                           milliseconds(100));
  }
  ASSERT_TRUE(seen) << "candump never showed the marker: " << dump.output();

  for (const Expect& e : cases()) {
    Frame f;
    f.id = e.id;
    f.extended = e.extended;
    f.rtr = e.rtr;
    f.dlc = e.dlc;
    for (std::size_t i = 0; i < e.data.size(); ++i) f.data[i] = e.data[i];
    ASSERT_TRUE(bus->send(f).ok());
  }
  Frame end;
  end.id = 0x5EF;
  ASSERT_TRUE(bus->send(end).ok());
  ASSERT_TRUE(
      dump.read_until([](const std::string& o) { return o.find("5EF#\n") != std::string::npos; },
                      milliseconds(5000)))
      << dump.output();
  dump.stop();
  const std::string& out = dump.output();
  std::size_t from = out.rfind("5EE#");
  for (const Expect& e : cases()) {
    const std::string want = std::string(" ") + e.cansend + "\n";
    const std::size_t at = out.find(want, from);
    EXPECT_NE(at, std::string::npos) << "candump did not show " << e.cansend << ":\n" << out;
    if (at != std::string::npos) from = at;  // and in the order we sent them
  }
  EXPECT_EQ(bus->stats().frames_sent, markers + cases().size() + 1);
}

void expect_error_frame(SocketCanBus& bus, std::uint32_t cls, std::uint8_t data1, const char* who) {
  Frame f;
  Status s = bus.receive(f, milliseconds(10000));
  ASSERT_TRUE(s.ok()) << who << ": " << s.to_string();
  EXPECT_TRUE(f.error) << who;
  EXPECT_EQ(f.error_class, cls) << who;
  EXPECT_EQ(f.dlc, 8) << who;
  EXPECT_EQ(f.data[1], data1) << who;
}

TEST(SocketCanInterop, ErrorFramesFromIndependentPeers) {
  auto bus = open_or_fail(vcan());
  ASSERT_NE(bus, nullptr);
  // python3-can (Debian's /usr/bin/python3): controller problem, TX error-passive.
  const std::string py =
      "import can\n"
      "b = can.Bus(interface='socketcan', channel='" +
      std::string(vcan()) +
      "')\n"
      "b.send(can.Message(arbitration_id=0x004, is_error_frame=True, is_extended_id=False,\n"
      "                   data=[0, 0x20, 0, 0, 0, 0, 0, 0]))\n"
      "b.shutdown()\n";
  std::string out;
  ASSERT_EQ(run({"/usr/bin/python3", "-c", py}, &out), 0) << out;
  expect_error_frame(*bus, error_class::kController, error_class::kCtrlTxPassive, "python3-can");

  // cansend: the CAN_ERR_FLAG (0x20000000) written as a raw 8-digit id, bus-off.
  ASSERT_EQ(run({"cansend", vcan(), "20000040#0000000000000000"}, &out), 0) << out;
  expect_error_frame(*bus, error_class::kBusOff, 0, "cansend");
  EXPECT_EQ(bus->stats().error_frames, 2u);

  // With an error mask that excludes bus-off, that class is not delivered.
  auto quiet = open_or_fail(vcan(), SocketCanOptions{.error_mask = error_class::kController});
  ASSERT_NE(quiet, nullptr);
  ASSERT_EQ(run({"cansend", vcan(), "20000040#0000000000000000"}, &out), 0) << out;
  Frame f;
  EXPECT_EQ(quiet->receive(f, milliseconds(200)).code(), ErrorCode::kTimeout);
}

TEST(SocketCanInterop, InterfaceDownIsReportedByName) {
  ASSERT_EQ(run({"ip", "link", "set", "vcan1", "down"}), 0);
  auto bus = SocketCanBus::open("vcan1");
  ASSERT_FALSE(bus.ok());
  EXPECT_EQ(bus.status().code(), ErrorCode::kUnavailable) << bus.status().to_string();
  EXPECT_NE(bus.status().message().find("vcan1 is down"), std::string_view::npos)
      << bus.status().to_string();
  ASSERT_EQ(run({"ip", "link", "set", "vcan1", "up"}), 0);
  auto again = SocketCanBus::open("vcan1");
  EXPECT_TRUE(again.ok()) << again.status().to_string();

  auto missing = SocketCanBus::open("vcan9");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), ErrorCode::kNotFound);
  EXPECT_NE(missing.status().message().find("vcan9: no such CAN interface"), std::string_view::npos)
      << missing.status().to_string();

  auto lo = SocketCanBus::open("lo");
  ASSERT_FALSE(lo.ok());
  EXPECT_EQ(lo.status().code(), ErrorCode::kInvalidArgument) << lo.status().to_string();
}

// A reader that does not keep up: with a tiny buffer the kernel drops and SO_RXQ_OVFL counts
// exactly what was lost; with the default 8 MiB nothing is lost.
TEST(SocketCanInterop, DropsAreCountedAndLargeBufferKeepsBursts) {
  constexpr int kBurst = 5000;
  for (const int rcvbuf : {1024, 8 * 1024 * 1024}) {
    auto tx = open_or_fail(vcan());
    auto rx = open_or_fail(vcan(), SocketCanOptions{.receive_buffer_bytes = rcvbuf});
    ASSERT_TRUE(tx && rx);
    Frame f;
    f.id = 0x181;
    f.dlc = 8;
    for (int i = 0; i < kBurst; ++i) {
      f.data[0] = static_cast<std::uint8_t>(i);
      Status s = tx->send(f);
      ASSERT_TRUE(s.ok()) << s.to_string();
    }
    std::uint64_t got = 0;
    Frame r;
    while (rx->receive(r, milliseconds(1000)).ok()) ++got;  // the burst is queued already
    // The kernel stamps each queued frame with the drop total so far; frames lost after the last
    // queued one are reported with the next frame, so one more is sent once the queue is empty.
    f.data[0] = 0xFF;
    ASSERT_TRUE(tx->send(f).ok());
    Status s = rx->receive(r, milliseconds(5000));
    ASSERT_TRUE(s.ok()) << s.to_string();
    ++got;
    const BusStats st = rx->stats();
    std::printf("rcvbuf %d (granted %d): %llu received, %llu dropped\n", rcvbuf,
                rx->receive_buffer_bytes(), static_cast<unsigned long long>(got),
                static_cast<unsigned long long>(st.rx_dropped));
    EXPECT_EQ(st.frames_received, got);
    if (rcvbuf < 8 * 1024 * 1024) {
      EXPECT_GT(st.rx_dropped, 0u) << "a 1 KiB buffer cannot hold a 5000-frame burst";
      EXPECT_EQ(got + st.rx_dropped, static_cast<std::uint64_t>(kBurst + 1))
          << "vcan loses nothing else: every frame is either received or counted as dropped";
    } else {
      EXPECT_EQ(got, static_cast<std::uint64_t>(kBurst + 1));
      EXPECT_EQ(st.rx_dropped, 0u);
    }
  }
}

}  // namespace
}  // namespace cdpr::can
