// The CanBus contract, checked against every transport with the same cases. Built twice:
//   CDPR_CAN_CONFORMANCE_VIRTUAL   -> VirtualCanBus (unit test)
//   CDPR_CAN_CONFORMANCE_SOCKETCAN -> SocketCanBus on vcan0 (through tests/vcan/vcan-run)
#include <gtest/gtest.h>

#include <cstdlib>
#include <functional>
#include <memory>
#include <string>

#include "alloc_counter.hpp"
#include "cdpr/can/can_bus.hpp"
#include "cdpr/can/socketcan_bus.hpp"
#include "cdpr/can/virtual_bus.hpp"

namespace cdpr::can {
namespace {

using std::chrono::milliseconds;
using std::chrono::nanoseconds;

// Two endpoints on one bus, plus a way to put an error frame on that bus.
struct BusPair {
  std::shared_ptr<void> keep;  // owns the bus and clock of a virtual pair
  std::unique_ptr<CanBus> a;
  std::unique_ptr<CanBus> b;
  std::function<Status(std::uint32_t, const std::array<std::uint8_t, 8>&)> inject_error;
  bool waits = true;  // receive(timeout) really waits (false for a manual clock)
};

struct Transport {
  std::string name;
  std::function<BusPair()> make;
};

std::ostream& operator<<(std::ostream& os, const Transport& t) {
  return os << t.name;
}

class CanBusConformance : public ::testing::TestWithParam<Transport> {
 protected:
  void SetUp() override {
    pair_ = GetParam().make();
    ASSERT_TRUE(pair_.a && pair_.b) << "could not create the transport";
    drain(*pair_.a);
    drain(*pair_.b);
  }
  static void drain(CanBus& bus) {
    Frame f;
    while (bus.receive(f, nanoseconds(0)).ok()) {
    }
  }
  // Receive with a generous timeout where waiting is real.
  Status get(CanBus& bus, Frame& f) { return bus.receive(f, milliseconds(pair_.waits ? 2000 : 0)); }

