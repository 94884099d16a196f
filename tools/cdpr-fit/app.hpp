// cdpr-fit's command line: parses argv (CLI11), runs one subcommand (commands.hpp) and prints its
// result, human text by default or JSON with --json. main() is only `return run(...)`.
#pragma once

#include <ostream>

namespace cdpr::fit {

// Exit status: 0 success, 1 the input was refused or the work failed (the message on `err` says
// why, naming the file, line and column where there is one), 2 command-line usage error (also an
// output path that names an input or another output); `diagnose` also exits 3 when it found a
// mismatch (named or not) and 4 when the recording is too small to tell (0 there means "no missing
// physics found"); 70 internal error (a bug: an unexpected exception, reported on `err`). No
// exception leaves run().
int run(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

inline constexpr int kExitFailed = 1;
inline constexpr int kExitUsage = 2;
inline constexpr int kExitInternal = 70;  // EX_SOFTWARE of sysexits.h

}  // namespace cdpr::fit
