// Path programs (docs/motion.md "Path files"): a small G-code-like subset in SI units, one
// instruction per line, parsed into the segments of a Path (path.hpp). Reading a file is
// cdpr/config/path_file.hpp's (drivers/).
//
//   ; a square with a rounded corner and a pause (metres, radians, m/s, s)
//   G1 X0.10 Y0.00 Z0.05 F0.05     ; straight line to the pose; omitted axes keep their value
//   G3 X0.00 Y0.10 I-0.10 J0.00    ; counter-clockwise arc about the centre start + (I, J, K)
//   G4 P0.5                        ; dwell 0.5 s
//   G5 Y0.05                ; spline waypoint; consecutive G5 lines form one C2 spline
//   G5 Y0.00 C0.1           ; (A B C: roll, pitch, yaw in rad)
//   G1 X0 Y0 Z0 A0 B0 C0
//
// Words: G0 (a line at the limits, no feed), G1, G2 (clockwise), G3 (counter-clockwise), G4
// (dwell P seconds), G5 (spline waypoint), G17/G18/G19 (arc plane XY/ZX/YZ, axis +Z/+Y/+X; G17 by
// default), G90 (absolute, the only mode); X Y Z (m), A B C (rad), I J K (m, the arc centre's
// offset from the arc's start), F (m/s, modal), P (s), N (line number, ignored). Motion modes,
// the plane, F and every coordinate are modal; a line with only coordinates repeats the last
// motion mode. Comments: from ';' to the end of the line, and '(' ... ')' within a line. Letters
// are case-insensitive. Refused, naming file, line and word: G20/G21 (inches, millimetres), G91
// (relative), R (radius) arcs, unknown words, a word twice on a line, numbers that are not finite
// or beyond 1e6, lines longer than kMaxPathLineBytes, more than kMaxPathSegments instructions,
// files larger than kMaxPathFileBytes.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/path.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

inline constexpr std::size_t kMaxPathFileBytes = 1 << 20;
inline constexpr std::size_t kMaxPathLineBytes = 256;
inline constexpr std::size_t kMaxPathSegments = 100000;

// The segments of a path program starting at `start` (the modal coordinates begin there).
// kParseError "<name>:<line>: <word>: <reason>" on the first bad line (never throws).
Result<std::vector<PathSegment>> parse_path_program(std::string_view text, std::string_view name,
                                                    const Pose& start);

}  // namespace cdpr
