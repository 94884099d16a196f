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

TEST_F(MasterTest, SetModeWhileRunningWaitsForTheModeDisplay) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  run(20ms);
  drain();
  drives[2]->set_mode_display_delay(60ms);  // 0x6061 follows 60 ms after 0x6060
  const auto syncs_before = drives[2]->syncs();
  const Timestamp t0 = net.now();
  Status s = master->set_mode(2, Mode::kProfilePosition);
  ASSERT_TRUE(s.ok()) << s.to_string();
  EXPECT_GE(net.now() - t0, 60ms);
  EXPECT_LT(net.now() - t0, 200ms);
  EXPECT_EQ(drives[2]->od().get({0x6061, 0}), 1);
  EXPECT_EQ(master->drive(2)->mode(), Mode::kProfilePosition);
  // The master kept cycling while it waited: SYNCs, RPDOs and heartbeats went on.
  EXPECT_GE(drives[2]->syncs() - syncs_before, 14u);
  for (const EventType t : drain()) EXPECT_NE(t, EventType::kHeartbeatLost);
  EXPECT_FALSE(master->faulted());
  for (NodeId id = 1; id <= 8; ++id) EXPECT_TRUE(master->drive(id)->enabled()) << int{id};
  EXPECT_EQ(drives[2]->position(), 2017);  // held during the switch
  // CSP commands are not taken in profile position.
  EXPECT_FALSE(master->drive(2)->set_target_counts(2500));
}

TEST_F(MasterTest, SetModeTimesOutNamingTheNodeWhenTheDriveNeverConfirms) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  Drive* d4 = master->drive(4);
  ASSERT_TRUE(d4->set_target_counts(4017 + 300));
  run(20ms);
  ASSERT_EQ(drives[4]->position(), 4317);
  drives[4]->set_ignore_mode_switch(true);
  const Timestamp t0 = net.now();
  Status s = master->set_mode(4, Mode::kProfilePosition);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::kTimeout);
  EXPECT_EQ(std::string(s.message()),
            "node 4: 0x6061 shows mode 8 1000 ms after writing 0x6060 = 1 (profile_position)");
  EXPECT_GE(net.now() - t0, 1000ms);
  EXPECT_LT(net.now() - t0, 1100ms);
  // The drive is held where it is: no mode is assumed, no command of either mode is taken.
  EXPECT_EQ(d4->mode(), Mode::kNone);
  EXPECT_FALSE(d4->set_target_counts(9000));
  EXPECT_FALSE(d4->move_to_counts(9000));
  run(40ms);
  EXPECT_EQ(drives[4]->position(), 4317);
  EXPECT_EQ(d4->target_counts(), 4317);
  // The network stayed up during the wait.
  EXPECT_FALSE(master->faulted());
  EXPECT_TRUE(d4->enabled());
  // Once the drive follows again the switch succeeds.
  drives[4]->set_ignore_mode_switch(false);
  ASSERT_TRUE(master->set_mode(4, Mode::kCyclicSyncPosition).ok());
  EXPECT_TRUE(d4->set_target_counts(4317 + 5));
}

TEST_F(MasterTest, ProfilePositionMoveHandshakeAndTargetReached) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  Status s = master->set_mode(3, Mode::kProfilePosition);
  ASSERT_TRUE(s.ok()) << s.to_string();
  run(20ms);
  Drive* d = master->drive(3);
  EXPECT_FALSE(master->drive(1)->move_to_counts(5000));  // drive 1 is in CSP
  EXPECT_TRUE(d->move_done());
  const std::int32_t start = 3017;
  ASSERT_EQ(drives[3]->position(), start);
  ASSERT_TRUE(d->move_to_counts(start + 2000));
  EXPECT_FALSE(d->move_done());

  // One cycle at a time: master bit 4 (new set-point), drive bit 12 (set-point acknowledge).
  int first_bit4 = -1, first_ack = -1, bit4_dropped = -1, ack_dropped = -1, done_at = -1;
  std::int32_t last = start;
  std::int32_t max_step = 0;
  for (int k = 0; k < 200 && done_at < 0; ++k) {
    run(config.sync_period);
    const bool bit4 = (d->controlword() & cia402::cw::kNewSetPoint) != 0;
    const bool ack = (d->statusword() & cia402::sw::kSetPointAcknowledge) != 0;
    if (bit4 && first_bit4 < 0) first_bit4 = k;
    if (ack && first_ack < 0) first_ack = k;
    if (first_bit4 >= 0 && !bit4 && bit4_dropped < 0) bit4_dropped = k;
    if (first_ack >= 0 && !ack && ack_dropped < 0) ack_dropped = k;
    const std::int32_t p = drives[3]->position();
    EXPECT_GE(p, last);          // monotonic
    EXPECT_LE(p, start + 2000);  // no overshoot
    max_step = std::max(max_step, p - last);
    last = p;
    if (d->move_done()) done_at = k;
  }
  ASSERT_GE(done_at, 0) << "move not done";
  EXPECT_EQ(first_bit4, 0);
  EXPECT_GT(first_ack, first_bit4);      // the drive acknowledged the set-point
  EXPECT_GE(bit4_dropped, first_ack);    // then the master dropped bit 4
  EXPECT_GT(ack_dropped, bit4_dropped);  // then the drive dropped the acknowledge
  EXPECT_GE(done_at, ack_dropped);       // target reached judged after the handshake
  EXPECT_GE(done_at, 2000 / 80);         // 20000 counts/s at 4 ms: 80 counts per SYNC
  EXPECT_LE(max_step, 80);
  EXPECT_EQ(drives[3]->position(), start + 2000);
  EXPECT_EQ(d->actual_counts(), start + 2000);
  EXPECT_EQ(drives[3]->od().get({0x607A, 0}, true), start + 2000);
  EXPECT_NE(d->statusword() & cia402::sw::kTargetReached, 0);

  // A second move in SI units (1e6 counts per m), backwards.
  ASSERT_TRUE(d->move_to(d->actual_position() - 0.0005));
  for (int k = 0; k < 200 && !d->move_done(); ++k) run(config.sync_period);
  EXPECT_TRUE(d->move_done());
  EXPECT_EQ(drives[3]->position(), start + 1500);
  // Not enabled: no move is taken.
  master->drive(3)->disable();
  run(40ms);
  EXPECT_FALSE(d->move_to_counts(start));
}

