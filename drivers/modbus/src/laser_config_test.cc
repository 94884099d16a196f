#include <gtest/gtest.h>

#include <string>

#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::modbus {
namespace {

constexpr const char* kRtu = R"(name: platform
transport: rtu
device: /dev/ttyUSB3
baud: 57600
parity: even
data_bits: 8
stop_bits: 1
rs485: true
slave_id: 1
response_timeout: 0.05
retries: 1
poll_rate: 100
register_map: baumer-om20-om30.yaml
)";

TEST(LaserConfig, RtuWithMapFileRelativeToTheConfig) {
  const Result<LaserConfig> c = parse_laser_config(kRtu, "laser.yaml", CDPR_LASER_MAP_DIR);
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  const auto& rtu = std::get<RtuSettings>(c->link.transport);
  EXPECT_EQ(rtu.device, "/dev/ttyUSB3");
  EXPECT_EQ(rtu.baud, 57600);
  EXPECT_EQ(rtu.parity, 'E');
  EXPECT_TRUE(rtu.rs485);
  EXPECT_EQ(c->link.slave_id, 1);
  EXPECT_DOUBLE_EQ(c->link.response_timeout_s, 0.05);
  EXPECT_EQ(c->link.retries, 1);
  EXPECT_DOUBLE_EQ(c->poll_rate_hz, 100.0);
  EXPECT_EQ(c->map.name, "baumer-om20-om30");
  EXPECT_EQ(c->name, "platform");
}

TEST(LaserConfig, TcpWithInlineMap) {
  const char* yaml = R"(transport: tcp
host: 10.0.0.7
port: 1502
slave_id: 0
register_map:
  name: inline
  source: test
  table: holding
  value: {register: 4, type: u32, order: CDAB, scale: 0.0001}
  range: {min: 0, max: 10}
)";
  const Result<LaserConfig> c = parse_laser_config(yaml, "tcp.yaml", "");
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  const auto& tcp = std::get<TcpSettings>(c->link.transport);
  EXPECT_EQ(tcp.host, "10.0.0.7");
  EXPECT_EQ(tcp.port, 1502);
  EXPECT_EQ(c->link.slave_id, 0);
  EXPECT_EQ(c->map.type, ValueType::kU32);
  EXPECT_EQ(c->map.word_order, WordOrder::kLowFirst);
}

void expect_error(const std::string& yaml, const std::string& n1, const std::string& n2) {
  const Result<LaserConfig> c = parse_laser_config(yaml, "cfg/laser.yaml", CDPR_LASER_MAP_DIR);
  ASSERT_FALSE(c.ok()) << "expected error with " << n1;
  const std::string msg(c.status().message());
  EXPECT_NE(msg.find(n1), std::string::npos) << msg;
  EXPECT_NE(msg.find(n2), std::string::npos) << msg;
}

std::string rtu_with(const std::string& from, const std::string& to) {
  std::string s = kRtu;
  s.replace(s.find(from), from.size(), to);
  return s;
}

TEST(LaserConfig, ErrorsNameFileLineAndField) {
  expect_error(rtu_with("parity: even", "parity: mark"), "cfg/laser.yaml:5:", "parity");
  expect_error(rtu_with("slave_id: 1\n", ""), "slave_id", "missing");
  expect_error(rtu_with("slave_id: 1", "slave_id: 248"), "slave_id", "outside");
  expect_error(rtu_with("baud: 57600", "baud: 57600\nhost: x"), "host", "only for transport: tcp");
  expect_error(rtu_with("poll_rate: 100", "poll_rate: 5000"), "poll_rate", "0.1..1000");
  expect_error(rtu_with("response_timeout: 0.05", "response_timeout: 0"), "response_timeout",
               "0.001..10");
  expect_error(rtu_with("baumer-om20-om30.yaml", "missing.yaml"),
               "cfg/laser.yaml:13:", "missing.yaml");
  expect_error(rtu_with("transport: rtu", "transport: usb"), "transport", "rtu, tcp");
  expect_error(rtu_with("rs485: true", "rs485: maybe"), "rs485", "true or false");
}

TEST(LaserConfig, MissingFileIsNotFound) {
  const Result<LaserConfig> c = load_laser_config("/nonexistent/laser.yaml");
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), ErrorCode::kNotFound);
}

}  // namespace
}  // namespace cdpr::modbus
