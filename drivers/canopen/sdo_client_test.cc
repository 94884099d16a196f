#include "cdpr/canopen/sdo_client.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <set>
#include <string>
#include <vector>

#include "cdpr/canopen/codes.hpp"
#include "testing/sim_network.hpp"

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;

class SdoTest : public ::testing::Test {
 protected:
  SdoTest()
      : drive(net.add<slave::Drive402>(3)),
        sdo(net.master_bus(), 3, SdoTiming{50ms, 2}),
        pump(
            net.master_bus(), [this] { return net.now(); }, 0ns) {
    pump.add(sdo);
    pump.on_idle([this] { net.idle(); });
    net.power_on();
    net.step_slaves();
  }
  testing::SimNetwork net;
  slave::Drive402& drive;
  SdoClient sdo;
  BusPump pump;
};

TEST_F(SdoTest, ExpeditedUploadOfEachWidth) {
  auto u32 = sdo.read<std::uint32_t>({0x1018, 1}, pump);
  ASSERT_TRUE(u32.ok()) << u32.status().to_string();
  EXPECT_EQ(*u32, drive.od().get({0x1018, 1}));
  auto u8 = sdo.read<std::uint8_t>({0x1018, 0}, pump);
  ASSERT_TRUE(u8.ok());
  EXPECT_EQ(*u8, 4);
  drive.od().set({0x60C2, 2}, static_cast<std::uint8_t>(-4));
  auto i8 = sdo.read<std::int8_t>({0x60C2, 2}, pump);
  ASSERT_TRUE(i8.ok());
  EXPECT_EQ(*i8, -4);
  auto wrong = sdo.read<std::uint16_t>({0x1018, 1}, pump);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("returned 4 bytes, expected 2"), std::string::npos);
}

TEST_F(SdoTest, ExpeditedDownloadOfEachWidth) {
  ASSERT_TRUE(sdo.write<std::uint16_t>({0x1017, 0}, 250, pump).ok());
  EXPECT_EQ(drive.od().get({0x1017, 0}), 250);
  ASSERT_TRUE(sdo.write<std::int32_t>({0x607A, 0}, -123456, pump).ok());
  EXPECT_EQ(drive.od().get({0x607A, 0}, true), -123456);
  ASSERT_TRUE(sdo.write<std::int16_t>({0x6007, 0}, -2, pump).ok());
  EXPECT_EQ(drive.od().get({0x6007, 0}, true), -2);
  ASSERT_TRUE(sdo.write<std::int8_t>({0x6060, 0}, 8, pump).ok());
  EXPECT_EQ(drive.od().get({0x6061, 0}), 8);
}

TEST_F(SdoTest, SegmentedUploadAndDownload) {
  auto name = sdo.read_string({0x1008, 0}, pump);
  ASSERT_TRUE(name.ok()) << name.status().to_string();
  const auto& e = drive.od().find({0x1008, 0})->data;
  EXPECT_EQ(*name, std::string(e.begin(), e.end()));
  EXPECT_GT(name->size(), 7u);  // really segmented

  drive.od().add_string({0x2000, 0}, "", slave::Access::kRw);
  // 7n, 7n+1 and short lengths exercise the last-segment sizes.
  for (const std::string text :
       {"exactly14bytes", "fifteen bytes!!", "a much longer text of 40 bytes, segmented"}) {
    ASSERT_TRUE(sdo.write_string({0x2000, 0}, text, pump).ok()) << text;
    const auto& d = drive.od().find({0x2000, 0})->data;
    EXPECT_EQ(std::string(d.begin(), d.end()), text);
    auto back = sdo.read_string({0x2000, 0}, pump);
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(*back, text);
  }
}

