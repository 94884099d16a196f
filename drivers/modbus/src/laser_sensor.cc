#include "cdpr/modbus/laser_sensor.hpp"

#include <time.h>

#include <chrono>
#include <cmath>
#include <type_traits>

#include "cdpr/modbus/robust_stats.hpp"

namespace cdpr::modbus {

static_assert(std::is_trivially_copyable_v<LaserReading>, "LaserReading goes through a SeqLock");

namespace {

// After this many failed readings in a row a TCP connection is re-opened (a stale connection
// only times out; a fresh one recovers a restarted server or gateway).
constexpr int kTcpReconnectAfterFailures = 3;

void sleep_s(double s) {
  if (s <= 0.0) return;
  std::this_thread::sleep_for(std::chrono::nanoseconds(static_cast<std::int64_t>(s * 1e9)));
}

// Counts a caller of the link for its lifetime (LaserSensor::callers_).
class CallerScope {
 public:
  explicit CallerScope(std::atomic<int>& n) : n_(n) { n_.fetch_add(1, std::memory_order_acq_rel); }
  ~CallerScope() { n_.fetch_sub(1, std::memory_order_acq_rel); }
  CallerScope(const CallerScope&) = delete;
  CallerScope& operator=(const CallerScope&) = delete;

 private:
  std::atomic<int>& n_;
};

}  // namespace

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

Status LaserConfig::validate() const {
  if (Status s = link.validate(); !s.ok()) return with_context("laser '" + name + "': ", s);
  if (Status s = map.validate(); !s.ok()) return with_context("laser '" + name + "': ", s);
  if (!(poll_rate_hz >= 0.1 && poll_rate_hz <= 1000.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "laser '%s': poll_rate %g Hz is outside 0.1..1000", name.c_str(),
                         poll_rate_hz);
  }
  return Status::success();
}

LaserSensor::LaserSensor(LaserConfig config)
    : config_(std::move(config)), link_(config_.link), block_(125, 0) {}

LaserSensor::~LaserSensor() {
  stop();
}

Status LaserSensor::start() {
  CDPR_RETURN_IF_ERROR(config_.validate());
  if (thread_.joinable()) return Status::success();
  {
    std::lock_guard<std::mutex> lk(stop_mutex_);
    stop_requested_ = false;
  }
  thread_ = std::thread([this] { poll_loop(); });
  return Status::success();
}

void LaserSensor::stop() {
  {
    std::lock_guard<std::mutex> lk(stop_mutex_);
    stop_requested_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void LaserSensor::poll_loop() {
  const auto period =
      std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / config_.poll_rate_hz));
  auto next = std::chrono::steady_clock::now();
  for (;;) {
    if (callers_.load(std::memory_order_acquire) == 0) {
      std::lock_guard<std::mutex> lk(bus_mutex_);
      latest_.store(take_reading());
    }
    next += period;
    const auto now = std::chrono::steady_clock::now();
    if (next < now) next = now;  // overran: skip the missed slots instead of bursting
    std::unique_lock<std::mutex> lk(stop_mutex_);
    if (stop_cv_.wait_until(lk, next, [this] { return stop_requested_; })) break;
  }
}

LaserReading LaserSensor::read_once() {
  const CallerScope caller(callers_);
  std::lock_guard<std::mutex> lk(bus_mutex_);
  LaserReading r = take_reading();
  latest_.store(r);
  return r;
}

LaserReading LaserSensor::take_reading() {
  const RegisterMap& map = config_.map;
  LaserReading r;
  r.sequence = ++sequence_;
  const std::int64_t t0 = monotonic_ns();
  bool link_failed_to_open = false;
  auto fail = [&](const Status& s) {
    const std::int64_t t1 = monotonic_ns();
    r.status =
        s.code() == ErrorCode::kTimeout ? ReadingStatus::kTimeout : ReadingStatus::kCommError;
    r.error = s;
    r.stamp_ns = t0 + (t1 - t0) / 2;
    r.latency_ns = t1 - t0;
    ++consecutive_failures_;
    if (!link_.connected() && s.code() == ErrorCode::kIoError && !link_failed_to_open) {
      next_connect_ns_ = 0;  // the link closed itself after an I/O error: reconnect at once
    }
    const bool tcp = std::holds_alternative<TcpSettings>(config_.link.transport);
    if (tcp && consecutive_failures_ >= kTcpReconnectAfterFailures && link_.connected()) {
      link_.close();
      next_connect_ns_ = 0;
    }
    return r;
  };

  if (Status s = config_.map.validate(); !s.ok()) return fail(s);
  if (!link_.connected()) {
    if (t0 < next_connect_ns_) {
      Status s = Status::error(
          ErrorCode::kUnavailable, "%s: not connected, next attempt in %.0f ms",
          link_.describe().c_str(), static_cast<double>(next_connect_ns_ - t0) * 1e-6);
      if (!last_connect_error_.ok()) {
        s = with_context("not connected: ", last_connect_error_);
      }
      return fail(s);
    }
    Status c = link_.connect();
    if (!c.ok()) {
      link_failed_to_open = true;
      last_connect_error_ = c;
      next_connect_ns_ =
          monotonic_ns() + static_cast<std::int64_t>(config_.link.reconnect_delay_s * 1e9);
      return fail(c);
    }
    if (sequence_ > 1) ++reconnects_;
    last_connect_error_ = Status::success();
  }

  if (map.trigger) {
    Status s = link_.write_register(map.pdu(map.trigger->address), map.trigger->value);
    if (!s.ok()) return fail(with_context("laser '" + config_.name + "' trigger: ", s));
    sleep_s(map.trigger->settle_s);
  }
  const std::uint16_t count = map.block_count();
  std::span<std::uint16_t> block(block_.data(), count);
  Status s = link_.read_registers(map.table, map.pdu(map.block_start()), block);
  if (!s.ok()) return fail(with_context("laser '" + config_.name + "': ", s));
  std::optional<std::uint16_t> quality;
  if (map.quality && !map.quality_in_block()) {
    std::uint16_t q = 0;
    s = link_.read_registers(map.table, map.pdu(map.quality->address), {&q, 1});
    if (!s.ok()) return fail(with_context("laser '" + config_.name + "' quality: ", s));
    quality = q;
  }
  const std::int64_t t1 = monotonic_ns();
  consecutive_failures_ = 0;

  const Interpretation in = interpret(map, block, quality);
  r.status = in.status;
  r.distance_m = in.distance_m;
  r.raw = in.raw;
  r.stamp_ns = t0 + (t1 - t0) / 2;
  r.latency_ns = t1 - t0;
  if (in.quality) {
    r.quality = *in.quality;
    r.has_quality = true;
  }
  r.error = in.detail;
  return r;
}

Result<Measurement> LaserSensor::measure(int n, const MeasureOptions& options) {
  if (n < 1 || n > 100000) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "laser '%s': measure(%d): n must be 1..100000", config_.name.c_str(), n);
  }
  CDPR_RETURN_IF_ERROR(config_.validate());
  const double interval =
      options.interval_s >= 0.0 ? options.interval_s : 1.0 / config_.poll_rate_hz;
  const double min_sigma =
      options.min_sigma_m >= 0.0 ? options.min_sigma_m : config_.map.resolution_m();
  const int min_valid = options.min_valid > 0 ? options.min_valid : (n + 1) / 2;

  std::vector<double> values;
  values.reserve(static_cast<std::size_t>(n));
  Measurement m;
  const CallerScope caller(callers_);  // the polling thread waits for the whole series
  for (int i = 0; i < n; ++i) {
    if (i > 0) sleep_s(interval);
    const LaserReading r = read_once();
    if (r.ok()) {
      values.push_back(r.distance_m);
    } else {
      ++m.failed;
      m.last_failure = r.error;
      // The readings left cannot make `min_valid` any more: a silent laser fails the pose after
      // n - min_valid + 1 tries, not n.
      if (n - m.failed < min_valid) break;
    }
  }
  const RobustMean rm = robust_mean(values, options.reject_k, min_sigma);
  m.mean_m = rm.mean;
  m.stddev_m = rm.stddev;
  m.median_m = rm.median;
  m.used = rm.used;
  m.rejected = rm.rejected;
  if (m.used < min_valid) {
    Status s = Status::error(ErrorCode::kUnavailable,
                             "laser '%s': measure(%d): %d readings usable, %d needed (%d failed, "
                             "%d outliers); last problem: ",
                             config_.name.c_str(), n, m.used, min_valid, m.failed, m.rejected);
    const std::string last = m.last_failure.ok() ? std::string("none") : m.last_failure.to_string();
    return Status(ErrorCode::kUnavailable, std::string(s.message()) + last);
  }
  return m;
}

DriverStatus LaserSensor::status() const {
  DriverStatus d;
  d.running = thread_.joinable();
  d.latest = latest_.load();
  std::lock_guard<std::mutex> lk(bus_mutex_);
  d.connected = link_.connected();
  d.link = link_.describe();
  d.warnings = link_.warnings();
  d.counters = link_.counters();
  d.reconnects = reconnects_;
  d.last_connect_error = last_connect_error_;
  return d;
}

}  // namespace cdpr::modbus
