#include "cdpr/canopen/bus_supervisor.hpp"

#include <gtest/gtest.h>

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;
namespace ec = can::error_class;

can::Frame error_frame(std::uint32_t cls, std::uint8_t ctrl = 0) {
  can::Frame f;
  f.error = true;
  f.error_class = cls;
  f.dlc = 8;
  f.data[1] = ctrl;
  return f;
}

TEST(BusSupervisor, ErrorPassiveBusOffAndTimedRecovery) {
  BusSupervisor b(BusRecoveryPolicy{200ms});
  Events ev;
  int restarts = 0;
  b.set_restart_hook([](void* c) { ++*static_cast<int*>(c); }, &restarts);
  b.on_error_frame(error_frame(ec::kController, ec::kCtrlTxWarning), Timestamp{0}, ev);
  EXPECT_EQ(b.state(), BusState::kWarning);
  b.on_error_frame(error_frame(ec::kController | ec::kCounters, ec::kCtrlTxPassive), Timestamp{0},
                   ev);
  EXPECT_EQ(b.state(), BusState::kErrorPassive);
  EXPECT_EQ(b.error_passive_count(), 1u);
  b.on_error_frame(error_frame(ec::kBusOff), Timestamp{1s}, ev);
  EXPECT_EQ(b.state(), BusState::kBusOff);
  EXPECT_FALSE(b.may_transmit(Timestamp{1s + 199ms}, ev));
  EXPECT_TRUE(b.may_transmit(Timestamp{1s + 200ms}, ev));
  EXPECT_EQ(b.state(), BusState::kErrorActive);
  EXPECT_EQ(restarts, 1);
  EXPECT_EQ(b.bus_off_count(), 1u);
  EXPECT_EQ(b.recoveries(), 1u);
  // A controller that restarts by itself ends bus-off at once.
  b.on_error_frame(error_frame(ec::kBusOff), Timestamp{2s}, ev);
  b.on_error_frame(error_frame(ec::kRestarted), Timestamp{2s + 10ms}, ev);
  EXPECT_TRUE(b.may_transmit(Timestamp{2s + 10ms}, ev));
  EXPECT_EQ(b.bus_off_count(), 2u);
  EXPECT_EQ(b.recoveries(), 2u);
  std::vector<EventType> types;
  Event e;
  while (ev.pop(e)) types.push_back(e.type);
  EXPECT_EQ(types, (std::vector<EventType>{EventType::kBusErrorWarning, EventType::kBusErrorPassive,
                                           EventType::kBusOff, EventType::kBusRecovered,
                                           EventType::kBusOff, EventType::kBusRecovered}));
}

TEST(BusSupervisor, ReportsReceiveOverflowOncePerChange) {
  BusSupervisor b;
  Events ev;
  can::BusStats s;
  s.rx_dropped = 5;
  b.on_stats(s, Timestamp{0}, ev);
  b.on_stats(s, Timestamp{0}, ev);
  ASSERT_EQ(ev.size(), 1u);
  Event e;
  ev.pop(e);
  EXPECT_EQ(e.value, 5u);
  EXPECT_EQ(b.rx_dropped(), 5u);
}

TEST(BusLoad, MatchesTheWorstCaseBitCount) {
  // 8 drives with 6-byte RPDO and TPDO, two 8-byte force TPDOs, SYNC without counter.
  std::vector<PeriodicFrame> frames{{0, 1}, {6, 16}, {8, 2}};
  const BusLoad l = compute_bus_load(frames, 4ms);
  // 55 + 16 * 115 + 2 * 135 bits (47 + 8n + floor((33 + 8n) / 4))
  EXPECT_DOUBLE_EQ(l.bits_per_cycle, 55 + 16 * 115 + 2 * 135);
  EXPECT_NEAR(l.load, 2165e-6 / 4e-3, 1e-12);
  EXPECT_FALSE(l.warning);
  EXPECT_TRUE(compute_bus_load(frames, 3ms).warning);  // 72 %
}

}  // namespace
}  // namespace cdpr::canopen