TEST_F(SdoTest, ToggleErrorFailsWithoutRetryAndRecoversWithRetry) {
  sdo.set_timing({50ms, 0});
  drive.faults().bad_toggle = true;
  auto r = sdo.read_string({0x1008, 0}, pump);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kProtocolError);
  EXPECT_NE(r.status().message().find("node 3: SDO upload 0x1008:00: toggle bit not alternated"),
            std::string::npos)
      << r.status().message();

  drive.od().add_string({0x2000, 0}, "", slave::Access::kRw);
  drive.faults().bad_toggle = true;
  Status s = sdo.write_string({0x2000, 0}, "twenty bytes of text", pump);
  EXPECT_EQ(s.code(), ErrorCode::kProtocolError);
  EXPECT_NE(s.message().find("toggle bit not alternated"), std::string::npos);

  sdo.set_timing({50ms, 1});
  drive.faults().bad_toggle = true;
  auto ok = sdo.read_string({0x1008, 0}, pump);
  ASSERT_TRUE(ok.ok()) << ok.status().to_string();
  EXPECT_EQ(sdo.attempts(), 2);
}

TEST_F(SdoTest, TimeoutRetriesThenFails) {
  drive.faults().drop_sdo_requests = 1;
  const Timestamp t0 = net.now();
  ASSERT_TRUE(sdo.write<std::uint16_t>({0x1017, 0}, 100, pump).ok());
  EXPECT_EQ(sdo.attempts(), 2);
  EXPECT_GE(net.now() - t0, 50ms);  // one timeout elapsed
  EXPECT_EQ(drive.od().get({0x1017, 0}), 100);

  drive.faults().drop_sdo_requests = 100;
  Status s = sdo.write<std::uint16_t>({0x1017, 0}, 200, pump);
  EXPECT_EQ(s.code(), ErrorCode::kTimeout);
  EXPECT_EQ(std::string(s.message()),
            "node 3: SDO download 0x1017:00 timed out: no answer in 50 ms (3 attempts)");
  EXPECT_EQ(drive.od().get({0x1017, 0}), 100);
}

TEST_F(SdoTest, EveryAbortCodeIsDecoded) {
  std::set<std::string_view> texts;
  for (std::uint32_t code : known_sdo_abort_codes()) {
    drive.faults().abort_on[ObjectAddress{0x6060, 0}.key()] = code;
    Status s = sdo.write<std::int8_t>({0x6060, 0}, 8, pump);
    ASSERT_EQ(s.code(), ErrorCode::kAborted);
    char expected[200];
    const auto text = sdo_abort_text(code);
    std::snprintf(expected, sizeof expected, "node 3: SDO download 0x6060:00 aborted: 0x%08X %.*s",
                  code, static_cast<int>(text.size()), text.data());
    EXPECT_EQ(std::string(s.message()), expected);
    EXPECT_NE(text, "unknown abort code");
    texts.insert(text);
  }
  EXPECT_EQ(texts.size(), known_sdo_abort_codes().size());  // all distinct
  EXPECT_GE(known_sdo_abort_codes().size(), 31u);
  EXPECT_EQ(sdo_abort_text(0x12345678), "unknown abort code");
}

TEST_F(SdoTest, ServerAbortsNameTheReason) {
  Status s = sdo.write<std::int8_t>({0x6060, 0}, 5, pump);
  EXPECT_EQ(std::string(s.message()),
            "node 3: SDO download 0x6060:00 aborted: 0x06090030 value range of parameter exceeded");
  auto r = sdo.read<std::uint32_t>({0x2FFF, 0}, pump);
  EXPECT_NE(r.status().message().find("0x06020000 object does not exist"), std::string::npos);
  auto r2 = sdo.read<std::uint32_t>({0x1018, 9}, pump);
  EXPECT_NE(r2.status().message().find("0x06090011 sub-index does not exist"), std::string::npos);
  Status ro = sdo.write<std::uint16_t>({0x6041, 0}, 1, pump);
  EXPECT_NE(ro.message().find("0x06010002 attempt to write a read only object"), std::string::npos);
  Status len = sdo.write<std::uint32_t>({0x1017, 0}, 1, pump);
  EXPECT_NE(len.message().find("0x06070012"), std::string::npos);
}

