#include "cdpr/calibration/calibration_verdict.hpp"

#include <cmath>
#include <cstdio>

#include "cdpr/calibration/mismatch.hpp"

namespace cdpr {

const char* to_string(CalibrationVerdict::Kind kind) {
  switch (kind) {
    case CalibrationVerdict::Kind::kPassed:
      return "passed";
    case CalibrationVerdict::Kind::kFitRejected:
      return "fit_rejected";
    case CalibrationVerdict::Kind::kNotTrustworthy:
      return "not_trustworthy";
  }
  return "unknown";
}

FitTest chi_square_fit_test(double chi2, int dof, double alpha) {
  FitTest t;
  // A chi^2 that is not a number (a diverged fit) is no evidence of a fit: p = 0.
  t.p_value = dof > 0 && std::isfinite(chi2) ? chi2_upper_tail(chi2, dof) : 0.0;
  t.passed = t.p_value >= alpha;
  return t;
}

CalibrationVerdict judge_calibration(const IdentificationReport& report,
                                     const CalibrationVerdictOptions& options) {
  CalibrationVerdict v;
  v.chi2 = report.chi2;
  v.dof = report.dof;
  v.alpha = options.alpha;
  v.converged = report.converged;
  v.at_bound = report.parameters_at_bound();
  const FitTest fit = chi_square_fit_test(report.chi2, report.dof, options.alpha);
  v.p_value = fit.p_value;
  char buf[256];

  bool solution = true;
  if (!report.converged) {
    solution = false;
    v.reasons.push_back("the solver did not converge (" + report.termination + ")");
  }
  if (!v.at_bound.empty()) {
    solution = false;
    std::string names;
    for (const std::string& n : v.at_bound) names += (names.empty() ? "" : ", ") + n;
    v.reasons.push_back("parameters ended on the bound of their physical range: " + names);
  }
  const bool rejected = !fit.passed;
  if (rejected) {
    std::snprintf(buf, sizeof(buf),
                  "the fit test failed: chi-square %.1f for %d degrees of freedom (chi2/dof %.2f), "
                  "p = %.2g < %.2g: the residuals are larger than the stated noise explains",
                  report.chi2, report.dof, report.dof > 0 ? report.chi2 / report.dof : 0.0,
                  v.p_value, options.alpha);
    v.reasons.emplace_back(buf);
  }
  // The identification's own checks; the convergence and bound warnings are stated above.
  bool other_warning = false;
  for (const std::string& w : report.warnings) {
    const bool stated = w.rfind("the solver did not converge", 0) == 0 ||
                        w.find("ended on the") != std::string::npos;
    if (stated) continue;
    other_warning = true;
    v.reasons.push_back(w);
  }
  if (!solution) {
    v.kind = CalibrationVerdict::Kind::kNotTrustworthy;
  } else if (rejected) {
    v.kind = CalibrationVerdict::Kind::kFitRejected;
  } else if (other_warning) {
    v.kind = CalibrationVerdict::Kind::kNotTrustworthy;
  }
  return v;
}

double scale_uncertainty_for_misfit(const CalibrationVerdict& verdict,
                                    IdentificationReport* report) {
  if (!(verdict.p_value < verdict.alpha) || verdict.dof <= 0 || !(verdict.chi2 > verdict.dof)) {
    return 1.0;
  }
  const double ratio = verdict.chi2 / verdict.dof;
  const double factor = std::sqrt(ratio);
  for (ParameterEstimate& p : report->parameters) p.std_dev *= factor;
  report->covariance *= ratio;
  for (auto& s : report->pose_std) s *= factor;
  return factor;
}

}  // namespace cdpr
