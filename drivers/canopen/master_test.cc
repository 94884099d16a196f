#include "cdpr/canopen/master.hpp"

#include <gtest/gtest.h>

#include "alloc_counter.hpp"
#include "cdpr/canopen/codes.hpp"
#include "testing/sim_network.hpp"

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;

class MasterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto c = load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    config = *c;
    for (NodeId id = 1; id <= 8; ++id) {
      drives[id] = &net.add<slave::Drive402>(id, 1000 * id + 17);  // arbitrary start positions
    }
    force = &net.add<slave::SlaveNode>(9);
    for (std::uint8_t ch = 1; ch <= 8; ++ch) {
      force->od().add({0x6401, ch}, DataType::kI16, 0, slave::Access::kRo);
    }
    net.power_on();
  }

  Status make_and_boot() {
    MasterHooks hooks;
    hooks.now = [this] { return net.now(); };
    hooks.idle = [this] { net.idle(); };
    hooks.receive_timeout = 0ns;
    auto m = Master::create(net.master_bus(), config, hooks);
    if (!m.ok()) return m.status();
    master = std::move(*m);
    return master->boot();
  }

  // Runs the RT loop for `d`: cycle at the SYNC period, slaves in between.
  void run(std::chrono::nanoseconds d) {
    const Timestamp end = net.now() + d;
    while (net.now() < end) {
      master->cycle(net.now());
      const Timestamp next = net.now() + config.sync_period;
      while (net.now() < next) net.idle();
    }
  }

  std::vector<EventType> drain(std::vector<Event>* out = nullptr) {
    std::vector<EventType> t;
    Event e;
    while (master->events().pop(e)) {
      t.push_back(e.type);
      if (out) out->push_back(e);
    }
    return t;
  }

  testing::SimNetwork net;
  MasterConfig config;
  std::array<slave::Drive402*, 9> drives{};
  slave::SlaveNode* force = nullptr;
  std::unique_ptr<Master> master;
};

TEST_F(MasterTest, BootsConfiguresAndStreamsWithoutJump) {
  ASSERT_TRUE(make_and_boot().ok());
  for (NodeId id = 1; id <= 8; ++id) {
    auto& od = drives[id]->od();
    EXPECT_EQ(drives[id]->nmt_state(), NmtState::kOperational);
    EXPECT_EQ(od.get({0x1600, 0}), 2);
    EXPECT_EQ(od.get({0x1600, 2}), 0x607A0020);
    EXPECT_EQ(od.get({0x1A00, 1}), 0x60410010);
    EXPECT_EQ(od.get({0x1400, 1}), 0x200 + id);  // enabled (bit 31 clear)
    EXPECT_EQ(od.get({0x6061, 0}), 8);           // CSP, confirmed through 0x6061
    EXPECT_EQ(od.get({0x60C2, 1}), 4);           // 4 ms = 4 * 10^-3 s
    EXPECT_EQ(od.get({0x60C2, 2}, true), -3);
    EXPECT_EQ(od.get({0x1016, 1}), (127u << 16) | 150u);
    EXPECT_EQ(od.get({0x6007, 0}, true), 3);
    EXPECT_EQ(od.get({0x1017, 0}), 50);
    EXPECT_EQ(master->nodes().state(id), NmtState::kOperational);
  }
  EXPECT_EQ(force->od().get({0x1A01, 4}), 0x64010810);

  ASSERT_TRUE(master->enable_all(2s).ok());
  run(20ms);
  for (NodeId id = 1; id <= 8; ++id) {
    Drive* d = master->drive(id);
    ASSERT_NE(d, nullptr);
    EXPECT_TRUE(d->enabled());
    EXPECT_EQ(drives[id]->max_jump_on_enable(), 0) << "node " << int{id};
    EXPECT_EQ(d->max_enable_error(), 0);
    EXPECT_EQ(drives[id]->position(), 1000 * id + 17);
    EXPECT_EQ(d->actual_counts(), 1000 * id + 17);
  }
  // Stream a ramp in SI units (m of cable): the drives follow.
  Drive* d3 = master->drive(3);
  const double start = d3->actual_position();
  for (int k = 1; k <= 10; ++k) {
    ASSERT_TRUE(d3->set_target(start + 1e-4 * k));
    run(config.sync_period);
  }
  run(3 * config.sync_period);
  EXPECT_EQ(drives[3]->position(), 3017 + 1000);
  EXPECT_NEAR(d3->actual_position(), start + 1e-3, 1e-9);

  const BusLoad load = master->bus_load();
  EXPECT_GT(load.load, 0.5);
  EXPECT_LT(load.load, 0.7);
  EXPECT_FALSE(load.warning);
}

