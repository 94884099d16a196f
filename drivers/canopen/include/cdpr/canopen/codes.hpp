// Texts for the codes a CANopen peer sends: SDO abort codes (CiA 301, 7.2.4.3.17), emergency error
// codes (CiA 301 table 21 plus the common CiA 402 drive codes) and the error register bits.
// All texts are static; nothing allocates.
#pragma once

#include <cstdint>
#include <span>
#include <string_view>

namespace cdpr::canopen {

// Every abort code of CiA 301. Unknown codes give "unknown abort code".
std::string_view sdo_abort_text(std::uint32_t code);

// All abort codes sdo_abort_text knows (for tests and documentation).
std::span<const std::uint32_t> known_sdo_abort_codes();

namespace abort_code {
inline constexpr std::uint32_t kToggleBit = 0x05030000;
inline constexpr std::uint32_t kTimeout = 0x05040000;
inline constexpr std::uint32_t kCommandSpecifier = 0x05040001;
inline constexpr std::uint32_t kOutOfMemory = 0x05040005;
inline constexpr std::uint32_t kUnsupportedAccess = 0x06010000;
inline constexpr std::uint32_t kWriteOnly = 0x06010001;
inline constexpr std::uint32_t kReadOnly = 0x06010002;
inline constexpr std::uint32_t kNoObject = 0x06020000;
inline constexpr std::uint32_t kNotMappable = 0x06040041;
inline constexpr std::uint32_t kPdoLength = 0x06040042;
inline constexpr std::uint32_t kParamIncompatible = 0x06040043;
inline constexpr std::uint32_t kLengthMismatch = 0x06070010;
inline constexpr std::uint32_t kLengthTooHigh = 0x06070012;
inline constexpr std::uint32_t kLengthTooLow = 0x06070013;
inline constexpr std::uint32_t kNoSubIndex = 0x06090011;
inline constexpr std::uint32_t kValueRange = 0x06090030;
inline constexpr std::uint32_t kValueTooHigh = 0x06090031;
inline constexpr std::uint32_t kValueTooLow = 0x06090032;
inline constexpr std::uint32_t kGeneral = 0x08000000;
inline constexpr std::uint32_t kDeviceState = 0x08000022;
}  // namespace abort_code

// Text of an emergency error code: the exact code when known, else its class ("current", ...).
std::string_view emcy_code_text(std::uint16_t code);

// Names of the set bits of the error register (0x1001), e.g. "generic,current"; writes into `out`
// (no allocation) and returns the written view.
std::string_view error_register_text(std::uint8_t reg, std::span<char> out);

}  // namespace cdpr::canopen
