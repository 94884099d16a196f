// Robust averaging for the calibration sequence: median / MAD outlier rejection, then the mean
// and sample standard deviation of the values kept.
#pragma once

#include <span>

namespace cdpr::modbus {

struct RobustMean {
  double mean = 0.0;
  double stddev = 0.0;  // sample standard deviation (n - 1) of the values kept; 0 for one value
  double median = 0.0;
  double sigma = 0.0;  // robust scale used for rejection: max(1.4826 * MAD, min_sigma)
  int used = 0;
  int rejected = 0;
};

// Keeps the values within k * sigma of the median, sigma = max(1.4826 * MAD, min_sigma).
// min_sigma keeps quantised data (most values equal, MAD = 0) from rejecting one-step neighbours:
// pass the sensor resolution. Empty input gives used = 0. Non-finite values are rejected.
RobustMean robust_mean(std::span<const double> values, double k = 3.5, double min_sigma = 0.0);

}  // namespace cdpr::modbus
