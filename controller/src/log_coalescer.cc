#include "cdpr/controller/log_coalescer.hpp"

#include <cstdio>

namespace cdpr::controller {

namespace {

std::string seconds(LogCoalescer::Time d) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f s", std::chrono::duration<double>(d).count());
  return b;
}

}  // namespace

std::optional<std::string> LogCoalescer::report(const std::string& key, const std::string& message,
                                                Time now) {
  auto it = conditions_.find(key);
  if (it == conditions_.end() || now - it->second.last > quiet_) {
    Condition& c = conditions_[key];
    c = Condition{message, now, now, now, 1};
    return message;
  }
  Condition& c = it->second;
  ++c.count;
  c.last = now;
  c.message = message;
  if (now - c.reminded < remind_) return std::nullopt;
  c.reminded = now;
  return message + " (still: " + std::to_string(c.count) + " times in " + seconds(now - c.first) +
         ")";
}

std::vector<std::string> LogCoalescer::expire(Time now) {
  std::vector<std::string> out;
  for (auto it = conditions_.begin(); it != conditions_.end();) {
    const Condition& c = it->second;
    if (now - c.last <= quiet_) {
      ++it;
      continue;
    }
    if (c.count > 1) {
      out.push_back(c.message + " ended: " + std::to_string(c.count) + " times in " +
                    seconds(c.last - c.first));
    }
    it = conditions_.erase(it);
  }
  return out;
}

}  // namespace cdpr::controller
