// A change detector for a normalised residual (zero mean, unit variance while nothing changed):
// the two-sided CUSUM of Page,
//   S+ = max(0, S+ + z - k),   S- = max(0, S- - z - k),   alarm when S+ > h or S- > h,
// with the allowance k (half the shift, in sigmas, it is tuned for) and the threshold h derived
// from a STATED false-alarm rate per hour (cusum_threshold).
//
// Threshold: Siegmund's approximation of the in-control average run length of a one-sided CUSUM on
// N(0, 1) samples,
//   ARL0(h, k) = (exp(2 k b) - 2 k b - 1) / (2 k^2),   b = h + 1.166,
// the two sides together alarm twice as often (1/ARL = 1/ARL+ + 1/ARL-), and C channels watched at
// once C times as often (independent channels; correlated ones alarm less, so the stated rate is
// an upper bound). With n samples per hour per channel and a stated rate lambda per hour:
//   ARL0(h, k) = 2 C n / lambda,
// solved for h by bisection. change_detector_test.cc checks the rate by simulation.
//
// update() allocates nothing, locks nothing, throws nothing.
#pragma once

#include "cdpr/status.hpp"

namespace cdpr {

// Siegmund's in-control ARL (samples) of a one-sided CUSUM with allowance k > 0, threshold h >= 0.
double cusum_arl0(double h, double k);

// The threshold h for which `channels` two-sided CUSUMs with allowance k, each fed
// `samples_per_hour` samples, together raise `false_alarms_per_hour` false alarms per hour.
// kInvalidArgument for a non-positive rate, count or allowance.
Result<double> cusum_threshold(double false_alarms_per_hour, double samples_per_hour, int channels,
                               double k);

class Cusum {
 public:
  Cusum() = default;
  Cusum(double k, double h) : k_(k), h_(h) {}

  // Adds one normalised sample (a non-finite one is skipped). True when this sample raised an
  // alarm (S+ or S- crossed h); the sums then restart from 0.
  bool update(double z) {
    if (!(z - z == 0.0)) return false;  // NaN or infinite
    plus_ = plus_ + z - k_ > 0.0 ? plus_ + z - k_ : 0.0;
    minus_ = minus_ - z - k_ > 0.0 ? minus_ - z - k_ : 0.0;
    if (plus_ > h_ || minus_ > h_) {
      last_sign_ = plus_ > h_ ? 1 : -1;
      plus_ = minus_ = 0.0;
      return true;
    }
    return false;
  }
  void reset() {
    plus_ = minus_ = 0.0;
    last_sign_ = 0;
  }

  double plus() const { return plus_; }
  double minus() const { return minus_; }
  double statistic() const { return plus_ > minus_ ? plus_ : minus_; }  // of h: alarm above h
  int last_alarm_sign() const { return last_sign_; }  // +1: residual grew, -1: fell, 0: none yet
  double threshold() const { return h_; }
  double allowance() const { return k_; }

 private:
  double k_ = 0.5;
  double h_ = 5.0;
  double plus_ = 0.0;
  double minus_ = 0.0;
  int last_sign_ = 0;
};

}  // namespace cdpr
