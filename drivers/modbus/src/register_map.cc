#include "cdpr/modbus/register_map.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>

namespace cdpr::modbus {

std::string_view to_string(RegisterTable t) {
  return t == RegisterTable::kHolding ? "holding" : "input";
}

std::string_view to_string(ValueType t) {
  switch (t) {
    case ValueType::kU16:
      return "u16";
    case ValueType::kI16:
      return "i16";
    case ValueType::kU32:
      return "u32";
    case ValueType::kI32:
      return "i32";
    case ValueType::kF32:
      return "f32";
  }
  return "?";
}

std::string_view order_name(WordOrder w, ByteOrder b) {
  if (w == WordOrder::kHighFirst) return b == ByteOrder::kBig ? "ABCD" : "BADC";
  return b == ByteOrder::kBig ? "CDAB" : "DCBA";
}

std::string_view to_string(ReadingStatus s) {
  switch (s) {
    case ReadingStatus::kNone:
      return "none";
    case ReadingStatus::kOk:
      return "ok";
    case ReadingStatus::kNoTarget:
      return "no target";
    case ReadingStatus::kOutOfRange:
      return "out of range";
    case ReadingStatus::kSensorError:
      return "sensor error";
    case ReadingStatus::kTimeout:
      return "timeout";
    case ReadingStatus::kCommError:
      return "communication error";
  }
  return "?";
}

namespace {

std::uint16_t swap_bytes(std::uint16_t v) {
  return static_cast<std::uint16_t>(((v & 0x00FFu) << 8) | ((v & 0xFF00u) >> 8));
}

// The 16-bit word as the value sees it (register bytes put in value order).
std::uint16_t word(std::uint16_t reg, ByteOrder bytes) {
  return bytes == ByteOrder::kBig ? reg : swap_bytes(reg);
}

std::uint32_t join32(std::span<const std::uint16_t> regs, WordOrder words, ByteOrder bytes) {
  const std::uint32_t w0 = word(regs[0], bytes);
  const std::uint32_t w1 = word(regs[1], bytes);
  return words == WordOrder::kHighFirst ? ((w0 << 16) | w1) : ((w1 << 16) | w0);
}

void split32(std::uint32_t v, WordOrder words, ByteOrder bytes, std::span<std::uint16_t> regs) {
  const auto hi = static_cast<std::uint16_t>(v >> 16);
  const auto lo = static_cast<std::uint16_t>(v & 0xFFFFu);
  regs[0] = word(words == WordOrder::kHighFirst ? hi : lo, bytes);
  regs[1] = word(words == WordOrder::kHighFirst ? lo : hi, bytes);
}

bool contains(const std::vector<double>& values, double raw) {
  return std::find(values.begin(), values.end(), raw) != values.end();
}

bool contains16(const std::vector<std::uint16_t>& values, std::uint16_t v) {
  return std::find(values.begin(), values.end(), v) != values.end();
}

}  // namespace

double decode_raw(std::span<const std::uint16_t> regs, ValueType type, WordOrder words,
                  ByteOrder bytes) {
  switch (type) {
    case ValueType::kU16:
      return static_cast<double>(word(regs[0], bytes));
    case ValueType::kI16:
      return static_cast<double>(std::bit_cast<std::int16_t>(word(regs[0], bytes)));
    case ValueType::kU32:
      return static_cast<double>(join32(regs, words, bytes));
    case ValueType::kI32:
      return static_cast<double>(std::bit_cast<std::int32_t>(join32(regs, words, bytes)));
    case ValueType::kF32:
      return static_cast<double>(std::bit_cast<float>(join32(regs, words, bytes)));
  }
  return 0.0;
}

void encode_raw(double raw, ValueType type, WordOrder words, ByteOrder bytes,
                std::span<std::uint16_t> regs) {
  switch (type) {
    case ValueType::kU16:
      regs[0] = word(static_cast<std::uint16_t>(std::lround(raw)), bytes);
      break;
    case ValueType::kI16:
      regs[0] =
          word(std::bit_cast<std::uint16_t>(static_cast<std::int16_t>(std::lround(raw))), bytes);
      break;
    case ValueType::kU32:
      split32(static_cast<std::uint32_t>(std::llround(raw)), words, bytes, regs);
      break;
    case ValueType::kI32:
      split32(std::bit_cast<std::uint32_t>(static_cast<std::int32_t>(std::llround(raw))), words,
              bytes, regs);
      break;
    case ValueType::kF32:
      split32(std::bit_cast<std::uint32_t>(static_cast<float>(raw)), words, bytes, regs);
      break;
  }
}

std::uint16_t RegisterMap::block_start() const {
  if (read_start) return *read_start;
  if (quality && quality->address < address && address - quality->address <= 8) {
    return quality->address;
  }
  return address;
}

std::uint16_t RegisterMap::block_count() const {
  if (read_count) return *read_count;
  const int start = block_start();
  int end = address + register_count(type);  // one past the last register
  if (quality && quality->address >= start && quality->address + 1 - start <= 10) {
    end = std::max(end, quality->address + 1);
  }
  return static_cast<std::uint16_t>(end - start);
}

bool RegisterMap::quality_in_block() const {
  if (!quality) return false;
  const int start = block_start();
  return quality->address >= start && quality->address < start + block_count();
}

double RegisterMap::resolution_m() const {
  return type == ValueType::kF32 ? 0.0 : std::fabs(scale);
}

Status RegisterMap::validate() const {
  const char* n = name.c_str();
  if (address_base != 0 && address_base != 1) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': address_base is %d, must be 0 or 1", n, address_base);
  }
  if (address < address_base) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': value.register %u is below address_base %d", n,
                         address, address_base);
  }
  if (!std::isfinite(scale) || scale == 0.0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': value.scale must be finite and non-zero", n);
  }
  if (!std::isfinite(offset)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': value.offset must be finite", n);
  }
  if (!std::isfinite(min_m) || !std::isfinite(max_m) || !(min_m < max_m)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': range needs finite min < max (got %g, %g)", n, min_m,
                         max_m);
  }
  const int start = block_start();
  const int count = block_count();
  if (start < address_base) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': read.start %d is below address_base %d", n, start,
                         address_base);
  }
  if (count < 1 || count > 125) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': read.count %d must be 1..125 (Modbus limit)", n,
                         count);
  }
  if (start - address_base + count > 65536) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': read block runs past register 65535", n);
  }
  if (address < start || address + register_count(type) > start + count) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "register map '%s': value.register %u (%d registers) is not inside the "
                         "read block %d..%d",
                         n, address, register_count(type), start, start + count - 1);
  }
  if (quality) {
    if (quality->address < address_base) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "register map '%s': quality.register %u is below address_base %d", n,
                           quality->address, address_base);
    }
    if (quality->ok_values.empty()) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "register map '%s': quality.ok must list at least one value", n);
    }
  }
  if (trigger) {
    if (trigger->address < address_base) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "register map '%s': trigger.register %u is below address_base %d", n,
                           trigger->address, address_base);
    }
    if (!std::isfinite(trigger->settle_s) || trigger->settle_s < 0.0 || trigger->settle_s > 1.0) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "register map '%s': trigger.settle must be 0..1 s", n);
    }
  }
  return Status::success();
}

