#include "cdpr/canopen/codes.hpp"

#include <array>
#include <cstring>

namespace cdpr::canopen {
namespace {

struct AbortEntry {
  std::uint32_t code;
  std::string_view text;
};

constexpr std::array kAbortTable{
    AbortEntry{0x05030000, "toggle bit not alternated"},
    AbortEntry{0x05040000, "SDO protocol timed out"},
    AbortEntry{0x05040001, "client/server command specifier not valid or unknown"},
    AbortEntry{0x05040002, "invalid block size (block mode only)"},
    AbortEntry{0x05040003, "invalid sequence number (block mode only)"},
    AbortEntry{0x05040004, "CRC error (block mode only)"},
    AbortEntry{0x05040005, "out of memory"},
    AbortEntry{0x06010000, "unsupported access to an object"},
    AbortEntry{0x06010001, "attempt to read a write only object"},
    AbortEntry{0x06010002, "attempt to write a read only object"},
    AbortEntry{0x06020000, "object does not exist in the object dictionary"},
    AbortEntry{0x06040041, "object cannot be mapped to the PDO"},
    AbortEntry{0x06040042,
               "the number and length of the objects to be mapped would exceed PDO length"},
    AbortEntry{0x06040043, "general parameter incompatibility reason"},
    AbortEntry{0x06040047, "general internal incompatibility in the device"},
    AbortEntry{0x06060000, "access failed due to a hardware error"},
    AbortEntry{0x06070010, "data type does not match, length of service parameter does not match"},
    AbortEntry{0x06070012, "data type does not match, length of service parameter too high"},
    AbortEntry{0x06070013, "data type does not match, length of service parameter too low"},
    AbortEntry{0x06090011, "sub-index does not exist"},
    AbortEntry{0x06090030, "value range of parameter exceeded"},
    AbortEntry{0x06090031, "value of parameter written too high"},
    AbortEntry{0x06090032, "value of parameter written too low"},
    AbortEntry{0x06090036, "maximum value is less than minimum value"},
    AbortEntry{0x060A0023, "resource not available: SDO connection"},
    AbortEntry{0x08000000, "general error"},
    AbortEntry{0x08000020, "data cannot be transferred or stored to the application"},
    AbortEntry{0x08000021,
               "data cannot be transferred or stored to the application because of local control"},
    AbortEntry{0x08000022,
               "data cannot be transferred or stored to the application because of the present "
               "device state"},
    AbortEntry{0x08000023,
               "object dictionary dynamic generation fails or no object dictionary is present"},
    AbortEntry{0x08000024, "no data available"},
};

constexpr std::array<std::uint32_t, kAbortTable.size()> make_codes() {
  std::array<std::uint32_t, kAbortTable.size()> c{};
  for (std::size_t i = 0; i < kAbortTable.size(); ++i) c[i] = kAbortTable[i].code;
  return c;
}
constexpr auto kAbortCodes = make_codes();

struct EmcyEntry {
  std::uint16_t code;
  std::string_view text;
};

// Exact codes first (CiA 301 table 21, CiA 402 drive codes); the class fallback is below.
constexpr std::array kEmcyTable{
    EmcyEntry{0x0000, "error reset or no error"},
    EmcyEntry{0x1000, "generic error"},
    EmcyEntry{0x2000, "current"},
    EmcyEntry{0x2100, "current, device input side"},
    EmcyEntry{0x2200, "current inside the device"},
    EmcyEntry{0x2300, "current, device output side"},
    EmcyEntry{0x2310, "continuous over-current"},
    EmcyEntry{0x2320, "short circuit / earth leakage"},
    EmcyEntry{0x2330, "earth leakage"},
    EmcyEntry{0x2340, "short circuit"},
    EmcyEntry{0x3000, "voltage"},
    EmcyEntry{0x3100, "mains voltage"},
    EmcyEntry{0x3110, "mains over-voltage"},
    EmcyEntry{0x3120, "mains under-voltage"},
    EmcyEntry{0x3200, "voltage inside the device"},
    EmcyEntry{0x3210, "DC link over-voltage"},
    EmcyEntry{0x3220, "DC link under-voltage"},
    EmcyEntry{0x3300, "output voltage"},
    EmcyEntry{0x4000, "temperature"},
    EmcyEntry{0x4100, "ambient temperature"},
    EmcyEntry{0x4200, "device temperature"},
    EmcyEntry{0x4210, "excess temperature device"},
    EmcyEntry{0x4300, "drive temperature"},
    EmcyEntry{0x4310, "excess temperature drive"},
    EmcyEntry{0x5000, "device hardware"},
    EmcyEntry{0x5100, "supply"},
    EmcyEntry{0x5400, "power section"},
    EmcyEntry{0x5500, "data storage"},
    EmcyEntry{0x6000, "device software"},
    EmcyEntry{0x6100, "internal software"},
    EmcyEntry{0x6200, "user software"},
    EmcyEntry{0x6300, "data set"},
    EmcyEntry{0x6320, "parameter error"},
    EmcyEntry{0x7000, "additional modules"},
    EmcyEntry{0x7100, "power"},
    EmcyEntry{0x7121, "motor blocked"},
    EmcyEntry{0x7300, "sensor"},
    EmcyEntry{0x7305, "incremental sensor 1 fault"},
    EmcyEntry{0x7310, "speed"},
    EmcyEntry{0x7320, "position"},
    EmcyEntry{0x8000, "monitoring"},
    EmcyEntry{0x8100, "communication"},
    EmcyEntry{0x8110, "CAN overrun (objects lost)"},
    EmcyEntry{0x8120, "CAN in error passive mode"},
    EmcyEntry{0x8130, "life guard error or heartbeat error"},
    EmcyEntry{0x8140, "recovered from bus off"},
    EmcyEntry{0x8150, "CAN-ID collision"},
    EmcyEntry{0x8200, "protocol error"},
    EmcyEntry{0x8210, "PDO not processed due to length error"},
    EmcyEntry{0x8220, "PDO length exceeded"},
    EmcyEntry{0x8230, "DAM MPDO not processed, destination object not available"},
    EmcyEntry{0x8240, "unexpected SYNC data length"},
    EmcyEntry{0x8250, "RPDO timeout"},
    EmcyEntry{0x8400, "velocity speed controller"},
    EmcyEntry{0x8500, "position controller"},
    EmcyEntry{0x8611, "following error"},
    EmcyEntry{0x8612, "reference limit"},
    EmcyEntry{0x9000, "external error"},
    EmcyEntry{0xF000, "additional functions"},
    EmcyEntry{0xFF00, "device specific"},
};

}  // namespace

std::string_view sdo_abort_text(std::uint32_t code) {
  for (const auto& e : kAbortTable) {
    if (e.code == code) return e.text;
  }
  return "unknown abort code";
}

std::span<const std::uint32_t> known_sdo_abort_codes() {
  return kAbortCodes;
}

std::string_view emcy_code_text(std::uint16_t code) {
  for (const auto& e : kEmcyTable) {
    if (e.code == code) return e.text;
  }
  // Fall back to the sub-class (xx00), then the class (x000): codes are hierarchical.
  const std::uint16_t sub = code & 0xFF00;
  const std::uint16_t cls = code & 0xF000;
  if (sub == 0xFF00) return "device specific";
  for (const auto& e : kEmcyTable) {
    if (e.code == sub) return e.text;
  }
  for (const auto& e : kEmcyTable) {
    if (e.code == cls) return e.text;
  }
  return "unknown error code";
}

std::string_view error_register_text(std::uint8_t reg, std::span<char> out) {
  static constexpr std::array<std::string_view, 8> kBits{
      "generic",       "current",        "voltage",  "temperature",
      "communication", "device profile", "reserved", "manufacturer"};
  std::size_t n = 0;
  for (int b = 0; b < 8; ++b) {
    if ((reg & (1u << b)) == 0) continue;
    const std::string_view name = kBits[static_cast<std::size_t>(b)];
    const std::size_t need = name.size() + (n > 0 ? 1 : 0);
    if (n + need > out.size()) break;
    if (n > 0) out[n++] = ',';
    std::memcpy(out.data() + n, name.data(), name.size());
    n += name.size();
  }
  return {out.data(), n};
}

}  // namespace cdpr::canopen
