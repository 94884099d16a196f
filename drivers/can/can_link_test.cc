// CanLink without a kernel CAN bus: the restart request's netlink encoding, and the errors for
// interfaces that are not there or are no CAN controller (the loopback interface). The vcan side
// (kind, refused restart, down/up, recovery) runs in tests/canopen/bus_off_vcan_test.cc.
#include "cdpr/can/can_link.hpp"

#include <gtest/gtest.h>
#include <linux/can/netlink.h>
#include <linux/if_link.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>

#include <array>
#include <cstring>
#include <string>

namespace cdpr::can {
namespace {

struct Attr {
  std::uint16_t type = 0;
  std::size_t offset = 0;  // of the payload
  std::size_t length = 0;  // of the payload
};

// The attributes at [offset, offset + length), decoded by hand from the bytes.
std::vector<Attr> attrs(const std::uint8_t* buf, std::size_t offset, std::size_t length) {
  std::vector<Attr> out;
  std::size_t off = offset;
  while (off + 4 <= offset + length) {
    std::uint16_t len = 0, type = 0;
    std::memcpy(&len, buf + off, 2);
    std::memcpy(&type, buf + off + 2, 2);
    if (len < 4) break;
    out.push_back({type, off + 4, static_cast<std::size_t>(len - 4)});
    off += (len + 3u) & ~3u;
  }
  return out;
}

TEST(CanLink, RestartRequestIsRtmNewlinkWithCanRestartNested) {
  std::array<std::uint8_t, 256> buf{};
  const std::size_t n = CanLink::build_restart_request(buf.data(), buf.size(), 7, 42);
  ASSERT_GT(n, 0u);
  std::uint32_t len = 0;
  std::uint16_t type = 0, flags = 0;
  std::uint32_t seq = 0;
  std::memcpy(&len, buf.data(), 4);
  std::memcpy(&type, buf.data() + 4, 2);
  std::memcpy(&flags, buf.data() + 6, 2);
  std::memcpy(&seq, buf.data() + 8, 4);
  EXPECT_EQ(len, n);
  EXPECT_EQ(type, RTM_NEWLINK);
  EXPECT_EQ(flags, NLM_F_REQUEST | NLM_F_ACK);
  EXPECT_EQ(seq, 42u);
  int ifindex = 0;
  std::memcpy(&ifindex, buf.data() + 16 + 4, 4);  // ifinfomsg: family, pad, type, index
  EXPECT_EQ(ifindex, 7);
  const std::size_t first = 16 + 16;  // nlmsghdr + ifinfomsg
  const auto top = attrs(buf.data(), first, n - first);
  ASSERT_EQ(top.size(), 1u);
  EXPECT_EQ(top[0].type, IFLA_LINKINFO);
  const auto info = attrs(buf.data(), top[0].offset, top[0].length);
  ASSERT_EQ(info.size(), 2u);
  EXPECT_EQ(info[0].type, IFLA_INFO_KIND);
  EXPECT_STREQ(reinterpret_cast<const char*>(buf.data() + info[0].offset), "can");
  EXPECT_EQ(info[1].type, IFLA_INFO_DATA);
  const auto data = attrs(buf.data(), info[1].offset, info[1].length);
  ASSERT_EQ(data.size(), 1u);
  EXPECT_EQ(data[0].type, IFLA_CAN_RESTART);
  std::uint32_t one = 0;
  std::memcpy(&one, buf.data() + data[0].offset, 4);
  EXPECT_EQ(one, 1u);
  EXPECT_EQ(CanLink::build_restart_request(buf.data(), 20, 7, 1), 0u);  // too small
}

TEST(CanLink, UnknownInterfaceIsNamed) {
  auto l = CanLink::open("nosuchcan7");
  ASSERT_FALSE(l.ok());
  EXPECT_EQ(l.status().code(), ErrorCode::kNotFound);
  EXPECT_NE(l.status().message().find("nosuchcan7: no such interface"), std::string::npos);
}

TEST(CanLink, LoopbackIsNoControllerAndItsRestartIsRefused) {
  auto l = CanLink::open("lo");
  if (!l.ok()) GTEST_SKIP() << "no netlink here: " << l.status().to_string();
  LinkInfo info;
  ASSERT_TRUE((*l)->query(info).ok());
  EXPECT_TRUE(info.up);
  EXPECT_FALSE(info.controller);
  EXPECT_EQ(info.state, ControllerState::kUnknown);
  EXPECT_EQ(info.ifindex, (*l)->ifindex());
  const Status s = (*l)->restart();
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.message().rfind("lo: ", 0), 0u) << s.message();
}

}  // namespace
}  // namespace cdpr::can
