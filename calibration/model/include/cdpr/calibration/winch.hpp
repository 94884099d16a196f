// Winch transmission (Jin et al. 2018, Eq. 1): encoder counts <-> cable length.
//
//   L = sqrt((pi d)^2 + p^2) * theta          theta in drum revolutions (field notes: in radians
//                                             L = theta * sqrt(r^2 + (p / 2 pi)^2), r = d / 2)
//
// d: drum diameter, p: groove pitch (the cable advances p along the drum per revolution, so one
// revolution pays out the helix length sqrt((pi d)^2 + p^2)). The motor turns gear_ratio times
// per drum revolution and the encoder counts counts_per_rev per motor revolution, so
//
//   metres_per_count = sqrt((pi d)^2 + p^2) / (gear_ratio * counts_per_rev).
//
// Absolute length (encoder zero): the winch measures the cable length command l (the unstretched
// length from the frame anchor D to the platform anchor, see ik_compensation.hpp) as
//
//   l = length_offset + direction * counts * metres_per_count,
//
// where length_offset (WinchModel) is l at count 0 and direction = +1 when positive counts pay
// cable out. All functions are templates (double or ceres::Jet) and allocate nothing.
#pragma once

#include <cmath>
#include <cstdint>
#include <numbers>

#include "cdpr/calibration/robot_model.hpp"

namespace cdpr {

// Cable paid out per drum revolution, m (Eq. 1 with theta = 1 revolution).
template <typename T>
T winch_length_per_drum_revolution(const T& drum_diameter, const T& drum_pitch) {
  using std::sqrt;
  const T circumference = std::numbers::pi * drum_diameter;
  return sqrt(circumference * circumference + drum_pitch * drum_pitch);
}

// Metres of cable per encoder count (> 0), for a model whose diameter/pitch may be estimated.
template <typename T>
T winch_metres_per_count(const T& drum_diameter, const T& drum_pitch, double gear_ratio,
                         double counts_per_rev) {
  return winch_length_per_drum_revolution<T>(drum_diameter, drum_pitch) /
         (gear_ratio * counts_per_rev);
}

inline double winch_metres_per_count(const WinchModel& w) {
  return winch_metres_per_count<double>(w.drum_diameter, w.drum_pitch, w.gear_ratio,
                                        w.counts_per_rev);
}

// Eq. 1 itself: cable paid out for `drum_revolutions` turns of the drum, m.
template <typename T>
T winch_length_from_drum_revolutions(const WinchModel& w, const T& drum_revolutions) {
  return drum_revolutions * winch_length_per_drum_revolution<double>(w.drum_diameter, w.drum_pitch);
}

// Change of cable length for a change of `delta_counts` (signed, direction applied), m.
template <typename T>
T winch_length_change(const WinchModel& w, const T& delta_counts) {
  return delta_counts * (static_cast<double>(w.direction) * winch_metres_per_count(w));
}

// Encoder change for a cable length change (inverse of winch_length_change), counts.
template <typename T>
T winch_counts_change(const WinchModel& w, const T& delta_length) {
  return delta_length / (static_cast<double>(w.direction) * winch_metres_per_count(w));
}

// Absolute: cable length command from an encoder reading, m.
template <typename T>
T winch_counts_to_length(const WinchModel& w, const T& counts) {
  return w.length_offset + winch_length_change<T>(w, counts);
}

// Absolute: encoder reading (fractional) for a cable length command.
template <typename T>
T winch_length_to_counts(const WinchModel& w, const T& length) {
  return winch_counts_change<T>(w, length - w.length_offset);
}

// Nearest integer count, for the drive's position target.
inline std::int64_t winch_length_to_counts_rounded(const WinchModel& w, double length) {
  return std::llround(winch_length_to_counts<double>(w, length));
}

}  // namespace cdpr
