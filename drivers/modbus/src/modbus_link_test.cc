// Link and driver behaviour that needs no peer: validation, missing devices, refused TCP
// connections, bounded failure. Real peers are in tests/modbus/.
#include "cdpr/modbus/modbus_link.hpp"

#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <string>

#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::modbus {
namespace {

RegisterMap simple_map() {
  RegisterMap m;
  m.name = "simple";
  m.table = RegisterTable::kHolding;
  m.address = 0;
  m.type = ValueType::kU16;
  m.scale = 1e-3;
  m.min_m = 0.0;
  m.max_m = 10.0;
  return m;
}

// A TCP port on 127.0.0.1 with nothing listening: bind, read the port, close.
int closed_port() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  close(fd);
  return ntohs(a.sin_port);
}

TEST(ExceptionText, NamesStandardCodes) {
  EXPECT_EQ(exception_text(1), "illegal function");
  EXPECT_EQ(exception_text(2), "illegal data address");
  EXPECT_EQ(exception_text(3), "illegal data value");
  EXPECT_EQ(exception_text(4), "slave device failure");
  EXPECT_EQ(exception_text(11), "gateway target device failed to respond");
  EXPECT_EQ(exception_text(99), "unknown exception");
}

TEST(LinkConfig, ValidateRejectsBadSettings) {
  LinkConfig c;
  c.transport = RtuSettings{"/dev/ttyS0", 9600, 'X', 8, 1, false};
  EXPECT_NE(c.validate().message().find("parity"), std::string_view::npos);
  c.transport = RtuSettings{"/dev/ttyS0", 9600, 'N', 8, 1, false};
  c.slave_id = 0;
  EXPECT_NE(c.validate().message().find("slave id 0"), std::string_view::npos);
  c.slave_id = 1;
  EXPECT_TRUE(c.validate().ok());
  c.response_timeout_s = 0.0;
  EXPECT_FALSE(c.validate().ok());
  c.response_timeout_s = 0.1;
  c.transport = TcpSettings{"", 502};
  EXPECT_FALSE(c.validate().ok());
  c.transport = TcpSettings{"localhost", 70000};
  EXPECT_FALSE(c.validate().ok());
}

TEST(ModbusLink, MissingSerialDeviceIsNotFoundAndNamed) {
  LinkConfig c;
  c.transport = RtuSettings{"/dev/cdpr-no-such-tty", 19200, 'E', 8, 1, false};
  c.slave_id = 5;
  ModbusLink link(c);
  EXPECT_EQ(link.describe(), "RTU /dev/cdpr-no-such-tty slave 5");
  const Status s = link.connect();
  EXPECT_EQ(s.code(), ErrorCode::kNotFound) << s.to_string();
  EXPECT_NE(s.message().find("/dev/cdpr-no-such-tty"), std::string_view::npos);
  EXPECT_FALSE(link.connected());
  std::uint16_t r = 0;
  const Status read = link.read_registers(RegisterTable::kHolding, 0, {&r, 1});
  EXPECT_EQ(read.code(), ErrorCode::kUnavailable);
  EXPECT_NE(read.message().find("not connected"), std::string_view::npos);
}

TEST(ModbusLink, RefusedTcpConnectionFailsFast) {
  LinkConfig c;
  const int port = closed_port();
  c.transport = TcpSettings{"127.0.0.1", port};
  c.response_timeout_s = 10.0;  // the longest allowed: "fast" is well before it, also when loaded
  ModbusLink link(c);
  const auto t0 = std::chrono::steady_clock::now();
  const Status s = link.connect();
  const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("127.0.0.1:" + std::to_string(port)), std::string_view::npos)
      << s.to_string();
  EXPECT_LT(dt, 5.0);
}

