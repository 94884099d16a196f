#include "cdpr/canopen/nmt.hpp"

#include <gtest/gtest.h>

#include <vector>

#include "cdpr/canopen/codes.hpp"

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;

TEST(Nmt, CommandFramesAndStates) {
  const can::Frame f = nmt_frame(NmtCommand::kResetCommunication, 0);
  EXPECT_EQ(f.id, 0u);
  EXPECT_EQ(f.dlc, 2);
  EXPECT_EQ(f.data[0], 0x82);
  EXPECT_EQ(nmt_frame(NmtCommand::kStart, 5).data[1], 5);
  EXPECT_EQ(static_cast<int>(NmtCommand::kEnterPreOperational), 0x80);
  EXPECT_EQ(static_cast<int>(NmtCommand::kResetNode), 0x81);
  EXPECT_EQ(static_cast<int>(NmtCommand::kStop), 0x02);
}

TEST(Nmt, MonitorTracksBootUpHeartbeatAndLoss) {
  NodeMonitor m;
  Events ev;
  m.consume(7, 150ms);
  m.check(Timestamp{10s}, ev);
  EXPECT_EQ(m.state(7), NmtState::kUnknown);  // never heard: not lost
  EXPECT_TRUE(ev.empty());
  Timestamp t{1s};
  ASSERT_TRUE(m.on_frame(heartbeat_frame(7, NmtState::kBootUp), t, ev));
  EXPECT_EQ(m.node(7).boot_count, 1u);
  ASSERT_TRUE(m.on_frame(heartbeat_frame(7, NmtState::kOperational), t += 100ms, ev));
  EXPECT_EQ(m.state(7), NmtState::kOperational);
  m.check(t + 149ms, ev);
  EXPECT_EQ(m.state(7), NmtState::kOperational);
  m.check(t + 151ms, ev);
  EXPECT_EQ(m.state(7), NmtState::kLost);
  m.check(t + 300ms, ev);  // reported once
  Event e;
  std::vector<EventType> types;
  Event lost;
  while (ev.pop(e)) {
    types.push_back(e.type);
    if (e.type == EventType::kHeartbeatLost) lost = e;
  }
  ASSERT_EQ(types.size(), 3u);
  EXPECT_EQ(types[0], EventType::kBootUp);
  EXPECT_EQ(types[1], EventType::kNmtStateChanged);
  EXPECT_EQ(types[2], EventType::kHeartbeatLost);
  EXPECT_EQ(lost.node, 7);
  EXPECT_EQ(lost.nmt, NmtState::kOperational);
  ASSERT_TRUE(m.on_frame(heartbeat_frame(7, NmtState::kOperational), t + 400ms, ev));
  ASSERT_TRUE(ev.pop(e));
  EXPECT_EQ(e.type, EventType::kHeartbeatRegained);
  EXPECT_FALSE(m.on_frame(make_frame(0x707, 2), t, ev));  // wrong length
}

TEST(Nmt, SyncProducerKeepsItsScheduleAndCountsOverruns) {
  SyncProducer s(4ms, 0);
  can::Frame f;
  EXPECT_FALSE(s.poll(Timestamp{0}, f));  // not started
  s.start(Timestamp{0});
  ASSERT_TRUE(s.poll(Timestamp{0}, f));
  EXPECT_EQ(f.id, 0x80u);
  EXPECT_EQ(f.dlc, 0);
  EXPECT_FALSE(s.poll(Timestamp{3ms}, f));
  EXPECT_TRUE(s.poll(Timestamp{4ms + 100us}, f));  // jitter does not shift the schedule
  EXPECT_EQ(s.next_due(), Timestamp{8ms});
  EXPECT_TRUE(s.poll(Timestamp{17ms}, f));  // 8 and 12 missed: one SYNC, overruns counted
  EXPECT_EQ(s.overruns(), 2u);
  EXPECT_EQ(s.next_due(), Timestamp{20ms});
  SyncProducer c(20ms, 3);
  c.start(Timestamp{0});
  std::vector<int> counters;
  for (int i = 0; i < 4; ++i) {
    ASSERT_TRUE(c.poll(Timestamp{20ms * i}, f));
    EXPECT_EQ(f.dlc, 1);
    counters.push_back(f.data[0]);
  }
  EXPECT_EQ(counters, (std::vector<int>{1, 2, 3, 1}));
}