// Found by the vcan interop test: a server that stalls for longer than the SDO timeout answers
// the aborted attempt late, in a burst with its answer to the retry. The late initiate answer
// used to be taken for the retry's; everything after was one step off and the transfer failed
// with "unexpected answer to upload segment (command byte 0x41)".
TEST_F(SdoTest, LateAnswerToAnAbortedAttemptIsNotTakenForTheRetry) {
  drive.faults().delay_sdo_answers = 1;
  drive.faults().sdo_answer_delay = 70ms;  // longer than the 50 ms timeout
  auto name = sdo.read_string({0x1008, 0}, pump);
  ASSERT_TRUE(name.ok()) << name.status().to_string();
  EXPECT_EQ(*name, "cdpr simulated CANopen node");
  EXPECT_EQ(sdo.attempts(), 2);
  // The following transfers are in step: each gets its own answer.
  auto type = sdo.read<std::uint32_t>({0x1000, 0}, pump);
  ASSERT_TRUE(type.ok()) << type.status().to_string();
  EXPECT_EQ(*type, 0x00020192u);
  auto vendor = sdo.read<std::uint32_t>({0x1018, 1}, pump);
  ASSERT_TRUE(vendor.ok()) << vendor.status().to_string();
  EXPECT_EQ(*vendor, 0x00CD9001u);
  EXPECT_EQ(sdo.attempts(), 1);
}

// The same burst without a quiet period: the phase checks alone keep the transfer in step.
TEST_F(SdoTest, DuplicateInitiateAnswerIsDiscardedWithoutQuietPeriod) {
  sdo.set_timing({50ms, 2, 0ns});
  drive.faults().delay_sdo_answers = 1;
  drive.faults().sdo_answer_delay = 70ms;
  auto name = sdo.read_string({0x1008, 0}, pump);
  ASSERT_TRUE(name.ok()) << name.status().to_string();
  EXPECT_EQ(*name, "cdpr simulated CANopen node");
  EXPECT_EQ(sdo.attempts(), 2);
  EXPECT_EQ(sdo.stale_answers(), 1u);  // the second initiate answer
  // Segmented download: the late 0x60 starts the segments, the retry's 0x60 is dropped.
  drive.od().add_string({0x2000, 0}, "", slave::Access::kRw);
  drive.faults().delay_sdo_answers = 1;
  ASSERT_TRUE(sdo.write_string({0x2000, 0}, "a label of 24 characters", pump).ok());
  const auto& d = drive.od().find({0x2000, 0})->data;
  EXPECT_EQ(std::string(d.begin(), d.end()), "a label of 24 characters");
  EXPECT_EQ(sdo.attempts(), 2);
  EXPECT_EQ(sdo.stale_answers(), 2u);
  auto type = sdo.read<std::uint32_t>({0x1000, 0}, pump);
  ASSERT_TRUE(type.ok()) << type.status().to_string();
  EXPECT_EQ(*type, 0x00020192u);
}

// With the quiet period the late answer arrives while the client waits, and the retry's initiate
// is sent only after it.
TEST_F(SdoTest, QuietPeriodDrainsTheLateAnswerBeforeTheRetry) {
  sdo.set_timing({50ms, 2, 40ms});
  drive.faults().delay_sdo_answers = 1;
  drive.faults().sdo_answer_delay = 70ms;
  const Timestamp t0 = net.now();
  auto name = sdo.read_string({0x1008, 0}, pump);
  ASSERT_TRUE(name.ok()) << name.status().to_string();
  EXPECT_EQ(*name, "cdpr simulated CANopen node");
  EXPECT_EQ(sdo.attempts(), 2);
  EXPECT_EQ(sdo.stale_answers(), 1u);
  EXPECT_GE(net.now() - t0, 90ms);  // timeout + quiet period
  EXPECT_LT(net.now() - t0, 100ms);
  // Server side: initiate (late), abort, initiate, 4 segments; nothing of the retry was lost.
  EXPECT_EQ(drive.sdo_requests(), 7u);
}

