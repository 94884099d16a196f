// The reusable slave library against the CiA 301/402 rules that independent masters found it
// breaking (issue 14): PDO parameters with immediate effect, COB-ID changes of valid PDOs,
// event-driven TPDOs, EMCY after a fault reset, 0x1014, statusword bit 12 in CSP, 0x6502, expedited
// downloads without size, the SYNC length check against 0x1019, reset communication restoring the
// defaults, and dictionaries built from an EDS.
#include "cdpr/canopen/slave/slave.hpp"

#include <gtest/gtest.h>

#include <vector>

#include "cdpr/canopen/cia402.hpp"
#include "cdpr/canopen/codes.hpp"
#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/sdo_client.hpp"
#include "testing/sim_network.hpp"

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;

constexpr NodeId kNode = 4;

class SlaveTest : public ::testing::Test {
 protected:
  SlaveTest()
      : drive(net.add<slave::Drive402>(kNode, 1234)),
        sdo(net.master_bus(), kNode, SdoTiming{50ms, 0}),
        pump(
            net.master_bus(), [this] { return net.now(); }, 0ns) {
    pump.add(sdo);
    pump.on_idle([this] { net.idle(); });
    pump.on_other([this](const can::Frame& f) { seen.push_back({net.now(), f}); });
    net.power_on();
    net.step_slaves();
  }

  // Sends a frame from the master's endpoint and lets the node take it.
  void send(const can::Frame& f) {
    ASSERT_TRUE(net.master_bus().send(f).ok());
    net.idle();
    collect();
  }
  void sync(std::uint8_t dlc = 0, std::uint8_t counter = 0) {
    can::Frame f = make_frame(cob::kSync, dlc);
    f.data[0] = counter;
    send(f);
  }
  void collect() {
    can::Frame f;
    while (net.master_bus().receive(f, 0ns).ok()) seen.push_back({net.now(), f});
  }
  // Advances the clock by `d` in the network's steps, collecting what the node sends.
  void wait(std::chrono::nanoseconds d) {
    const Timestamp end = net.now() + d;
    while (net.now() < end) {
      net.idle();
      collect();
    }
  }
  std::vector<can::Frame> frames(std::uint32_t id) {
    collect();
    std::vector<can::Frame> out;
    for (const auto& s : seen) {
      if (!s.frame.error && s.frame.id == id) out.push_back(s.frame);
    }
    return out;
  }
  std::vector<Timestamp> times(std::uint32_t id) {
    collect();
    std::vector<Timestamp> out;
    for (const auto& s : seen) {
      if (!s.frame.error && s.frame.id == id) out.push_back(s.frame.timestamp);  // sent at
    }
    return out;
  }
  template <typename T>
  void write(ObjectAddress a, T v) {
    const Status s = sdo.write<T>(a, v, pump);
    ASSERT_TRUE(s.ok()) << s.to_string();
  }
  // TPDO1 = statusword, transmission `type`, through SDO in CiA 301 order.
  void map_tpdo1(std::uint8_t type) {
    PdoConfig p;
    p.direction = PdoDirection::kTpdo;
    p.number = 1;
    p.transmission_type = type;
    p.entries = {{{0x6041, 0}, DataType::kU16}};
    const Status s = configure_pdo(sdo, pump, p);
    ASSERT_TRUE(s.ok()) << s.to_string();
  }
  // RPDO `number` with transmission type 255 (applied on arrival) carrying `entries`.
  void map_rpdo(int number, std::vector<PdoEntry> entries) {
    PdoConfig p;
    p.direction = PdoDirection::kRpdo;
    p.number = number;
    p.transmission_type = 255;
    p.entries = std::move(entries);
    const Status s = configure_pdo(sdo, pump, p);
    ASSERT_TRUE(s.ok()) << s.to_string();
  }
  void start() { send(nmt_frame(NmtCommand::kStart, kNode)); }

