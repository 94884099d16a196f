#include "cdpr/calibration/winch.hpp"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

namespace cdpr {
namespace {

WinchModel example_winch() {
  WinchModel w;
  w.drum_diameter = 0.04;
  w.drum_pitch = 0.002;
  w.gear_ratio = 10.0;
  w.counts_per_rev = 65536.0;
  w.direction = 1;
  w.length_offset = 0.8;
  return w;
}

TEST(Winch, OneDrumRevolutionPaysOutTheHelixLength) {
  const WinchModel w = example_winch();
  const double turn = std::hypot(std::numbers::pi * w.drum_diameter, w.drum_pitch);
  EXPECT_NEAR(winch_length_from_drum_revolutions(w, 1.0), turn, 1e-16);
  // One drum revolution = gear_ratio motor revolutions = gear_ratio * counts_per_rev counts.
  EXPECT_NEAR(winch_length_change(w, w.gear_ratio * w.counts_per_rev), turn, 1e-15);
  // The radian form of the field notes: L = theta * sqrt(r^2 + (p / 2 pi)^2).
  const double theta = 2.0 * std::numbers::pi * 3.7;
  const double r = w.drum_diameter / 2;
  const double p = w.drum_pitch / (2 * std::numbers::pi);
  EXPECT_NEAR(winch_length_from_drum_revolutions(w, 3.7), theta * std::sqrt(r * r + p * p), 1e-15);
  // No pitch: the circumference.
  WinchModel flat = w;
  flat.drum_pitch = 0.0;
  EXPECT_NEAR(winch_length_from_drum_revolutions(flat, 1.0), std::numbers::pi * 0.04, 1e-17);
}

TEST(Winch, CountsAndLengthsRoundTripBothWaysAndDirections) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(-1e7, 1e7);
  for (const int direction : {1, -1}) {
    WinchModel w = example_winch();
    w.direction = direction;
    for (int k = 0; k < 100; ++k) {
      const double counts = u(rng);
      const double length = winch_counts_to_length(w, counts);
      EXPECT_NEAR(winch_length_to_counts(w, length), counts, 1e-6);
      EXPECT_NEAR(winch_counts_to_length(w, winch_length_to_counts(w, length)), length, 1e-13);
    }
    // Count 0 is the length offset; positive counts pay out when direction = +1.
    EXPECT_EQ(winch_counts_to_length(w, 0.0), w.length_offset);
    EXPECT_EQ(winch_counts_to_length(w, 1000.0) > w.length_offset, direction > 0);
    EXPECT_EQ(winch_length_to_counts_rounded(w, w.length_offset + 1e-3),
              std::llround(winch_length_to_counts(w, w.length_offset + 1e-3)));
  }
}

TEST(Winch, TemplatesDifferentiateThroughCeresJet) {
  using Jet = ceres::Jet<double, 3>;
  const WinchModel w = example_winch();
  // d length / d counts = direction * metres per count.
  const Jet l = winch_counts_to_length(w, Jet(12345.0, 0));
  EXPECT_NEAR(l.v(0), winch_metres_per_count(w), 1e-22);
  // d metres_per_count / d (diameter, pitch) vs finite differences.
  const Jet mpc = winch_metres_per_count<Jet>(Jet(w.drum_diameter, 1), Jet(w.drum_pitch, 2),
                                              w.gear_ratio, w.counts_per_rev);
  const double h = 1e-7;
  const double dd = (winch_metres_per_count<double>(w.drum_diameter + h, w.drum_pitch, 10, 65536) -
                     winch_metres_per_count<double>(w.drum_diameter - h, w.drum_pitch, 10, 65536)) /
                    (2 * h);
  const double dp = (winch_metres_per_count<double>(w.drum_diameter, w.drum_pitch + h, 10, 65536) -
                     winch_metres_per_count<double>(w.drum_diameter, w.drum_pitch - h, 10, 65536)) /
                    (2 * h);
  EXPECT_NEAR(mpc.v(1), dd, 1e-12);
  EXPECT_NEAR(mpc.v(2), dp, 1e-12);
  EXPECT_GT(mpc.v(1), 0.0);
}

}  // namespace
}  // namespace cdpr