  BusPair pair_;
};

Frame make(std::uint32_t id, std::uint8_t dlc, bool extended = false) {
  Frame f;
  f.id = id;
  f.dlc = dlc;
  f.extended = extended;
  for (std::uint8_t i = 0; i < dlc; ++i) f.data[i] = static_cast<std::uint8_t>(0xA0 + i * 3);
  return f;
}

void expect_same(const Frame& sent, const Frame& got) {
  EXPECT_EQ(got.id, sent.id);
  EXPECT_EQ(got.extended, sent.extended);
  EXPECT_EQ(got.rtr, sent.rtr);
  EXPECT_FALSE(got.error);
  EXPECT_EQ(got.dlc, sent.dlc);
  for (std::uint8_t i = 0; i < 8; ++i) {
    const std::uint8_t want = (!sent.rtr && i < sent.dlc) ? sent.data[i] : 0;
    EXPECT_EQ(got.data[i], want) << "byte " << int{i};
  }
}

TEST_P(CanBusConformance, StandardIdBothWays) {
  const Frame f1 = make(0x123, 4);
  ASSERT_TRUE(pair_.a->send(f1).ok());
  Frame got;
  ASSERT_TRUE(get(*pair_.b, got).ok());
  expect_same(f1, got);

  const Frame f2 = make(0x7FF, 2);  // highest 11-bit id
  ASSERT_TRUE(pair_.b->send(f2).ok());
  ASSERT_TRUE(get(*pair_.a, got).ok());
  expect_same(f2, got);
}

TEST_P(CanBusConformance, ExtendedId) {
  for (std::uint32_t id : {0x0u, 0x123u, 0x1ABCDEF0u, 0x1FFFFFFFu}) {
    const Frame f = make(id, 5, true);
    ASSERT_TRUE(pair_.a->send(f).ok());
    Frame got;
    ASSERT_TRUE(get(*pair_.b, got).ok()) << std::hex << id;
    expect_same(f, got);
  }
}

TEST_P(CanBusConformance, RemoteRequestCarriesDlcButNoData) {
  Frame f = make(0x701, 1);
  f.rtr = true;
  ASSERT_TRUE(pair_.a->send(f).ok());
  Frame got;
  ASSERT_TRUE(get(*pair_.b, got).ok());
  EXPECT_TRUE(got.rtr);
  expect_same(f, got);
}

TEST_P(CanBusConformance, ZeroLengthFrame) {
  const Frame f = make(0x080, 0);  // like a CANopen SYNC
  ASSERT_TRUE(pair_.a->send(f).ok());
  Frame got;
  ASSERT_TRUE(get(*pair_.b, got).ok());
  expect_same(f, got);
}

TEST_P(CanBusConformance, EightByteFrameAndOrder) {
  for (std::uint32_t i = 0; i < 50; ++i) {
    Frame f = make(0x200 + i, 8);
    f.data[7] = static_cast<std::uint8_t>(i);
    ASSERT_TRUE(pair_.a->send(f).ok());
  }
  for (std::uint32_t i = 0; i < 50; ++i) {
    Frame got;
    ASSERT_TRUE(get(*pair_.b, got).ok()) << "frame " << i;
    EXPECT_EQ(got.id, 0x200 + i);
    EXPECT_EQ(got.dlc, 8);
    EXPECT_EQ(got.data[7], i);
    EXPECT_EQ(got.data[0], 0xA0);
  }
  EXPECT_EQ(pair_.a->stats().frames_sent, 50u);
  EXPECT_GE(pair_.b->stats().frames_received, 50u);
  EXPECT_EQ(pair_.b->stats().rx_dropped, 0u);
}

TEST_P(CanBusConformance, SenderDoesNotReceiveItsOwnFrame) {
  ASSERT_TRUE(pair_.a->send(make(0x10, 1)).ok());
  Frame got;
  ASSERT_TRUE(get(*pair_.b, got).ok());
  EXPECT_EQ(pair_.a->receive(got, milliseconds(20)).code(), ErrorCode::kTimeout);
}

TEST_P(CanBusConformance, TimeoutWhenNothingComes) {
  Frame got;
  Status s = pair_.b->receive(got, nanoseconds(0));
  EXPECT_EQ(s.code(), ErrorCode::kTimeout);
  EXPECT_NE(s.message().find(pair_.b->name()), std::string_view::npos) << s.to_string();

  // A bus on the steady clock waits the timeout out; one on a manual clock returns at once, so it
  // is given a timeout far longer than a loaded host can stall a call that does not wait.
  const milliseconds timeout(pair_.waits ? 50 : 20000);
  const auto t0 = std::chrono::steady_clock::now();
  s = pair_.b->receive(got, timeout);
  const auto waited = std::chrono::steady_clock::now() - t0;
  EXPECT_EQ(s.code(), ErrorCode::kTimeout);
  if (pair_.waits) {
    EXPECT_GE(waited, timeout);
  }
  EXPECT_LT(waited, milliseconds(5000)) << (pair_.waits ? "must not hang" : "must not wait");
}

TEST_P(CanBusConformance, InvalidFramesAreRefusedWithTheInterfaceName) {
  Frame f = make(0x100, 8);
  f.dlc = 9;
  Status s = pair_.a->send(f);
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(s.message().find(pair_.a->name()), std::string_view::npos) << s.to_string();
  EXPECT_NE(s.message().find("dlc"), std::string_view::npos) << s.to_string();

  EXPECT_EQ(pair_.a->send(make(0x800, 1)).code(), ErrorCode::kInvalidArgument);
  EXPECT_EQ(pair_.a->send(make(0x20000000, 1, true)).code(), ErrorCode::kInvalidArgument);
  EXPECT_EQ(pair_.a->stats().frames_sent, 0u);
  Frame got;
  EXPECT_EQ(pair_.b->receive(got, milliseconds(20)).code(), ErrorCode::kTimeout)
      << "a refused frame must not reach the bus";
}

TEST_P(CanBusConformance, ErrorFrameIsReceivedWithItsClass) {
  std::array<std::uint8_t, 8> data{};
  data[1] = error_class::kCtrlRxPassive | error_class::kCtrlTxPassive;
  data[6] = 128;  // TX error counter
  data[7] = 130;  // RX error counter
  ASSERT_TRUE(pair_.inject_error(error_class::kController | error_class::kCounters, data).ok());
  Frame got;
  ASSERT_TRUE(get(*pair_.b, got).ok());
  EXPECT_TRUE(got.error);
  EXPECT_EQ(got.error_class, error_class::kController | error_class::kCounters);
  EXPECT_EQ(got.dlc, 8);
  EXPECT_EQ(got.data[1], data[1]);
  EXPECT_EQ(got.data[6], 128);
  EXPECT_EQ(got.data[7], 130);
  EXPECT_EQ(pair_.b->stats().error_frames, 1u);

  ASSERT_TRUE(pair_.inject_error(error_class::kBusOff, {}).ok());
  ASSERT_TRUE(get(*pair_.b, got).ok());
  EXPECT_TRUE(got.error);
  EXPECT_EQ(got.error_class, error_class::kBusOff);
}

// The RT loop calls send() and receive() directly: neither may allocate, on any path.
TEST_P(CanBusConformance, SendAndReceiveDoNotAllocate) {
  Frame f = make(0x181, 8);
  Frame bad = make(0x181, 8);
  bad.dlc = 9;
  Frame got;
  test::AllocationCounter count;
  for (int i = 0; i < 20; ++i) {
    ASSERT_TRUE(pair_.a->send(f).ok());
    ASSERT_TRUE(get(*pair_.b, got).ok());
  }
  EXPECT_EQ(pair_.b->receive(got, milliseconds(1)).code(), ErrorCode::kTimeout);
  EXPECT_EQ(pair_.a->send(bad).code(), ErrorCode::kInvalidArgument);
  (void)pair_.b->stats();
  EXPECT_EQ(count.allocations(), 0u);
}

TEST_P(CanBusConformance, TimestampsAdvance) {
  ASSERT_TRUE(pair_.a->send(make(1, 1)).ok());
  ASSERT_TRUE(pair_.a->send(make(2, 1)).ok());
  Frame f1, f2;
  ASSERT_TRUE(get(*pair_.b, f1).ok());
  ASSERT_TRUE(get(*pair_.b, f2).ok());
  EXPECT_GE(f2.timestamp, f1.timestamp);
  if (pair_.waits) {
    // Monotonic base: close to steady_clock now.
    const auto now = std::chrono::steady_clock::now().time_since_epoch();
    EXPECT_LT(std::chrono::abs(now - f2.timestamp), std::chrono::seconds(5));
  }
}

#if defined(CDPR_CAN_CONFORMANCE_VIRTUAL)

BusPair virtual_pair(bool manual) {
  struct Owner {
    ManualClock manual_clock;
    SteadyClock steady_clock;
    std::unique_ptr<VirtualCanBus> bus;
  };
  auto owner = std::make_shared<Owner>();
  const Clock& clock = manual ? static_cast<const Clock&>(owner->manual_clock)
                              : static_cast<const Clock&>(owner->steady_clock);
  owner->bus = std::make_unique<VirtualCanBus>(clock);
  BusPair p;
  p.a = owner->bus->endpoint("a");
  p.b = owner->bus->endpoint("b");
  VirtualCanBus* bus = owner->bus.get();
  p.inject_error = [bus](std::uint32_t cls, const std::array<std::uint8_t, 8>& data) {
    bus->inject_error(cls, data);
    return Status::success();
  };
  p.waits = !manual;
  p.keep = owner;
  return p;
}

INSTANTIATE_TEST_SUITE_P(
    Virtual, CanBusConformance,
    ::testing::Values(Transport{"SteadyClock", [] { return virtual_pair(false); }},
                      Transport{"ManualClock", [] { return virtual_pair(true); }}),
    [](const auto& param_info) { return param_info.param.name; });

#elif defined(CDPR_CAN_CONFORMANCE_SOCKETCAN)

// Two sockets on vcan0 see each other's frames; a third one sends the error frames (vcan passes
// frames with CAN_ERR_FLAG through to sockets whose error filter matches).
BusPair socketcan_pair() {
  const char* env = std::getenv("CDPR_VCAN");
  const std::string ifname = env != nullptr ? env : "vcan0";
  BusPair p;
  auto a = SocketCanBus::open(ifname);
  auto b = SocketCanBus::open(ifname);
  auto c = SocketCanBus::open(ifname);
  if (!a || !b || !c) {
    ADD_FAILURE() << (!a ? a.status() : !b ? b.status() : c.status()).to_string();
    return p;
  }
  std::shared_ptr<CanBus> injector = std::move(*c);
  p.a = std::move(*a);
  p.b = std::move(*b);
  p.inject_error = [injector](std::uint32_t cls, const std::array<std::uint8_t, 8>& data) {
    Frame f;
    f.error = true;
    f.error_class = cls;
    f.dlc = 8;
    f.data = data;
    return injector->send(f);
  };
  p.keep = injector;
  return p;
}

INSTANTIATE_TEST_SUITE_P(SocketCan, CanBusConformance,
                         ::testing::Values(Transport{"vcan0", socketcan_pair}),
                         [](const auto& param_info) { return param_info.param.name; });

class PathPrinter : public ::testing::Environment {
 public:
  void SetUp() override {
    const char* path = std::getenv("CDPR_VCAN_PATH");
    std::printf("can_conformance_socketcan: kernel CAN path: %s\n",
                path != nullptr ? path : "unknown (not started by vcan-run)");
  }
};
const auto* const kPathPrinter = ::testing::AddGlobalTestEnvironment(new PathPrinter);

#else
#error "define CDPR_CAN_CONFORMANCE_VIRTUAL or CDPR_CAN_CONFORMANCE_SOCKETCAN"
#endif

}  // namespace
}  // namespace cdpr::can
