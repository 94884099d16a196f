// The virtual robot's laser distance sensor as a Modbus slave (libmodbus server), serving one of
// the driver's register maps (cdpr::modbus::RegisterMap, config/lasers/*.yaml) in its own thread.
//
// Transports:
// - RTU on a pseudo-terminal the slave creates itself (posix_openpt/grantpt/unlockpt). A master
//   (the driver, mbpoll) opens pty_path(), e.g. /dev/pts/7; with `pty_link` set, a symlink to it
//   is made at that path (and removed on stop). Baud and parity only matter to the master.
// - TCP on host:port (127.0.0.1; port 0 picks a free port, see port()).
//
// Every request gets a fresh reading: the distance set by the physics (set_distance) plus white
// Gaussian noise (noise_sigma_m, own seeded generator), encoded with the map's type, word and
// byte order and scale (modbus::encode_raw, the inverse of the driver's decode). The quality
// register, if the map has one, holds its first `ok` value (first `no_target` value when there is
// no target). Fault modes (LaserFaultMode) emulate a broken sensor:
//   kTimeout    : requests are read and dropped, no answer;
//   kGarbage    : the value registers hold the map's `error` sentinel if it has one, else a NaN
//                 (f32) or all-ones words (integers);
//   kOutOfRange : the value is max + (max - min) / 2 of the map's range (clamped to its type).
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>

#include "cdpr/modbus/register_map.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/status.hpp"

struct _modbus;            // libmodbus's modbus_t, kept out of this header
struct _modbus_mapping_t;  // libmodbus's modbus_mapping_t

namespace cdpr::sim {

enum class LaserFaultMode : std::uint8_t { kNone, kTimeout, kGarbage, kOutOfRange };
std::string_view to_string(LaserFaultMode m);
// The mode a scenario fault asks for (kNone for faults that are not the laser's).
LaserFaultMode laser_fault_mode(const Fault* fault);

struct LaserSlaveConfig {
  enum class Transport { kRtuPty, kTcp };
  Transport transport = Transport::kRtuPty;
  modbus::RegisterMap map;
  int slave_id = 1;      // RTU address 1..247 (TCP: unit id, not checked)
  std::string pty_link;  // RTU: optional symlink to the pty slave path
  int baud = 115200;     // RTU: nominal settings (a pty ignores them)
  char parity = 'N';
  std::string host = "127.0.0.1";  // TCP
  int port = 0;                    // TCP; 0: a free port
  double noise_sigma_m = 0.0;      // per-request noise, m
  std::uint64_t seed = 1;
};

class LaserSlave {
 public:
  // Creates the pty or the listening socket and starts the server thread.
  static Result<std::unique_ptr<LaserSlave>> start(const LaserSlaveConfig& config);
  ~LaserSlave();
  LaserSlave(const LaserSlave&) = delete;
  LaserSlave& operator=(const LaserSlave&) = delete;

  // Stops and joins the server thread, closes the pty/sockets, removes the symlink. Idempotent.
  void stop();

  // The physics' noise-free distance and its status (thread-safe).
  void set_distance(double distance_m, LaserStatus status);
  void set_fault(LaserFaultMode mode);

  const std::string& pty_path() const { return pty_path_; }  // RTU: "/dev/pts/N"
  int port() const { return port_; }                         // TCP: the bound port
  // "RTU /dev/pts/7 (link /tmp/laser) slave 1, map baumer-om20-om30" or "TCP 127.0.0.1:5020 ...".
  std::string describe() const;
  std::uint64_t answered() const { return answered_.load(); }  // replies sent
  std::uint64_t dropped() const { return dropped_.load(); }    // requests left unanswered

 private:
  explicit LaserSlave(const LaserSlaveConfig& config);
  Status open_transport();
  void serve();
  void fill_registers();  // under mutex_
  void handle(int fd);

  LaserSlaveConfig config_;
  ::_modbus* ctx_ = nullptr;
  ::_modbus_mapping_t* mapping_ = nullptr;
  int master_fd_ = -1;     // RTU: pty master
  int pty_slave_fd_ = -1;  // RTU: kept open so the pty never hangs up between masters
  int listen_fd_ = -1;     // TCP
  int wake_[2] = {-1, -1};
  int throw_away_client_ = -1;  // TCP: a client closed while handling it
  std::string pty_path_;
  int port_ = 0;
  std::uint16_t lo_ = 0;  // lowest PDU address in the mapping

  std::mutex mutex_;
  double distance_m_ = kNaN;
  LaserStatus status_ = LaserStatus::kNoTarget;
  LaserFaultMode fault_ = LaserFaultMode::kNone;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};

  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> answered_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::thread thread_;
};

}  // namespace cdpr::sim