// A stall in the middle of a segmented upload: the late segment answer arrives in the retry's
// initiate phase and is discarded (it used to fail with "unexpected answer to initiate upload").
TEST_F(SdoTest, LateSegmentAnswerIsDiscardedByTheRetry) {
  sdo.set_timing({50ms, 2, 0ns});
  drive.faults().delay_sdo_after = 2;  // initiate and first segment answered in time
  drive.faults().delay_sdo_answers = 1;
  drive.faults().sdo_answer_delay = 70ms;
  auto name = sdo.read_string({0x1008, 0}, pump);
  ASSERT_TRUE(name.ok()) << name.status().to_string();
  EXPECT_EQ(*name, "cdpr simulated CANopen node");
  EXPECT_EQ(sdo.attempts(), 2);
  EXPECT_EQ(sdo.stale_answers(), 1u);
}

// A transfer that failed on a timeout leaves an answer on its way; it must not be taken by the
// next transfer (another object), with or without the quiet period.
TEST_F(SdoTest, LateAnswerOfAFailedTransferDoesNotLeakIntoTheNext) {
  for (const auto quiet : {std::chrono::nanoseconds(0), std::chrono::nanoseconds(50ms)}) {
    sdo.set_timing({50ms, 0, quiet});
    drive.faults().delay_sdo_answers = 1;
    drive.faults().sdo_answer_delay = 70ms;
    auto lost = sdo.read<std::uint32_t>({0x1018, 1}, pump);
    ASSERT_FALSE(lost.ok());
    EXPECT_EQ(lost.status().code(), ErrorCode::kTimeout);
    const auto stale_before = sdo.stale_answers();
    auto type = sdo.read<std::uint32_t>({0x1000, 0}, pump);
    ASSERT_TRUE(type.ok()) << type.status().to_string();
    EXPECT_EQ(*type, 0x00020192u);
    EXPECT_EQ(sdo.stale_answers(), stale_before + 1);
    // Drain the bus so that nothing of this round reaches the next.
    for (int i = 0; i < 400; ++i) pump.step();
  }
}

TEST(SdoClientStateMachine, RejectsSecondTransferAndIgnoresOtherNodes) {
  cdpr::ManualClock clock;
  can::VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  SdoClient c(*a, 5);
  ASSERT_TRUE(c.start_upload({0x1000, 0}, clock.now()).ok());
  EXPECT_FALSE(c.start_upload({0x1000, 0}, clock.now()).ok());
  can::Frame req;
  ASSERT_TRUE(b->receive(req, 0ns).ok());
  EXPECT_EQ(req.id, 0x605u);
  EXPECT_EQ(req.data[0], 0x40);
  can::Frame other = make_frame(0x586, 8);
  EXPECT_FALSE(c.on_frame(other, clock.now()));
  can::Frame ans = make_frame(0x585, 8);
  ans.data = {0x4B, 0x00, 0x10, 0x00, 0x34, 0x12, 0, 0};  // 2 bytes indicated
  EXPECT_TRUE(c.on_frame(ans, clock.now()));
  EXPECT_EQ(c.state(), SdoClient::State::kDone);
  ASSERT_EQ(c.data().size(), 2u);
  EXPECT_EQ(get_u16(c.data().data()), 0x1234);
}

