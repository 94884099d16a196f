// Path runs and the setpoint stream through the daemon's requests, against the in-process virtual
// cell (virtual_cell.hpp): `run` checks the whole program before anything moves and runs it with
// progress; `abort` stops it smoothly; a stream of setpoints on the stream socket is followed,
// held on a gap and refused on a jump. Robot time is the cell's manual clock.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <numbers>
#include <string>
#include <thread>

#include "cdpr/controller/setpoint_stream.hpp"
#include "cell_fixture.hpp"

namespace cdpr::controller {
namespace {

using json = nlohmann::json;

class DaemonMotion : public testing::CellTest {
 protected:
  DaemonMotion() : CellTest("cdprd-motion-") {}
  void SetUp() override {
    CellTest::SetUp();
    testing::VirtualCell::Settings s;
    s.extra = "control: {socket: cdprd.sock}\n";
    start_daemon(s);
    home_ = daemon().rt().snapshot().pose();
  }
  std::string x(double dx) const { return std::to_string(home_.position.x() + dx); }
  std::string y(double dy) const { return std::to_string(home_.position.y() + dy); }
  Reply run(const std::string& program, const std::string& source = "app.path") {
    return request("run", {{"program", program}, {"source", source}});
  }
  json st() { return daemon().status(); }
  Pose home_;
};

TEST_F(DaemonMotion, RunsAPathProgramWithProgressAndEndsHoldingAtItsEnd) {
  // A line, a full circle (r = 20 mm) and back.
  const std::string program = "G1 X" + x(0.03) + " F0.05\nG3 X" + x(0.03) + " Y" + y(0.0) +
                              " I-0.02 J0\nG1 X" + x(0.0) + " Y" + y(0.0) + "\n";
  const Reply r = run(program);
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_GT(r.result["points_checked"].get<int>(), 10);
  bool seen_arc = false;
  ASSERT_TRUE(run_until(
      [&] {
        const json s = st();
        if (s["run"]["line"] == 2) {
          seen_arc = true;
          EXPECT_GT(s["run"]["fraction"].get<double>(), 0.0);
          EXPECT_LT(s["run"]["fraction"].get<double>(), 1.0);
        }
        return s["run"]["outcome"] == "done";
      },
      30.0));
  EXPECT_TRUE(seen_arc);
  EXPECT_EQ(st()["run"]["fraction"], 1.0);
  EXPECT_GE(cell_->count_events("run", "outcome", "running"), 3);
  EXPECT_EQ(cell_->count_events("run", "outcome", "done"), 1);
  EXPECT_LT((daemon().rt().snapshot().pose().position - home_.position).norm(), 1e-9);
  EXPECT_TRUE(holds_settled(10.0));
}

TEST_F(DaemonMotion, RefusesAProgramNamingItsLineBeforeAnythingMoves) {
  const Reply parse = run("G1 X0.0\nG1 X1.2.3\n", "bad.path");
  ASSERT_FALSE(parse.ok);
  EXPECT_NE(parse.message.find("bad.path:2: X1.2.3"), std::string::npos) << parse.message;
  // Line 2 leaves the workspace (2 m away): refused whole, before line 1 moves.
  const Reply far = run("G1 X" + x(0.01) + "\nG1 X" + x(2.0) + "\n", "far.path");
  ASSERT_FALSE(far.ok);
  EXPECT_EQ(far.code, "bad_request");
  EXPECT_NE(far.message.find("line 2"), std::string::npos) << far.message;
  cell_->run_until([] { return false; }, 0.2);
  EXPECT_EQ(daemon().rt().snapshot().pose().position, home_.position);
}

TEST_F(DaemonMotion, AbortStopsARunSmoothlyAndHoldsWhereItCameToRest) {
  const Reply r = run("G1 X" + x(0.1) + " F0.1\n");
  ASSERT_TRUE(r.ok) << r.message;
  cell_->run_until([] { return false; }, 0.6);
  ASSERT_TRUE(request("abort").ok);
  ASSERT_TRUE(run_until([&] { return st()["run"]["outcome"] == "aborted"; }, 10.0));
  const double reached = daemon().rt().snapshot().pose().position.x() - home_.position.x();
  EXPECT_GT(reached, 0.01);
  EXPECT_LT(reached, 0.1);
  EXPECT_TRUE(holds_settled(10.0));
  EXPECT_TRUE(st()["fault"].is_null());
  EXPECT_FALSE(request("abort").ok) << "nothing left to abort";
}

// A datagram client of the stream socket (what tools/cdpr-stream.py does).
class StreamClient {
 public:
  explicit StreamClient(const std::string& path) : fd_(::socket(AF_UNIX, SOCK_DGRAM, 0)) {
    addr_.sun_family = AF_UNIX;
    std::strncpy(addr_.sun_path, path.c_str(), sizeof addr_.sun_path - 1);
  }
  ~StreamClient() { ::close(fd_); }
  bool send(std::uint64_t seq, std::int64_t sent_ns, const Pose& p) {
    const auto b = encode_setpoint(seq, sent_ns, p);
    return ::sendto(fd_, b.data(), b.size(), 0, reinterpret_cast<const sockaddr*>(&addr_),
                    sizeof addr_) == static_cast<ssize_t>(b.size());
  }

