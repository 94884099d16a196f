#include "cdpr/canopen/sdo_client.hpp"

#include <gtest/gtest.h>

#include <set>
#include <string>

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

TEST(SdoClientStateMachine, RejectsSecondTransferAndIgnoresOtherNodes) {
  can::ManualClock clock;
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

}  // namespace
}  // namespace cdpr::canopen
