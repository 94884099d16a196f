// The laser distance sensor on the platform, read over Modbus (RTU or TCP).
//
//   auto cfg = load_laser_config("config/laser.yaml");          // link + register map + rate
//   LaserSensor laser(std::move(*cfg));
//   laser.start();                                              // polls in its own thread
//   LaserReading r = laser.latest();                            // RT loop: lock-free, no alloc
//   Result<Measurement> m = laser.measure(20);                  // calibration: robust mean
//
// Readings carry a CLOCK_MONOTONIC time stamp and a status (ok, no target, out of range, sensor
// error, timeout, communication error with the message). The driver never logs; non-fatal
// problems (e.g. RS-485 mode unavailable) are in status().warnings.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <limits>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "cdpr/core/seqlock.hpp"
#include "cdpr/modbus/modbus_link.hpp"
#include "cdpr/modbus/register_map.hpp"
#include "cdpr/status.hpp"

namespace cdpr::modbus {

struct LaserConfig {
  std::string name = "laser";
  LinkConfig link;
  RegisterMap map;
  double poll_rate_hz = 20.0;  // polling thread rate, 0.1..1000 Hz

  Status validate() const;
};

// Reads a laser configuration (link settings, poll rate and the register map, given inline as
// `register_map: {...}` or as a file path relative to `base_dir`). Errors name file, line, field.
Result<LaserConfig> parse_laser_config(std::string_view yaml_text, std::string_view file,
                                       std::string_view base_dir);
Result<LaserConfig> load_laser_config(const std::string& path);

struct LaserReading {
  ReadingStatus status = ReadingStatus::kNone;
  double distance_m = std::numeric_limits<double>::quiet_NaN();
  double raw = std::numeric_limits<double>::quiet_NaN();
  std::int64_t stamp_ns = 0;    // CLOCK_MONOTONIC, midpoint between request and answer
  std::int64_t latency_ns = 0;  // request sent to answer received (all requests of the reading)
  std::uint64_t sequence = 0;   // 1, 2, 3, ... for each reading taken (0: none yet)
  std::uint16_t quality = 0;    // quality register, when the map has one
  bool has_quality = false;
  Status error;  // why status is not kOk (names device/host, slave, register, reason)

  bool ok() const { return status == ReadingStatus::kOk; }
};

struct MeasureOptions {
  double reject_k = 3.5;      // keep |x - median| <= k * sigma
  double min_sigma_m = -1.0;  // floor of sigma; < 0: the map's resolution (one raw unit)
  double interval_s = -1.0;   // between readings; < 0: one poll period
  int min_valid = 0;          // readings needed after rejection; 0: half of n, rounded up
};

struct Measurement {
  double mean_m = 0.0;
  double stddev_m = 0.0;  // of the readings used
  double median_m = 0.0;
  int used = 0;
  int rejected = 0;  // valid readings rejected as outliers
  int failed = 0;    // readings that were not ok (timeout, no target, ...)
  Status last_failure;
};

struct DriverStatus {
  bool running = false;
  bool connected = false;
  std::string link;  // "RTU /dev/ttyUSB0 slave 1"
  std::vector<std::string> warnings;
  LinkCounters counters;
  std::uint64_t reconnects = 0;
  Status last_connect_error;
  LaserReading latest;
};

class LaserSensor {
 public:
  explicit LaserSensor(LaserConfig config);
  ~LaserSensor();
  LaserSensor(const LaserSensor&) = delete;
  LaserSensor& operator=(const LaserSensor&) = delete;

  // Starts the polling thread. Fails only on a bad configuration: an absent sensor shows up as
  // readings with an error, and the thread reconnects after reconnect_delay.
  Status start();
  // Stops and joins the polling thread (bounded: one reading at most).
  void stop();
  bool running() const { return thread_.joinable(); }

  // The newest reading. Lock-free and allocation-free: safe in the RT loop.
  LaserReading latest() const noexcept { return latest_.load(); }
  // Takes one reading now (connecting first if needed) and publishes it.
  LaserReading read_once();
  // Takes n readings and averages them with median/MAD outlier rejection. Fails (with the last
  // problem) when fewer than options.min_valid readings remain; stops reading as soon as the
  // failed ones leave fewer than min_valid to come (a silent laser costs n - min_valid + 1 tries).
  Result<Measurement> measure(int n, const MeasureOptions& options = {});

  DriverStatus status() const;
  const LaserConfig& config() const { return config_; }

 private:
  LaserReading take_reading();  // caller holds bus_mutex_
  void poll_loop();

  LaserConfig config_;
  mutable std::mutex bus_mutex_;  // the link: polling thread and read_once/measure
  // read_once/measure calls in progress: the polling thread stands aside while any is (a mutex
  // is not fair: a poll re-locking at once could starve a measurement for many readings).
  std::atomic<int> callers_{0};
  ModbusLink link_;
  std::int64_t next_connect_ns_ = 0;
  int consecutive_failures_ = 0;
  std::uint64_t sequence_ = 0;
  std::uint64_t reconnects_ = 0;
  Status last_connect_error_;
  std::vector<std::uint16_t> block_;

  SeqLock<LaserReading> latest_;

  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool stop_requested_ = false;
  std::thread thread_;
};

// CLOCK_MONOTONIC now, in nanoseconds.
std::int64_t monotonic_ns();

}  // namespace cdpr::modbus
