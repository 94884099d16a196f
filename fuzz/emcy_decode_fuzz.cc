// The EMCY decoder (canopen::decode_emcy) on arbitrary frames: a frame is accepted exactly when
// it is a data frame of COB-ID 0x81..0xFF with at least one byte, and then it names the sending
// node and carries the frame's bytes (zero-padded).
#include <cstddef>
#include <cstdint>

#include "cdpr/canopen/events.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // Each frame takes 12 bytes: id (2, low 11 bits; 4 with the extended flag), flags, dlc, data.
  while (size >= 12) {
    cdpr::can::Frame f;
    const std::uint8_t flags = data[2];
    f.extended = (flags & 1) != 0;
    f.rtr = (flags & 2) != 0;
    f.error = (flags & 4) != 0;
    f.id = f.extended
               ? (std::uint32_t{data[0]} | std::uint32_t{data[1]} << 8 |
                  static_cast<std::uint32_t>(flags >> 3) << 16) &
                     cdpr::can::kMaxExtendedId
               : (std::uint32_t{data[0]} | std::uint32_t{data[1]} << 8) & cdpr::can::kMaxStandardId;
    f.dlc = static_cast<std::uint8_t>(data[3] % (cdpr::can::kMaxDlc + 1));
    for (std::size_t i = 0; i < 8; ++i) f.data[i] = data[4 + i];
    cdpr::canopen::Emcy e;
    const bool accepted = cdpr::canopen::decode_emcy(f, e);
    const bool is_emcy =
        !f.extended && !f.rtr && !f.error && f.id > 0x80 && f.id <= 0xFF && f.dlc > 0;
    CDPR_FUZZ_CHECK(accepted == is_emcy, "accepted exactly the EMCY frames");
    if (accepted) {
      CDPR_FUZZ_CHECK(e.node == f.id - 0x80, "names the sending node");
      std::uint8_t expected[8] = {};
      for (std::size_t i = 0; i < f.dlc; ++i) expected[i] = f.data[i];
      CDPR_FUZZ_CHECK(e.code == (expected[0] | expected[1] << 8), "error code little endian");
      CDPR_FUZZ_CHECK(e.error_register == expected[2], "error register");
      for (std::size_t i = 0; i < 5; ++i) {
        CDPR_FUZZ_CHECK(e.manufacturer[i] == expected[3 + i], "manufacturer bytes, zero-padded");
      }
    }
    data += 12;
    size -= 12;
  }
  return 0;
}
