#include "cdpr/modbus/modbus_link.hpp"

#include <modbus/modbus.h>

#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace cdpr::modbus {

namespace {

// libmodbus takes timeouts as seconds + microseconds.
void split_seconds(double s, std::uint32_t& sec, std::uint32_t& usec) {
  const double us_total = std::round(s * 1e6);
  sec = static_cast<std::uint32_t>(us_total / 1e6);
  usec = static_cast<std::uint32_t>(us_total - static_cast<double>(sec) * 1e6);
  if (usec >= 1000000u) usec = 999999u;
}

bool is_exception(int err) {
  return err >= EMBXILFUN && err <= EMBXGTAR;
}

}  // namespace

std::string_view exception_text(int code) {
  switch (code) {
    case 1:
      return "illegal function";
    case 2:
      return "illegal data address";
    case 3:
      return "illegal data value";
    case 4:
      return "slave device failure";
    case 5:
      return "acknowledge";
    case 6:
      return "slave device busy";
    case 7:
      return "negative acknowledge";
    case 8:
      return "memory parity error";
    case 10:
      return "gateway path unavailable";
    case 11:
      return "gateway target device failed to respond";
    default:
      return "unknown exception";
  }
}

Status LinkConfig::validate() const {
  if (const auto* rtu = std::get_if<RtuSettings>(&transport)) {
    if (rtu->device.empty()) {
      return Status(ErrorCode::kInvalidArgument, "modbus RTU: device is empty");
    }
    if (rtu->baud <= 0 || rtu->baud > 4000000) {
      return Status::error(ErrorCode::kInvalidArgument, "modbus RTU %s: baud %d is not valid",
                           rtu->device.c_str(), rtu->baud);
    }
    if (rtu->parity != 'N' && rtu->parity != 'E' && rtu->parity != 'O') {
      return Status::error(ErrorCode::kInvalidArgument, "modbus RTU %s: parity must be N, E or O",
                           rtu->device.c_str());
    }
    if (rtu->data_bits < 5 || rtu->data_bits > 8) {
      return Status::error(ErrorCode::kInvalidArgument, "modbus RTU %s: data bits %d not 5..8",
                           rtu->device.c_str(), rtu->data_bits);
    }
    if (rtu->stop_bits != 1 && rtu->stop_bits != 2) {
      return Status::error(ErrorCode::kInvalidArgument, "modbus RTU %s: stop bits %d not 1 or 2",
                           rtu->device.c_str(), rtu->stop_bits);
    }
    if (slave_id < 1 || slave_id > 247) {
      return Status::error(ErrorCode::kInvalidArgument, "modbus RTU %s: slave id %d is not 1..247",
                           rtu->device.c_str(), slave_id);
    }
  } else {
    const auto& tcp = std::get<TcpSettings>(transport);
    if (tcp.host.empty()) return Status(ErrorCode::kInvalidArgument, "modbus TCP: host is empty");
    if (tcp.port < 1 || tcp.port > 65535) {
      return Status::error(ErrorCode::kInvalidArgument, "modbus TCP %s: port %d not 1..65535",
                           tcp.host.c_str(), tcp.port);
    }
    if (slave_id < 0 || slave_id > 255) {
      return Status::error(ErrorCode::kInvalidArgument, "modbus TCP %s: unit id %d not 0..255",
                           tcp.host.c_str(), slave_id);
    }
  }
  if (!(response_timeout_s >= 0.001 && response_timeout_s <= 10.0)) {
    return Status(ErrorCode::kInvalidArgument, "modbus: response_timeout must be 0.001..10 s");
  }
  if (!(byte_timeout_s >= 0.0001 && byte_timeout_s <= 10.0)) {
    return Status(ErrorCode::kInvalidArgument, "modbus: byte_timeout must be 0.0001..10 s");
  }
  if (retries < 0 || retries > 10) {
    return Status(ErrorCode::kInvalidArgument, "modbus: retries must be 0..10");
  }
  if (!(reconnect_delay_s >= 0.0 && reconnect_delay_s <= 60.0)) {
    return Status(ErrorCode::kInvalidArgument, "modbus: reconnect_delay must be 0..60 s");
  }
  return Status::success();
}

