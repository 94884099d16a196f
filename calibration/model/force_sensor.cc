#include "cdpr/calibration/force_sensor.hpp"

#include <algorithm>
#include <cmath>

namespace cdpr {

Result<ForceSensorFit> fit_force_sensor(std::span<const ForceCalibrationSample> samples,
                                        double gravity) {
  const int n = static_cast<int>(samples.size());
  if (!(gravity > 0.0) || !std::isfinite(gravity)) {
    return Status::error(ErrorCode::kInvalidArgument, "force sensor fit: gravity %g must be > 0",
                         gravity);
  }
  if (n < 3) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "force sensor fit: %d samples; gain, offset and their standard errors "
                         "need at least 3 (with 2 or more distinct masses)",
                         n);
  }
  double x_mean = 0.0;
  double y_mean = 0.0;
  for (int k = 0; k < n; ++k) {
    const ForceCalibrationSample& s = samples[static_cast<std::size_t>(k)];
    if (!std::isfinite(s.mass) || !std::isfinite(s.raw)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "force sensor fit: sample %d is not finite (mass %g kg, raw %g)", k,
                           s.mass, s.raw);
    }
    if (s.mass < 0.0) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "force sensor fit: sample %d has a negative mass (%g kg)", k, s.mass);
    }
    x_mean += s.mass * gravity;
    y_mean += s.raw;
  }
  x_mean /= n;
  y_mean /= n;
  double sxx = 0.0;
  double sxy = 0.0;
  double x_max = 0.0;
  for (const ForceCalibrationSample& s : samples) {
    const double dx = s.mass * gravity - x_mean;
    sxx += dx * dx;
    sxy += dx * (s.raw - y_mean);
    x_max = std::max(x_max, s.mass * gravity);
  }
  // Spread below rounding of the tensions themselves: a single mass.
  if (!(sxx > n * 1e-24 * std::max(1.0, x_max * x_max))) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "force sensor fit: all %d samples use the same mass (%g kg); the gain "
                         "needs at least two different masses",
                         n, samples[0].mass);
  }
  ForceSensorFit fit;
  fit.num_samples = n;
  fit.sensor.gain = sxy / sxx;
  fit.sensor.offset = y_mean - fit.sensor.gain * x_mean;
  double ssr = 0.0;
  for (const ForceCalibrationSample& s : samples) {
    const double e = s.raw - force_sensor_raw(fit.sensor, s.mass * gravity);
    ssr += e * e;
    fit.max_abs_residual = std::max(fit.max_abs_residual, std::abs(e));
  }
  const double sigma2 = ssr / (n - 2);
  fit.residual_rms = std::sqrt(sigma2);
  fit.gain_stderr = std::sqrt(sigma2 / sxx);
  fit.offset_stderr = std::sqrt(sigma2 * (1.0 / n + x_mean * x_mean / sxx));
  if (!(std::abs(fit.sensor.gain) > 3.0 * fit.gain_stderr)) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "force sensor fit: the readings do not depend on the load (gain %.4g "
                         "+- %.2g raw/N): sensor disconnected or the masses not hanging on it?",
                         fit.sensor.gain, fit.gain_stderr);
  }
  return fit;
}

}  // namespace cdpr