  struct Seen {
    Timestamp time;
    can::Frame frame;
  };
  testing::SimNetwork net;
  slave::Drive402& drive;
  SdoClient sdo;
  BusPump pump;
  std::vector<Seen> seen;
};

// Item 1: bit 31 of a PDO's COB-ID deletes/creates the PDO at once, in OPERATIONAL too.
TEST_F(SlaveTest, TpdoDisabledInOperationalStopsSendingAtOnce) {
  map_tpdo1(1);
  start();
  for (int i = 0; i < 5; ++i) sync();
  EXPECT_EQ(frames(cob::tpdo(1, kNode)).size(), 5u);
  write<std::uint32_t>({0x1800, 1}, cob::kInvalidBit | cob::tpdo(1, kNode));
  ASSERT_EQ(drive.nmt_state(), NmtState::kOperational);
  for (int i = 0; i < 5; ++i) sync();
  EXPECT_EQ(frames(cob::tpdo(1, kNode)).size(), 5u) << "a deleted TPDO kept sending";
}

TEST_F(SlaveTest, TpdoEnabledInOperationalSendsWithoutANewStart) {
  map_tpdo1(1);
  write<std::uint32_t>({0x1800, 1}, cob::kInvalidBit | cob::tpdo(1, kNode));
  start();
  for (int i = 0; i < 3; ++i) sync();
  EXPECT_TRUE(frames(cob::tpdo(1, kNode)).empty());
  write<std::uint32_t>({0x1800, 1}, cob::tpdo(1, kNode));
  for (int i = 0; i < 3; ++i) sync();
  EXPECT_EQ(frames(cob::tpdo(1, kNode)).size(), 3u) << "a created TPDO waited for NMT start";
}

TEST_F(SlaveTest, RpdoCreatedInOperationalIsAppliedAtOnce) {
  PdoConfig p;
  p.direction = PdoDirection::kRpdo;
  p.number = 2;
  p.transmission_type = 255;
  p.entries = {{{0x607A, 0}, DataType::kI32}};
  ASSERT_TRUE(configure_pdo(sdo, pump, p).ok());
  write<std::uint32_t>({0x1401, 1}, cob::kInvalidBit | cob::rpdo(2, kNode));
  start();
  can::Frame f = make_frame(cob::rpdo(2, kNode), 4);
  put_u32(f.data.data(), 777);
  send(f);
  EXPECT_EQ(drive.od().get({0x607A, 0}, true), 0);
  write<std::uint32_t>({0x1401, 1}, cob::rpdo(2, kNode));
  send(f);
  EXPECT_EQ(drive.od().get({0x607A, 0}, true), 777);
}

// Item 2: bits 0..29 of a valid PDO's COB-ID may not change (abort 0x06090030).
TEST_F(SlaveTest, ChangingTheCobIdOfAValidPdoIsRefused) {
  map_tpdo1(1);
  const Status s = sdo.write<std::uint32_t>({0x1800, 1}, 0x190, pump);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("0x06090030"), std::string::npos) << s.message();
  EXPECT_EQ(drive.od().get({0x1800, 1}), cob::tpdo(1, kNode));
  // Deleted first, it may change.
  write<std::uint32_t>({0x1800, 1}, cob::kInvalidBit | cob::tpdo(1, kNode));
  write<std::uint32_t>({0x1800, 1}, cob::kInvalidBit | 0x190);
  write<std::uint32_t>({0x1800, 1}, 0x190);
  start();
  sync();
  EXPECT_EQ(frames(0x190).size(), 1u);
  // 29-bit identifiers are not supported.
  EXPECT_FALSE(sdo.write<std::uint32_t>({0x1801, 1}, cob::kInvalidBit | 0x20000000u, pump).ok());
}