TEST(ModbusLink, RequestsOutsideTheModbusLimitsAreRejectedBeforeSending) {
  LinkConfig c;
  c.transport = TcpSettings{"127.0.0.1", 502};
  ModbusLink link(c);
  std::vector<std::uint16_t> regs(126);
  EXPECT_EQ(link.read_registers(RegisterTable::kInput, 0, regs).code(),
            ErrorCode::kInvalidArgument);
  EXPECT_EQ(link.read_registers(RegisterTable::kInput, 65535, {regs.data(), 2}).code(),
            ErrorCode::kInvalidArgument);
}

TEST(LaserSensor, AbsentDeviceGivesErrorReadingsNotCrashesOrHangs) {
  LaserConfig cfg;
  cfg.name = "absent";
  cfg.link.transport = RtuSettings{"/dev/cdpr-no-such-tty", 19200, 'E', 8, 1, false};
  cfg.link.reconnect_delay_s = 0.05;
  cfg.map = simple_map();
  cfg.poll_rate_hz = 200;
  LaserSensor laser(cfg);
  EXPECT_EQ(laser.latest().status, ReadingStatus::kNone);
  const LaserReading r = laser.read_once();
  EXPECT_EQ(r.status, ReadingStatus::kCommError);
  EXPECT_NE(r.error.message().find("/dev/cdpr-no-such-tty"), std::string_view::npos);
  EXPECT_GT(r.stamp_ns, 0);
  EXPECT_EQ(r.sequence, 1u);

  ASSERT_TRUE(laser.start().ok());
  // The thread keeps polling (and failing) at its rate: a few readings, however loaded the host.
  const auto t_start = std::chrono::steady_clock::now();
  LaserReading p = laser.latest();
  while (p.sequence <= 3 && std::chrono::steady_clock::now() - t_start < std::chrono::seconds(30)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
    p = laser.latest();
  }
  EXPECT_GT(p.sequence, 3u);
  EXPECT_EQ(p.status, ReadingStatus::kCommError);
  const DriverStatus st = laser.status();
  EXPECT_TRUE(st.running);
  EXPECT_FALSE(st.connected);
  EXPECT_EQ(st.last_connect_error.code(), ErrorCode::kNotFound);
  const auto t0 = std::chrono::steady_clock::now();
  laser.stop();  // not held up by the reconnect attempts: no hang
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 10.0);
  EXPECT_FALSE(laser.running());

  const Result<Measurement> m = laser.measure(4, {.interval_s = 0.0});
  ASSERT_FALSE(m.ok());
  EXPECT_NE(m.status().message().find("0 readings usable"), std::string_view::npos)
      << m.status().to_string();
  EXPECT_NE(m.status().message().find("/dev/cdpr-no-such-tty"), std::string_view::npos);
}

TEST(LaserSensor, MeasureStopsOnceTooFewReadingsAreLeftToSucceed) {
  LaserConfig cfg;
  cfg.name = "absent";
  cfg.link.transport = RtuSettings{"/dev/cdpr-no-such-tty", 19200, 'E', 8, 1, false};
  cfg.map = simple_map();
  LaserSensor laser(cfg);  // not started: only measure() reads
  constexpr int kReadings = 10;
  const Result<Measurement> m = laser.measure(kReadings, {.interval_s = 0.0, .min_valid = 4});
  ASSERT_FALSE(m.ok());
  // 7 failures leave 3 readings, fewer than the 4 needed: no eighth try.
  EXPECT_EQ(laser.latest().sequence, static_cast<std::uint64_t>(kReadings - 4 + 1));
  EXPECT_NE(m.status().message().find("7 failed"), std::string_view::npos)
      << m.status().to_string();
}

TEST(LaserSensor, BadConfigurationIsRefusedAtStart) {
  LaserConfig cfg;
  cfg.link.transport = TcpSettings{"127.0.0.1", 502};
  cfg.map = simple_map();
  cfg.map.max_m = -1.0;
  LaserSensor laser(cfg);
  const Status s = laser.start();
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_FALSE(laser.running());
  EXPECT_EQ(laser.measure(0).status().code(), ErrorCode::kInvalidArgument);
}

}  // namespace
}  // namespace cdpr::modbus