ModbusLink::ModbusLink(LinkConfig config) : config_(std::move(config)) {
  std::array<char, 200> d{};
  if (const auto* rtu = std::get_if<RtuSettings>(&config_.transport)) {
    std::snprintf(d.data(), d.size(), "RTU %s slave %d", rtu->device.c_str(), config_.slave_id);
  } else {
    const auto& tcp = std::get<TcpSettings>(config_.transport);
    std::snprintf(d.data(), d.size(), "TCP %s:%d unit %d", tcp.host.c_str(), tcp.port,
                  config_.slave_id);
  }
  description_ = d.data();
}

ModbusLink::~ModbusLink() {
  close();
}

void ModbusLink::close() {
  if (ctx_ != nullptr) {
    if (connected_) modbus_close(ctx_);
    modbus_free(ctx_);
    ctx_ = nullptr;
  }
  connected_ = false;
}

Status ModbusLink::connect() {
  close();
  warnings_.clear();
  CDPR_RETURN_IF_ERROR(config_.validate());
  const auto* rtu = std::get_if<RtuSettings>(&config_.transport);
  if (rtu != nullptr) {
    ctx_ =
        modbus_new_rtu(rtu->device.c_str(), rtu->baud, rtu->parity, rtu->data_bits, rtu->stop_bits);
  } else {
    const auto& tcp = std::get<TcpSettings>(config_.transport);
    const std::string service = std::to_string(tcp.port);
    ctx_ = modbus_new_tcp_pi(tcp.host.c_str(), service.c_str());
  }
  if (ctx_ == nullptr) {
    const int err = errno;
    return Status::error(ErrorCode::kInvalidArgument, "%s: cannot create the context: %s",
                         description_.c_str(), modbus_strerror(err));
  }
  std::uint32_t sec = 0;
  std::uint32_t usec = 0;
  split_seconds(config_.response_timeout_s, sec, usec);
  modbus_set_response_timeout(ctx_, sec, usec);
  split_seconds(config_.byte_timeout_s, sec, usec);
  modbus_set_byte_timeout(ctx_, sec, usec);
  modbus_set_error_recovery(ctx_, MODBUS_ERROR_RECOVERY_NONE);
  if (modbus_set_slave(ctx_, config_.slave_id) != 0) {
    const int err = errno;
    close();
    return Status::error(ErrorCode::kInvalidArgument, "%s: slave id rejected: %s",
                         description_.c_str(), modbus_strerror(err));
  }
  if (modbus_connect(ctx_) != 0) {
    const int err = errno;
    close();
    const ErrorCode code = err == ENOENT                              ? ErrorCode::kNotFound
                           : (err == ETIMEDOUT || err == EINPROGRESS) ? ErrorCode::kTimeout
                           : err == ECONNREFUSED                      ? ErrorCode::kUnavailable
                                                                      : ErrorCode::kIoError;
    return Status::error(code, "%s: cannot connect: %s (errno %d)", description_.c_str(),
                         modbus_strerror(err), err);
  }
  connected_ = true;
  ++counters_.connects;
  if (rtu != nullptr && rtu->rs485) {
    if (modbus_rtu_set_serial_mode(ctx_, MODBUS_RTU_RS485) != 0) {
      // A pty or a plain UART has no RS-485 mode (ENOTTY): the adapter then switches direction
      // itself or the line is RS-232/USB. Record it and carry on.
      const int err = errno;
      std::array<char, 200> w{};
      std::snprintf(w.data(), w.size(),
                    "%s: RS-485 mode not available (%s, errno %d); using the line as it is",
                    description_.c_str(), std::strerror(err), err);
      warnings_.emplace_back(w.data());
    }
  }
  modbus_flush(ctx_);
  return Status::success();
}

