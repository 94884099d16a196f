// Refusing a command's output path that would destroy one of its inputs or another output.
//
// `calibrate --out rec.csv --recording rec.csv` must not replace the recording it reads, and
// `--out x --report x` must not leave one output where two were promised. Every command that writes
// files checks its paths first:
//
//   CDPR_RETURN_IF_ERROR(io::check_output_paths({{"--config", cfg}, {"--recording", rec}},
//                                               {{"--out", out}, {"--report", report}}));
//
// Two paths are the same file when both exist and are one inode (std::filesystem::equivalent:
// hard links, symbolic links, "./a" and "a"), or, when one does not exist yet, when their
// resolved absolute paths (std::filesystem::weakly_canonical) are equal. Empty paths (an option
// not given) are skipped. The error (kInvalidArgument) names both options and both paths:
//   "--out rec.csv is the same file as the input --recording ./rec.csv: refusing to overwrite it"
// Not for the RT path (file system calls, allocation).
#pragma once

#include <string>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::io {

// A path named on a command line, with the option that named it ("--out", "--scenario").
struct NamedPath {
  std::string option;
  std::string path;
};

// Whether `a` and `b` name the same file (see above).
bool same_file(const std::string& a, const std::string& b);

// Refuses an output that is the same file as an input or as another output.
Status check_output_paths(const std::vector<NamedPath>& inputs,
                          const std::vector<NamedPath>& outputs);

}  // namespace cdpr::io
