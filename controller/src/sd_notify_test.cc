#include "cdpr/controller/sd_notify.hpp"

#include <gtest/gtest.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

namespace cdpr::controller {
namespace {

namespace fs = std::filesystem;

// A datagram socket in a fresh temporary directory, set as NOTIFY_SOCKET (as systemd does).
class NotifySocket {
 public:
  NotifySocket() {
    char tmpl[] = "/tmp/cdpr-sdnotify-XXXXXX";
    dir_ = mkdtemp(tmpl);
    path_ = (fs::path(dir_) / "notify").string();
    fd_ = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    path_.copy(addr.sun_path, sizeof addr.sun_path - 1);
    ok_ = fd_ >= 0 && bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
    setenv("NOTIFY_SOCKET", path_.c_str(), 1);
  }
  ~NotifySocket() {
    unsetenv("NOTIFY_SOCKET");
    if (fd_ >= 0) close(fd_);
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  bool ok() const { return ok_; }
  const std::string& path() const { return path_; }
  // The next datagram, or nullopt after 10 s (generous: only a datagram never sent fails).
  std::optional<std::string> receive() {
    pollfd p{fd_, POLLIN, 0};
    if (poll(&p, 1, 10000) != 1) return std::nullopt;
    char buf[4096];
    const ssize_t n = recv(fd_, buf, sizeof buf, 0);
    if (n < 0) return std::nullopt;
    return std::string(buf, static_cast<std::size_t>(n));
  }
  bool nothing_pending() {
    pollfd p{fd_, POLLIN, 0};
    return poll(&p, 1, 0) == 0;
  }

 private:
  std::string dir_, path_;
  int fd_ = -1;
  bool ok_ = false;
};

TEST(SystemdNotifier, SendsTheExactMessagesToNotifySocket) {
  NotifySocket sock;
  ASSERT_TRUE(sock.ok());
  SystemdNotifier n;
  EXPECT_TRUE(SystemdNotifier::enabled());

  ASSERT_TRUE(n.ready("holding, geometry v3").ok());
  EXPECT_EQ(sock.receive(), "READY=1\nSTATUS=holding, geometry v3");
  ASSERT_TRUE(n.ready().ok());
  EXPECT_EQ(sock.receive(), "READY=1");
  ASSERT_TRUE(n.status("measuring pose 3 of 25").ok());
  EXPECT_EQ(sock.receive(), "STATUS=measuring pose 3 of 25");
  ASSERT_TRUE(n.watchdog().ok());
  EXPECT_EQ(sock.receive(), "WATCHDOG=1");
  ASSERT_TRUE(n.stopping().ok());
  EXPECT_EQ(sock.receive(), "STOPPING=1");
  ASSERT_TRUE(n.stopping("quick stop done").ok());
  EXPECT_EQ(sock.receive(), "STOPPING=1\nSTATUS=quick stop done");
  ASSERT_TRUE(n.extend_timeout(std::chrono::seconds{30}).ok());
  EXPECT_EQ(sock.receive(), "EXTEND_TIMEOUT_USEC=30000000");
  EXPECT_TRUE(sock.nothing_pending());
}

TEST(SystemdNotifier, StatusIsKeptToOneLine) {
  NotifySocket sock;
  ASSERT_TRUE(sock.ok());
  SystemdNotifier n;
  ASSERT_TRUE(n.status("fault: node 3\nEMCY 0x2310").ok());
  EXPECT_EQ(sock.receive(), "STATUS=fault: node 3 EMCY 0x2310");
}

TEST(SystemdNotifier, WithoutNotifySocketEveryCallIsANoOp) {
  unsetenv("NOTIFY_SOCKET");
  SystemdNotifier n;
  EXPECT_FALSE(SystemdNotifier::enabled());
  EXPECT_TRUE(n.ready("x").ok());
  EXPECT_TRUE(n.status("x").ok());
  EXPECT_TRUE(n.watchdog().ok());
  EXPECT_TRUE(n.stopping().ok());
}

TEST(SystemdNotifier, ASocketThatIsGoneIsAnErrorNamingIt) {
  std::string path;
  {
    NotifySocket sock;
    path = sock.path();
  }
  setenv("NOTIFY_SOCKET", path.c_str(), 1);
  SystemdNotifier n;
  const Status st = n.watchdog();
  unsetenv("NOTIFY_SOCKET");
  EXPECT_EQ(st.code(), ErrorCode::kIoError);
  EXPECT_NE(st.message().find(path), std::string_view::npos) << st.message();
  EXPECT_NE(st.message().find("ENOENT"), std::string_view::npos) << st.message();
}

TEST(SystemdNotifier, WatchdogIntervalFollowsWatchdogUsecForThisProcess) {
  unsetenv("WATCHDOG_USEC");
  unsetenv("WATCHDOG_PID");
  EXPECT_FALSE(SystemdNotifier::watchdog_interval().has_value());

  setenv("WATCHDOG_USEC", "2500000", 1);
  setenv("WATCHDOG_PID", std::to_string(getpid()).c_str(), 1);
  const auto wd = SystemdNotifier::watchdog_interval();
  ASSERT_TRUE(wd.has_value());
  EXPECT_EQ(*wd, std::chrono::microseconds{2'500'000});

  // Meant for another process (e.g. inherited from a parent): not ours to feed.
  setenv("WATCHDOG_PID", std::to_string(getpid() + 1).c_str(), 1);
  EXPECT_FALSE(SystemdNotifier::watchdog_interval().has_value());
  unsetenv("WATCHDOG_USEC");
  unsetenv("WATCHDOG_PID");
}

TEST(WatchdogFeeder, FeedsOnlyWhileTheCounterAdvances) {
  NotifySocket sock;
  ASSERT_TRUE(sock.ok());
  SystemdNotifier n;
  WatchdogFeeder feeder(n);
  // The loop has not cycled yet: nothing is sent.
  Result<bool> r = feeder.feed_if_advanced(0);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(*r);
  EXPECT_TRUE(sock.nothing_pending());
  r = feeder.feed_if_advanced(250);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(*r);
  EXPECT_EQ(sock.receive(), "WATCHDOG=1");
  // Stuck loop: the counter does not move, the watchdog is not fed.
  EXPECT_FALSE(*feeder.feed_if_advanced(250));
  EXPECT_FALSE(*feeder.feed_if_advanced(250));
  EXPECT_EQ(feeder.stalled_checks(), 2u);
  EXPECT_TRUE(sock.nothing_pending());
  EXPECT_TRUE(*feeder.feed_if_advanced(251));
  EXPECT_EQ(sock.receive(), "WATCHDOG=1");
  EXPECT_EQ(feeder.stalled_checks(), 0u);
}

}  // namespace
}  // namespace cdpr::controller
