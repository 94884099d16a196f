// The identification of Jin et al. 2018 (Section 5.2) as a reference method: the baseline we
// measure the joint estimator (identification.hpp) against, in speed and accuracy.
//
// Algorithm (Figure 13 of the paper):
//   1. For the current frame anchors, solve the forward kinematics of every pose by a nested
//      Newton-Raphson (Gauss-Newton on the m length equations, finite-difference pose Jacobian)
//      from the measured cable lengths (Eq. 5).
//   2. Stack the errors of all poses: M cable errors (predicted minus measured length at the FK
//      pose, Eq. 7) and one laser error (ray-plane distance at the FK pose minus the reading,
//      Eqs. 8-9) per pose: ((M + 1) N) x 1 (Eq. 10).
//   3. Finite-difference Jacobian of the stacked error w.r.t. the chosen anchor coordinates V
//      (Eq. 11; every column needs N new forward kinematics).
//   4. V <- V - lambda J^+ Error (Eq. 12), until ||Error|| <= E_stop or max_iterations.
//
// Details the paper leaves open, fixed here:
// - Measured length: the readings relative to the home pose plus the home length from the current
//   anchors ("the calibration initially starts from the same EE position"): the encoder zero is
//   a function of the anchors, not a parameter. Pose `home_pose_index` must be the home pose.
// - Elongation: readings are unstretched lengths; with measured tensions they are converted to
//   kinematic lengths with the model's elongation (the paper's polynomial, Section 4.1).
// - The coordinates not in V stay at their initial values (the paper fixed them at measured
//   values), the laser plane and platform anchors are known.
// - Besides E_stop, the iteration also stops when the relative decrease of ||Error|| over an
//   iteration is below `min_relative_decrease` (with noisy data E_stop is never reached).
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct PaperMethodOptions {
  AnchorMask parameters;  // empty = the paper's V (paper_anchor_mask())
  double lambda = 0.5;    // under-relaxation, 0 < lambda <= 1
  double e_stop = 1e-9;   // m, stop when ||Error|| <= e_stop
  int max_iterations = 200;
  double min_relative_decrease = 1e-6;
  double fd_step = 1e-6;  // m, for the Jacobian w.r.t. V
  int fk_max_iterations = 50;
  double fk_tolerance = 1e-13;  // m, step norm that ends the inner Newton-Raphson
  bool use_laser = true;
  int home_pose_index = 0;
  double pinv_tolerance = 1e-10;  // relative singular value cut of J^+
};

struct PaperMethodReport {
  CalibratedModel estimate;
  std::vector<Pose> poses;  // FK poses at the final anchors
  int iterations = 0;
  long fk_solves = 0;
  double initial_error_norm = 0.0;  // ||Error||, m
  double final_error_norm = 0.0;
  std::vector<double> error_history;
  bool converged = false;  // E_stop reached or the error stopped decreasing
  std::string termination;
  double time_s = 0.0;
  std::string summary() const;
};

Result<PaperMethodReport> paper_method(const CalibratedModel& initial, const MeasurementSet& set,
                                       const PaperMethodOptions& options = {});

}  // namespace cdpr
