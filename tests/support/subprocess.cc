#include "subprocess.hpp"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>
#include <thread>

extern char** environ;

namespace cdpr::test {

Subprocess::Subprocess(const std::vector<std::string>& argv, const std::string& out_path,
                       std::chrono::nanoseconds stop_grace)
    : stop_grace_(stop_grace) {
  if (argv.empty()) {
    error_ = "no command given";
    return;
  }
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  if (!out_path.empty()) {
    posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, out_path.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, STDOUT_FILENO, STDERR_FILENO);
  }
  posix_spawn_file_actions_addopen(&fa, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  std::vector<char*> args;
  args.reserve(argv.size() + 1);
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  const int rc = posix_spawnp(&pid_, args[0], &fa, nullptr, args.data(), environ);
  if (rc != 0) {
    pid_ = -1;
    error_ = std::strerror(rc);
  }
  posix_spawn_file_actions_destroy(&fa);
}

Subprocess::~Subprocess() {
  stop(SIGTERM, stop_grace_);
}

bool Subprocess::running() {
  if (pid_ <= 0 || status_) return false;
  int st = 0;
  const pid_t r = ::waitpid(pid_, &st, WNOHANG);
  if (r == pid_) {
    status_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    return false;
  }
  return r == 0;
}

std::optional<int> Subprocess::wait(std::chrono::nanoseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (running()) {
    if (std::chrono::steady_clock::now() >= end) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return status_;
}

std::optional<int> Subprocess::stop(int sig, std::chrono::nanoseconds timeout) {
  if (!running()) return status_;
  ::kill(pid_, sig);
  if (auto s = wait(timeout)) return s;
  ::kill(pid_, SIGKILL);
  return wait(std::chrono::seconds(10));
}

}  // namespace cdpr::test
