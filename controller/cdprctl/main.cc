// cdprctl: the maintenance command of cdprd. The logic lives in app.cc (tests call it).
#include <sys/ioctl.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdlib>
#include <iostream>

#include "app.hpp"

namespace {

std::atomic<bool> g_interrupted{false};

void on_signal(int) {
  g_interrupted = true;
}

}  // namespace

int main(int argc, char** argv) {
  // Without SA_RESTART, so that a wait in poll() returns at once with EINTR.
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);

  cdpr::ctl::Environment env;
  if (const char* s = std::getenv("CDPR_SOCKET"); s != nullptr) env.socket_env = s;
  env.terminal = ::isatty(STDOUT_FILENO) == 1;
  winsize ws{};
  if (env.terminal && ::ioctl(STDOUT_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col > 0) {
    env.terminal_width = ws.ws_col;
  }
  env.interrupted = &g_interrupted;
  return cdpr::ctl::run(argc, argv, std::cout, std::cerr, env);
}
