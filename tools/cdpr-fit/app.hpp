// cdpr-fit's command line: parses argv (CLI11), runs one subcommand (commands.hpp) and prints its
// result, human text by default or JSON with --json. main() is only `return run(...)`.
#pragma once

#include <ostream>

namespace cdpr::fit {

// Exit status: 0 success, 1 the input was refused or the work failed (the message on `err` says
// why, naming the file, line and column where there is one), 2 command-line usage error; `diagnose`
// also exits 3 when it found a mismatch (named or not) and 4 when the recording is too small to
// tell (0 there means "no missing physics found").
int run(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace cdpr::fit
