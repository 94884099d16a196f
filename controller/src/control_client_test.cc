#include "cdpr/controller/control_client.hpp"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <thread>

#include "cdpr/controller/control_server.hpp"

namespace cdpr::control {
namespace {

using json = nlohmann::json;
using namespace std::chrono_literals;

class ControlClientTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/cdpr-client-XXXXXX";
    ASSERT_NE(::mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    path_ = dir_ + "/cdprd.sock";
  }
  void TearDown() override {
    if (server_) server_->stop();
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }
  void start() {
    ControlServerOptions o;
    o.path = path_;
    auto s = ControlServer::start(o, [](const ControlRequest& r) {
      if (r.cmd == "geometry_history") std::this_thread::sleep_for(1500ms);  // a slow answer
      return ControlReply::ok({{"cmd", r.cmd}});
    });
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    server_ = std::move(s.value());
  }

  std::string dir_, path_;
  std::unique_ptr<ControlServer> server_;
};

TEST_F(ControlClientTest, ConnectNamesWhyThereIsNoDaemon) {
  auto none = ControlClient::connect(path_, deadline_after(1));
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), ErrorCode::kNotFound);
  EXPECT_NE(none.status().to_string().find(path_), std::string::npos);

  std::ofstream(path_) << "not a socket";
  auto file = ControlClient::connect(path_, deadline_after(1));
  ASSERT_FALSE(file.ok());
  EXPECT_EQ(file.status().code(), ErrorCode::kUnavailable);
}

TEST_F(ControlClientTest, KeepsEventsThatArriveWhileWaitingForAReply) {
  start();
  auto c = ControlClient::connect(path_, deadline_after(5));
  ASSERT_TRUE(c.ok());
  ASSERT_TRUE(c->call("watch", json::object(), deadline_after(5)).ok());
  server_->publish("log", {{"message", "first"}});
  server_->publish("log", {{"message", "second"}});
  std::this_thread::sleep_for(50ms);  // both events are on the wire before the request
  auto r = c->call("status", json::object(), deadline_after(5));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->result()["cmd"], json("status"));
  auto e1 = c->next_event(deadline_after(10));
  auto e2 = c->next_event(deadline_after(10));
  ASSERT_TRUE(e1.ok() && e2.ok());
  EXPECT_EQ(e1->data["message"], json("first"));
  EXPECT_EQ(e2->data["message"], json("second"));
}

TEST_F(ControlClientTest, ATimedOutCallDoesNotConfuseTheNextOne) {
  start();
  auto c = ControlClient::connect(path_, deadline_after(5));
  ASSERT_TRUE(c.ok());
  auto slow = c->call("geometry_history", json::object(), deadline_after(0.05));
  ASSERT_FALSE(slow.ok());
  EXPECT_EQ(slow.status().code(), ErrorCode::kTimeout);
  // The late reply to the first call arrives first and is skipped by its id.
  auto next = c->call("status", json::object(), deadline_after(5));
  ASSERT_TRUE(next.ok()) << next.status().to_string();
  EXPECT_EQ(next->result()["cmd"], json("status"));
}

TEST_F(ControlClientTest, ACancelFlagEndsAWaitForEvents) {
  start();
  auto c = ControlClient::connect(path_, deadline_after(5));
  ASSERT_TRUE(c.ok());
  ASSERT_TRUE(c->call("watch", json::object(), deadline_after(5)).ok());
  std::atomic<bool> cancel{false};
  std::thread t([&] {
    std::this_thread::sleep_for(100ms);
    cancel = true;
  });
  const auto t0 = std::chrono::steady_clock::now();
  auto ev = c->next_event(std::nullopt, &cancel);
  t.join();
  ASSERT_FALSE(ev.ok());
  EXPECT_EQ(ev.status().code(), ErrorCode::kAborted);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 10s);  // no hang, however loaded the host
}

TEST_F(ControlClientTest, DeadlineAfterZeroMeansNoBound) {
  EXPECT_FALSE(deadline_after(0).has_value());
  EXPECT_FALSE(deadline_after(-1).has_value());
  ASSERT_TRUE(deadline_after(1.5).has_value());
  EXPECT_GT(*deadline_after(1.5), ControlClient::Clock::now() + 1s);
}

}  // namespace
}  // namespace cdpr::control
