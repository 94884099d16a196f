// What would explain a mismatch: for each candidate effect family of the mismatch locator the
// variable its signature grows with, and the normalised cable-length residuals of a diagnosis
// against that variable (the points of the reports' residual plots).
//
// The variables are computed from the MeasurementSet, the poses estimated by the standard
// identification and its model (inverse kinematics), the same for the residuals before and after
// the accepted effects, so that every point "before" has its partner "after".
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/measurement.hpp"

namespace cdpr {

// The explaining variable of each candidate family (ExplainingVariable, explaining_variable) is
// the effect library's (effect_library.hpp).

// Normalised cable-length residuals (residual / sigma) against an explaining variable.
struct ExplainedResiduals {
  std::string title;                  // "cable elasticity (Hooke, ~F*L), one EA for all cables"
  std::string effect_id;              // candidate id, "" when no candidate
  std::string variable;               // "tension x loaded length"
  std::string unit;                   // "N m"
  std::vector<double> x;              // one per (pose, cable) with a finite residual
  std::vector<int> cable;             // 0-based
  std::vector<double> before, after;  // `after` empty without a refit
};

// One series per accepted effect, else for the top refitted candidate, else the top screened
// candidate, else one against the pose index. When the variable was not recorded (no tensions,
// no time) the series falls back to the pose index and its title says so.
std::vector<ExplainedResiduals> explained_residuals(const Diagnosis& d, const MeasurementSet& set);

}  // namespace cdpr