// A client on one end of a virtual bus and the test as the server on the other end: it feeds the
// server's answers by hand and reads what the client sent.
struct RawServer {
  explicit RawServer(SdoTiming timing) : c(*a, 5, timing) {}
  bool answer(std::array<std::uint8_t, 8> d) {
    can::Frame f = make_frame(0x585, 8);
    f.data = d;
    return c.on_frame(f, clock.now());
  }
  std::vector<can::Frame> sent() {
    std::vector<can::Frame> frames;
    can::Frame f;
    while (b->receive(f, 0ns).ok()) frames.push_back(f);
    return frames;
  }
  cdpr::ManualClock clock;
  can::VirtualCanBus bus{clock};
  std::unique_ptr<can::CanBus> a = bus.endpoint("a");
  std::unique_ptr<can::CanBus> b = bus.endpoint("b");
  SdoClient c;
};

// Found by fuzz/sdo_client: a server that never sends the last segment of an upload without a
// size made the client's buffer grow without limit.
TEST(SdoClientStateMachine, UploadLargerThanTheLimitIsAbortedWhetherAnnouncedOrNot) {
  RawServer server(SdoTiming{100ms, 0, 0ms});
  SdoClient& c = server.c;
  auto answer = [&](std::array<std::uint8_t, 8> d) { return server.answer(d); };
  auto last_sent = [&] { return server.sent().back(); };
  auto abort_code_of = [](const can::Frame& f) { return get_u32(&f.data[4]); };

  // Without a size: segments keep coming, none is the last.
  ASSERT_TRUE(c.start_upload({0x1008, 0}, server.clock.now()).ok());
  ASSERT_TRUE(answer({0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0}));  // segmented, size not indicated
  std::size_t segments = 0;
  bool toggle = false;
  while (c.busy() && segments < 2 * SdoClient::kMaxUpload / 7) {
    const std::uint8_t cmd = toggle ? 0x10 : 0x00;  // 7 bytes, not the last
    can::Frame request;
    ASSERT_TRUE(server.b->receive(request, 0ns).ok());  // the client's segment request (or abort)
    ASSERT_TRUE(answer({cmd, 1, 2, 3, 4, 5, 6, 7}));
    toggle = !toggle;
    ++segments;
  }
  EXPECT_EQ(c.state(), SdoClient::State::kFailed);
  EXPECT_EQ(segments, SdoClient::kMaxUpload / 7 + 1);
  EXPECT_NE(c.result().message().find("without a last segment"), std::string::npos)
      << c.result().to_string();
  can::Frame abort = last_sent();
  EXPECT_EQ(abort.data[0], 0x80);
  EXPECT_EQ(abort_code_of(abort), abort_code::kOutOfMemory);

  // Announced too large: refused at the initiate answer.
  ASSERT_TRUE(c.start_upload({0x1008, 0}, server.clock.now()).ok());
  const auto big = static_cast<std::uint32_t>(SdoClient::kMaxUpload + 1);
  ASSERT_TRUE(answer({0x41, 0x08, 0x10, 0x00, static_cast<std::uint8_t>(big & 0xFF),
                      static_cast<std::uint8_t>((big >> 8) & 0xFF),
                      static_cast<std::uint8_t>((big >> 16) & 0xFF), 0}));
  EXPECT_EQ(c.state(), SdoClient::State::kFailed);
  EXPECT_NE(c.result().message().find("server announced 65537 bytes"), std::string::npos)
      << c.result().to_string();
  EXPECT_EQ(abort_code_of(last_sent()), abort_code::kOutOfMemory);
}