Interpretation interpret(const RegisterMap& map, std::span<const std::uint16_t> block,
                         std::optional<std::uint16_t> quality) {
  Interpretation out;
  const char* n = map.name.c_str();
  const int offset = map.address - map.block_start();
  if (offset < 0 || block.size() < static_cast<std::size_t>(offset + register_count(map.type))) {
    out.status = ReadingStatus::kCommError;
    out.detail = Status::error(ErrorCode::kInternal,
                               "laser '%s': answer has %zu registers, value needs %d at offset %d",
                               n, block.size(), register_count(map.type), offset);
    return out;
  }
  out.raw = decode_raw(block.subspan(static_cast<std::size_t>(offset)), map.type, map.word_order,
                       map.byte_order);
  // Integers print exactly, floats short.
  std::array<char, 32> raw_text{};
  if (map.type == ValueType::kF32) {
    std::snprintf(raw_text.data(), raw_text.size(), "%g", out.raw);
  } else {
    std::snprintf(raw_text.data(), raw_text.size(), "%.0f", out.raw);
  }

  if (map.quality) {
    if (map.quality_in_block()) {
      quality = block[static_cast<std::size_t>(map.quality->address - map.block_start())];
    }
    if (quality) {
      out.quality = quality;
      const auto q = static_cast<std::uint16_t>(*quality & map.quality->mask);
      if (!contains16(map.quality->ok_values, q)) {
        const bool nt = contains16(map.quality->no_target_values, q);
        out.status = nt ? ReadingStatus::kNoTarget : ReadingStatus::kSensorError;
        out.detail =
            Status::error(nt ? ErrorCode::kUnavailable : ErrorCode::kProtocolError,
                          "laser '%s' quality register %u = 0x%04X (masked 0x%04X): %s", n,
                          map.quality->address, *quality, q, nt ? "no target" : "sensor error");
        return out;
      }
    }
  }
  if (contains(map.error_raw, out.raw)) {
    out.status = ReadingStatus::kSensorError;
    out.detail = Status::error(ErrorCode::kProtocolError,
                               "laser '%s' register %u: raw %s is the error value", n, map.address,
                               raw_text.data());
    return out;
  }
  if (contains(map.no_target_raw, out.raw)) {
    out.status = ReadingStatus::kNoTarget;
    out.detail = Status::error(ErrorCode::kUnavailable,
                               "laser '%s' register %u: raw %s is the no-target value", n,
                               map.address, raw_text.data());
    return out;
  }
  if (!std::isfinite(out.raw)) {
    out.status = ReadingStatus::kSensorError;
    out.detail =
        Status::error(ErrorCode::kProtocolError,
                      "laser '%s' register %u: value is not a finite number", n, map.address);
    return out;
  }
  out.distance_m = out.raw * map.scale + map.offset;
  if (out.distance_m < map.min_m || out.distance_m > map.max_m) {
    out.status = ReadingStatus::kOutOfRange;
    out.detail = Status::error(ErrorCode::kOutOfRange,
                               "laser '%s' register %u: %.6f m is outside the valid range "
                               "[%g, %g] m",
                               n, map.address, out.distance_m, map.min_m, map.max_m);
    return out;
  }
  out.status = ReadingStatus::kOk;
  return out;
}

}  // namespace cdpr::modbus
