// Child processes for the Modbus integration tests: a socat pty pair and the python laser slave.
// Every wait is bounded; destructors terminate the children (SIGTERM, then SIGKILL) and remove
// their files, so a failing test leaves nothing behind. Children also die with the test process
// (PR_SET_PDEATHSIG) should it be killed.
#pragma once

#include <sys/types.h>

#include <string>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::modbus::testing {

class ChildProcess {
 public:
  ChildProcess() = default;
  ~ChildProcess() { terminate(); }
  ChildProcess(ChildProcess&& o) noexcept;
  ChildProcess& operator=(ChildProcess&& o) noexcept;
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // Starts argv[0] (a path) with stdout and stderr going to `log_path`.
  static Result<ChildProcess> spawn(const std::vector<std::string>& argv,
                                    const std::string& log_path);
  bool running();  // reaps the child if it exited
  // SIGTERM, wait up to 2 s, then SIGKILL. Idempotent.
  void terminate();
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
};

// A fresh directory under /tmp, removed (with its files) on destruction.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }
  std::string file(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

// Waits until `path` exists, at most timeout_s. False on timeout.
bool wait_for_file(const std::string& path, double timeout_s);
std::string read_text(const std::string& path);

// socat pty pair: master_path() for the driver, slave_path() for the peer.
class PtyPair {
 public:
  explicit PtyPair(const TempDir& dir);
  Status start();
  const std::string& master_path() const { return a_; }
  const std::string& slave_path() const { return b_; }

 private:
  std::string a_, b_, log_;
  ChildProcess socat_;
};

struct SlaveOptions {
  std::string map_path{};
  int slave_id = 17;
  std::vector<double> distances = {1.0};
  std::string raw{};  // serve this raw value instead ("0xFFFF")
  int quality = -1;
  std::string mode = "normal";  // normal, bad-crc, silent
};

// The python laser slave (tests/modbus/laser_slave.py), on a pty or on TCP 127.0.0.1.
class LaserSlave {
 public:
  explicit LaserSlave(const TempDir& dir, std::string name = "slave");
  Status start_rtu(const std::string& device, const SlaveOptions& o);
  Status start_tcp(int port, const SlaveOptions& o);  // port 0: any free port
  int port() const { return port_; }
  void stop() { proc_.terminate(); }
  std::string log() const { return read_text(log_); }

 private:
  Status start(const std::vector<std::string>& where, const SlaveOptions& o);
  std::string ready_, log_;
  int port_ = 0;
  ChildProcess proc_;
};

std::string source_dir();  // CDPR_SOURCE_DIR

}  // namespace cdpr::modbus::testing