TEST(Nmt, MasterHeartbeatProducer) {
  HeartbeatProducer hb(0x77F, 50ms);
  can::Frame f;
  ASSERT_TRUE(hb.poll(Timestamp{0}, NmtState::kOperational, f));
  EXPECT_EQ(f.id, 0x77Fu);
  EXPECT_EQ(f.data[0], 0x05);
  EXPECT_FALSE(hb.poll(Timestamp{49ms}, NmtState::kOperational, f));
  EXPECT_TRUE(hb.poll(Timestamp{50ms}, NmtState::kOperational, f));
}

// Issue 14, item 9: polled once per cycle, the heartbeat is due a period after the previous due
// time, not after it was sent (which made it late by up to a cycle every period).
TEST(Nmt, MasterHeartbeatIsDueEveryPeriodWhateverTheCycle) {
  HeartbeatProducer hb(0x77F, 50ms);
  can::Frame f;
  std::vector<Timestamp> sent;
  for (Timestamp t{0}; t <= 1000ms; t += 20ms) {  // a 20 ms cycle, as in user-mode-linux tests
    if (hb.poll(t, NmtState::kOperational, f)) sent.push_back(t);
  }
  // Due at 0, 50, 100, ...: sent at the first cycle at or after each.
  ASSERT_EQ(sent.size(), 21u);
  for (std::size_t k = 0; k < sent.size(); ++k) {
    EXPECT_GE(sent[k], 50ms * static_cast<int>(k));
    EXPECT_LT(sent[k], 50ms * static_cast<int>(k) + 20ms);
  }
  // Late by whole periods: one heartbeat, then the schedule goes on (no burst).
  EXPECT_TRUE(hb.poll(1230ms, NmtState::kOperational, f));
  EXPECT_FALSE(hb.poll(1240ms, NmtState::kOperational, f));
  EXPECT_TRUE(hb.poll(1250ms, NmtState::kOperational, f));
  EXPECT_EQ(hb.boot_up().data[0], 0x00);
  EXPECT_EQ(hb.boot_up().id, 0x77Fu);
}

TEST(Emcy, DecodesCodeRegisterAndManufacturerBytes) {
  can::Frame f = make_frame(0x84, 8);
  f.data = {0x10, 0x23, 0x03, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE};
  Emcy e;
  ASSERT_TRUE(decode_emcy(f, e));
  EXPECT_EQ(e.node, 4);
  EXPECT_EQ(e.code, 0x2310);
  EXPECT_EQ(e.error_register, 0x03);
  EXPECT_EQ(e.manufacturer, (std::array<std::uint8_t, 5>{0xAA, 0xBB, 0xCC, 0xDD, 0xEE}));
  EXPECT_EQ(emcy_code_text(e.code), "continuous over-current");
  char buf[64];
  EXPECT_EQ(error_register_text(e.error_register, buf), "generic,current");
  EXPECT_EQ(emcy_code_text(0x8130), "life guard error or heartbeat error");
  EXPECT_EQ(emcy_code_text(0x8611), "following error");
  EXPECT_EQ(emcy_code_text(0x3211), "voltage inside the device");  // falls back to the sub-class
  EXPECT_EQ(emcy_code_text(0x4999), "temperature");                // then the class
  EXPECT_EQ(emcy_code_text(0xFF42), "device specific");
  EXPECT_FALSE(decode_emcy(make_frame(0x80, 0), e));  // that is SYNC
  EXPECT_FALSE(decode_emcy(make_frame(0x184, 8), e));
}

}  // namespace
}  // namespace cdpr::canopen
