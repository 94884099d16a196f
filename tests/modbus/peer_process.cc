#include "peer_process.hpp"

#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

namespace cdpr::modbus::testing {

namespace {

using Clock = std::chrono::steady_clock;

double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

}  // namespace

std::string source_dir() {
  return CDPR_SOURCE_DIR;
}

ChildProcess::ChildProcess(ChildProcess&& o) noexcept : pid_(o.pid_) {
  o.pid_ = -1;
}

ChildProcess& ChildProcess::operator=(ChildProcess&& o) noexcept {
  if (this != &o) {
    terminate();
    pid_ = o.pid_;
    o.pid_ = -1;
  }
  return *this;
}

Result<ChildProcess> ChildProcess::spawn(const std::vector<std::string>& argv,
                                         const std::string& log_path) {
  if (argv.empty()) return Status(ErrorCode::kInvalidArgument, "spawn: empty argv");
  // Everything the child needs is prepared before fork (only async-signal-safe calls after).
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const int log_fd = open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (log_fd < 0) {
    return Status::error(ErrorCode::kIoError, "spawn: cannot open %s", log_path.c_str());
  }
  const pid_t parent = getpid();
  const pid_t pid = fork();
  if (pid < 0) {
    close(log_fd);
    return Status(ErrorCode::kIoError, "spawn: fork failed");
  }
  if (pid == 0) {
    setpgid(0, 0);
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (getppid() != parent) _exit(127);
    dup2(log_fd, STDOUT_FILENO);
    dup2(log_fd, STDERR_FILENO);
    const int devnull = open("/dev/null", O_RDONLY);
    if (devnull >= 0) dup2(devnull, STDIN_FILENO);
    execv(args[0], args.data());
    _exit(127);
  }
  close(log_fd);
  ChildProcess c;
  c.pid_ = pid;
  return c;
}

bool ChildProcess::running() {
  if (pid_ <= 0) return false;
  int status = 0;
  const pid_t r = waitpid(pid_, &status, WNOHANG);
  if (r == pid_) {
    pid_ = -1;
    return false;
  }
  return true;
}

void ChildProcess::terminate() {
  if (pid_ <= 0) return;
  kill(-pid_, SIGTERM);  // its process group (setpgid in the child)
  kill(pid_, SIGTERM);
  const auto t0 = Clock::now();
  int status = 0;
  while (since(t0) < 2.0) {
    if (waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  kill(-pid_, SIGKILL);
  kill(pid_, SIGKILL);
  waitpid(pid_, &status, 0);
  pid_ = -1;
}

TempDir::TempDir() {
  std::string tmpl = "/tmp/cdpr-modbus-XXXXXX";
  if (mkdtemp(tmpl.data()) != nullptr) path_ = tmpl;
}

TempDir::~TempDir() {
  if (!path_.empty()) {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
}

bool wait_for_file(const std::string& path, double timeout_s) {
  const auto t0 = Clock::now();
  while (since(t0) < timeout_s) {
    struct stat st {};
    if (stat(path.c_str(), &st) == 0) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return false;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

PtyPair::PtyPair(const TempDir& dir)
    : a_(dir.file("pty-driver")), b_(dir.file("pty-slave")), log_(dir.file("socat.log")) {}

Status PtyPair::start() {
  Result<ChildProcess> p = ChildProcess::spawn(
      {"/usr/bin/socat", "-d", "-d", "pty,raw,echo=0,link=" + a_, "pty,raw,echo=0,link=" + b_},
      log_);
  if (!p.ok()) return p.status();
  socat_ = std::move(*p);
  if (!wait_for_file(a_, 30.0) || !wait_for_file(b_, 30.0)) {
    return Status::error(ErrorCode::kTimeout, "socat made no pty pair in 30 s: %s",
                         read_text(log_).c_str());
  }
  return Status::success();
}

LaserSlave::LaserSlave(const TempDir& dir, std::string name)
    : ready_(dir.file(name + ".ready")), log_(dir.file(name + ".log")) {}

Status LaserSlave::start_rtu(const std::string& device, const SlaveOptions& o) {
  return start({"--rtu", device}, o);
}

Status LaserSlave::start_tcp(int port, const SlaveOptions& o) {
  Status s = start({"--tcp", std::to_string(port)}, o);
  if (s.ok()) port_ = std::stoi(read_text(ready_));
  return s;
}

Status LaserSlave::start(const std::vector<std::string>& where, const SlaveOptions& o) {
  proc_.terminate();
  std::filesystem::remove(ready_);
  std::vector<std::string> argv = {"/usr/bin/python3",
                                   source_dir() + "/tests/modbus/laser_slave.py"};
  argv.insert(argv.end(), where.begin(), where.end());
  argv.insert(argv.end(), {"--map", o.map_path, "--slave", std::to_string(o.slave_id), "--mode",
                           o.mode, "--ready", ready_, "--lifetime", "120"});
  if (!o.raw.empty()) {
    argv.insert(argv.end(), {"--raw", o.raw});
  } else {
    argv.emplace_back("--distance");
    for (double d : o.distances) {
      std::ostringstream s;
      s.precision(17);
      s << d;
      argv.push_back(s.str());
    }
  }
  if (o.quality >= 0) argv.insert(argv.end(), {"--quality", std::to_string(o.quality)});
  Result<ChildProcess> p = ChildProcess::spawn(argv, log_);
  if (!p.ok()) return p.status();
  proc_ = std::move(*p);
  const auto t0 = Clock::now();
  while (since(t0) < 60.0) {
    if (wait_for_file(ready_, 0.05)) return Status::success();
    if (!proc_.running()) {
      return Status::error(ErrorCode::kUnavailable, "laser slave exited: %s", log().c_str());
    }
  }
  return Status::error(ErrorCode::kTimeout, "laser slave not ready in 60 s: %s", log().c_str());
}

}  // namespace cdpr::modbus::testing