// Item 3: transmission types 254/255 send on change and by the event timer, never faster than
// the inhibit time.
TEST_F(SlaveTest, EventDrivenTpdoSendsOnChangeByTimerAndRespectsTheInhibitTime) {
  map_tpdo1(255);
  write<std::uint32_t>({0x1800, 1}, cob::kInvalidBit | cob::tpdo(1, kNode));
  write<std::uint16_t>({0x1800, 3}, 200);  // 20 ms
  write<std::uint32_t>({0x1800, 1}, cob::tpdo(1, kNode));
  write<std::uint16_t>({0x1800, 5}, 100);  // event timer 100 ms
  start();
  wait(1ms);
  ASSERT_EQ(frames(cob::tpdo(1, kNode)).size(), 1u) << "no frame on entering OPERATIONAL";
  write<std::uint16_t>({0x6040, 0}, 0x06);  // SWITCH_ON_DISABLED -> READY_TO_SWITCH_ON: a change
  wait(30ms);
  ASSERT_EQ(frames(cob::tpdo(1, kNode)).size(), 2u);
  // No change: the event timer alone sends, every 100 ms.
  seen.clear();
  wait(350ms);
  const auto t = times(cob::tpdo(1, kNode));
  ASSERT_EQ(t.size(), 3u);
  for (std::size_t i = 1; i < t.size(); ++i) {
    EXPECT_GE(t[i] - t[i - 1], 100ms);
    EXPECT_LE(t[i] - t[i - 1], 100ms + net.step());
  }
  // A change is sent at once (the last frame is > 20 ms old)...
  seen.clear();
  write<std::uint16_t>({0x6040, 0}, 0x07);  // READY_TO_SWITCH_ON -> SWITCHED_ON
  wait(1ms);
  auto f = frames(cob::tpdo(1, kNode));
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(get_u16(f[0].data.data()) & 0x6F, 0x23);
  const Timestamp first = times(cob::tpdo(1, kNode)).front();
  // ... and a second change right after waits for the inhibit time.
  write<std::uint16_t>({0x6040, 0}, 0x06);  // -> READY_TO_SWITCH_ON
  wait(30ms);
  f = frames(cob::tpdo(1, kNode));
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(get_u16(f[1].data.data()) & 0x6F, 0x21);
  EXPECT_GE(times(cob::tpdo(1, kNode))[1] - first, 20ms);
  // The inhibit time may not change while the PDO exists.
  EXPECT_FALSE(sdo.write<std::uint16_t>({0x1800, 3}, 10, pump).ok());
  // Reserved and RTR-only transmission types are refused.
  EXPECT_FALSE(sdo.write<std::uint8_t>({0x1800, 2}, 245, pump).ok());
  EXPECT_FALSE(sdo.write<std::uint8_t>({0x1800, 2}, 252, pump).ok());
}

TEST_F(SlaveTest, AcyclicSynchronousTpdoSendsAtTheSyncAfterAChange) {
  map_tpdo1(0);
  start();
  sync();
  sync();
  EXPECT_EQ(frames(cob::tpdo(1, kNode)).size(), 1u);
  write<std::uint16_t>({0x6040, 0}, 0x06);
  EXPECT_EQ(frames(cob::tpdo(1, kNode)).size(), 1u);  // not before the SYNC
  sync();
  sync();
  EXPECT_EQ(frames(cob::tpdo(1, kNode)).size(), 2u);
}

