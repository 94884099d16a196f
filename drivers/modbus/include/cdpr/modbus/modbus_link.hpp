// A Modbus master link (RTU over a serial line, or TCP) to one slave, on top of libmodbus.
//
// Every call is bounded in time: connect and each request wait at most the response timeout per
// try, and a request makes 1 + retries tries. Errors are values that name the transport (device
// or host), the slave id, the registers and the reason (timeout, CRC error, Modbus exception
// text, errno text). Not thread-safe: one thread at a time (LaserSensor serialises access).
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "cdpr/modbus/register_map.hpp"
#include "cdpr/status.hpp"

struct _modbus;  // libmodbus's modbus_t, kept out of this header

namespace cdpr::modbus {

struct RtuSettings {
  std::string device;  // e.g. /dev/ttyUSB0
  int baud = 19200;
  char parity = 'E';  // 'N', 'E' or 'O'
  int data_bits = 8;
  int stop_bits = 1;
  bool rs485 = false;  // switch the UART to RS-485 mode (TIOCSRS485); a warning where unsupported
};

struct TcpSettings {
  std::string host = "127.0.0.1";  // name or address
  int port = 502;
};

struct LinkConfig {
  std::variant<RtuSettings, TcpSettings> transport;
  int slave_id = 1;                 // 1..247 (RTU); TCP unit id 0..255
  double response_timeout_s = 0.1;  // per try
  double byte_timeout_s = 0.02;     // gap allowed between bytes of one answer
  int retries = 2;                  // extra tries after a timeout or a corrupted answer
  double reconnect_delay_s = 0.5;   // LaserSensor: wait between reconnect attempts

  Status validate() const;
};

// Counters since construction.
struct LinkCounters {
  std::uint64_t requests = 0;  // successful transactions
  std::uint64_t timeouts = 0;
  std::uint64_t crc_errors = 0;
  std::uint64_t exceptions = 0;
  std::uint64_t other_errors = 0;
  std::uint64_t retries = 0;
  std::uint64_t connects = 0;
};

// Text of a Modbus exception code ("illegal data address" for 2).
std::string_view exception_text(int code);

class ModbusLink {
 public:
  explicit ModbusLink(LinkConfig config);
  ~ModbusLink();
  ModbusLink(const ModbusLink&) = delete;
  ModbusLink& operator=(const ModbusLink&) = delete;

  // Opens the serial device or TCP connection (bounded by the response timeout for TCP).
  Status connect();
  void close();
  bool connected() const { return connected_; }

  // Reads `out.size()` registers from PDU address `pdu_address`. Retries timeouts and corrupted
  // answers; a Modbus exception is returned at once (kAborted, with the exception text); an I/O
  // error closes the link (kIoError) so the caller reconnects.
  Status read_registers(RegisterTable table, std::uint16_t pdu_address,
                        std::span<std::uint16_t> out);
  // Writes one holding register (function 06) at PDU address `pdu_address`.
  Status write_register(std::uint16_t pdu_address, std::uint16_t value);

  // "RTU /dev/ttyUSB0 slave 3" or "TCP 127.0.0.1:502 unit 1".
  const std::string& describe() const { return description_; }
  // Non-fatal problems met while connecting (e.g. RS-485 mode unsupported on this device).
  const std::vector<std::string>& warnings() const { return warnings_; }
  const LinkCounters& counters() const { return counters_; }
  const LinkConfig& config() const { return config_; }

 private:
  // Maps errno after a failed libmodbus call; `what` names the request.
  Status failure(int err, const char* what, int tries);

  LinkConfig config_;
  std::string description_;
  _modbus* ctx_ = nullptr;
  bool connected_ = false;
  std::vector<std::string> warnings_;
  LinkCounters counters_;
};

}  // namespace cdpr::modbus
