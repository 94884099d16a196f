// One log line per condition, with a count, while it lasts: a condition that repeats (a transmit
// failure at every SYNC while the bus is gone, an EMCY a babbling node repeats) is logged when it
// starts, then at most every `remind` with the count so far, and once when it ends (nothing for
// `quiet`) with the total ("... ended: 2500 times in 10.0 s"). The caller logs what it returns;
// the coalescer itself neither logs nor reads a clock (times come in). Not for the RT path (it
// allocates): the daemon's supervisor uses it for the RT loop's events.
#pragma once

#include <chrono>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace cdpr::controller {

class LogCoalescer {
 public:
  using Time = std::chrono::nanoseconds;  // any monotonic clock's time since its epoch
  explicit LogCoalescer(Time quiet = std::chrono::seconds(2),
                        Time remind = std::chrono::seconds(60))
      : quiet_(quiet), remind_(remind) {}

  // One occurrence of condition `key` (described by `message`) at `now`. Returns the line to log
  // now, if any: the start of the condition, or a reminder with the count.
  std::optional<std::string> report(const std::string& key, const std::string& message, Time now);
  // The conditions that ended (nothing reported for `quiet` before `now`): one line each, with
  // the count. Conditions that occurred once end silently (their start said it all).
  std::vector<std::string> expire(Time now);
  // Conditions currently lasting.
  std::size_t active() const { return conditions_.size(); }

 private:
  struct Condition {
    std::string message;
    Time first{0}, last{0}, reminded{0};
    std::uint64_t count = 0;
  };
  Time quiet_, remind_;
  std::map<std::string, Condition> conditions_;
};

}  // namespace cdpr::controller
