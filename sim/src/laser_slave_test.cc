// The Modbus laser slave against the project's own laser driver (drivers/modbus), in process:
// every shipped register map over the slave's own pty (RTU) and over TCP, plus the fault modes.
#include "cdpr/sim/laser_slave.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::sim {
namespace {

using modbus::LaserConfig;
using modbus::LaserReading;
using modbus::LaserSensor;
using modbus::ReadingStatus;
using modbus::RegisterMap;

const std::string kMaps = std::string(CDPR_SOURCE_DIR) + "/config/lasers";

std::vector<std::string> shipped_maps() {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(kMaps)) {
    if (e.path().extension() == ".yaml") names.push_back(e.path().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

RegisterMap load_map(const std::string& path) {
  Result<RegisterMap> m = modbus::load_register_map(path);
  EXPECT_TRUE(m.ok()) << m.status().to_string();
  return m.ok() ? *m : RegisterMap{};
}

// A reading the slave answers must never time out on a loaded machine: the driver waits
// generously (and tries twice); only the fault mode that drops requests waits the timeout out
// (kDropTimeoutS, short: nothing ever answers a dropped request).
constexpr double kAnswerTimeoutS = 5.0;
constexpr double kDropTimeoutS = 0.2;

LaserConfig driver_config(const LaserSlave& slave, const LaserSlaveConfig& sc) {
  LaserConfig c;
  c.name = sc.map.name;
  if (sc.transport == LaserSlaveConfig::Transport::kRtuPty) {
    c.link.transport = modbus::RtuSettings{slave.pty_path(), 115200, 'N', 8, 1, false};
  } else {
    c.link.transport = modbus::TcpSettings{"127.0.0.1", slave.port()};
  }
  c.link.slave_id = sc.slave_id;
  c.link.response_timeout_s = kAnswerTimeoutS;
  c.link.retries = 1;
  c.link.reconnect_delay_s = 0.05;
  c.map = sc.map;
  return c;
}

double test_distance(const RegisterMap& m) {
  return m.min_m + 0.3719 * (m.max_m - m.min_m);
}
double tolerance(const RegisterMap& m, double d) {
  return m.type == modbus::ValueType::kF32 ? 1e-6 * std::max(1.0, d)
                                           : 0.5 * m.resolution_m() + 1e-12;
}

std::string transport_name(
    const ::testing::TestParamInfo<LaserSlaveConfig::Transport>& param_info) {
  return param_info.param == LaserSlaveConfig::Transport::kTcp ? "Tcp" : "Rtu";
}

class LaserSlaveTest : public ::testing::TestWithParam<LaserSlaveConfig::Transport> {};

TEST_P(LaserSlaveTest, DriverReadsTheSimValueForEveryShippedMap) {
  for (const std::string& path : shipped_maps()) {
    SCOPED_TRACE(path);
    LaserSlaveConfig sc;
    sc.transport = GetParam();
    sc.map = load_map(path);
    sc.slave_id = 17;
    auto slave = LaserSlave::start(sc);
    ASSERT_TRUE(slave.ok()) << slave.status().to_string();
    const double d = test_distance(sc.map);
    (*slave)->set_distance(d, LaserStatus::kOk);
    LaserSensor laser(driver_config(**slave, sc));
    const LaserReading r = laser.read_once();
    ASSERT_EQ(r.status, ReadingStatus::kOk) << r.error.to_string();
    EXPECT_NEAR(r.distance_m, d, tolerance(sc.map, d));
    // A new value is served at the next request.
    const double d2 = sc.map.min_m + 0.61 * (sc.map.max_m - sc.map.min_m);
    (*slave)->set_distance(d2, LaserStatus::kOk);
    const LaserReading r2 = laser.read_once();
    ASSERT_EQ(r2.status, ReadingStatus::kOk) << r2.error.to_string();
    EXPECT_NEAR(r2.distance_m, d2, tolerance(sc.map, d2));
    EXPECT_GE((*slave)->answered(), 2u);
  }
}

TEST_P(LaserSlaveTest, FaultModes) {
  LaserSlaveConfig sc;
  sc.transport = GetParam();
  sc.map = load_map(kMaps + "/baumer-om20-om30.yaml");
  sc.slave_id = 1;
  auto slave = LaserSlave::start(sc);
  ASSERT_TRUE(slave.ok()) << slave.status().to_string();
  (*slave)->set_distance(0.55, LaserStatus::kOk);
  std::optional<LaserSensor> laser(std::in_place, driver_config(**slave, sc));
  ASSERT_EQ(laser->read_once().status, ReadingStatus::kOk);

  (*slave)->set_fault(LaserFaultMode::kOutOfRange);
  EXPECT_EQ(laser->read_once().status, ReadingStatus::kOutOfRange);
  (*slave)->set_fault(LaserFaultMode::kGarbage);
  const LaserReading g = laser->read_once();
  EXPECT_NE(g.status, ReadingStatus::kOk);
  EXPECT_NE(g.status, ReadingStatus::kTimeout);
  // Dropped requests: a driver with a short timeout (the pty is opened exclusively: one at once).
  laser.reset();
  {
    LaserConfig short_wait = driver_config(**slave, sc);
    short_wait.link.response_timeout_s = kDropTimeoutS;
    short_wait.link.retries = 0;
    LaserSensor impatient(short_wait);
    (*slave)->set_fault(LaserFaultMode::kTimeout);
    EXPECT_EQ(impatient.read_once().status, ReadingStatus::kTimeout);
    EXPECT_GE((*slave)->dropped(), 1u);
  }
  (*slave)->set_fault(LaserFaultMode::kNone);
  laser.emplace(driver_config(**slave, sc));
  // The physics says: no target (quality register "critical signal").
  (*slave)->set_distance(kNaN, LaserStatus::kNoTarget);
  LaserReading n = laser->read_once();
  for (int k = 0; k < 5 && n.status == ReadingStatus::kCommError; ++k) n = laser->read_once();
  EXPECT_EQ(n.status, ReadingStatus::kNoTarget) << n.error.to_string();
  (*slave)->set_distance(0.4, LaserStatus::kOk);
  LaserReading ok = laser->read_once();
  for (int k = 0; k < 5 && ok.status != ReadingStatus::kOk; ++k) ok = laser->read_once();
  ASSERT_EQ(ok.status, ReadingStatus::kOk) << ok.error.to_string();
  EXPECT_NEAR(ok.distance_m, 0.4, 1e-6);
}

TEST_P(LaserSlaveTest, NoiseIsFreshPerRequestAndSeeded) {
  LaserSlaveConfig sc;
  sc.transport = GetParam();
  sc.map = load_map(kMaps + "/baumer-om20-om30.yaml");
  sc.noise_sigma_m = 0.001;
  sc.seed = 5;
  auto slave = LaserSlave::start(sc);
  ASSERT_TRUE(slave.ok()) << slave.status().to_string();
  (*slave)->set_distance(0.5, LaserStatus::kOk);
  LaserSensor laser(driver_config(**slave, sc));
  std::vector<double> v;
  for (int k = 0; k < 40; ++k) {
    const LaserReading r = laser.read_once();
    ASSERT_EQ(r.status, ReadingStatus::kOk) << r.error.to_string();
    v.push_back(r.distance_m);
  }
  double mean = 0.0;
  for (double x : v) mean += x / static_cast<double>(v.size());
  double var = 0.0;
  for (double x : v) var += (x - mean) * (x - mean) / static_cast<double>(v.size() - 1);
  EXPECT_NEAR(mean, 0.5, 0.001);  // 5 standard errors
  EXPECT_GT(std::sqrt(var), 0.0005);
  EXPECT_LT(std::sqrt(var), 0.0015);
}

INSTANTIATE_TEST_SUITE_P(Transports, LaserSlaveTest,
                         ::testing::Values(LaserSlaveConfig::Transport::kRtuPty,
                                           LaserSlaveConfig::Transport::kTcp),
                         transport_name);

TEST(LaserSlave, SymlinkToThePtyIsMadeAndRemoved) {
  const std::string link = "/tmp/cdpr-sim-laser-test-" + std::to_string(getpid());
  LaserSlaveConfig sc;
  sc.map = load_map(kMaps + "/wit-wt53r-485.yaml");
  sc.pty_link = link;
  auto slave = LaserSlave::start(sc);
  ASSERT_TRUE(slave.ok()) << slave.status().to_string();
  ASSERT_TRUE(std::filesystem::is_symlink(link));
  EXPECT_EQ(std::filesystem::read_symlink(link).string(), (*slave)->pty_path());
  (*slave)->set_distance(1.234, LaserStatus::kOk);
  LaserConfig c = driver_config(**slave, sc);
  c.link.transport = modbus::RtuSettings{link, 115200, 'N', 8, 1, false};
  LaserSensor laser(c);
  const LaserReading r = laser.read_once();
  ASSERT_EQ(r.status, ReadingStatus::kOk) << r.error.to_string();
  EXPECT_NEAR(r.distance_m, 1.234, 0.0005 + 1e-12);
  (*slave)->stop();
  EXPECT_FALSE(std::filesystem::exists(std::filesystem::symlink_status(link)));
}

TEST(LaserSlave, RefusesABadMap) {
  LaserSlaveConfig sc;
  sc.map.name = "bad";
  sc.map.min_m = 2.0;
  sc.map.max_m = 1.0;
  EXPECT_FALSE(LaserSlave::start(sc).ok());
}

}  // namespace
}  // namespace cdpr::sim
