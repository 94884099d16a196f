// Where and how a laser distance sensor publishes its distance over Modbus.
//
// Real sensors differ in register table (input or holding), address numbering (0-based PDU
// addresses or vendor numbers from 1), value type, word order, byte order, unit and sentinels. A
// RegisterMap captures all of that; it is normally read from config/lasers/*.yaml (see
// docs/modbus-laser.md for the fields). Decoding is done here, word by word and byte by byte, not
// with libmodbus's float helpers.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::modbus {

// `context` + the message of `s`, same code (an ok Status stays ok). Allocates: not for the RT
// loop. (Status::prepend trips GCC's -Wformat-truncation under -Werror.)
inline Status with_context(std::string_view context, const Status& s) {
  if (s.ok()) return s;
  std::string m(context);
  m += s.message();
  return Status(s.code(), m);
}

enum class RegisterTable : std::uint8_t { kHolding, kInput };
enum class ValueType : std::uint8_t { kU16, kI16, kU32, kI32, kF32 };
// Order of the 16-bit registers of a 32-bit value: high word at the lower address, or low word.
enum class WordOrder : std::uint8_t { kHighFirst, kLowFirst };
// Order of the two bytes inside each register as sent on the wire: big endian (Modbus standard,
// high byte first) or little endian (swapped).
enum class ByteOrder : std::uint8_t { kBig, kLittle };

std::string_view to_string(RegisterTable t);
std::string_view to_string(ValueType t);
// Combined notation: ABCD (high word first, big), CDAB (low word first, big), BADC (high word
// first, little), DCBA (low word first, little). A, B, C, D are the bytes of the value, most
// significant first, in the order they appear on the wire.
std::string_view order_name(WordOrder w, ByteOrder b);

// Number of 16-bit registers a value of this type occupies.
constexpr int register_count(ValueType t) {
  return (t == ValueType::kU16 || t == ValueType::kI16) ? 1 : 2;
}

// The raw value of `type` held in regs[0..register_count(type)) (register values as libmodbus
// returns them: the first byte on the wire in bits 15..8). u32 and i32 are exact in a double.
double decode_raw(std::span<const std::uint16_t> regs, ValueType type, WordOrder words,
                  ByteOrder bytes);
// The inverse (used by tests and the simulator): registers that decode_raw maps back to raw.
// raw must be representable in `type` (integers are rounded, f32 is narrowed).
void encode_raw(double raw, ValueType type, WordOrder words, ByteOrder bytes,
                std::span<std::uint16_t> regs);

// What a reading means.
enum class ReadingStatus : std::uint8_t {
  kNone,         // nothing read yet
  kOk,           // a valid distance
  kNoTarget,     // the sensor says it sees no target (sentinel value or quality register)
  kOutOfRange,   // a number outside the map's valid range
  kSensorError,  // the sensor reports an error (sentinel, quality register, NaN)
  kTimeout,      // no answer in time
  kCommError,    // CRC error, exception, I/O error, not connected, ...
};
std::string_view to_string(ReadingStatus s);

struct QualityRegister {
  std::uint16_t address = 0;  // as documented (address_base applies)
  std::uint16_t mask = 0xFFFF;
  std::vector<std::uint16_t> ok_values;         // (value & mask) in here: reading is valid
  std::vector<std::uint16_t> no_target_values;  // in here: no target; anything else: sensor error
};

struct TriggerWrite {
  std::uint16_t address = 0;  // holding register, as documented (address_base applies)
  std::uint16_t value = 1;
  double settle_s = 0.0;  // wait after the write before reading
};

struct RegisterMap {
  std::string name;    // short name, used in messages
  std::string source;  // what documentation or assumption the map rests on
  RegisterTable table = RegisterTable::kInput;
  int address_base = 0;  // 0: addresses are PDU addresses; 1: vendor numbers, 1 = PDU address 0
  std::uint16_t address = 0;  // of the distance value, as documented
  ValueType type = ValueType::kU16;
  WordOrder word_order = WordOrder::kHighFirst;
  ByteOrder byte_order = ByteOrder::kBig;
  double scale = 1e-3;  // metres per raw unit
  double offset = 0.0;  // metres, added after scaling
  double min_m = 0.0;   // valid range, metres (inclusive)
  double max_m = 1e3;
  std::vector<double> no_target_raw;  // raw values meaning "no target"
  std::vector<double> error_raw;      // raw values meaning "sensor error"
  std::optional<QualityRegister> quality;
  std::optional<TriggerWrite> trigger;
  // One read request [read_start, read_start + read_count) (documented addresses). When not set
  // the request covers the distance value only, plus the quality register if it is adjacent.
  std::optional<std::uint16_t> read_start;
  std::optional<std::uint16_t> read_count;

  // Internal consistency (register inside the block, base 0 or 1, finite scale, min < max, ...).
  Status validate() const;

  // PDU address of a documented address.
  std::uint16_t pdu(std::uint16_t documented) const {
    return static_cast<std::uint16_t>(documented - address_base);
  }
  // The request to send: documented start and count (after defaults).
  std::uint16_t block_start() const;
  std::uint16_t block_count() const;
  // Whether the quality register lies inside the read block (else it needs its own request).
  bool quality_in_block() const;
  // One raw unit in metres (for integer types), 0 for f32: the floor of outlier rejection.
  double resolution_m() const;
};

// The meaning of one answer.
struct Interpretation {
  ReadingStatus status = ReadingStatus::kNone;
  double distance_m = 0.0;  // scaled value (also set when out of range)
  double raw = 0.0;
  std::optional<std::uint16_t> quality;
  Status detail;  // why the status is not ok (names the value)
};

// Interprets a block read at block_start() with block_count() registers. `quality` is the quality
// register when it was read separately (ignored when it lies in the block).
Interpretation interpret(const RegisterMap& map, std::span<const std::uint16_t> block,
                         std::optional<std::uint16_t> quality = std::nullopt);

// Reads a register map from YAML text; `file` names it in errors ("file:line: field: reason").
Result<RegisterMap> parse_register_map(std::string_view yaml_text, std::string_view file);
Result<RegisterMap> load_register_map(const std::string& path);

}  // namespace cdpr::modbus
