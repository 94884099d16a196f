// Test support shared by the identification's channel tests (sensor_channels_test.cc,
// suspended_identification_test.cc): simulated recordings that fail the test when the simulator
// does, the largest residual, and the check of the exact (automatic) derivatives of every
// residual against central finite differences. Not installed.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/simulate.hpp"

namespace cdpr::testing {

// simulate_measurements of `truth` at `poses`, default sensor noise; an error fails the test and
// gives an empty recording.
inline SimulatedMeasurements simulated(const CalibratedModel& truth, const std::vector<Pose>& poses,
                                       const SimulationOptions& options, std::uint64_t seed) {
  auto sim = simulate_measurements(truth, poses, SensorNoise{}, seed, options);
  EXPECT_TRUE(sim.ok()) << sim.status().to_string();
  return sim.ok() ? *sim : SimulatedMeasurements{};
}

// The largest |normalised residual| over the poses of evaluate_residuals.
inline double largest_residual(const std::vector<Eigen::VectorXd>& residuals) {
  double w = 0.0;
  for (const Eigen::VectorXd& v : residuals) w = std::max(w, v.cwiseAbs().maxCoeff());
  return w;
}

// The Jacobians of geometry_information at `at` and `poses` (every pose's blocks kept), compared
// with central differences (step `step`) of evaluate_residuals: each row within
// `tolerance` x max(1, |exact|).
class ResidualDerivativeCheck {
 public:
  ResidualDerivativeCheck(CalibratedModel at, const MeasurementSet& set, std::vector<Pose> poses,
                          IdentificationOptions options, double step, double tolerance)
      : at_(std::move(at)),
        set_(set),
        poses_(std::move(poses)),
        options_(std::move(options)),
        step_(step),
        tolerance_(tolerance) {
    auto gi = geometry_information(at_, set_, poses_, options_, /*keep_jacobians=*/true);
    EXPECT_TRUE(gi.ok()) << gi.status().to_string();
    if (gi.ok()) gi_ = std::move(*gi);
  }

  bool ok() const { return gi_.jacobian_pose.size() == poses_.size(); }
  const GeometryInformation& information() const { return gi_; }

  // The column of `id` among the estimated parameters; -1 (and a test failure) if not estimated.
  int column(const ParameterId& id) const {
    const auto it = std::find(gi_.ids.begin(), gi_.ids.end(), id);
    if (it == gi_.ids.end()) {
      ADD_FAILURE() << parameter_name(id) << " is not estimated";
      return -1;
    }
    return static_cast<int>(it - gi_.ids.begin());
  }

  // The six coordinates of pose `j`: the derivative of its residuals against jacobian_pose[j].
  void expect_pose_derivatives(std::size_t j) const {
    for (int q = 0; q < 6; ++q) {
      std::vector<Pose> plus = poses_, minus = poses_;
      auto vp = plus[j].vector();
      auto vm = minus[j].vector();
      vp(q) += step_;
      vm(q) -= step_;
      plus[j] = Pose::from_vector(vp);
      minus[j] = Pose::from_vector(vm);
      const Eigen::VectorXd fd =
          (residuals(at_, plus)[j] - residuals(at_, minus)[j]) / (2.0 * step_);
      expect_close(fd, gi_.jacobian_pose[j].col(q), "pose coordinate " + std::to_string(q));
    }
  }

  // The parameter `id`, which `apply(model, x)` moves by x: the derivative of the residuals of
  // pose `only_pose` (every pose when negative) against its jacobian_geometry column.
  void expect_parameter_derivatives(const ParameterId& id,
                                    const std::function<void(CalibratedModel&, double)>& apply,
                                    int only_pose = -1) const {
    const int col = column(id);
    if (col < 0) return;
    CalibratedModel plus = at_, minus = at_;
    apply(plus, step_);
    apply(minus, -step_);
    const std::vector<Eigen::VectorXd> rp = residuals(plus, poses_);
    const std::vector<Eigen::VectorXd> rm = residuals(minus, poses_);
    for (std::size_t j = 0; j < poses_.size(); ++j) {
      if (only_pose >= 0 && j != static_cast<std::size_t>(only_pose)) continue;
      expect_close((rp[j] - rm[j]) / (2.0 * step_), gi_.jacobian_geometry[j].col(col),
                   parameter_name(id) + " at pose " + std::to_string(j));
    }
  }

 private:
  std::vector<Eigen::VectorXd> residuals(const CalibratedModel& model,
                                         const std::vector<Pose>& poses) const {
    auto r = evaluate_residuals(model, set_, poses, options_);
    EXPECT_TRUE(r.ok()) << r.status().to_string();
    return r.ok() ? *r : std::vector<Eigen::VectorXd>(poses.size());
  }

  void expect_close(const Eigen::VectorXd& fd, const Eigen::VectorXd& exact,
                    const std::string& what) const {
    ASSERT_EQ(fd.size(), exact.size()) << what;
    for (Eigen::Index q = 0; q < fd.size(); ++q) {
      EXPECT_NEAR(fd(q), exact(q), tolerance_ * std::max(1.0, std::abs(exact(q))))
          << what << ", row " << q;
    }
  }

  CalibratedModel at_;
  MeasurementSet set_;
  std::vector<Pose> poses_;
  IdentificationOptions options_;
  double step_, tolerance_;
  GeometryInformation gi_;
};

}  // namespace cdpr::testing
