#include "cdpr/canopen/master.hpp"

#include <gtest/gtest.h>

#include <set>

#include "alloc_counter.hpp"
#include "cdpr/canopen/codes.hpp"
#include "cdpr/canopen/eds.hpp"
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
    // Round figures for the moves in SI units below (the file's are the MINI's winches').
    for (NodeConfig& n : config.nodes) n.drive.counts_per_unit = 1e6;
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

TEST_F(MasterTest, TransmitSendsTheTargetsAndRequestsMadeAfterReceive) {
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  run(20ms);
  // A controller's cycle: receive, compute on what came in, transmit in the same cycle.
  master->receive(net.now());
  Drive* d3 = master->drive(3);
  Drive* d5 = master->drive(5);
  const std::int32_t target = d3->actual_counts() + 25;
  ASSERT_TRUE(d3->set_target_counts(target));
  d5->quick_stop();
  master->transmit(net.now());
  EXPECT_EQ(d3->target_counts(), target) << "the target goes out in this cycle";
  EXPECT_EQ(d3->controlword() & cia402::cw::kStateMask, cia402::cw::kEnableOperation);
  EXPECT_EQ(d5->controlword() & cia402::cw::kStateMask, cia402::cw::kQuickStop)
      << "the request goes out in this cycle";
  const Timestamp next = net.now() + config.sync_period;
  while (net.now() < next) net.idle();
  run(3 * config.sync_period);
  EXPECT_EQ(drives[3]->position(), target);
  EXPECT_FALSE(d5->enabled());
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

// Issue 39 (7): drives that fault on a lost master heartbeat (0x6007 = 1) stay quiet after an
// orderly shutdown: the master turned their consumer off (0x1016:01 = 0) before it went.
TEST_F(MasterTest, AfterShutdownNoDriveFaultsOnTheMissingMasterHeartbeat) {
  for (auto& n : config.nodes) {
    if (n.kind == NodeKind::kCia402Drive) n.drive.abort_connection_option = 1;
  }
  ASSERT_TRUE(make_and_boot().ok());
  ASSERT_TRUE(master->enable_all(2s).ok());
  run(100ms);
  const Status s = master->shutdown(2s);
  ASSERT_TRUE(s.ok()) << s.to_string();
  for (int i = 0; i < 4000; ++i) net.idle();  // 1 s without the master
  for (NodeId id = 1; id <= 8; ++id) {
    EXPECT_FALSE(drives[id]->master_lost()) << "node " << int{id};
    EXPECT_EQ(drives[id]->od().get({0x1016, 1}), 0) << "node " << int{id};
    EXPECT_EQ(cia402::decode_state(drives[id]->statusword()), cia402::State::kSwitchOnDisabled)
        << "node " << int{id};
    EXPECT_EQ(drives[id]->nmt_state(), NmtState::kPreOperational);
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

// Drives by configuration: a drive whose 0x6061 never follows boots with the no_mode_display
// quirk (the master reads 0x6060 back).
TEST_F(MasterTest, NoModeDisplayQuirkBootsADriveWhose6061NeverFollows) {
  drives[2]->set_ignore_mode_switch(true);
  config.nodes[1].drive.mode_switch_timeout = 200ms;
  const Status without = make_and_boot();
  ASSERT_FALSE(without.ok());
  EXPECT_NE(without.message().find("node 2: 0x6061 shows mode"), std::string::npos)
      << without.to_string();
  config.nodes[1].drive.quirks |= static_cast<std::uint32_t>(DriveQuirk::kNoModeDisplay);
  const Status with = make_and_boot();
  ASSERT_TRUE(with.ok()) << with.to_string();
  EXPECT_EQ(master->drive(2)->mode(), Mode::kCyclicSyncPosition);
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

// --- issue 14: the master's own conformance, default PDOs, EDS/DCF ------------------------------

// The MINI network built from the shipped EDS files, as the simulator builds it: the drives come
// with their default PDO mappings enabled. The bus measures its load (bit-time model).
class MasterEdsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto c = load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    config = *c;
    ASSERT_NE(config.nodes[0].eds_data, nullptr);
    for (NodeId id = 1; id <= 8; ++id) {
      drives[id] = &net.add<slave::Drive402>(id, 1000 * id + 17);
      const Status s = drives[id]->load_eds(*config.nodes[id - 1].eds_data);
      ASSERT_TRUE(s.ok()) << s.to_string();
    }
    force = &net.add<slave::SlaveNode>(9);
    const Status s = force->load_eds(*config.nodes[8].eds_data);
    ASSERT_TRUE(s.ok()) << s.to_string();
    net.power_on();
  }

  Status make_and_boot() {
    MasterHooks hooks;
    hooks.now = [this] { return net.now(); };
    hooks.idle = [this] {
      net.idle();
      take_spy();
    };
    hooks.receive_timeout = 0ns;
    auto m = Master::create(net.master_bus(), config, hooks);
    if (!m.ok()) return m.status();
    master = std::move(*m);
    return master->boot();
  }

  void take_spy() {
    can::Frame f;
    while (spy->receive(f, 0ns).ok()) {
      f.timestamp = net.now();
      seen.push_back(f);
    }
  }

  void run(std::chrono::nanoseconds d) {
    const Timestamp end = net.now() + d;
    while (net.now() < end) {
      master->cycle(net.now());
      const Timestamp next = net.now() + config.sync_period;
      while (net.now() < next) {
        net.idle();
        take_spy();
      }
    }
  }

  // Bus load measured over `d` of running (frames' worst-case bit times / time).
  double measure_load(std::chrono::nanoseconds d) {
    const can::LoadSample a = net.bus().load_sample();
    run(d);
    return can::bus_load(a, net.bus().load_sample());
  }

  testing::SimNetwork net{can::VirtualBusOptions{1024, true, 1'000'000}};
  std::unique_ptr<can::VirtualCanEndpoint> spy = net.bus().endpoint("spy");
  std::vector<can::Frame> seen;  // everything on the bus, stamped with the receive time
  MasterConfig config;
  std::array<slave::Drive402*, 9> drives{};
  slave::SlaveNode* force = nullptr;
  std::unique_ptr<Master> master;
};

// Item 11: the default PDOs real drives ship enabled are invalidated at boot; only what the
// configuration uses is on the bus.
TEST_F(MasterEdsTest, UnusedDefaultPdosAreDisabledAtBoot) {
  // The drives start with all four RPDOs and TPDOs enabled.
  for (std::uint16_t comm : {0x1401, 0x1402, 0x1403, 0x1801, 0x1802, 0x1803}) {
    ASSERT_EQ(drives[1]->od().get({comm, 1}) & cob::kInvalidBit, 0u) << std::hex << comm;
  }
  const Status s = make_and_boot();
  ASSERT_TRUE(s.ok()) << s.to_string();
  // The configuration uses RPDO1, TPDO1 and TPDO2 (the digital inputs) of each drive.
  for (NodeId id = 1; id <= 8; ++id) {
    for (std::uint16_t comm : {0x1401, 0x1402, 0x1403, 0x1802, 0x1803}) {
      EXPECT_NE(drives[id]->od().get({comm, 1}) & cob::kInvalidBit, 0u)
          << "node " << int{id} << " 0x" << std::hex << comm << " still enabled";
    }
    EXPECT_EQ(drives[id]->od().get({0x1801, 1}) & cob::kInvalidBit, 0u) << int{id};
    EXPECT_EQ(master->disabled_pdos(id),
              (std::vector<std::uint16_t>{0x1401, 0x1402, 0x1403, 0x1802, 0x1803}));
  }
  EXPECT_TRUE(master->disabled_pdos(9).empty());  // the force node's defaults are the used ones
  EXPECT_EQ(master->stats().pdos_disabled, 8u * 5u);
  ASSERT_TRUE(master->enable_all(2s).ok());
  seen.clear();
  run(200ms);
  std::set<std::uint32_t> ids;
  for (const can::Frame& f : seen) ids.insert(f.id);
  for (NodeId id = 1; id <= 8; ++id) {
    for (int n = 3; n <= 4; ++n) {
      EXPECT_EQ(ids.count(cob::tpdo(n, id)), 0u) << "TPDO" << n << " of node " << int{id};
    }
    EXPECT_EQ(ids.count(cob::tpdo(2, id)), 1u) << "the digital inputs of node " << int{id};
  }
  EXPECT_EQ(ids.count(cob::tpdo(1, 1)), 1u);
}

// Item 11, the figure in docs/canopen.md: the MINI network at 4 ms measured on the bit-time
// model, with and without the cleanup; the master's own figure counts only what is left.
TEST_F(MasterEdsTest, BusLoadWithAndWithoutTheCleanupOfDefaultPdos) {
  auto measure = [&](bool cleanup, double& computed) {
    config.disable_unused_pdos = cleanup;
    // A fresh network each time: reset node restores the drives' defaults.
    for (NodeId id = 1; id <= 9; ++id) {
      EXPECT_TRUE(net.master_bus().send(nmt_frame(NmtCommand::kResetNode, id)).ok());
    }
    for (int i = 0; i < 4; ++i) net.idle();
    const Status s = make_and_boot();
    EXPECT_TRUE(s.ok()) << s.to_string();
    EXPECT_TRUE(master->enable_all(2s).ok());
    run(100ms);
    computed = master->bus_load().load;
    const double measured = measure_load(1s);
    (void)master->shutdown(1s);
    return measured;
  };
  double computed_with = 0, computed_without = 0;
  const double without = measure(false, computed_without);
  const double with = measure(true, computed_with);
  std::printf(
      "[bus load] MINI at 4 ms, 1 Mbit/s: %.1f %% measured with the cleanup of default "
      "PDOs (master's figure %.1f %%), %.1f %% without\n",
      100 * with, 100 * computed_with, 100 * without);
  EXPECT_GT(without, 1.0) << "the default PDOs alone should overload the bus";
  EXPECT_LT(with, 0.7);
  EXPECT_NEAR(with, computed_with, 0.03);
}

// Item 9: the master's heartbeat keeps its period whatever the cycle (it was late by up to a
// cycle every period: 52 ms for 50 ms at a 4 ms cycle).
TEST_F(MasterEdsTest, MasterHeartbeatKeepsItsPeriod) {
  ASSERT_TRUE(make_and_boot().ok());
  seen.clear();
  run(1s);
  std::vector<Timestamp> t;
  for (const can::Frame& f : seen) {
    if (f.id == config.heartbeat_cob_id()) t.push_back(f.timestamp);
  }
  ASSERT_GE(t.size(), 10u);
  const double mean = to_ms(t.back() - t.front()) / static_cast<double>(t.size() - 1);
  EXPECT_NEAR(mean, 50.0, 0.5);
  for (std::size_t i = 1; i < t.size(); ++i) {
    EXPECT_LE(t[i] - t[i - 1], 50ms + config.sync_period);
  }
}

// Item 12: the master's boot-up message precedes its first heartbeat (and the NMT reset).
TEST_F(MasterEdsTest, MasterSendsItsBootUpBeforeItsFirstHeartbeat) {
  ASSERT_TRUE(make_and_boot().ok());
  run(100ms);
  int first_own = -1, first_nmt = -1;
  for (std::size_t i = 0; i < seen.size(); ++i) {
    if (first_own < 0 && seen[i].id == config.heartbeat_cob_id()) first_own = static_cast<int>(i);
    if (first_nmt < 0 && seen[i].id == cob::kNmt) first_nmt = static_cast<int>(i);
  }
  ASSERT_GE(first_own, 0);
  EXPECT_EQ(seen[static_cast<std::size_t>(first_own)].dlc, 1);
  EXPECT_EQ(seen[static_cast<std::size_t>(first_own)].data[0], 0x00)
      << "first own frame is not a boot-up";
  EXPECT_LT(first_own, first_nmt);
  int boot_ups = 0;
  for (const can::Frame& f : seen) {
    boot_ups += f.id == config.heartbeat_cob_id() && f.data[0] == 0x00 ? 1 : 0;
  }
  EXPECT_EQ(boot_ups, 1);
}

// Item 10: with a SYNC counter the master writes 0x1019 on every node, so conforming nodes take
// the 1-byte SYNC instead of raising EMCY 0x8240 and leaving OPERATIONAL.
TEST_F(MasterEdsTest, SyncCounterOverflowIsWrittenToTheNodes) {
  config.sync_counter_overflow = 5;
  const Status s = make_and_boot();
  ASSERT_TRUE(s.ok()) << s.to_string();
  ASSERT_TRUE(master->enable_all(2s).ok());
  const auto syncs = drives[3]->syncs();
  run(100ms);
  for (NodeId id = 1; id <= 8; ++id) {
    EXPECT_EQ(drives[id]->od().get({0x1019, 0}), 5) << "node " << int{id};
    EXPECT_EQ(drives[id]->nmt_state(), NmtState::kOperational) << "node " << int{id};
  }
  EXPECT_EQ(force->od().get({0x1019, 0}), 5);
  EXPECT_GE(drives[3]->syncs() - syncs, 20u);
  Event e;
  while (master->events().pop(e)) {
    EXPECT_FALSE(e.type == EventType::kEmcy && e.emcy.code == 0x8240) << "node " << int{e.node};
  }
  EXPECT_FALSE(master->faulted());
  bool counter = false;
  for (const can::Frame& f : seen) counter = counter || (f.id == cob::kSync && f.dlc == 1);
  EXPECT_TRUE(counter);
}

// The DCF of what the master applied: the EDS with ParameterValue for every object it wrote.
TEST_F(MasterEdsTest, WritesTheDcfOfTheAppliedConfiguration) {
  ASSERT_TRUE(make_and_boot().ok());
  const std::string dir = ::testing::TempDir();
  ASSERT_TRUE(master->write_dcfs(dir).ok());
  auto dcf = eds::Eds::load(dir + "/winch3.dcf");
  ASSERT_TRUE(dcf.ok()) << dcf.status().to_string();
  auto value = [&](ObjectAddress a) -> std::int64_t {
    const eds::SubObject* s = dcf->find(a);
    if (s == nullptr || !s->parameter_value) return -999999;
    auto v = dcf->value(*s, 3, true);
    return v.ok() ? *v : -999999;
  };
  EXPECT_EQ(value({0x1017, 0}), 50);
  EXPECT_EQ(value({0x1016, 1}), (127 << 16) | 150);
  EXPECT_EQ(value({0x1600, 2}), 0x607A0020);
  EXPECT_EQ(value({0x1400, 1}), 0x203);
  EXPECT_EQ(value({0x1801, 1}), 0x283);       // TPDO2 (digital inputs), configured
  EXPECT_EQ(value({0x1802, 1}), 0x80000383);  // disabled default TPDO3
  EXPECT_EQ(value({0x6060, 0}), 8);
  EXPECT_EQ(value({0x60C2, 2}), -3);
  EXPECT_FALSE(dcf->find({0x6041, 0})->parameter_value.has_value());
  bool node_id = false;
  for (const auto& [k, v] : dcf->commissioning()) node_id = node_id || (k == "nodeid" && v == "3");
  EXPECT_TRUE(node_id);
  // The applied values are those the node holds.
  for (const auto& [key, v] : *master->applied(3)) {
    const ObjectAddress a{static_cast<std::uint16_t>(key >> 8), static_cast<std::uint8_t>(key)};
    if (a.index == 0x6040 || a.index == 0x6060) continue;  // changed by the RPDO / the model
    const auto* e = drives[3]->od().find(a);
    ASSERT_NE(e, nullptr);
    std::int64_t raw = 0;
    for (std::size_t i = 0; i < e->data.size() && i < 8; ++i)
      raw |= std::int64_t{e->data[i]} << (8 * i);
    EXPECT_EQ(raw, v) << std::hex << a.index << ":" << int{a.sub};
  }
}

TEST_F(MasterTest, WritesADcfForANodeWithoutEds) {
  config.nodes[8].eds_data.reset();
  config.nodes[8].eds.clear();
  ASSERT_TRUE(make_and_boot().ok());
  const std::string path = ::testing::TempDir() + "/forces-no-eds.dcf";
  ASSERT_TRUE(master->write_dcf(9, path).ok());
  auto dcf = eds::Eds::load(path);
  ASSERT_TRUE(dcf.ok()) << dcf.status().to_string();
  const eds::SubObject* m = dcf->find({0x1A01, 4});
  ASSERT_NE(m, nullptr);
  ASSERT_TRUE(m->parameter_value.has_value());
  auto v = dcf->value(*m, 9, true);
  ASSERT_TRUE(v.ok());
  EXPECT_EQ(*v, 0x64010810);
  EXPECT_EQ(m->data_type, eds::type::kUnsigned32);
  // Issue 39 (7): complete per CiA 306: the mandatory objects, a filled [DeviceInfo].
  for (std::uint16_t index : {0x1000, 0x1001, 0x1018}) {
    EXPECT_NE(dcf->object(index), nullptr) << "mandatory object 0x" << std::hex << index;
  }
  const eds::SubObject* vendor = dcf->find({0x1018, 1});
  ASSERT_NE(vendor, nullptr);
  auto vendor_id = dcf->value(*vendor, 9);
  ASSERT_TRUE(vendor_id.ok()) << vendor_id.status().to_string();
  EXPECT_EQ(*vendor_id, force->od().get({0x1018, 1}));
  for (const char* key : {"VendorName", "VendorNumber", "ProductName", "ProductNumber",
                          "RevisionNumber", "BaudRate_1000", "SimpleBootUpSlave", "Granularity",
                          "NrOfRXPDO", "NrOfTXPDO", "LSS_Supported"}) {
    EXPECT_FALSE(dcf->device_info(key).empty()) << "[DeviceInfo] lacks " << key;
  }
  EXPECT_EQ(dcf->device_info("BaudRate_1000"), "1");
  EXPECT_EQ(dcf->device_info("NrOfTXPDO"), "2");
}

}  // namespace
}  // namespace cdpr::canopen
