// The laser driver against a real Modbus peer in another process: pymodbus 3.0 serving each
// shipped register map, over a socat pty pair (RTU) and over TCP on 127.0.0.1.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/modbus/laser_sensor.hpp"
#include "peer_process.hpp"

namespace cdpr::modbus {
namespace {

using testing::LaserSlave;
using testing::PtyPair;
using testing::SlaveOptions;
using testing::TempDir;
using Clock = std::chrono::steady_clock;

double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string map_dir() {
  return testing::source_dir() + "/config/lasers";
}

std::vector<std::string> shipped_maps() {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(map_dir())) {
    if (e.path().extension() == ".yaml") names.push_back(e.path().stem().string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

RegisterMap load_map(const std::string& name) {
  Result<RegisterMap> m = load_register_map(map_dir() + "/" + name + ".yaml");
  EXPECT_TRUE(m.ok()) << m.status().to_string();
  return m.ok() ? *m : RegisterMap{};
}

// Wall-clock bounds (CI runs on a loaded 2-core machine): a slave that answers is waited for
// generously, so only a hang fails; a read that must time out (nobody answers) uses a short
// timeout, which is the outcome expected; "answered at once" means well before the answer timeout.
constexpr double kAnswerTimeoutS = 10.0;
constexpr double kAtOnceS = kAnswerTimeoutS / 2;
constexpr double kHangS = 30.0;

LaserConfig rtu_config(const std::string& device, const RegisterMap& map, int slave = 17) {
  LaserConfig c;
  c.name = map.name;
  c.link.transport = RtuSettings{device, 115200, 'E', 8, 1, false};
  c.link.slave_id = slave;
  c.link.response_timeout_s = kAnswerTimeoutS;
  c.link.retries = 1;
  c.link.reconnect_delay_s = 0.1;
  c.map = map;
  c.poll_rate_hz = 50.0;
  return c;
}

LaserConfig tcp_config(int port, const RegisterMap& map, int slave = 17) {
  LaserConfig c = rtu_config("", map, slave);
  c.link.transport = TcpSettings{"127.0.0.1", port};
  return c;
}

// A distance inside the map's range, and what the map can represent of it.
double test_distance(const RegisterMap& m) {
  return m.min_m + 0.3719 * (m.max_m - m.min_m);
}
double tolerance(const RegisterMap& m, double d) {
  return m.type == ValueType::kF32 ? 1e-6 * std::max(1.0, d) : 0.5 * m.resolution_m() + 1e-12;
}

// A pty pair with the python slave on one end, for one map.
struct RtuRig {
  TempDir dir;
  PtyPair pty{dir};
  LaserSlave slave{dir};
  Status start(const SlaveOptions& o) {
    if (dir.path().empty()) return Status(ErrorCode::kIoError, "mkdtemp failed");
    if (Status s = pty.start(); !s.ok()) return s;
    return slave.start_rtu(pty.slave_path(), o);
  }
};

class ShippedMap : public ::testing::TestWithParam<std::string> {};

TEST_P(ShippedMap, RtuReadsTheRightMetres) {
  const RegisterMap map = load_map(GetParam());
  RtuRig rig;
  const double d = test_distance(map);
  ASSERT_TRUE(
      rig.start({.map_path = map_dir() + "/" + GetParam() + ".yaml", .distances = {d}}).ok());
  LaserSensor laser(rtu_config(rig.pty.master_path(), map));
  const LaserReading r = laser.read_once();
  ASSERT_EQ(r.status, ReadingStatus::kOk) << r.error.to_string() << "\n" << rig.slave.log();
  EXPECT_NEAR(r.distance_m, d, tolerance(map, d))
      << to_string(map.type) << " " << order_name(map.word_order, map.byte_order);
  EXPECT_GT(r.stamp_ns, 0);
  EXPECT_LE(r.stamp_ns, monotonic_ns());
  EXPECT_GT(r.latency_ns, 0);
  EXPECT_LT(r.latency_ns, 200'000'000);
  EXPECT_EQ(r.has_quality, map.quality.has_value());
}

TEST_P(ShippedMap, TcpReadsTheRightMetres) {
  const RegisterMap map = load_map(GetParam());
  TempDir dir;
  LaserSlave slave(dir);
  const double d = test_distance(map) * 0.9 + 0.1 * map.min_m;
  const Status s =
      slave.start_tcp(0, {.map_path = map_dir() + "/" + GetParam() + ".yaml", .distances = {d}});
  ASSERT_TRUE(s.ok()) << s.to_string();
  ASSERT_GT(slave.port(), 0);
  LaserSensor laser(tcp_config(slave.port(), map));
  const LaserReading r = laser.read_once();
  ASSERT_EQ(r.status, ReadingStatus::kOk) << r.error.to_string() << "\n" << slave.log();
  EXPECT_NEAR(r.distance_m, d, tolerance(map, d));
}

INSTANTIATE_TEST_SUITE_P(Lasers, ShippedMap, ::testing::ValuesIn(shipped_maps()),
                         [](const ::testing::TestParamInfo<std::string>& i) {
                           std::string n = i.param;
                           for (char& c : n) {
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           }
                           return n;
                         });

TEST(LaserRtu, BaumerCdabFloatAndQualityRegister) {
  RegisterMap map = load_map("baumer-om20-om30");
  ASSERT_EQ(order_name(map.word_order, map.byte_order), "CDAB");
  RtuRig rig;
  ASSERT_TRUE(rig.start({.map_path = map_dir() + "/baumer-om20-om30.yaml",
                         .distances = {0.069743},
                         .quality = 1})
                  .ok());
  {
    LaserSensor laser(rtu_config(rig.pty.master_path(), map));
    const LaserReading r = laser.read_once();
    ASSERT_TRUE(r.ok()) << r.error.to_string();
    EXPECT_NEAR(r.distance_m, 0.069743, 1e-7);
    ASSERT_TRUE(r.has_quality);
    EXPECT_EQ(r.quality, 1);  // weak signal: still valid
  }                           // closes the serial port (opened exclusively)

  // The same answer decoded with the words swapped (ABCD) is a different number: 0x7C6A428B
  // is about 4.9e36 mm, far outside the map's range.
  map.word_order = WordOrder::kHighFirst;
  LaserSensor wrong(rtu_config(rig.pty.master_path(), map));
  const LaserReading w = wrong.read_once();
  EXPECT_EQ(w.status, ReadingStatus::kOutOfRange) << w.error.to_string();
  EXPECT_GT(std::fabs(w.distance_m - 0.069743), 1e3);
}

TEST(LaserRtu, QualityRegisterSaysNoTarget) {
  const RegisterMap map = load_map("baumer-om20-om30");
  RtuRig rig;
  ASSERT_TRUE(
      rig.start(
             {.map_path = map_dir() + "/baumer-om20-om30.yaml", .distances = {0.1}, .quality = 2})
          .ok());
  LaserSensor laser(rtu_config(rig.pty.master_path(), map));
  const LaserReading r = laser.read_once();
  EXPECT_EQ(r.status, ReadingStatus::kNoTarget) << r.error.to_string();
  EXPECT_NE(r.error.message().find("quality register 200"), std::string_view::npos);
}

TEST(LaserRtu, SentinelAndOutOfRangeThroughTheWire) {
  const RegisterMap map = load_map("wit-wt53r-485");
  {
    RtuRig rig;
    ASSERT_TRUE(rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml", .raw = "0xFFFF"}).ok());
    LaserSensor laser(rtu_config(rig.pty.master_path(), map));
    const LaserReading r = laser.read_once();
    EXPECT_EQ(r.status, ReadingStatus::kNoTarget) << r.error.to_string();
    EXPECT_EQ(r.raw, 65535.0);
  }
  {
    RtuRig rig;
    ASSERT_TRUE(rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml", .raw = "10"}).ok());
    LaserSensor laser(rtu_config(rig.pty.master_path(), map));
    const LaserReading r = laser.read_once();
    EXPECT_EQ(r.status, ReadingStatus::kOutOfRange) << r.error.to_string();
    EXPECT_NEAR(r.distance_m, 0.010, 1e-12);
  }
}

TEST(LaserRtu, TriggerWriteStartsEachMeasurement) {
  const RegisterMap map = load_map("generic-rs485-0p1mm-trigger");
  ASSERT_TRUE(map.trigger.has_value());
  RtuRig rig;
  ASSERT_TRUE(rig.start({.map_path = map_dir() + "/generic-rs485-0p1mm-trigger.yaml",
                         .distances = {1.2345, 2.5}})
                  .ok());
  {
    LaserSensor laser(rtu_config(rig.pty.master_path(), map));
    LaserReading r = laser.read_once();
    ASSERT_TRUE(r.ok()) << r.error.to_string() << "\n" << rig.slave.log();
    EXPECT_NEAR(r.distance_m, 1.2345, 0.5e-4 + 1e-12);
    r = laser.read_once();
    ASSERT_TRUE(r.ok()) << r.error.to_string();
    EXPECT_NEAR(r.distance_m, 2.5, 0.5e-4 + 1e-12);
  }  // closes the serial port (opened exclusively)
  // Without the trigger the module has no fresh measurement: its no-target value.
  RegisterMap no_trigger = map;
  no_trigger.trigger.reset();
  LaserSensor lazy(rtu_config(rig.pty.master_path(), no_trigger));
  EXPECT_EQ(lazy.read_once().status, ReadingStatus::kNoTarget);
}

TEST(LaserRtu, PollingThreadPublishesFreshTimestampedReadings) {
  const RegisterMap map = load_map("wit-wt53r-485");
  RtuRig rig;
  ASSERT_TRUE(rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml", .distances = {0.75}}).ok());
  LaserConfig cfg = rtu_config(rig.pty.master_path(), map);
  cfg.poll_rate_hz = 50.0;
  LaserSensor laser(cfg);
  ASSERT_TRUE(laser.start().ok());
  const auto t0 = Clock::now();
  LaserReading first = laser.latest();
  while (first.sequence == 0 && since(t0) < kHangS) {
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    first = laser.latest();
  }
  ASSERT_GT(first.sequence, 0u);
  // At least 20 more readings (however long a loaded machine takes), never faster than 50 Hz.
  const auto t_first = Clock::now();
  LaserReading last = laser.latest();
  while (last.sequence < first.sequence + 20 && since(t_first) < kHangS) {
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    last = laser.latest();
  }
  laser.stop();
  ASSERT_TRUE(last.ok()) << last.error.to_string();
  EXPECT_NEAR(last.distance_m, 0.75, 0.5e-3);
  const auto n = last.sequence - first.sequence;
  EXPECT_GE(n, 20u);
  EXPECT_GT(last.stamp_ns, first.stamp_ns);
  // A request starts no earlier than one period after the previous slot, nor before the previous
  // request ended (stamps are mid-request): n readings after `first` span >= (n - 1) periods.
  const double span_s = 1e-9 * static_cast<double>(last.stamp_ns - first.stamp_ns);
  EXPECT_LE(static_cast<double>(n), 50.0 * span_s + 1.5) << "polls faster than its rate";
  EXPECT_LT(monotonic_ns() - last.stamp_ns, static_cast<std::int64_t>(kHangS * 1e9));
  const DriverStatus st = laser.status();
  EXPECT_FALSE(st.running);
  EXPECT_GE(st.counters.requests, n);
  EXPECT_EQ(st.counters.timeouts, 0u);
}

TEST(LaserRtu, MeasureRejectsOutliers) {
  const RegisterMap map = load_map("wit-wt53r-485");
  RtuRig rig;
  // Served in turn; 1.5 m (a reflection) and 0.3 m (the beam on a cable) are outliers.
  ASSERT_TRUE(rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml",
                         .distances = {1.000, 1.001, 0.999, 1.000, 1.500, 1.000, 1.002, 0.998,
                                       0.300, 1.000}})
                  .ok());
  LaserSensor laser(rtu_config(rig.pty.master_path(), map));
  const Result<Measurement> m = laser.measure(20, {.interval_s = 0.0});
  ASSERT_TRUE(m.ok()) << m.status().to_string();
  EXPECT_EQ(m->used + m->rejected + m->failed, 20);
  EXPECT_EQ(m->rejected, 4);
  EXPECT_EQ(m->failed, 0);
  EXPECT_NEAR(m->mean_m, 1.000, 1e-9);
  EXPECT_NEAR(m->median_m, 1.000, 1e-9);
  EXPECT_GT(m->stddev_m, 0.0);
  EXPECT_LT(m->stddev_m, 0.002);
}

TEST(LaserRtu, RS485ModeOnAPtyDegradesToAWarning) {
  const RegisterMap map = load_map("wit-wt53r-485");
  RtuRig rig;
  ASSERT_TRUE(rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml", .distances = {2.0}}).ok());
  LaserConfig cfg = rtu_config(rig.pty.master_path(), map);
  std::get<RtuSettings>(cfg.link.transport).rs485 = true;
  LaserSensor laser(cfg);
  const LaserReading r = laser.read_once();
  ASSERT_TRUE(r.ok()) << r.error.to_string();
  EXPECT_NEAR(r.distance_m, 2.0, 0.5e-3);
  const DriverStatus st = laser.status();
  ASSERT_EQ(st.warnings.size(), 1u);
  EXPECT_NE(st.warnings[0].find("RS-485"), std::string::npos) << st.warnings[0];
  EXPECT_NE(st.warnings[0].find(rig.pty.master_path()), std::string::npos);
  EXPECT_NE(st.warnings[0].find("errno 25"), std::string::npos) << st.warnings[0];  // ENOTTY
}

TEST(LaserRtu, SlaveNotAnsweringTimesOutBoundedAndNamed) {
  const RegisterMap map = load_map("wit-wt53r-485");
  TempDir dir;
  PtyPair pty(dir);
  ASSERT_TRUE(pty.start().ok());  // nobody on the other end
  LaserConfig cfg = rtu_config(pty.master_path(), map);
  cfg.link.response_timeout_s = 0.1;
  cfg.link.retries = 2;
  LaserSensor laser(cfg);
  const auto t0 = Clock::now();
  const LaserReading r = laser.read_once();
  const double dt = since(t0);
  EXPECT_EQ(r.status, ReadingStatus::kTimeout);
  EXPECT_EQ(r.error.code(), ErrorCode::kTimeout);
  const std::string msg(r.error.message());
  EXPECT_NE(msg.find(pty.master_path()), std::string::npos) << msg;
  EXPECT_NE(msg.find("slave 17"), std::string::npos) << msg;
  EXPECT_NE(msg.find("holding"), std::string::npos) << msg;
  EXPECT_NE(msg.find("address 52"), std::string::npos) << msg;  // register 0x34
  EXPECT_NE(msg.find("3 tries"), std::string::npos) << msg;
  EXPECT_GE(dt, 0.29);
  EXPECT_LT(dt, kHangS);
  EXPECT_EQ(laser.status().counters.timeouts, 1u);
}

TEST(LaserRtu, WrongSlaveIdIsATimeoutNamingTheId) {
  const RegisterMap map = load_map("wit-wt53r-485");
  RtuRig rig;
  ASSERT_TRUE(
      rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml", .slave_id = 18, .distances = {1.5}})
          .ok());
  LaserConfig cfg = rtu_config(rig.pty.master_path(), map, 17);
  cfg.link.response_timeout_s = 0.1;
  cfg.link.retries = 0;
  {
    LaserSensor wrong(cfg);
    const auto t0 = Clock::now();
    const LaserReading r = wrong.read_once();
    EXPECT_LT(since(t0), kHangS);
    EXPECT_EQ(r.status, ReadingStatus::kTimeout) << r.error.to_string();
    EXPECT_NE(r.error.message().find("no answer from slave 17"), std::string_view::npos)
        << r.error.to_string();
  }  // closes the serial port (opened exclusively)
  // The slave is alive: the right id gets the value. The python slave loses the first request
  // after the port is opened again, so this read is retried: 5 tries of 1 s (never 5 misses).
  LaserConfig right_cfg = rtu_config(rig.pty.master_path(), map, 18);
  right_cfg.link.response_timeout_s = 1.0;
  right_cfg.link.retries = 4;
  LaserSensor right(right_cfg);
  const LaserReading ok = right.read_once();
  ASSERT_TRUE(ok.ok()) << ok.error.to_string();
  EXPECT_NEAR(ok.distance_m, 1.5, 0.5e-3);
}

TEST(LaserRtu, CorruptedFrameIsACrcError) {
  const RegisterMap map = load_map("wit-wt53r-485");
  RtuRig rig;
  ASSERT_TRUE(
      rig.start(
             {.map_path = map_dir() + "/wit-wt53r-485.yaml", .distances = {1.0}, .mode = "bad-crc"})
          .ok());
  LaserConfig cfg = rtu_config(rig.pty.master_path(), map);
  cfg.link.retries = 1;
  LaserSensor laser(cfg);
  const auto t0 = Clock::now();
  const LaserReading r = laser.read_once();
  EXPECT_LT(since(t0), kAtOnceS);  // no answer timeout waited out
  EXPECT_EQ(r.status, ReadingStatus::kCommError);
  EXPECT_EQ(r.error.code(), ErrorCode::kProtocolError);
  EXPECT_NE(r.error.message().find("CRC"), std::string_view::npos) << r.error.to_string();
  EXPECT_NE(r.error.message().find("slave 17"), std::string_view::npos);
  EXPECT_EQ(laser.status().counters.crc_errors, 1u);
  EXPECT_EQ(laser.status().counters.retries, 1u);
}

TEST(LaserRtu, ExceptionIsDecodedToText) {
  RegisterMap map = load_map("wit-wt53r-485");
  RtuRig rig;
  ASSERT_TRUE(rig.start({.map_path = map_dir() + "/wit-wt53r-485.yaml", .distances = {1.0}}).ok());
  map.address = 900;  // the slave has no register there
  LaserSensor laser(rtu_config(rig.pty.master_path(), map));
  const auto t0 = Clock::now();
  const LaserReading r = laser.read_once();
  EXPECT_LT(since(t0), kAtOnceS);  // answered at once, not retried
  EXPECT_EQ(r.status, ReadingStatus::kCommError);
  EXPECT_EQ(r.error.code(), ErrorCode::kAborted);
  EXPECT_NE(r.error.message().find("exception 2 (illegal data address)"), std::string_view::npos)
      << r.error.to_string();
  EXPECT_NE(r.error.message().find("address 900"), std::string_view::npos);
  EXPECT_EQ(laser.status().counters.exceptions, 1u);
  EXPECT_EQ(laser.status().counters.retries, 0u);
}

TEST(LaserTcp, ExceptionAndWrongUnitId) {
  RegisterMap map = load_map("proxitron-lma-u32");
  TempDir dir;
  LaserSlave slave(dir);
  ASSERT_TRUE(
      slave.start_tcp(0, {.map_path = map_dir() + "/proxitron-lma-u32.yaml", .distances = {12.345}})
          .ok());
  LaserConfig wrong_id = tcp_config(slave.port(), map, 99);
  wrong_id.link.response_timeout_s = 0.1;
  wrong_id.link.retries = 0;
  LaserSensor a(wrong_id);
  const LaserReading ra = a.read_once();
  EXPECT_EQ(ra.status, ReadingStatus::kTimeout) << ra.error.to_string();
  EXPECT_NE(ra.error.message().find("127.0.0.1:" + std::to_string(slave.port()) + " unit 99"),
            std::string_view::npos)
      << ra.error.to_string();

  map.address = 4000;
  LaserSensor b(tcp_config(slave.port(), map));
  const LaserReading rb = b.read_once();
  EXPECT_EQ(rb.error.code(), ErrorCode::kAborted) << rb.error.to_string();
  EXPECT_NE(rb.error.message().find("illegal data address"), std::string_view::npos);
}

TEST(LaserTcp, ReconnectsAfterTheServerRestarts) {
  const RegisterMap map = load_map("proxitron-lma-u32");
  TempDir dir;
  LaserSlave slave(dir, "first");
  ASSERT_TRUE(
      slave.start_tcp(0, {.map_path = map_dir() + "/proxitron-lma-u32.yaml", .distances = {5.0}})
          .ok());
  const int port = slave.port();
  LaserConfig cfg = tcp_config(port, map);
  cfg.link.response_timeout_s = 1.0;
  cfg.link.retries = 0;
  cfg.link.reconnect_delay_s = 0.05;
  cfg.poll_rate_hz = 100;
  LaserSensor laser(cfg);
  ASSERT_TRUE(laser.start().ok());
  auto wait_for = [&](auto pred, double timeout_s) {
    const auto t0 = Clock::now();
    while (since(t0) < timeout_s) {
      if (pred(laser.latest())) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return false;
  };
  ASSERT_TRUE(wait_for([](const LaserReading& r) { return r.ok(); }, kHangS));
  EXPECT_NEAR(laser.latest().distance_m, 5.0, 0.5e-3);

  slave.stop();
  ASSERT_TRUE(wait_for([](const LaserReading& r) { return !r.ok() && r.sequence > 0; }, kHangS));
  const LaserReading down = laser.latest();
  EXPECT_NE(down.error.message().find(std::to_string(port)), std::string_view::npos)
      << down.error.to_string();

  LaserSlave again(dir, "second");
  ASSERT_TRUE(
      again.start_tcp(port, {.map_path = map_dir() + "/proxitron-lma-u32.yaml", .distances = {7.5}})
          .ok());
  ASSERT_TRUE(wait_for([](const LaserReading& r) { return r.ok(); }, kHangS))
      << laser.latest().error.to_string();
  EXPECT_NEAR(laser.latest().distance_m, 7.5, 0.5e-3);
  const DriverStatus st = laser.status();
  EXPECT_GE(st.reconnects, 1u);
  EXPECT_TRUE(st.connected);
  laser.stop();
}

}  // namespace
}  // namespace cdpr::modbus
