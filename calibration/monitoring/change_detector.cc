#include "cdpr/calibration/change_detector.hpp"

#include <cmath>

namespace cdpr {

double cusum_arl0(double h, double k) {
  const double a = 2.0 * k * (h + 1.166);
  return (std::exp(a) - a - 1.0) / (2.0 * k * k);
}

Result<double> cusum_threshold(double false_alarms_per_hour, double samples_per_hour, int channels,
                               double k) {
  if (!(false_alarms_per_hour > 0.0) || !(samples_per_hour > 0.0) || channels < 1 || !(k > 0.0) ||
      !std::isfinite(false_alarms_per_hour * samples_per_hour * k)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "cusum_threshold: rate %g /h, %g samples/h, %d channels, allowance %g: "
                         "each must be positive and finite",
                         false_alarms_per_hour, samples_per_hour, channels, k);
  }
  // Each side of each channel may alarm once per `target` samples.
  const double target = 2.0 * channels * samples_per_hour / false_alarms_per_hour;
  double lo = 0.0, hi = 1.0;
  while (cusum_arl0(hi, k) < target) hi *= 2.0;
  if (cusum_arl0(lo, k) >= target) return lo;
  for (int it = 0; it < 200 && hi - lo > 1e-12 * hi; ++it) {
    const double mid = 0.5 * (lo + hi);
    (cusum_arl0(mid, k) < target ? lo : hi) = mid;
  }
  return hi;
}

}  // namespace cdpr