TEST(SdoClientStateMachine, DiscardsAnswersThatCannotBelongToTheAttempt) {
  RawServer server(SdoTiming{100ms, 1, 20ms});
  SdoClient& c = server.c;
  cdpr::ManualClock& clock = server.clock;
  auto answer = [&](std::array<std::uint8_t, 8> d) { return server.answer(d); };
  auto sent = [&] {
    std::vector<std::uint8_t> cmds;
    for (const can::Frame& f : server.sent()) cmds.push_back(f.data[0]);
    return cmds;
  };
  // Idle: a late answer is consumed and counted.
  EXPECT_TRUE(answer({0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4}));
  EXPECT_EQ(c.stale_answers(), 1u);

  ASSERT_TRUE(c.start_upload({0x1000, 0}, clock.now()).ok());
  EXPECT_EQ(sent(), std::vector<std::uint8_t>{0x40});
  // Initiate phase: an answer for another object, a segment answer and an abort of another
  // object cannot answer this initiate.
  EXPECT_TRUE(answer({0x43, 0x18, 0x10, 0x01, 1, 0, 0, 0}));
  EXPECT_TRUE(answer({0x00, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_TRUE(answer({0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x02, 0x06}));
  EXPECT_TRUE(c.busy());
  EXPECT_EQ(c.stale_answers(), 4u);

  // Timeout: abort, then nothing until the quiet period is over; what comes meanwhile is stale.
  clock.advance(100ms);
  c.poll(clock.now());
  EXPECT_EQ(sent(), std::vector<std::uint8_t>{0x80});
  EXPECT_EQ(c.attempts(), 2);
  EXPECT_TRUE(answer({0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00}));  // late: no initiate yet
  EXPECT_EQ(c.stale_answers(), 5u);
  clock.advance(19ms);
  c.poll(clock.now());
  EXPECT_TRUE(sent().empty());
  clock.advance(1ms);
  c.poll(clock.now());
  EXPECT_EQ(sent(), std::vector<std::uint8_t>{0x40});
  // Still before any other answer: the server's echo of our abort (SDO timeout) and a
  // mid-transfer abort (toggle bit) belong to the aborted attempt.
  EXPECT_TRUE(answer({0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05}));
  EXPECT_TRUE(answer({0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x03, 0x05}));
  EXPECT_TRUE(c.busy());
  EXPECT_EQ(c.stale_answers(), 7u);
  EXPECT_TRUE(answer({0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00}));
  ASSERT_EQ(c.state(), SdoClient::State::kDone);
  EXPECT_EQ(get_u32(c.data().data()), 0x00020192u);

  // A server abort naming our object is the answer.
  ASSERT_TRUE(c.start_upload({0x2000, 0}, clock.now()).ok());
  EXPECT_TRUE(answer({0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x02, 0x06}));
  ASSERT_EQ(c.state(), SdoClient::State::kFailed);
  EXPECT_EQ(std::string(c.result().message()),
            "node 5: SDO upload 0x2000:00 aborted: 0x06020000 object does not exist in the object "
            "dictionary");

  // A timeout names the discarded answers (a server that always answers for another object).
  c.set_timing({100ms, 0, 20ms});
  ASSERT_TRUE(c.start_upload({0x1000, 0}, clock.now()).ok());
  EXPECT_TRUE(answer({0x43, 0x00, 0x10, 0x01, 1, 0, 0, 0}));
  clock.advance(100ms);
  c.poll(clock.now());
  ASSERT_EQ(c.state(), SdoClient::State::kFailed);
  EXPECT_EQ(std::string(c.result().message()),
            "node 5: SDO upload 0x1000:00 timed out: no answer in 100 ms (1 attempt; 1 stale "
            "answer discarded, last command byte 0x43 for 0x1000:01)");

  // In the segment phase a second initiate answer is dropped before the first segment answer,
  // and is a protocol error after it.
  clock.advance(20ms);
  sent();
  ASSERT_TRUE(c.start_upload({0x1008, 0}, server.clock.now()).ok());
  EXPECT_TRUE(answer({0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0}));
  EXPECT_TRUE(answer({0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0}));
  EXPECT_TRUE(c.busy());
  EXPECT_TRUE(answer({0x00, 'a', 'b', 'c', 'd', 'e', 'f', 'g'}));
  EXPECT_TRUE(answer({0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0}));
  ASSERT_EQ(c.state(), SdoClient::State::kFailed);
  EXPECT_NE(c.result().message().find("unexpected answer to upload segment (command byte 0x41)"),
            std::string::npos)
      << c.result().message();
}

}  // namespace
}  // namespace cdpr::canopen
