// A child process for integration tests: started with posix_spawnp, stdout+stderr to a file,
// stdin from /dev/null, and always ended (SIGTERM, then SIGKILL) and reaped on every exit path.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <optional>
#include <string>
#include <vector>

namespace cdpr::test {

class Subprocess {
 public:
  // argv[0] is looked up on PATH when it has no '/'. An empty out_path keeps the test's output.
  // `stop_grace` is how long the destructor waits after SIGTERM before SIGKILL.
  Subprocess(const std::vector<std::string>& argv, const std::string& out_path,
             std::chrono::nanoseconds stop_grace = std::chrono::seconds(20));
  ~Subprocess();
  Subprocess(const Subprocess&) = delete;
  Subprocess& operator=(const Subprocess&) = delete;

  bool started() const { return pid_ > 0; }
  const std::string& error() const { return error_; }  // why it did not start
  // True while it runs; collects the exit status when it has ended.
  bool running();
  // Waits up to `timeout` for the exit: the exit status (128 + signal when killed) or nullopt.
  std::optional<int> wait(std::chrono::nanoseconds timeout);
  // Sends `sig`, waits up to `timeout`, then SIGKILL. Returns the exit status.
  std::optional<int> stop(int sig, std::chrono::nanoseconds timeout);
  std::optional<int> status() const { return status_; }

 private:
  pid_t pid_ = -1;
  std::optional<int> status_;
  std::string error_;
  std::chrono::nanoseconds stop_grace_;
};

}  // namespace cdpr::test