TEST_F(MasterTest, FaultEmcyQuickStopAndFaultReset) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  drain();
  drives[4]->inject_fault(0x2310);
  run(40ms);
  std::vector<Event> evs;
  const auto types = drain(&evs);
  bool emcy = false, fault = false;
  for (const Event& e : evs) {
    if (e.type == EventType::kEmcy && e.node == 4) {
      emcy = true;
      EXPECT_EQ(e.emcy.code, 0x2310);
      EXPECT_EQ(emcy_code_text(e.emcy.code), "continuous over-current");
      EXPECT_EQ(e.emcy.error_register, 0x01);
    }
    if (e.type == EventType::kDriveFault && e.node == 4) fault = true;
  }
  EXPECT_TRUE(emcy);
  EXPECT_TRUE(fault);
  EXPECT_TRUE(master->faulted());
  EXPECT_EQ(master->drive(4)->state(), cia402::State::kFault);
  // Every other drive got a quick stop (this model then goes to SWITCH_ON_DISABLED, 0x605A = 2).
  for (NodeId id : {1, 2, 3, 5, 6, 7, 8}) {
    EXPECT_FALSE(master->drive(id)->enabled()) << int{id};
    EXPECT_TRUE(master->drive(id)->supervisor().reached());
  }
  // Fault reset (edge on bit 7), clear the latch, enable again.
  master->clear_fault();
  master->drive(4)->reset_fault();
  Status en = master->enable_all(2s);
  ASSERT_TRUE(en.ok()) << en.to_string();
  EXPECT_EQ(master->drive(4)->state(), cia402::State::kOperationEnabled);
  EXPECT_EQ(drives[4]->max_jump_on_enable(), 0);
  // Orderly shutdown: quick stop, disable voltage, pre-operational.
  ASSERT_TRUE(master->shutdown(1s).ok());
  run(0ms);
  for (int i = 0; i < 40; ++i) net.idle();
  EXPECT_EQ(drives[1]->nmt_state(), NmtState::kPreOperational);
  EXPECT_EQ(cia402::decode_state(drives[1]->statusword()), cia402::State::kSwitchOnDisabled);
}

TEST_F(MasterTest, StuckDriveIsNamed) {
  ASSERT_TRUE(make_and_boot().ok());
  drives[4]->set_ignore_controlword(true);
  Status s = master->enable_all(2s);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(std::string(s.message()),
            "node 4: stuck in SWITCH_ON_DISABLED for 500 ms after shutdown");
}

TEST_F(MasterTest, HeartbeatLossIsReportedWithTheNode) {
  ASSERT_TRUE(make_and_boot().ok());
  run(100ms);
  drain();
  drives[5]->faults().silent = true;
  run(300ms);
  std::vector<Event> evs;
  drain(&evs);
  int lost = 0;
  for (const Event& e : evs) {
    if (e.type == EventType::kHeartbeatLost) {
      ++lost;
      EXPECT_EQ(e.node, 5);
    }
  }
  EXPECT_EQ(lost, 1);
  EXPECT_EQ(master->nodes().state(5), NmtState::kLost);
  EXPECT_TRUE(master->faulted());
}

TEST_F(MasterTest, DrivesStopWhenTheMasterDies) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  for (int i = 0; i < 800; ++i) net.idle();  // 200 ms without master traffic
  for (NodeId id = 1; id <= 8; ++id) {
    EXPECT_TRUE(drives[id]->master_lost());
    EXPECT_NE(cia402::decode_state(drives[id]->statusword()), cia402::State::kOperationEnabled);
  }
}

TEST_F(MasterTest, BusOffSilencesThenRecovers) {
  ASSERT_TRUE(make_and_boot().ok());
  run(20ms);
  const auto syncs_before = drives[1]->syncs();
  net.bus().inject_error(can::error_class::kBusOff);
  run(400ms);  // < 500 ms recovery wait: nothing sent
  EXPECT_EQ(drives[1]->syncs(), syncs_before);
  EXPECT_EQ(master->bus().state(), BusState::kBusOff);
  run(200ms);
  EXPECT_GT(drives[1]->syncs(), syncs_before);
  EXPECT_EQ(master->bus().bus_off_count(), 1u);
  EXPECT_EQ(master->bus().recoveries(), 1u);
  const auto types = drain();
  EXPECT_NE(std::find(types.begin(), types.end(), EventType::kBusOff), types.end());
  EXPECT_NE(std::find(types.begin(), types.end(), EventType::kBusRecovered), types.end());
}

TEST_F(MasterTest, ForceSensorTensions) {
  ASSERT_TRUE(make_and_boot().ok());
  for (std::uint8_t ch = 1; ch <= 8; ++ch) {
    force->od().set({0x6401, ch}, static_cast<std::uint16_t>(2 * (10 * ch) + 0));  // 10*ch N
  }
  force->od().set({0x6401, 8}, static_cast<std::uint16_t>(-6));
  run(20ms);
  ForceSensor* f = master->force_sensor(9);
  ASSERT_NE(f, nullptr);
  ASSERT_EQ(f->channels(), 8u);
  for (std::size_t ch = 0; ch < 7; ++ch) EXPECT_DOUBLE_EQ(f->tension(ch), 10.0 * (ch + 1));
  EXPECT_EQ(f->raw(7), -6);
  EXPECT_DOUBLE_EQ(f->tension(7), -3.0);
}

TEST_F(MasterTest, BootFailsNamingTheMissingNode) {
  drives[6]->faults().silent = true;
  Status s = make_and_boot();
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(std::string(s.message()),
            "node 6 (winch6): no boot-up within 5000 ms after NMT reset communication");
}

TEST_F(MasterTest, CycleDoesNotAllocate) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  std::uint64_t allocations = 0;
  for (int i = 0; i < 500; ++i) {
    const std::uint64_t before = cdpr::test::thread_allocations();
    master->cycle(net.now());
    master->drive(1)->set_target_counts(1017 + i);
    allocations += cdpr::test::thread_allocations() - before;
    for (int k = 0; k < 16; ++k) net.idle();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_GE(master->stats().tpdos_received, 500u * 9);
  EXPECT_EQ(drives[1]->position(), 1017 + 498);
}

}  // namespace
}  // namespace cdpr::canopen
