#include "cdpr/sim/laser_slave.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <vector>

namespace cdpr::sim {
namespace {

Status os_error(const char* what, int err) {
  return Status::error(ErrorCode::kIoError, "laser slave: %s: %s (errno %d)", what,
                       std::strerror(err), err);
}

// Largest and smallest raw value a type can hold.
double type_max(modbus::ValueType t) {
  switch (t) {
    case modbus::ValueType::kU16:
      return 65535.0;
    case modbus::ValueType::kI16:
      return 32767.0;
    case modbus::ValueType::kU32:
      return 4294967295.0;
    case modbus::ValueType::kI32:
      return 2147483647.0;
    case modbus::ValueType::kF32:
      return static_cast<double>(std::numeric_limits<float>::max());
  }
  return 0.0;
}
double type_min(modbus::ValueType t) {
  switch (t) {
    case modbus::ValueType::kU16:
    case modbus::ValueType::kU32:
      return 0.0;
    case modbus::ValueType::kI16:
      return -32768.0;
    case modbus::ValueType::kI32:
      return -2147483648.0;
    case modbus::ValueType::kF32:
      return -static_cast<double>(std::numeric_limits<float>::max());
  }
  return 0.0;
}

}  // namespace

std::string_view to_string(LaserFaultMode m) {
  switch (m) {
    case LaserFaultMode::kNone:
      return "none";
    case LaserFaultMode::kTimeout:
      return "timeout";
    case LaserFaultMode::kGarbage:
      return "garbage";
    case LaserFaultMode::kOutOfRange:
      return "out of range";
  }
  return "unknown";
}

LaserFaultMode laser_fault_mode(const Fault* f) {
  if (f == nullptr) return LaserFaultMode::kNone;
  switch (f->kind) {
    case FaultKind::kLaserTimeout:
      return LaserFaultMode::kTimeout;
    case FaultKind::kLaserGarbage:
      return LaserFaultMode::kGarbage;
    case FaultKind::kLaserOutOfRange:
      return LaserFaultMode::kOutOfRange;
    default:
      return LaserFaultMode::kNone;
  }
}

LaserSlave::LaserSlave(const LaserSlaveConfig& config) : config_(config), rng_(config.seed) {}

LaserSlave::~LaserSlave() {
  stop();
}

Result<std::unique_ptr<LaserSlave>> LaserSlave::start(const LaserSlaveConfig& config) {
  const Status valid = config.map.validate();
  if (!valid.ok()) return modbus::with_context("laser slave: register map: ", valid);
  if (config.transport == LaserSlaveConfig::Transport::kRtuPty &&
      (config.slave_id < 1 || config.slave_id > 247)) {
    return Status::error(ErrorCode::kInvalidArgument, "laser slave: RTU slave id %d not in 1..247",
                         config.slave_id);
  }
  std::unique_ptr<LaserSlave> s(new LaserSlave(config));
  CDPR_RETURN_IF_ERROR(s->open_transport());
  {
    std::lock_guard<std::mutex> lock(s->mutex_);
    s->fill_registers();
  }
  s->thread_ = std::thread([p = s.get()] { p->serve(); });
  return s;
}

Status LaserSlave::open_transport() {
  const modbus::RegisterMap& map = config_.map;
  // One mapping (both tables) spanning every address the map uses.
  std::vector<std::uint16_t> used = {
      map.pdu(map.block_start()),
      static_cast<std::uint16_t>(map.pdu(map.block_start()) + map.block_count() - 1),
      map.pdu(map.address),
      static_cast<std::uint16_t>(map.pdu(map.address) + modbus::register_count(map.type) - 1)};
  if (map.quality) used.push_back(map.pdu(map.quality->address));
  if (map.trigger) used.push_back(map.pdu(map.trigger->address));
  lo_ = *std::min_element(used.begin(), used.end());
  const std::uint16_t hi = *std::max_element(used.begin(), used.end());
  const int n = hi - lo_ + 1;
  mapping_ = modbus_mapping_new_start_address(0, 0, 0, 0, lo_, n, lo_, n);
  if (mapping_ == nullptr) return os_error("modbus_mapping_new_start_address", errno);
  if (pipe2(wake_, O_CLOEXEC | O_NONBLOCK) != 0) return os_error("pipe2", errno);

  if (config_.transport == LaserSlaveConfig::Transport::kRtuPty) {
    master_fd_ = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (master_fd_ < 0) return os_error("posix_openpt", errno);
    if (grantpt(master_fd_) != 0) return os_error("grantpt", errno);
    if (unlockpt(master_fd_) != 0) return os_error("unlockpt", errno);
    std::array<char, 128> name{};
    if (ptsname_r(master_fd_, name.data(), name.size()) != 0) return os_error("ptsname_r", errno);
    pty_path_ = name.data();
    // Hold the slave side open (raw) so the master never sees a hang-up between clients.
    pty_slave_fd_ = open(pty_path_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
    if (pty_slave_fd_ < 0) return os_error("open pty slave", errno);
    termios tio{};
    if (tcgetattr(pty_slave_fd_, &tio) == 0) {
      cfmakeraw(&tio);
      tcsetattr(pty_slave_fd_, TCSANOW, &tio);
    }
    if (!config_.pty_link.empty()) {
      struct stat st {};
      if (lstat(config_.pty_link.c_str(), &st) == 0) {
        if (!S_ISLNK(st.st_mode)) {
          return Status::error(ErrorCode::kInvalidArgument,
                               "laser slave: %s exists and is not a symlink (not replaced)",
                               config_.pty_link.c_str());
        }
        unlink(config_.pty_link.c_str());
      }
      if (symlink(pty_path_.c_str(), config_.pty_link.c_str()) != 0) {
        return os_error(("symlink " + config_.pty_link).c_str(), errno);
      }
    }
    ctx_ = modbus_new_rtu(pty_path_.c_str(), config_.baud, config_.parity, 8, 1);
    if (ctx_ == nullptr) return os_error("modbus_new_rtu", errno);
    modbus_set_slave(ctx_, config_.slave_id);
    modbus_set_socket(ctx_, master_fd_);  // serve on the master side; no modbus_connect
  } else {
    ctx_ = modbus_new_tcp(config_.host.c_str(), config_.port);
    if (ctx_ == nullptr) return os_error("modbus_new_tcp", errno);
    listen_fd_ = modbus_tcp_listen(ctx_, 4);
    if (listen_fd_ < 0) {
      const int err = errno;
      return Status::error(ErrorCode::kIoError, "laser slave: listen on %s:%d: %s",
                           config_.host.c_str(), config_.port, modbus_strerror(err));
    }
    sockaddr_in addr{};
    socklen_t len = sizeof(addr);
    if (getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
      return os_error("getsockname", errno);
    }
    port_ = ntohs(addr.sin_port);
  }
  modbus_set_indication_timeout(ctx_, 0, 200000);
  modbus_set_byte_timeout(ctx_, 0, 50000);
  return Status::success();
}

void LaserSlave::stop() {
  if (thread_.joinable()) {
    stop_ = true;
    const char c = 1;
    [[maybe_unused]] const ssize_t n = write(wake_[1], &c, 1);
    thread_.join();
  }
  if (ctx_ != nullptr) {
    modbus_free(ctx_);  // not modbus_close: the descriptors are ours
    ctx_ = nullptr;
  }
  if (mapping_ != nullptr) {
    modbus_mapping_free(mapping_);
    mapping_ = nullptr;
  }
  for (int* fd : {&master_fd_, &pty_slave_fd_, &listen_fd_, &wake_[0], &wake_[1]}) {
    if (*fd >= 0) close(*fd);
    *fd = -1;
  }
  if (!config_.pty_link.empty() && !pty_path_.empty()) {
    struct stat st {};
    if (lstat(config_.pty_link.c_str(), &st) == 0 && S_ISLNK(st.st_mode)) {
      unlink(config_.pty_link.c_str());
    }
    pty_path_.clear();
  }
}

void LaserSlave::set_distance(double distance_m, LaserStatus status) {
  std::lock_guard<std::mutex> lock(mutex_);
  distance_m_ = distance_m;
  status_ = status;
}

void LaserSlave::set_fault(LaserFaultMode mode) {
  std::lock_guard<std::mutex> lock(mutex_);
  fault_ = mode;
}

std::string LaserSlave::describe() const {
  std::string s;
  if (config_.transport == LaserSlaveConfig::Transport::kRtuPty) {
    s = "RTU " + pty_path_;
    if (!config_.pty_link.empty()) s += " (link " + config_.pty_link + ")";
    s += " slave " + std::to_string(config_.slave_id);
  } else {
    s = "TCP " + config_.host + ":" + std::to_string(port_);
  }
  return s + ", map " + config_.map.name;
}

void LaserSlave::fill_registers() {
  const modbus::RegisterMap& map = config_.map;
  std::uint16_t* table = map.table == modbus::RegisterTable::kInput ? mapping_->tab_input_registers
                                                                    : mapping_->tab_registers;
  const std::size_t value_at = static_cast<std::size_t>(map.pdu(map.address) - lo_);
  std::span<std::uint16_t> regs(table + value_at,
                                static_cast<std::size_t>(modbus::register_count(map.type)));
  const double noise = config_.noise_sigma_m * normal_(rng_);  // one draw per request
  bool no_target = false;
  double raw = 0.0;
  if (fault_ == LaserFaultMode::kGarbage) {
    if (!map.error_raw.empty()) {
      raw = map.error_raw.front();
    } else if (map.type == modbus::ValueType::kF32) {
      raw = std::numeric_limits<double>::quiet_NaN();
    } else {
      for (std::uint16_t& r : regs) r = 0xFFFF;
      regs = {};
    }
  } else if (fault_ == LaserFaultMode::kOutOfRange) {
    const double d = map.max_m + 0.5 * (map.max_m - map.min_m);
    raw = (d - map.offset) / map.scale;
  } else if (status_ == LaserStatus::kNoTarget || !std::isfinite(distance_m_)) {
    no_target = true;
    if (!map.no_target_raw.empty()) {
      raw = map.no_target_raw.front();
    } else if (map.type == modbus::ValueType::kF32) {
      raw = std::numeric_limits<double>::quiet_NaN();
    } else {
      raw = type_max(map.type);
    }
  } else {
    raw = (distance_m_ + noise - map.offset) / map.scale;
  }
  if (!regs.empty()) {
    if (std::isfinite(raw) && (raw > type_max(map.type) || raw < type_min(map.type))) {
      // Not representable: the nearest value of the type that is not a sentinel.
      const bool high = raw > 0.0;
      raw = high ? type_max(map.type) : type_min(map.type);
      auto sentinel = [&](double v) {
        return std::find(map.no_target_raw.begin(), map.no_target_raw.end(), v) !=
                   map.no_target_raw.end() ||
               std::find(map.error_raw.begin(), map.error_raw.end(), v) != map.error_raw.end();
      };
      while (sentinel(raw)) raw += high ? -1.0 : 1.0;
    }
    modbus::encode_raw(raw, map.type, map.word_order, map.byte_order, regs);
  }
  if (map.quality) {
    std::uint16_t* qtable = table;
    const std::size_t q_at = static_cast<std::size_t>(map.pdu(map.quality->address) - lo_);
    std::uint16_t q = 0;
    if (no_target && !map.quality->no_target_values.empty()) {
      q = map.quality->no_target_values.front();
    } else if (!map.quality->ok_values.empty()) {
      q = map.quality->ok_values.front();
    }
    qtable[q_at] = q;
  }
}

void LaserSlave::handle(int fd) {
  std::array<std::uint8_t, MODBUS_TCP_MAX_ADU_LENGTH> query{};
  modbus_set_socket(ctx_, fd);
  const int rc = modbus_receive(ctx_, query.data());
  if (rc <= 0) {
    if (rc < 0 && config_.transport == LaserSlaveConfig::Transport::kTcp) {
      close(fd);  // the client went away (or sent junk): drop it
      modbus_set_socket(ctx_, -1);
      throw_away_client_ = fd;
    }
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (fault_ == LaserFaultMode::kTimeout) {
    dropped_.fetch_add(1);
    return;
  }
  fill_registers();
  // Counted before the reply leaves: a client that has its answer must see the count include it.
  answered_.fetch_add(1);
  if (modbus_reply(ctx_, query.data(), rc, mapping_) < 0) answered_.fetch_sub(1);
}

void LaserSlave::serve() {
  std::vector<int> clients;
  while (!stop_.load()) {
    std::vector<pollfd> fds;
    fds.push_back({wake_[0], POLLIN, 0});
    if (config_.transport == LaserSlaveConfig::Transport::kRtuPty) {
      fds.push_back({master_fd_, POLLIN, 0});
    } else {
      fds.push_back({listen_fd_, POLLIN, 0});
      for (int c : clients) fds.push_back({c, POLLIN, 0});
    }
    const int n = poll(fds.data(), fds.size(), 200);
    if (n <= 0) continue;
    if (fds[0].revents != 0) break;
    if (config_.transport == LaserSlaveConfig::Transport::kRtuPty) {
      if ((fds[1].revents & POLLIN) != 0) {
        handle(master_fd_);
      } else if (fds[1].revents != 0) {
        usleep(10000);  // no master connected right now (we hold the slave side, so rare)
      }
      continue;
    }
    if ((fds[1].revents & POLLIN) != 0) {
      const int c = accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (c >= 0) clients.push_back(c);
    }
    for (std::size_t k = 2; k < fds.size(); ++k) {
      if (fds[k].revents == 0) continue;
      throw_away_client_ = -1;
      handle(fds[k].fd);
      if (throw_away_client_ >= 0) {
        clients.erase(std::remove(clients.begin(), clients.end(), throw_away_client_),
                      clients.end());
      }
    }
  }
  for (int c : clients) close(c);
}

}  // namespace cdpr::sim