 private:
  int fd_;
  sockaddr_un addr_{};
};

TEST_F(DaemonMotion, StreamsACircleHoldsOnAGapCountsSequenceFaultsAndRefusesAJump) {
  const Reply start = request("stream", {{"action", "start"}});
  ASSERT_TRUE(start.ok) << start.message;
  StreamClient client(start.result["socket"].get<std::string>());
  cell_->cycle();
  std::uint64_t seq = 0, handed = 0;
  // Sends one setpoint and waits (wall clock, generous) until the receiver handed it over, then
  // runs one cycle.
  const auto step = [&](const Pose& p, std::uint64_t next_seq, bool counted = true) {
    if (counted) seq = next_seq;
    const std::string key = counted ? "received" : "reordered";
    const std::uint64_t base = st()["stream"].value(key, std::uint64_t{0});
    ASSERT_TRUE(client.send(next_seq, cell_->clock.now().count(), p));
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    const std::uint64_t want = handed + (counted ? 1 : 0);
    while (st()["stream"].value(key, std::uint64_t{0}) == base &&
           std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    handed = want;
    cell_->cycle();
  };
  const double r = 0.01, period = 2.0;  // a circle through home
  const auto circle = [&](double t) {
    const double a = 2.0 * std::numbers::pi * t / period;
    Pose p = home_;
    p.position.x() += r * (std::cos(a) - 1.0);
    p.position.y() += r * std::sin(a);
    return p;
  };
  const double cycle_s = std::chrono::duration<double>(cell_->network.sync_period).count();
  double t = 0.0;
  step(circle(t), seq + 1);  // from rest: the held pose itself
  for (int c = 0; c < 300; ++c) {
    t += cycle_s;
    const Pose p = circle(t);
    step(p, seq + 1);
    ASSERT_LT((daemon().rt().snapshot().pose().position - p.position).norm(), 1e-9) << c;
  }
  EXPECT_EQ(st()["stream"]["state"], "following");
  // A gap of 10 cycles (10 sequence numbers lost): the robot holds smoothly.
  for (int c = 0; c < 10; ++c) cell_->cycle();
  EXPECT_EQ(st()["stream"]["state"], "holding");
  EXPECT_EQ(st()["stream"]["holds"], 1);
  // It resumes from rest at the held pose (a step there ends the stream: resume_refused).
  t += 10 * cycle_s;
  step(daemon().rt().snapshot().pose(), seq + 11);
  t += cycle_s;
  EXPECT_EQ(st()["stream"]["state"], "following");
  EXPECT_EQ(st()["stream"]["gaps"], 10);
  step(circle(t), seq - 3, false);  // late, out of order: dropped
  EXPECT_EQ(st()["stream"]["reordered"], 1);
  // A jump of 5 cm: refused, the stream ends, the robot holds where it was.
  const Pose before = daemon().rt().snapshot().pose();
  Pose jump = before;
  jump.position.x() += 0.05;
  step(jump, seq + 1);
  ASSERT_TRUE(run_until([&] { return st()["stream"]["state"] == "off"; }, 5.0));
  EXPECT_EQ(st()["stream"]["ended"], "step_refused");
  EXPECT_LT((daemon().rt().snapshot().pose().position - before.position).norm(), 0.005);
  EXPECT_TRUE(holds_settled(10.0));
  EXPECT_GE(st()["stream"]["latency_us"]["count"].get<int>(), 300);
  EXPECT_TRUE(st()["fault"].is_null());
  EXPECT_FALSE(request("stream", {{"action", "stop"}}).ok) << "no stream left to stop";
}

TEST_F(DaemonMotion, MotionIsRefusedWhileTheStreamRuns) {
  ASSERT_TRUE(request("stream", {{"action", "start"}}).ok);
  cell_->run_until([] { return false; }, 0.1);
  const Reply r = run("G1 X" + x(0.01) + "\n");
  ASSERT_FALSE(r.ok);
  EXPECT_EQ(r.code, "invalid_state");
  ASSERT_TRUE(request("stream", {{"action", "stop"}}).ok);
  ASSERT_TRUE(run_until([&] { return st()["stream"]["state"] == "off"; }, 5.0));
  EXPECT_EQ(st()["stream"]["ended"], "stopped");
  EXPECT_TRUE(holds_settled(10.0));
}

}  // namespace
}  // namespace cdpr::controller
