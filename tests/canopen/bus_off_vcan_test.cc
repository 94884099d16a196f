// Bus-off recovery through rtnetlink on a kernel virtual CAN bus (issue 14, item 13), as far as
// vcan allows: vcan has no controller, so it never goes bus-off by itself and the kernel refuses
// a controller restart (EOPNOTSUPP); a bus-off error frame is injected instead, and the recovery
// falls back to taking the interface down and up, as CanLink::recover() does wherever a restart
// is refused. Runs through tests/vcan/vcan-run (native vcan or user-mode-linux, root there).
#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>

#include "cdpr/can/can_link.hpp"
#include "cdpr/can/socketcan_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/master.hpp"
#include "cdpr/canopen/slave/slave.hpp"

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

Timestamp mono_now() {
  return std::chrono::duration_cast<Timestamp>(Clock::now().time_since_epoch());
}

std::unique_ptr<can::SocketCanBus> open_bus() {
  auto b = can::SocketCanBus::open("vcan0");
  EXPECT_TRUE(b.ok()) << b.status().to_string();
  return b.ok() ? std::move(*b) : nullptr;
}

bool receive_id(can::CanBus& bus, std::uint32_t id, std::chrono::milliseconds within) {
  const auto end = Clock::now() + within;
  can::Frame f;
  while (Clock::now() < end) {
    if (bus.receive(f, 10ms).ok() && !f.error && f.id == id) return true;
  }
  return false;
}

TEST(CanLinkOnVcan, QueryRefusedRestartAndDownUp) {
  std::printf("vcan path: %s\n",
              std::getenv("CDPR_VCAN_PATH") ? std::getenv("CDPR_VCAN_PATH") : "?");
  auto link = can::CanLink::open("vcan0");
  ASSERT_TRUE(link.ok()) << link.status().to_string();
  can::LinkInfo info;
  ASSERT_TRUE((*link)->query(info).ok());
  EXPECT_STREQ(info.kind.data(), "vcan");
  EXPECT_FALSE(info.controller);
  EXPECT_TRUE(info.up);
  // vcan has no controller to restart: the kernel refuses, the message names the interface.
  const Status r = (*link)->restart();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.message().rfind("vcan0: ", 0), 0u) << r.message();
  std::printf("restart on vcan0: %s\n", r.to_string().c_str());

  auto a = open_bus();
  auto b = open_bus();
  ASSERT_TRUE(a && b);
  can::Frame f;
  f.id = 0x123;
  f.dlc = 1;
  ASSERT_TRUE((*link)->set_up(false).ok());
  ASSERT_TRUE((*link)->query(info).ok());
  EXPECT_FALSE(info.up);
  EXPECT_FALSE(a->send(f).ok()) << "sent on a down interface";
  ASSERT_TRUE((*link)->set_up(true).ok());
  // The sockets stay bound across down/up (each reports ENETDOWN once).
  bool sent = false;
  for (int i = 0; i < 50 && !sent; ++i) {
    sent = a->send(f).ok();
    if (!sent) std::this_thread::sleep_for(10ms);
  }
  ASSERT_TRUE(sent);
  EXPECT_TRUE(receive_id(*b, 0x123, 10000ms));

  // The recovery policy: restart refused, so down and up.
  const can::RecoveryOutcome o = (*link)->recover();
  EXPECT_EQ(o.action, can::RecoveryOutcome::Action::kLinkCycled) << can::to_string(o.action);
  EXPECT_NE(o.restart_error, 0);
  ASSERT_TRUE((*link)->query(info).ok());
  EXPECT_TRUE(info.up);
}

// The master sees a bus-off error frame, stays silent for bus_off_recovery_ms, then recovers the
// link through netlink and transmits again; a node on the same vcan sees SYNC stop and resume.
TEST(BusOffOnVcan, MasterRecoversTheLinkAndResumes) {
  auto config = parse_config(
      "master:\n"
      "  interface: vcan0\n"
      "  sync_period_ms: 20\n"
      "  heartbeat_ms: 50\n"
      "  boot_timeout_ms: 20000\n"
      "  sdo_timeout_ms: 2000\n"
      "  bus_off_recovery_ms: 300\n"
      "nodes:\n"
      "  - {id: 1, name: node1, heartbeat_ms: 100, heartbeat_timeout_ms: 5000}\n",
      "bus-off.yaml");
  ASSERT_TRUE(config.ok()) << config.status().to_string();
  auto master_bus = open_bus();
  auto node_bus = open_bus();
  auto injector = open_bus();
  ASSERT_TRUE(master_bus && node_bus && injector);
  // The master and the node run on a virtual clock, 1 ms per step, so that the figures below
  // (SYNCs per period, the recovery wait) hold however slowly a loaded host or user-mode-linux
  // runs; the frames, the error frame and the link recovery go through the kernel for real.
  Timestamp now = mono_now();
  slave::SlaveNode node(*node_bus, 1);
  node.power_on(now);
  MasterHooks hooks;
  hooks.now = [&] { return now; };
  hooks.idle = [&] {
    now += 1ms;
    node.step(now);
  };
  hooks.receive_timeout = 1ms;
  auto m = Master::create(*master_bus, *config, hooks);
  ASSERT_TRUE(m.ok()) << m.status().to_string();
  Master& master = **m;
  Status s = master.boot();
  ASSERT_TRUE(s.ok()) << s.to_string();
  s = master.enable_link_restart();
  ASSERT_TRUE(s.ok()) << s.to_string();

  auto run = [&](std::chrono::milliseconds d) {
    const Timestamp end = now + d;
    Timestamp next = now;
    for (; now < end; now += 1ms) {
      if (now >= next) {
        master.cycle(now);
        next += 20ms;
      }
      node.step(now);
    }
  };
  run(300ms);
  const auto before = node.syncs();
  EXPECT_GE(before, 5u);

  can::Frame bus_off;
  bus_off.error = true;
  bus_off.dlc = 8;
  bus_off.error_class = can::error_class::kBusOff;
  ASSERT_TRUE(injector->send(bus_off).ok());
  run(150ms);
  EXPECT_EQ(master.bus().state(), BusState::kBusOff);
  const auto during = node.syncs();
  EXPECT_LE(during - before, 2u) << "the master kept sending SYNC while bus-off";
  run(300ms);
  run(300ms);
  EXPECT_EQ(master.stats().link_restarts, 1u);
  EXPECT_EQ(master.stats().link_restart_failures, 0u);
  EXPECT_EQ(master.bus().recoveries(), 1u);
  EXPECT_GE(node.syncs() - during, 5u) << "SYNC did not resume after the recovery";
  bool restarted = false;
  Event e;
  while (master.events().pop(e)) {
    if (e.type == EventType::kLinkRestarted) {
      restarted = true;
      EXPECT_EQ(e.value, static_cast<std::uint32_t>(can::RecoveryOutcome::Action::kLinkCycled));
    }
  }
  EXPECT_TRUE(restarted);
  EXPECT_EQ(node.nmt_state(), NmtState::kOperational);
}

}  // namespace
}  // namespace cdpr::canopen
