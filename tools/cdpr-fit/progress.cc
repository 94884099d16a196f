#include "progress.hpp"

#include <unistd.h>

#include <cstdio>
#include <iostream>

namespace cdpr::fit {

ProgressCallback ProgressLine::callback() {
  if (!enabled_) return {};
  return [this](std::string_view what, int done, int total) { update(what, done, total); };
}

void ProgressLine::update(std::string_view what, int done, int total) {
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  if (what != what_) {  // a new stage starts its own clock
    what_ = std::string(what);
    started_ = now;
  } else if (now - last_ < std::chrono::milliseconds(100) && done < total) {
    return;
  }
  last_ = now;
  const double elapsed = std::chrono::duration<double>(now - started_).count();
  char line[200];
  if (what == "solver iteration") {
    std::snprintf(line, sizeof line, "cdpr-fit: %s %d (at most %d), %.1f s", what_.c_str(), done,
                  total, elapsed);
  } else if (total > 0 && done > 0) {
    const double left = elapsed / done * (total - done);
    std::snprintf(line, sizeof line, "cdpr-fit: %s %d/%d (%d %%), %.1f s, about %.1f s left",
                  what_.c_str(), done, total, static_cast<int>(100.0 * done / total), elapsed,
                  left);
  } else {
    std::snprintf(line, sizeof line, "cdpr-fit: %s %d/%d, %.1f s", what_.c_str(), done, total,
                  elapsed);
  }
  err_ << '\r' << line << "\x1b[K" << std::flush;  // rewrite the line, clear its old tail
  shown_ = true;
}

void ProgressLine::finish() {
  if (shown_) err_ << '\n' << std::flush;
  shown_ = false;
}

bool progress_wanted(std::string_view mode, const std::ostream& err) {
  if (mode == "always") return true;
  if (mode == "never") return false;
  return &err == &std::cerr && ::isatty(STDERR_FILENO) == 1;
}

}  // namespace cdpr::fit