// Item 4: after the fault reset, EMCY 0x0000 and 0x1001 = 0.
TEST_F(SlaveTest, FaultResetSendsErrorResetEmcyAndClearsTheErrorRegister) {
  start();
  sync();
  drive.inject_fault(0x2310);
  sync();
  ASSERT_EQ(cia402::decode_state(drive.statusword()), cia402::State::kFault);
  auto emcy = frames(cob::kEmcy + kNode);
  ASSERT_EQ(emcy.size(), 1u);
  EXPECT_EQ(get_u16(emcy[0].data.data()), 0x2310);
  auto reg = sdo.read<std::uint8_t>({0x1001, 0}, pump);
  ASSERT_TRUE(reg.ok());
  EXPECT_NE(*reg, 0);
  write<std::uint16_t>({0x6040, 0}, 0x00);
  write<std::uint16_t>({0x6040, 0}, 0x80);  // rising edge of bit 7
  EXPECT_EQ(cia402::decode_state(drive.statusword()), cia402::State::kSwitchOnDisabled);
  emcy = frames(cob::kEmcy + kNode);
  ASSERT_EQ(emcy.size(), 2u) << "no EMCY after the fault reset";
  EXPECT_EQ(get_u16(emcy[1].data.data()), 0x0000);
  EXPECT_EQ(emcy[1].data[2], 0x00);
  reg = sdo.read<std::uint8_t>({0x1001, 0}, pump);
  ASSERT_TRUE(reg.ok());
  EXPECT_EQ(*reg, 0) << "0x1001 still shows an error";
}

// Item 5: 0x1014 exists, names the EMCY COB-ID and its bit 31 turns EMCY off.
TEST_F(SlaveTest, EmcyCobIdObjectSelectsAndDisablesTheEmcy) {
  auto cob_id = sdo.read<std::uint32_t>({0x1014, 0}, pump);
  ASSERT_TRUE(cob_id.ok()) << cob_id.status().to_string();
  EXPECT_EQ(*cob_id, cob::kEmcy + kNode);
  // The CAN-ID of a valid EMCY may not change.
  EXPECT_FALSE(sdo.write<std::uint32_t>({0x1014, 0}, 0x0A1, pump).ok());
  write<std::uint32_t>({0x1014, 0}, cob::kInvalidBit | (cob::kEmcy + kNode));
  drive.inject_fault(0x2310);
  wait(1ms);
  EXPECT_TRUE(frames(cob::kEmcy + kNode).empty());
  write<std::uint32_t>({0x1014, 0}, cob::kInvalidBit | 0x0A1);
  write<std::uint32_t>({0x1014, 0}, 0x0A1);
  drive.inject_fault(0x3210);
  wait(1ms);
  const auto f = frames(0x0A1);
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(get_u16(f[0].data.data()), 0x3210);
}

// Item 6: statusword bit 12 in CSP is "target position used" while following.
TEST_F(SlaveTest, CspStatuswordBit12IsSetWhileFollowingTargets) {
  write<std::int8_t>({0x6060, 0}, 8);
  start();
  sync();
  for (std::uint16_t cw : {0x06, 0x07, 0x0F}) write<std::uint16_t>({0x6040, 0}, cw);
  sync();
  ASSERT_EQ(cia402::decode_state(drive.statusword()), cia402::State::kOperationEnabled);
  EXPECT_NE(drive.statusword() & 0x1000, 0) << "bit 12 is 0 while the drive follows";
  write<std::uint16_t>({0x6040, 0}, 0x07);
  EXPECT_EQ(drive.statusword() & 0x1000, 0) << "bit 12 set although targets are ignored";
}

// The safety chain's objects: the e-stop bit of the digital inputs, the holding brake output.
TEST_F(SlaveTest, AnAppliedBrakeHoldsTheShaftAgainstCspTargetsAndTheEStopBitIsAnInput) {
  constexpr std::int64_t kClosed = std::int64_t{1} << slave::Drive402::kSafetyInputBit;
  EXPECT_EQ(drive.od().get({0x60FD, 0}), kClosed) << "the chain is closed at power-on";
  drive.set_digital_input(slave::Drive402::kSafetyInputBit, false);
  EXPECT_EQ(drive.od().get({0x60FD, 0}), 0);
  write<std::int8_t>({0x6060, 0}, 8);
  start();
  sync();
  for (std::uint16_t cw : {0x06, 0x07, 0x0F}) write<std::uint16_t>({0x6040, 0}, cw);
  write<std::uint32_t>({0x60FE, 1}, 1);  // set brake
  write<std::int32_t>({0x607A, 0}, 5000);
  sync();
  EXPECT_TRUE(drive.brake_applied());
  EXPECT_EQ(drive.position(), 1234) << "a braked winch does not turn";
  EXPECT_EQ(drive.braked_syncs(), 1u);
  write<std::uint32_t>({0x60FE, 1}, 0);
  sync();
  EXPECT_EQ(drive.position(), 5000) << "released: it follows its target";
}

