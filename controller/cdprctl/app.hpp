// cdprctl, the maintenance command of cdprd (docs/control-protocol.md, "cdprctl"). It parses argv
// (CLI11), sends one command over the control socket and prints the result: human text by default,
// the raw result with --json. main() only fills in an Environment and calls run().
#pragma once

#include <atomic>
#include <ostream>
#include <string>

namespace cdpr::ctl {

// Exit statuses scripts can rely on (docs/control-protocol.md lists them with examples).
enum Exit : int {
  kExitOk = 0,
  kExitFailed = 1,       // the daemon refused or failed the command (named error printed), or a
                         // local file could not be read or written
  kExitUsage = 2,        // command-line usage error
  kExitNotRunning = 3,   // no socket, nobody accepts, or the daemon closed the connection
  kExitPermission = 4,   // the socket refused us (EACCES) or the command is not_permitted
  kExitRejected = 5,     // --wait: finished, but the gates failed, it was rejected or it failed
  kExitInterrupted = 6,  // --wait: aborted, or a robot fault
  kExitTimeout = 7,      // no answer (or no outcome, with --wait) before --timeout
  kExitCancelled = 130,  // --wait: Ctrl-C stopped the waiting (the calibration goes on)
};

inline constexpr const char* kDefaultSocket = "/run/cdpr/cdprd.sock";
// Seconds a plain request waits for its reply when --timeout is not given.
inline constexpr double kDefaultTimeoutS = 10.0;

struct Environment {
  std::string socket_env;  // $CDPR_SOCKET, "" when unset
  bool terminal = false;   // stdout is a terminal: live progress bar in watch and --wait
  int terminal_width = 100;
  const std::atomic<bool>* interrupted = nullptr;  // becomes true on SIGINT/SIGTERM
};

int run(int argc, const char* const* argv, std::ostream& out, std::ostream& err,
        const Environment& env);

}  // namespace cdpr::ctl
