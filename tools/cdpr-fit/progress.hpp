// Progress of cdpr-fit's long work on stderr (solver iterations, poses designed, bootstrap
// resamples), as one line rewritten in place:
//
//   cdpr-fit: poses designed 12/25 (48 %), 3.1 s, about 3.4 s left
//   cdpr-fit: solver iteration 7 (at most 100), 0.8 s
//
// Shown when stderr is a terminal (isatty), or always with --progress; never with --no-progress.
// Updates are at most every 0.1 s; the line is closed ("\n") when the command ends.
#pragma once

#include <chrono>
#include <ostream>
#include <string>
#include <string_view>

#include "cdpr/calibration/identification.hpp"

namespace cdpr::fit {

class ProgressLine {
 public:
  ProgressLine(std::ostream& err, bool enabled) : err_(err), enabled_(enabled) {}
  ~ProgressLine() { finish(); }
  ProgressLine(const ProgressLine&) = delete;
  ProgressLine& operator=(const ProgressLine&) = delete;

  bool enabled() const { return enabled_; }
  // The callback for the calibration options (empty when not enabled).
  ProgressCallback callback();
  void update(std::string_view what, int done, int total);
  // Ends the line (when one was shown).
  void finish();

 private:
  std::ostream& err_;
  bool enabled_ = false;
  bool shown_ = false;
  std::string what_;
  std::chrono::steady_clock::time_point started_{}, last_{};
};

// Whether progress is shown: `mode` "auto" (stderr a terminal), "always", "never".
bool progress_wanted(std::string_view mode, const std::ostream& err);

}  // namespace cdpr::fit
