#include "cdpr/core/clock.hpp"

#include <gtest/gtest.h>

#include <chrono>

namespace cdpr {
namespace {

using std::chrono::milliseconds;
using std::chrono::nanoseconds;

TEST(ManualClock, StandsStillUntilTheTestMovesIt) {
  ManualClock clock(milliseconds(5));
  const Clock& c = clock;
  EXPECT_FALSE(c.real_time());
  EXPECT_EQ(c.now(), milliseconds(5));
  EXPECT_EQ(c.now(), milliseconds(5));
  clock.advance(milliseconds(3));
  EXPECT_EQ(c.now(), milliseconds(8));
  clock.set(nanoseconds(42));
  EXPECT_EQ(c.now(), nanoseconds(42));
}

TEST(SteadyClock, RunsOnItsOwnAndNeverGoesBack) {
  SteadyClock clock;
  const Clock& c = clock;
  EXPECT_TRUE(c.real_time());
  const nanoseconds a = c.now();
  const nanoseconds b = c.now();
  EXPECT_GE(b, a);
  // The same base as std::chrono::steady_clock.
  const auto s = std::chrono::steady_clock::now().time_since_epoch();
  EXPECT_LE(b, s);
}

}  // namespace
}  // namespace cdpr
