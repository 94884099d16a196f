// Unit tests of the in-process virtual CAN bus: delivery rules, clock, bounded queues, threads,
// bit-time model, error injection and the no-allocation promise of send()/receive().
#include "cdpr/can/virtual_bus.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <thread>
#include <vector>

#include "alloc_counter.hpp"

namespace cdpr::can {
namespace {

using std::chrono::milliseconds;
using std::chrono::nanoseconds;

Frame data_frame(std::uint32_t id, std::uint8_t dlc, std::uint8_t seed = 0) {
  Frame f;
  f.id = id;
  f.dlc = dlc;
  for (std::uint8_t i = 0; i < dlc; ++i) f.data[i] = static_cast<std::uint8_t>(seed + i);
  return f;
}

TEST(VirtualCanBus, DeliversToAllOtherEndpointsNotToSender) {
  ManualClock clock(milliseconds(5));
  VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  auto c = bus.endpoint("c");
  ASSERT_TRUE(a->send(data_frame(0x181, 3, 7)).ok());

  for (auto* ep : {b.get(), c.get()}) {
    Frame f;
    ASSERT_TRUE(ep->receive(f, nanoseconds(0)).ok()) << ep->name();
    EXPECT_EQ(f.id, 0x181u);
    EXPECT_EQ(f.dlc, 3);
    EXPECT_EQ(f.data[0], 7);
    EXPECT_EQ(f.data[2], 9);
    EXPECT_EQ(f.timestamp, milliseconds(5)) << "timestamp must come from the bus clock";
  }
  Frame f;
  Status s = a->receive(f, milliseconds(10));
  EXPECT_EQ(s.code(), ErrorCode::kTimeout) << "the sender must not receive its own frame";
  EXPECT_NE(s.message().find("a:"), std::string_view::npos) << s.to_string();
  EXPECT_EQ(a->stats().frames_sent, 1u);
  EXPECT_EQ(b->stats().frames_received, 1u);
  EXPECT_EQ(a->name(), "a");
}

TEST(VirtualCanBus, TimestampsFollowTheManualClock) {
  ManualClock clock;
  VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  ASSERT_TRUE(a->send(data_frame(1, 0)).ok());
  clock.advance(milliseconds(3));
  ASSERT_TRUE(a->send(data_frame(2, 0)).ok());
  Frame f1, f2;
  ASSERT_TRUE(b->receive(f1, nanoseconds(0)).ok());
  ASSERT_TRUE(b->receive(f2, nanoseconds(0)).ok());
  EXPECT_EQ(f2.timestamp - f1.timestamp, milliseconds(3));
}

TEST(VirtualCanBus, ManualClockTimeoutReturnsAtOnce) {
  ManualClock clock;
  VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  const auto t0 = std::chrono::steady_clock::now();
  Frame f;
  EXPECT_EQ(a->receive(f, std::chrono::seconds(10)).code(), ErrorCode::kTimeout);
  // Half the timeout: a call that waited would take all of it; one that did not, however loaded
  // the host, far less.
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(5));
}

TEST(VirtualCanBus, SteadyClockTimeoutWaits) {
  SteadyClock clock;
  VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  const auto t0 = std::chrono::steady_clock::now();
  Frame f;
  EXPECT_EQ(a->receive(f, milliseconds(30)).code(), ErrorCode::kTimeout);
  EXPECT_GE(std::chrono::steady_clock::now() - t0, milliseconds(30));
}

TEST(VirtualCanBus, FullQueueDropsAndCounts) {
  ManualClock clock;
  VirtualCanBus bus(clock, VirtualBusOptions{.queue_capacity = 4});
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  for (std::uint32_t i = 0; i < 10; ++i) ASSERT_TRUE(a->send(data_frame(i, 1)).ok());
  EXPECT_EQ(b->stats().rx_dropped, 6u);
  // The oldest frames are kept (a socket buffer drops new arrivals, not queued ones).
  for (std::uint32_t i = 0; i < 4; ++i) {
    Frame f;
    ASSERT_TRUE(b->receive(f, nanoseconds(0)).ok());
    EXPECT_EQ(f.id, i);
  }
  Frame f;
  EXPECT_EQ(b->receive(f, nanoseconds(0)).code(), ErrorCode::kTimeout);
}

TEST(VirtualCanBus, RtrAndBytesBeyondDlcAreNotTransported) {
  ManualClock clock;
  VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  Frame rtr = data_frame(0x700, 4, 0x55);
  rtr.rtr = true;
  Frame short_frame = data_frame(0x10, 2, 1);
  short_frame.data[5] = 0xEE;  // garbage beyond dlc
  ASSERT_TRUE(a->send(rtr).ok());
  ASSERT_TRUE(a->send(short_frame).ok());
  Frame f;
  ASSERT_TRUE(b->receive(f, nanoseconds(0)).ok());
  EXPECT_TRUE(f.rtr);
  EXPECT_EQ(f.dlc, 4);
  EXPECT_EQ(f.data, (std::array<std::uint8_t, 8>{}));
  ASSERT_TRUE(b->receive(f, nanoseconds(0)).ok());
  EXPECT_EQ(f.data[5], 0);
}

TEST(VirtualCanBus, InjectedErrorReachesEveryEndpoint) {
  ManualClock clock;
  VirtualCanBus bus(clock);
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  std::array<std::uint8_t, 8> data{};
  data[1] = error_class::kCtrlTxPassive;
  bus.inject_error(error_class::kController, data);
  bus.inject_error(error_class::kBusOff);
  for (auto* ep : {a.get(), b.get()}) {
    Frame f;
    ASSERT_TRUE(ep->receive(f, nanoseconds(0)).ok());
    EXPECT_TRUE(f.error);
    EXPECT_EQ(f.error_class, error_class::kController);
    EXPECT_EQ(f.data[1], error_class::kCtrlTxPassive);
    ASSERT_TRUE(ep->receive(f, nanoseconds(0)).ok());
    EXPECT_EQ(f.error_class, error_class::kBusOff);
    EXPECT_EQ(ep->stats().error_frames, 2u);
  }
}

TEST(VirtualCanBus, FrameBitsMatchTheClassicCanWorstCase) {
  // Textbook worst cases (Davis et al., "CAN schedulability analysis revisited"):
  // 8-byte standard frame 135 bits, 8-byte extended 160 bits, empty standard 55 bits.
  EXPECT_EQ(frame_bits(data_frame(0x123, 8)), 135u);
  Frame ext = data_frame(0x123, 8);
  ext.extended = true;
  EXPECT_EQ(frame_bits(ext), 160u);
  EXPECT_EQ(frame_bits(data_frame(0x123, 0)), 55u);
  Frame rtr = data_frame(0x123, 8);
  rtr.rtr = true;
  EXPECT_EQ(frame_bits(rtr), frame_bits(data_frame(0x123, 0))) << "an RTR frame carries no data";
}

TEST(VirtualCanBus, BusLoadOverAWindow) {
  ManualClock clock;
  VirtualCanBus bus(clock, VirtualBusOptions{.bit_timing = true, .bitrate = 1'000'000});
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  const LoadSample s0 = bus.load_sample();
  // 4 ms cycle, 10 cycles, each: 8 six-byte frames, like a small PDO exchange.
  for (int cycle = 0; cycle < 10; ++cycle) {
    for (int i = 0; i < 8; ++i) ASSERT_TRUE(a->send(data_frame(0x200 + i, 6)).ok());
    clock.advance(milliseconds(4));
  }
  const LoadSample s1 = bus.load_sample();
  const double bits = 80.0 * frame_bits(data_frame(0x200, 6));
  EXPECT_NEAR(bus_load(s0, s1), bits * 1e-6 / 0.040, 1e-9);
  EXPECT_GT(bus_load(s0, s1), 0.0);
  EXPECT_EQ(bus_load(s1, s1), 0.0) << "an empty window has no load";

  // Without the model the bus stays idle.
  VirtualCanBus plain(clock);
  auto c = plain.endpoint("c");
  const LoadSample p0 = plain.load_sample();
  ASSERT_TRUE(c->send(data_frame(1, 8)).ok());
  clock.advance(milliseconds(1));
  EXPECT_EQ(bus_load(p0, plain.load_sample()), 0.0);
}

TEST(VirtualCanBus, ThreadsExchangeEveryFrameInOrder) {
  SteadyClock clock;
  VirtualCanBus bus(clock, VirtualBusOptions{.queue_capacity = 64});
  auto tx = bus.endpoint("tx");
  auto rx = bus.endpoint("rx");
  constexpr std::uint32_t kFrames = 20000;
  std::atomic<bool> stop{false};
  std::thread sender([&] {
    std::uint32_t i = 0;
    while (i < kFrames && !stop) {
      // Back off when the receiver's queue is full and resend: a frame that was dropped is not
      // queued, so the receiver must see every number exactly once, in order.
      const auto before = rx->stats().rx_dropped;
      Frame f = data_frame(i & 0x7FF, 4);
      f.data[0] = static_cast<std::uint8_t>(i);
      f.data[1] = static_cast<std::uint8_t>(i >> 8);
      f.data[2] = static_cast<std::uint8_t>(i >> 16);
      ASSERT_TRUE(tx->send(f).ok());
      if (rx->stats().rx_dropped == before) {
        ++i;
      } else {
        std::this_thread::yield();
      }
    }
  });
  std::uint32_t expected = 0;
  while (expected < kFrames) {
    Frame f;
    Status s = rx->receive(f, milliseconds(2000));
    if (!s.ok()) {
      stop = true;
      ADD_FAILURE() << s.to_string() << " after " << expected << " frames";
      break;
    }
    const std::uint32_t n = f.data[0] | (f.data[1] << 8) | (f.data[2] << 16);
    ASSERT_EQ(n, expected) << "frames lost, duplicated or reordered";
    ++expected;
  }
  sender.join();
  EXPECT_EQ(expected, kFrames);
}

TEST(VirtualCanBus, EndpointsMayOutliveTheBusObject) {
  ManualClock clock;
  auto bus = std::make_unique<VirtualCanBus>(clock);
  auto a = bus->endpoint("a");
  auto b = bus->endpoint("b");
  bus.reset();
  ASSERT_TRUE(a->send(data_frame(5, 1)).ok());
  Frame f;
  EXPECT_TRUE(b->receive(f, nanoseconds(0)).ok());
}

TEST(VirtualCanBus, SendAndReceiveDoNotAllocate) {
  SteadyClock clock;
  VirtualCanBus bus(clock, VirtualBusOptions{.queue_capacity = 8, .bit_timing = true});
  auto a = bus.endpoint("a");
  auto b = bus.endpoint("b");
  Frame bad = data_frame(0x800, 1);  // 11-bit id out of range: the error path too
  Frame f;
  test::AllocationCounter count;
  for (int i = 0; i < 100; ++i) {  // more than the queue holds: the drop path too
    ASSERT_TRUE(a->send(data_frame(0x100, 8)).ok());
  }
  for (int i = 0; i < 8; ++i) ASSERT_TRUE(b->receive(f, milliseconds(10)).ok());
  EXPECT_EQ(b->receive(f, milliseconds(1)).code(), ErrorCode::kTimeout);
  EXPECT_EQ(b->receive(f, nanoseconds(0)).code(), ErrorCode::kTimeout);
  EXPECT_EQ(a->send(bad).code(), ErrorCode::kInvalidArgument);
  bus.inject_error(error_class::kBusOff);
  ASSERT_TRUE(b->receive(f, nanoseconds(0)).ok());
  (void)bus.load_sample();
  (void)a->stats();
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(b->stats().rx_dropped, 92u);
  // The counter itself works: a vector must be seen allocating.
  test::AllocationCounter sanity;
  std::vector<int> v(10);
  __asm__ __volatile__("" : : "g"(v.data()) : "memory");  // keep the compiler from eliding it
  EXPECT_GE(sanity.allocations(), 1u);
}

}  // namespace
}  // namespace cdpr::can
