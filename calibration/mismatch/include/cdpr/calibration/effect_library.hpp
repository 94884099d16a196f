// The candidate effects of the mismatch locator, one descriptor each, in one table: where the
// candidate's columns come from, the identification switch that estimates it, how diagnose()
// refits it, the range its estimate is held in, its words for people, how it is written into the
// calibrated model and what its residuals are plotted against. Adding an effect is one entry here
// (and, for a new kind of columns, its columns in mismatch_design).
// Pure data and small functions (no I/O, no logging).
#pragma once

#include <Eigen/Core>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/robot_model.hpp"

namespace cdpr {

// The variable a candidate's signature grows with (the residual plots' horizontal axis):
// tension x loaded length (N m), tension (N), loaded length (m), time (s), the direction of the
// cable's last move (+1 paid out, -1 reeled in, 0 not yet moved); the pose index (no unit) for the
// effects without one.
struct ExplainingVariable {
  std::string name, unit;
};

// Where mismatch_design takes a candidate's columns from.
enum class EffectColumns {
  kLengthRows,             // a regressor on the length rows (one column, or one per cable)
  kCatenary,               // sag: the arc's excess on the length rows, the weight on the wrench
  kUnestimatedParameters,  // the identification Jacobian of parameters it did not estimate
  kSumOfPerCable,          // the sum of the per-cable member's columns (one shared coefficient)
  kLastMoveDirection,      // the direction of each cable's last move (hysteresis, friction)
};

// How diagnose() refits the model with the candidate added.
enum class EffectRefit {
  // identify() with the effect's switch on (`estimate`, optionally also `alternative`, the lower
  // BIC kept); when that fails, the Gauss-Newton augmented fit below.
  kIdentification,
  // Gauss-Newton: the coefficients from the projected columns, the effect moved into the
  // readings, identify() redone until the deviance settles.
  kGaussNewton,
  // Sag: the mass per length by Gauss-Newton on the exact catenary (sag_effect, mismatch.hpp).
  kCatenary,
};

struct EffectDescriptor {
  std::string_view id;      // candidate id ("hooke_shared", ...)
  std::string_view name;    // plain language (CandidateScreen::name)
  std::string_view family;  // candidates of one family are refinements of each other
  // Families that refine each other share a selection group (nonlinear elasticity refines
  // elasticity): one per forward-selection path, compared by nested tests, never confounded.
  std::string_view group;
  EffectColumns columns;
  EffectRefit refit;
  // kIdentification: switches on the estimate of the effect's parameters.
  void (*estimate)(IdentificationOptions&) = nullptr;
  // kIdentification: a reduced alternative (applied after `estimate`) also fitted, the lower BIC
  // kept (nullptr: none).
  void (*alternative)(IdentificationOptions&) = nullptr;
  // The range its estimate is held in (ParameterBounds field, or the constraint of the refit).
  std::string_view bounds;
  // A fitted coefficient q of k (Gauss-Newton or catenary) in engineer words; nullptr: generic.
  EffectParameter (*describe)(int q, int k, double value, double std_dev) = nullptr;
  // Writes the fitted coefficients into the model where the config can carry them (false: report
  // only). kIdentification effects are in identify()'s estimate already.
  bool (*write)(const Eigen::VectorXd& theta, CalibratedModel& model) = nullptr;
  ExplainingVariable plotted_against;
  // kUnestimatedParameters: the identification parameters whose Jacobian columns are the
  // candidate's (those the standard identification left fixed).
  std::vector<ParameterKind> parameters = {};
  // An effect shared by every cable at every pose (the platform's weight: one force and moment
  // pattern) whose misfit a per-cable effect of the same readings also explains, cable by cable
  // (the force sensor gains): that effect's id. The shared effect is named only when its rival is
  // not significant beside it (EffectFit::rival_p_value); the two share a selection group, so
  // that they are never in one model. Empty: none.
  std::string_view per_cable_rival = {};
};

// The library, in the order mismatch_design builds (and the screen ranks ties of) the candidates.
const std::vector<EffectDescriptor>& effect_library();

// The descriptor of a candidate id; nullptr when unknown.
const EffectDescriptor* find_effect(std::string_view id);

// A Gauss-Newton coefficient of a candidate in engineer words (the descriptor's `describe`, else
// "<id> coefficient <q>").
EffectParameter describe_coefficient(std::string_view id, int q, int k, double value,
                                     double std_dev);

// Carries fitted coefficients of a candidate into the calibrated model (the descriptor's `write`);
// false where the config cannot hold the effect.
bool write_effect(std::string_view id, const Eigen::VectorXd& theta, CalibratedModel& model);

// selection_group (mismatch.hpp) reads the descriptors' groups.

// The explaining variable of a candidate family ("elasticity", "compliance", "drum scale", ...):
// the plotted_against of its descriptors; the pose index for families without one.
ExplainingVariable explaining_variable(const std::string& family);

// Number formatting shared by the effects' words: digits so that a standard deviation shows one
// or two significant figures, and a signed fixed-point number.
int digits_for(double std_dev);
std::string signed_number(double v, int digits);

}  // namespace cdpr