TEST_F(MasterTest, SetActualPositionForTheReferencePlatform) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  Drive* d5 = master->drive(5);
  // A CSP target from before the homing: it is in the old coordinates and must not be replayed.
  ASSERT_TRUE(d5->set_target_counts(5017 + 100));
  run(20ms);
  ASSERT_EQ(drives[5]->position(), 5117);

  Status s = master->set_actual_position(5, 1.234567, 2s);  // m of cable at the reference pose
  ASSERT_TRUE(s.ok()) << s.to_string();
  EXPECT_EQ(drives[5]->od().get({0x6098, 0}, true), 37);
  EXPECT_EQ(drives[5]->od().get({0x607C, 0}, true), 1234567);
  EXPECT_EQ(drives[5]->homings(), 1u);
  EXPECT_EQ(drives[5]->position(), 1234567);
  EXPECT_EQ(d5->actual_counts(), 1234567);
  EXPECT_NEAR(d5->actual_position(), 1.234567, 1e-9);
  // Back in CSP, holding the new position (no jump to the old target).
  EXPECT_EQ(d5->mode(), Mode::kCyclicSyncPosition);
  EXPECT_EQ(drives[5]->od().get({0x6061, 0}), 8);
  run(40ms);
  EXPECT_EQ(drives[5]->position(), 1234567);
  ASSERT_TRUE(d5->set_target(1.234567 + 1e-4));
  run(20ms);
  EXPECT_EQ(drives[5]->position(), 1234667);
  // Nobody else moved or faulted.
  EXPECT_EQ(drives[1]->position(), 1017);
  EXPECT_FALSE(master->faulted());
  EXPECT_TRUE(d5->enabled());
}

TEST_F(MasterTest, HomingIsJudgedOnlyAfterTheDriveSawTheStart) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  drives[6]->set_homing_duration(40ms);
  Status s = master->set_actual_position(6, 0.5, 2s);
  ASSERT_TRUE(s.ok()) << s.to_string();
  EXPECT_EQ(drives[6]->position(), 500000);
  // The drive still shows "homing attained" from the first homing when the second one starts:
  // it must not be taken for the new one.
  const Timestamp t0 = net.now();
  s = master->set_actual_position(6, 0.25, 2s);
  ASSERT_TRUE(s.ok()) << s.to_string();
  EXPECT_GE(net.now() - t0, 40ms);
  EXPECT_EQ(drives[6]->homings(), 2u);
  EXPECT_EQ(drives[6]->position(), 250000);
  EXPECT_EQ(master->drive(6)->actual_counts(), 250000);
}

TEST_F(MasterTest, HomingErrorsAndPreconditionsNameTheNode) {
  ASSERT_TRUE(make_and_boot().ok());
  run(20ms);
  Status s = master->set_actual_position(7, 0.1, 1s);
  EXPECT_EQ(s.code(), ErrorCode::kFailedPrecondition);
  EXPECT_EQ(std::string(s.message()),
            "node 7: set actual position needs OPERATION_ENABLED (drive in SWITCH_ON_DISABLED)");
  EXPECT_EQ(master->set_actual_position(9, 0.1, 1s).code(), ErrorCode::kNotFound);
  ASSERT_TRUE(master->enable_all(2s).ok());
  // The drive refuses the home offset: the SDO abort is the answer.
  drives[7]->faults().abort_on[ObjectAddress{0x607C, 0}.key()] = abort_code::kValueRange;
  s = master->set_actual_position(7, 0.1, 1s);
  EXPECT_EQ(s.code(), ErrorCode::kAborted);
  EXPECT_NE(s.message().find("node 7: SDO download 0x607C:00 aborted: 0x06090030"),
            std::string::npos)
      << s.message();
  EXPECT_EQ(drives[7]->position(), 7017);
  // A homing method the drive cannot do ends with "homing error" (statusword bit 13).
  ASSERT_TRUE(master->set_mode(7, Mode::kHoming).ok());
  ASSERT_TRUE(master->sdo(7)->write<std::int8_t>({0x6098, 0}, 1, master->pump()).ok());
  Drive* d7 = master->drive(7);
  d7->start_homing();
  s = master->wait_for([&] { return d7->homing_done() || d7->homing_error(); }, 1s, "homing");
  ASSERT_TRUE(s.ok()) << s.to_string();
  EXPECT_TRUE(d7->homing_error());
  EXPECT_FALSE(d7->homing_done());
  EXPECT_EQ(drives[7]->position(), 7017);
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
