// LogCoalescer: a condition repeated at every cycle is one line when it starts and one with the
// count when it ends (issue 39: a 10 s bus loss wrote 16,136 "transmit failed" lines).
#include "cdpr/controller/log_coalescer.hpp"

#include <gtest/gtest.h>

namespace cdpr::controller {
namespace {

using namespace std::chrono_literals;

TEST(LogCoalescer, ARepeatedConditionIsOneLineWhenItStartsAndOneWithTheCountWhenItEnds) {
  LogCoalescer log(2s, 60s);
  std::vector<std::string> lines;
  LogCoalescer::Time t = 100s;
  for (int i = 0; i < 2500; ++i) {  // 10 s of failures at every 4 ms SYNC
    if (auto l = log.report("tx", "node 0: transmit failed", t)) lines.push_back(*l);
    for (const auto& e : log.expire(t)) lines.push_back(e);
    t += 4ms;
  }
  EXPECT_EQ(lines, (std::vector<std::string>{"node 0: transmit failed"}));
  EXPECT_EQ(log.active(), 1u);
  EXPECT_TRUE(log.expire(t + 1s).empty());  // not yet quiet for 2 s
  const auto ended = log.expire(t + 3s);
  ASSERT_EQ(ended.size(), 1u);
  EXPECT_EQ(ended[0], "node 0: transmit failed ended: 2500 times in 10.0 s");
  EXPECT_EQ(log.active(), 0u);
  // The same condition later is a new start.
  EXPECT_EQ(log.report("tx", "node 0: transmit failed", t + 10s), "node 0: transmit failed");
}

TEST(LogCoalescer, ALastingConditionIsRemindedWithItsCountAndConditionsAreKeptApart) {
  LogCoalescer log(2s, 60s);
  int lines = 0;
  std::string reminder;
  LogCoalescer::Time t = 0s;
  for (int i = 0; i <= 1300; ++i) {  // 130 s, 10 Hz
    if (auto l = log.report("a", "node 3: EMCY 0x8130", t)) {
      ++lines;
      if (lines == 2) reminder = *l;
    }
    t += 100ms;
  }
  EXPECT_EQ(lines, 3);  // start, after 60 s, after 120 s
  EXPECT_EQ(reminder, "node 3: EMCY 0x8130 (still: 601 times in 60.0 s)");
  EXPECT_TRUE(log.report("b", "node 4: heartbeat lost", t).has_value());
  EXPECT_EQ(log.active(), 2u);
  EXPECT_TRUE(log.expire(t + 5s).size() == 1u);  // "b" occurred once: it ends silently
  EXPECT_EQ(log.active(), 0u);
}

}  // namespace
}  // namespace cdpr::controller