// Item 7: 0x6502 supported drive modes.
TEST_F(SlaveTest, SupportedDriveModesListProfilePositionHomingAndCsp) {
  auto modes = sdo.read<std::uint32_t>({0x6502, 0}, pump);
  ASSERT_TRUE(modes.ok()) << modes.status().to_string();
  EXPECT_EQ(*modes, (1u << 0) | (1u << 5) | (1u << 7));
}

// Item 8: an expedited download without the size indicated (command 0x22) is accepted.
TEST_F(SlaveTest, ExpeditedDownloadWithoutSizeIndicatedIsAccepted) {
  struct Case {
    ObjectAddress object;
    std::uint32_t value;
  };
  for (const Case c : {Case{{0x6060, 0}, 1}, Case{{0x1017, 0}, 250}, Case{{0x607A, 0}, 99999}}) {
    can::Frame f = make_frame(cob::kSdoRx + kNode, 8);
    f.data[0] = 0x22;
    put_u16(&f.data[1], c.object.index);
    f.data[3] = c.object.sub;
    put_u32(&f.data[4], c.value);
    seen.clear();
    send(f);
    const auto answers = frames(cob::kSdoTx + kNode);
    ASSERT_EQ(answers.size(), 1u);
    EXPECT_EQ(answers[0].data[0], 0x60) << "abort 0x" << std::hex << get_u32(&answers[0].data[4]);
    EXPECT_EQ(drive.od().get(c.object), c.value);
  }
}

// Item 10 (the node's side): a SYNC whose length disagrees with 0x1019 raises EMCY 0x8240 and
// the node leaves OPERATIONAL.
TEST_F(SlaveTest, SyncWithACounterThat1019DoesNotExpectRaisesEmcy8240) {
  start();
  sync(0);
  EXPECT_EQ(drive.syncs(), 1u);
  sync(1, 1);
  EXPECT_EQ(drive.syncs(), 1u);
  EXPECT_EQ(drive.nmt_state(), NmtState::kPreOperational);
  const auto emcy = frames(cob::kEmcy + kNode);
  ASSERT_EQ(emcy.size(), 1u);
  EXPECT_EQ(get_u16(emcy[0].data.data()), 0x8240);
}

TEST_F(SlaveTest, SyncCounterAgreeingWith1019IsTaken) {
  write<std::uint8_t>({0x1019, 0}, 10);
  EXPECT_FALSE(sdo.write<std::uint8_t>({0x1019, 0}, 1, pump).ok());
  EXPECT_FALSE(sdo.write<std::uint8_t>({0x1019, 0}, 241, pump).ok());
  start();
  for (std::uint8_t c = 1; c <= 3; ++c) sync(1, c);
  EXPECT_EQ(drive.syncs(), 3u);
  EXPECT_EQ(drive.nmt_state(), NmtState::kOperational);
  sync(0);  // now a SYNC without the counter is the wrong one
  EXPECT_EQ(drive.nmt_state(), NmtState::kPreOperational);
  ASSERT_EQ(frames(cob::kEmcy + kNode).size(), 1u);
}

TEST_F(SlaveTest, ResetCommunicationRestoresTheCommunicationDefaults) {
  drive.od().set_default({0x1801, 1}, cob::tpdo(2, kNode));  // a default-enabled TPDO2
  write<std::uint32_t>({0x1801, 1}, cob::kInvalidBit | cob::tpdo(2, kNode));
  write<std::uint16_t>({0x1017, 0}, 100);
  write<std::int32_t>({0x607A, 0}, 55);
  send(nmt_frame(NmtCommand::kResetCommunication, kNode));
  EXPECT_EQ(drive.od().get({0x1801, 1}), cob::tpdo(2, kNode));
  EXPECT_EQ(drive.od().get({0x1017, 0}), 0);
  EXPECT_EQ(drive.od().get({0x607A, 0}, true), 55);  // the application area stays
  send(nmt_frame(NmtCommand::kResetNode, kNode));
  EXPECT_EQ(drive.od().get({0x607A, 0}, true), 0);
}