Status ModbusLink::failure(int err, const char* what, int tries) {
  const char* d = description_.c_str();
  if (err == ETIMEDOUT) {
    ++counters_.timeouts;
    return Status::error(ErrorCode::kTimeout,
                         "%s: %s: no answer from slave %d within %.0f ms (%d tries): wrong slave "
                         "id, wiring, baud rate or parity?",
                         d, what, config_.slave_id, config_.response_timeout_s * 1e3, tries);
  }
  if (err == EMBBADCRC) {
    ++counters_.crc_errors;
    return Status::error(ErrorCode::kProtocolError, "%s: %s: CRC error in the answer (%d tries)", d,
                         what, tries);
  }
  if (is_exception(err)) {
    ++counters_.exceptions;
    const int code = err - MODBUS_ENOBASE;
    const std::string_view text = exception_text(code);
    return Status::error(ErrorCode::kAborted, "%s: %s: Modbus exception %d (%.*s)", d, what, code,
                         static_cast<int>(text.size()), text.data());
  }
  ++counters_.other_errors;
  if (err == EMBBADSLAVE || err == EMBBADDATA || err == EMBBADEXC || err == EMBUNKEXC ||
      err == EMBMDATA) {
    return Status::error(ErrorCode::kProtocolError, "%s: %s: %s (%d tries)", d, what,
                         modbus_strerror(err), tries);
  }
  return Status::error(ErrorCode::kIoError, "%s: %s: %s (errno %d)", d, what, modbus_strerror(err),
                       err);
}

Status ModbusLink::read_registers(RegisterTable table, std::uint16_t pdu_address,
                                  std::span<std::uint16_t> out) {
  std::array<char, 80> what{};
  const int count = static_cast<int>(out.size());
  std::snprintf(what.data(), what.size(), "read %d %s register%s at PDU address %u", count,
                table == RegisterTable::kInput ? "input" : "holding", count == 1 ? "" : "s",
                pdu_address);
  if (count < 1 || count > MODBUS_MAX_READ_REGISTERS || pdu_address + count > 65536) {
    return Status::error(ErrorCode::kInvalidArgument, "%s: %s: count must be 1..125 within 65535",
                         description_.c_str(), what.data());
  }
  if (!connected_) {
    return Status::error(ErrorCode::kUnavailable, "%s: %s: not connected", description_.c_str(),
                         what.data());
  }
  int err = 0;
  int tries = 0;
  for (int attempt = 0; attempt <= config_.retries; ++attempt) {
    ++tries;
    if (attempt > 0) ++counters_.retries;
    const int n = table == RegisterTable::kInput
                      ? modbus_read_input_registers(ctx_, pdu_address, count, out.data())
                      : modbus_read_registers(ctx_, pdu_address, count, out.data());
    if (n == count) {
      ++counters_.requests;
      return Status::success();
    }
    err = n < 0 ? errno : EMBBADDATA;
    if (is_exception(err)) break;  // the slave answered; asking again changes nothing
    const bool transient = err == ETIMEDOUT || err == EMBBADCRC || err == EMBBADSLAVE ||
                           err == EMBBADDATA || err == EMBBADEXC || err == EMBUNKEXC;
    modbus_flush(ctx_);  // drop a late or partial answer before the next request
    if (!transient) {
      Status s = failure(err, what.data(), tries);
      close();  // I/O error: the caller reconnects
      return s;
    }
  }
  return failure(err, what.data(), tries);
}

Status ModbusLink::write_register(std::uint16_t pdu_address, std::uint16_t value) {
  std::array<char, 80> what{};
  std::snprintf(what.data(), what.size(), "write holding register at PDU address %u = %u",
                pdu_address, value);
  if (!connected_) {
    return Status::error(ErrorCode::kUnavailable, "%s: %s: not connected", description_.c_str(),
                         what.data());
  }
  int err = 0;
  int tries = 0;
  for (int attempt = 0; attempt <= config_.retries; ++attempt) {
    ++tries;
    if (attempt > 0) ++counters_.retries;
    if (modbus_write_register(ctx_, pdu_address, value) == 1) {
      ++counters_.requests;
      return Status::success();
    }
    err = errno;
    if (is_exception(err)) break;
    const bool transient = err == ETIMEDOUT || err == EMBBADCRC || err == EMBBADSLAVE ||
                           err == EMBBADDATA || err == EMBBADEXC || err == EMBUNKEXC;
    modbus_flush(ctx_);
    if (!transient) {
      Status s = failure(err, what.data(), tries);
      close();
      return s;
    }
  }
  return failure(err, what.data(), tries);
}

}  // namespace cdpr::modbus
