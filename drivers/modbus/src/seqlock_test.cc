// The laser reading as it travels from the polling thread to the RT loop (the lock itself is
// tested in core/seqlock_test.cc).
#include "cdpr/core/seqlock.hpp"

#include <gtest/gtest.h>

#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::modbus {
namespace {

TEST(SeqLock, CarriesALaserReadingWithItsMessage) {
  SeqLock<LaserReading> s;
  EXPECT_EQ(s.load().status, ReadingStatus::kNone);
  LaserReading r;
  r.status = ReadingStatus::kTimeout;
  r.sequence = 42;
  r.error = Status(ErrorCode::kTimeout, "RTU /dev/ttyX slave 3: no answer");
  s.store(r);
  const LaserReading back = s.load();
  EXPECT_EQ(back.sequence, 42u);
  EXPECT_EQ(back.status, ReadingStatus::kTimeout);
  EXPECT_EQ(back.error.message(), "RTU /dev/ttyX slave 3: no answer");
}

}  // namespace
}  // namespace cdpr::modbus