// Issue 39 (7): a mode written by RPDO has the checks and side effects of an SDO write.
TEST_F(SlaveTest, ModeWrittenByRpdoIsCheckedAndShownIn6061) {
  map_rpdo(2, {{{0x6060, 0}, DataType::kI8}});
  start();
  can::Frame f = make_frame(cob::rpdo(2, kNode), 1);
  f.data[0] = 8;  // CSP
  send(f);
  EXPECT_EQ(drive.od().get({0x6060, 0}, true), 8);
  EXPECT_EQ(drive.od().get({0x6061, 0}, true), 8) << "0x6061 did not follow a PDO-written mode";
  f.data[0] = 3;  // profile velocity: not supported (0x6502)
  send(f);
  EXPECT_EQ(drive.od().get({0x6060, 0}, true), 8) << "an unsupported mode was stored";
  EXPECT_EQ(drive.od().get({0x6061, 0}, true), 8);
  EXPECT_EQ(drive.rpdo_values_refused(), 1u);
  f.data[0] = 1;  // profile position
  send(f);
  EXPECT_EQ(drive.od().get({0x6061, 0}, true), 1);
}

// Issue 39 (7): EMCY 0x8210 (short RPDO) and 0x8240 (SYNC length) are acknowledged by a fault
// reset: 0x1001 = 0 and EMCY 0x0000.
TEST_F(SlaveTest, FaultResetClearsACommunicationErrorWithEmcy0000) {
  map_rpdo(1, {{{0x6040, 0}, DataType::kU16}, {{0x607A, 0}, DataType::kI32}});
  start();
  send(make_frame(cob::rpdo(1, kNode), 2));  // 2 bytes for a 6-byte mapping
  auto emcy = frames(cob::kEmcy + kNode);
  ASSERT_EQ(emcy.size(), 1u);
  EXPECT_EQ(get_u16(emcy[0].data.data()), 0x8210);
  EXPECT_NE(drive.od().get({0x1001, 0}), 0);
  can::Frame cw = make_frame(cob::rpdo(1, kNode), 6);
  send(cw);  // controlword 0
  put_u16(cw.data.data(), 0x80);
  send(cw);  // fault reset (rising edge of bit 7)
  emcy = frames(cob::kEmcy + kNode);
  ASSERT_EQ(emcy.size(), 2u) << "no EMCY 0x0000 after the fault reset";
  EXPECT_EQ(get_u16(emcy[1].data.data()), 0x0000);
  EXPECT_EQ(drive.od().get({0x1001, 0}), 0) << "0x1001 still shows the communication error";

  sync(1, 1);  // 0x8240, PRE-OPERATIONAL
  ASSERT_EQ(frames(cob::kEmcy + kNode).size(), 3u);
  EXPECT_NE(drive.od().get({0x1001, 0}), 0);
  write<std::uint16_t>({0x6040, 0}, 0x00);
  write<std::uint16_t>({0x6040, 0}, 0x80);
  emcy = frames(cob::kEmcy + kNode);
  ASSERT_EQ(emcy.size(), 4u);
  EXPECT_EQ(get_u16(emcy[3].data.data()), 0x0000);
  EXPECT_EQ(drive.od().get({0x1001, 0}), 0);
  write<std::uint16_t>({0x6040, 0}, 0x00);
  write<std::uint16_t>({0x6040, 0}, 0x80);  // nothing pending: no further EMCY
  EXPECT_EQ(frames(cob::kEmcy + kNode).size(), 4u);
}

