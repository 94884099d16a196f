#include "cdpr/canopen/cia402.hpp"

#include <gtest/gtest.h>

namespace cdpr::canopen::cia402 {
namespace {

using namespace std::chrono_literals;

TEST(Cia402, DecodesEveryStateFromTheMasks) {
  EXPECT_EQ(decode_state(0x0000), State::kNotReadyToSwitchOn);
  EXPECT_EQ(decode_state(0x0250), State::kSwitchOnDisabled);  // other bits ignored
  EXPECT_EQ(decode_state(0x0231), State::kReadyToSwitchOn);
  EXPECT_EQ(decode_state(0x0233), State::kSwitchedOn);
  EXPECT_EQ(decode_state(0x1637), State::kOperationEnabled);
  EXPECT_EQ(decode_state(0x0017), State::kQuickStopActive);
  EXPECT_EQ(decode_state(0x001F), State::kFaultReactionActive);
  EXPECT_EQ(decode_state(0x0008), State::kFault);
  EXPECT_EQ(decode_state(0x0088), State::kFault);
  EXPECT_EQ(to_string(decode_state(0x0040)), "SWITCH_ON_DISABLED");
}

TEST(Cia402, EveryTransitionOfTheStandard) {
  // (statusword, target) -> controlword
  EXPECT_EQ(next_controlword(0x40, Target::kOperationEnabled, false, 0), cw::kShutdown);  // T2
  EXPECT_EQ(next_controlword(0x21, Target::kOperationEnabled, false, 6), cw::kSwitchOn);  // T3
  EXPECT_EQ(next_controlword(0x23, Target::kOperationEnabled, false, 7),
            cw::kEnableOperation);                                                       // T4
  EXPECT_EQ(next_controlword(0x27, Target::kSwitchedOn, false, 15), cw::kSwitchOn);      // T5
  EXPECT_EQ(next_controlword(0x23, Target::kReadyToSwitchOn, false, 7), cw::kShutdown);  // T6
  EXPECT_EQ(next_controlword(0x21, Target::kSwitchOnDisabled, false, 6),
            cw::kDisableVoltage);                                                         // T7
  EXPECT_EQ(next_controlword(0x21, Target::kQuickStop, false, 6), cw::kQuickStop);        // T7
  EXPECT_EQ(next_controlword(0x27, Target::kReadyToSwitchOn, false, 15), cw::kShutdown);  // T8
  EXPECT_EQ(next_controlword(0x27, Target::kSwitchOnDisabled, false, 15),
            cw::kDisableVoltage);  // T9
  EXPECT_EQ(next_controlword(0x23, Target::kSwitchOnDisabled, false, 7),
            cw::kDisableVoltage);                                                    // T10
  EXPECT_EQ(next_controlword(0x27, Target::kQuickStop, false, 15), cw::kQuickStop);  // T11
  EXPECT_EQ(next_controlword(0x07, Target::kOperationEnabled, false, 2),
            cw::kDisableVoltage);  // T12
  EXPECT_EQ(next_controlword(0x07, Target::kQuickStop, false, 2), cw::kQuickStop);
  EXPECT_EQ(next_controlword(0x0F, Target::kOperationEnabled, true, 0), cw::kDisableVoltage);
  // Fault: hold without reset request; with it, 0x00 then 0x80 (rising edge of bit 7).
  EXPECT_EQ(next_controlword(0x08, Target::kOperationEnabled, false, 15), cw::kDisableVoltage);
  EXPECT_EQ(next_controlword(0x08, Target::kOperationEnabled, true, 15), cw::kDisableVoltage);
  EXPECT_EQ(next_controlword(0x08, Target::kOperationEnabled, true, 0), cw::kFaultReset);
  EXPECT_EQ(next_controlword(0x08, Target::kOperationEnabled, true, 0x80), cw::kDisableVoltage);
  EXPECT_EQ(next_controlword(0x00, Target::kOperationEnabled, false, 0), cw::kDisableVoltage);
  EXPECT_EQ(command_name(0x06), "shutdown");
  EXPECT_EQ(command_name(0x80), "fault reset");
}

TEST(Cia402, SupervisorNamesAStuckDrive) {
  Supervisor sup(4, 500ms);
  sup.request(Target::kOperationEnabled);
  Timestamp t{0};
  std::uint16_t c = 0;
  for (int i = 0; i < 200 && !sup.stuck(); ++i) {
    c = sup.step(0x0040, t);  // never leaves SWITCH_ON_DISABLED
    t += 4ms;
  }
  EXPECT_EQ(c, cw::kShutdown);
  ASSERT_TRUE(sup.stuck());
  EXPECT_EQ(std::string(sup.error().message()),
            "node 4: stuck in SWITCH_ON_DISABLED for 500 ms after shutdown");
  EXPECT_EQ(sup.error().code(), ErrorCode::kTimeout);
}

TEST(Cia402, SupervisorReportsFaultOnceAndResetsWithAnEdge) {
  Supervisor sup(2, 500ms);
  sup.request(Target::kOperationEnabled);
  Timestamp t{0};
  sup.step(0x0027, t);
  EXPECT_TRUE(sup.reached());
  sup.step(0x0008, t += 4ms);
  EXPECT_TRUE(sup.became_faulted());
  EXPECT_NE(sup.error().message().find("node 2: drive in FAULT"), std::string::npos);
  sup.step(0x0008, t += 4ms);
  EXPECT_FALSE(sup.became_faulted());
  // Without a reset request the drive stays in FAULT and is not "stuck".
  for (int i = 0; i < 200; ++i) sup.step(0x0008, t += 4ms);
  EXPECT_FALSE(sup.stuck());
  sup.request_fault_reset();
  EXPECT_EQ(sup.step(0x0008, t += 4ms), cw::kFaultReset);  // previous was 0x00
  EXPECT_EQ(sup.step(0x0008, t += 4ms), cw::kDisableVoltage);
  EXPECT_EQ(sup.step(0x0040, t += 4ms), cw::kShutdown);  // reset done, on to the target
}

}  // namespace
}  // namespace cdpr::canopen::cia402
