// SocketCanBus checks that need no kernel CAN bus. They find out what this kernel offers and
// assert the error that situation calls for (and print which situation it was).
#include "cdpr/can/socketcan_bus.hpp"

#include <gtest/gtest.h>
#include <linux/can.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>

namespace cdpr::can {
namespace {

// Independent probe: can this kernel open an AF_CAN raw socket at all?
bool kernel_has_af_can() {
  const int fd = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) return false;
  ::close(fd);
  return true;
}

bool contains(std::string_view s, std::string_view part) {
  return s.find(part) != std::string_view::npos;
}

TEST(SocketCanBus, UnknownInterfaceFailsNamingIt) {
  auto bus = SocketCanBus::open("vcan9");
  ASSERT_FALSE(bus.ok());
  const Status& s = bus.status();
  EXPECT_TRUE(contains(s.message(), "vcan9")) << s.to_string();
  if (kernel_has_af_can()) {
    std::printf("kernel has AF_CAN: expecting 'no such CAN interface'\n");
    EXPECT_EQ(s.code(), ErrorCode::kNotFound) << s.to_string();
    EXPECT_TRUE(contains(s.message(), "vcan9: no such CAN interface")) << s.to_string();
  } else {
    std::printf("kernel has no AF_CAN: expecting kUnavailable saying so\n");
    EXPECT_EQ(s.code(), ErrorCode::kUnavailable) << s.to_string();
    EXPECT_TRUE(contains(s.message(), "AF_CAN")) << s.to_string();
  }
}

TEST(SocketCanBus, NonCanInterfaceIsRefused) {
  // "lo" exists on every Linux machine (also inside a network namespace), but is not CAN.
  auto bus = SocketCanBus::open("lo");
  ASSERT_FALSE(bus.ok());
  const Status& s = bus.status();
  EXPECT_TRUE(contains(s.message(), "lo")) << s.to_string();
  if (kernel_has_af_can()) {
    std::printf("kernel has AF_CAN: expecting 'not a CAN interface'\n");
    EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument) << s.to_string();
    EXPECT_TRUE(contains(s.message(), "lo is not a CAN interface")) << s.to_string();
  } else {
    std::printf("kernel has no AF_CAN: expecting kUnavailable\n");
    EXPECT_EQ(s.code(), ErrorCode::kUnavailable) << s.to_string();
  }
}

TEST(SocketCanBus, BadInterfaceNamesAreRefused) {
  auto empty = SocketCanBus::open("");
  ASSERT_FALSE(empty.ok());
  EXPECT_EQ(empty.status().code(), ErrorCode::kInvalidArgument);
  auto long_name = SocketCanBus::open("a_name_longer_than_ifnamsiz");
  ASSERT_FALSE(long_name.ok());
  EXPECT_EQ(long_name.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(contains(long_name.status().message(), "a_name_longer_than_ifnamsiz"));
}

TEST(CheckFrame, RefusesWhatClassicCanCannotCarry) {
  Frame f;
  f.id = 0x7FF;
  f.dlc = 8;
  EXPECT_TRUE(check_frame(f, "can0").ok());
  f.dlc = 9;
  Status s = check_frame(f, "can0");
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(contains(s.message(), "can0")) << s.to_string();
  f.dlc = 1;
  f.id = 0x800;
  EXPECT_EQ(check_frame(f, "can0").code(), ErrorCode::kInvalidArgument);
  f.extended = true;
  EXPECT_TRUE(check_frame(f, "can0").ok());
  f.id = 0x20000000;
  EXPECT_EQ(check_frame(f, "can0").code(), ErrorCode::kInvalidArgument);
  Frame err;
  err.error = true;
  EXPECT_EQ(check_frame(err, "can0").code(), ErrorCode::kInvalidArgument) << "class 0";
  err.error_class = error_class::kBusOff;
  EXPECT_TRUE(check_frame(err, "can0").ok());
}

}  // namespace
}  // namespace cdpr::can
