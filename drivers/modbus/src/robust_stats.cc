#include "cdpr/modbus/robust_stats.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace cdpr::modbus {

namespace {

double median_of(std::vector<double>& v) {
  const std::size_t n = v.size();
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(n / 2);
  std::nth_element(v.begin(), mid, v.end());
  if (n % 2 == 1) return *mid;
  const double upper = *mid;
  const double lower = *std::max_element(v.begin(), mid);
  return 0.5 * (lower + upper);
}

}  // namespace

RobustMean robust_mean(std::span<const double> values, double k, double min_sigma) {
  RobustMean r;
  std::vector<double> finite;
  finite.reserve(values.size());
  for (double v : values) {
    if (std::isfinite(v)) finite.push_back(v);
  }
  r.rejected = static_cast<int>(values.size() - finite.size());
  if (finite.empty()) return r;

  std::vector<double> work = finite;
  r.median = median_of(work);
  for (std::size_t i = 0; i < finite.size(); ++i) work[i] = std::fabs(finite[i] - r.median);
  const double mad = median_of(work);
  r.sigma = std::max(1.4826 * mad, std::max(min_sigma, 0.0));
  const double limit = k * r.sigma;

  double sum = 0.0;
  int n = 0;
  for (double v : finite) {
    if (std::fabs(v - r.median) <= limit) {
      sum += v;
      ++n;
    }
  }
  r.used = n;
  r.rejected += static_cast<int>(finite.size()) - n;
  if (n == 0) {  // only with k * sigma == 0 and an even count: nothing sits on the median
    r.mean = r.median;
    return r;
  }
  r.mean = sum / n;
  double ss = 0.0;
  for (double v : finite) {
    if (std::fabs(v - r.median) <= limit) ss += (v - r.mean) * (v - r.mean);
  }
  r.stddev = n > 1 ? std::sqrt(ss / (n - 1)) : 0.0;
  return r;
}

}  // namespace cdpr::modbus
