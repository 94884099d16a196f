// Helpers shared by the benchmark programs (bench/*.cc). Not installed, not a library.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <utility>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/status.hpp"

namespace cdpr::bench {

// The value of `r`, or the reason on stderr and exit status 1: a benchmark cannot go on without it.
template <typename T>
T must(Result<T> r, const char* what) {
  if (!r.ok()) {
    std::fprintf(stderr, "%s failed: %s\n", what, r.status().to_string().c_str());
    std::exit(1);
  }
  return std::move(r).value();
}

// The sensor noise of the MINI benchmarks: laser 1 mm, encoder 0.1 mm, force 1 N.
inline SensorNoise mini_noise() {
  SensorNoise n;
  n.sigma_laser = 1e-3;
  n.sigma_length = 1e-4;
  n.sigma_force = 1.0;
  return n;
}

// RMS over the anchor coordinates (the parameters named a_...) of the Cramer-Rao std of the
// Fisher information `gi`: its pseudo-inverse, taken on the information scaled to a unit diagonal.
inline double anchor_crb_rms(const GeometryInformation& gi) {
  const Eigen::VectorXd d = gi.information.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
  const Eigen::MatrixXd In = d.asDiagonal() * gi.information * d.asDiagonal();
  const Eigen::MatrixXd cov =
      d.asDiagonal() * In.completeOrthogonalDecomposition().pseudoInverse() * d.asDiagonal();
  double sum = 0.0;
  int count = 0;
  for (std::size_t q = 0; q < gi.names.size(); ++q) {
    if (gi.names[q].rfind("a_", 0) != 0) continue;
    sum += cov(static_cast<Eigen::Index>(q), static_cast<Eigen::Index>(q));
    ++count;
  }
  return count ? std::sqrt(sum / count) : 0.0;
}

}  // namespace cdpr::bench