// Issue 39 (7): after power-on the drive is SWITCH_ON_DISABLED in PRE-OPERATIONAL, before any
// SYNC (CiA 402 transition 1 is the drive's own).
TEST_F(SlaveTest, StatuswordIsSwitchOnDisabledInPreOperationalBeforeAnySync) {
  wait(5ms);
  ASSERT_EQ(drive.nmt_state(), NmtState::kPreOperational);
  EXPECT_EQ(drive.syncs(), 0u);
  auto sw = sdo.read<std::uint16_t>({0x6041, 0}, pump);
  ASSERT_TRUE(sw.ok()) << sw.status().to_string();
  EXPECT_EQ(cia402::decode_state(*sw), cia402::State::kSwitchOnDisabled);
}

// Issue 39 (7): the heartbeat keeps its period on average although the node is stepped late
// (every 3 ms here, so a due time is missed by up to 3 ms).
TEST_F(SlaveTest, HeartbeatPeriodIsExactWhenStepsComeLate) {
  write<std::uint16_t>({0x1017, 0}, 100);
  seen.clear();
  for (int i = 0; i < 2100 / 3; ++i) {
    net.clock().advance(3ms);
    net.step_slaves();
    collect();
  }
  const auto t = times(cob::kHeartbeat + kNode);
  ASSERT_GE(t.size(), 20u);
  const double mean_ms = std::chrono::duration<double, std::milli>(t.back() - t.front()).count() /
                         static_cast<double>(t.size() - 1);
  EXPECT_NEAR(mean_ms, 100.0, 3.0 / static_cast<double>(t.size() - 1) + 1e-9);
  for (std::size_t i = 1; i < t.size(); ++i) {
    EXPECT_LE(t[i] - t[i - 1], 103ms);
    EXPECT_GE(t[i] - t[i - 1], 97ms);
  }
}

TEST(SlaveEds, BuildsTheDictionaryFromTheShippedDriveEds) {
  auto e = eds::Eds::load(CDPR_SOURCE_DIR "/config/eds/cdpr-sim-drive.eds");
  ASSERT_TRUE(e.ok()) << e.status().to_string();
  testing::SimNetwork net;
  auto& drive = net.add<slave::Drive402>(5);
  const Status s = drive.load_eds(*e);
  ASSERT_TRUE(s.ok()) << s.to_string();
  net.power_on();
  auto& od = drive.od();
  // $NODEID resolved, default PDO mappings enabled, identity and mappability from the EDS.
  EXPECT_EQ(od.get({0x1014, 0}), 0x85u);
  EXPECT_EQ(od.get({0x1801, 1}) & cob::kInvalidBit, 0u);
  EXPECT_EQ(od.get({0x1801, 1}) & 0x7FF, cob::tpdo(2, 5));
  EXPECT_GT(od.get({0x1A02, 0}), 0);
  EXPECT_FALSE(od.find({0x1018, 4})->mappable);
  EXPECT_TRUE(od.find({0x6041, 0})->mappable);
  EXPECT_EQ(od.find({0x6041, 0})->access, slave::Access::kRo);
  EXPECT_EQ(od.get({0x6502, 0}), (1u << 0) | (1u << 5) | (1u << 7));
}

TEST(SlaveEds, AnEdsThatLacksAnObjectOfTheModelIsRefused) {
  const char* text =
      "[MandatoryObjects]\nSupportedObjects=1\n1=0x1000\n"
      "[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\n"
      "DefaultValue=0x00020192\n";
  auto e = eds::Eds::parse(text, "tiny.eds");
  ASSERT_TRUE(e.ok()) << e.status().to_string();
  testing::SimNetwork net;
  auto& drive = net.add<slave::Drive402>(5);
  const Status s = drive.load_eds(*e);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("tiny.eds: node 5: the device model needs 0x1001:00"),
            std::string::npos)
      << s.message();
}

}  // namespace
}  // namespace cdpr::canopen
