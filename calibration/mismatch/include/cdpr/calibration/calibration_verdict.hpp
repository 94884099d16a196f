// Whether a calibration (identify()) can be trusted: the test `cdpr-fit calibrate` states in its
// exit status (docs/cdpr-fit.md).
//
// Checks, in this order:
// 1. The estimate is a solution: the solver converged and no parameter ended on the bound of its
//    physical range (ParameterBounds in identification.hpp). Otherwise kNotTrustworthy.
// 2. The fit test: with a correct model the normalised residuals give chi^2 ~ chi^2(dof), dof =
//    residuals - (parameters + free pose coordinates). The fit is rejected (kFitRejected) when its
//    upper-tail p-value P(chi^2(dof) > chi^2) is below `alpha`. A fixed ratio chi^2/dof would
//    ignore that the spread of chi^2/dof shrinks with the degrees of freedom (sqrt(2/dof)): 1.3
//    is 0.9 sigma at 10 dof but 2.9 sigma at 190.
// 3. The identification's own warnings (rank deficiency, condition number, huge standard
//    deviations, chi^2 far below its dof, missing tensions): any of them gives kNotTrustworthy.
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"

namespace cdpr {

struct CalibrationVerdictOptions {
  // Significance level of the chi^2 fit test: the fraction of calibrations of a correct model
  // (with truthful noise sigmas) that is rejected.
  double alpha = 0.01;
};

struct CalibrationVerdict {
  enum class Kind {
    kPassed,          // converged, inside the physical ranges, fit consistent with the noise
    kFitRejected,     // the residuals are larger than the noise explains (a missing effect)
    kNotTrustworthy,  // not converged, a parameter on its bound, or an identification warning
  };
  Kind kind = Kind::kPassed;
  double chi2 = 0.0;
  int dof = 0;
  double p_value = 1.0;  // P(chi^2(dof) > chi2)
  double alpha = 0.0;
  bool converged = false;
  std::vector<std::string> at_bound;  // parameters on a bound of their physical range
  // Plain-language reasons, most important first (empty when passed).
  std::vector<std::string> reasons;

  bool passed() const { return kind == Kind::kPassed; }
};

const char* to_string(CalibrationVerdict::Kind kind);  // "passed", "fit_rejected", ...

// The chi-square test of a weighted least-squares fit, the one used by every front end (cdpr-fit's
// verdict, the daemon's acceptance gate): p = P(chi^2(dof) > chi2), passed when p >= alpha. With no
// degrees of freedom left (dof <= 0), or a chi2 that is not finite, nothing is tested: p = 0, not
// passed.
struct FitTest {
  double p_value = 0.0;
  bool passed = false;
};
FitTest chi_square_fit_test(double chi2, int dof, double alpha);

CalibrationVerdict judge_calibration(const IdentificationReport& report,
                                     const CalibrationVerdictOptions& options = {});

// Honest uncertainty under misfit. When the fit test failed (p below alpha, chi^2 above dof), the
// stated noise explains only dof / chi^2 of the residuals' spread, and the standard deviations
// that assume the model right are too small by about sqrt(chi^2 / dof). Scales the parameters'
// and the poses' standard deviations by that factor and the covariance by its square (the Birge
// ratio: the misfit taken as noise, spread like the stated noise). Returns the factor applied
// (1: the fit passed, nothing changed). It does not make a wrong model right: an effect the model
// misses biases the estimate, and the scaled figures only say how far it may be off.
double scale_uncertainty_for_misfit(const CalibrationVerdict& verdict,
                                    IdentificationReport* report);

}  // namespace cdpr
