// The reports of `cdpr-fit diagnose`: JSON document, text for people, and a self-contained HTML
// page with inline SVG plots (no script, no external file, no network).
//
// The plots show the normalised cable-length residuals (residual / sigma) of the standard
// identification ("before") and of the identification with the accepted effects ("after")
// against the variable that would explain each effect: tension x loaded length for elasticity,
// tension for compliance, loaded length for drum scale, time for drift, the pose index otherwise.
// The explaining variables are computed here from the MeasurementSet, the estimated poses of the
// standard identification and its model (inverse_kinematics), the same for both series, so that
// every point "before" has its partner "after".
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/measurement.hpp"

namespace cdpr::fit {

// What the reports say about the run besides the Diagnosis.
struct DiagnoseContext {
  std::string config, config_hash;
  std::string recording, recording_hash;
  std::string validation, validation_hash;  // empty: none
  int poses = 0, cables = 0, lasers = 0;    // of the recording and the config
  std::vector<std::string> estimated;       // items of calibrate --estimate
  unsigned seed = 1;
  int bootstrap = 0, folds = 0;
  std::string calibrated_config;  // written config, "" when none
  std::vector<std::string> warnings;
};

// One plot of residuals against an explaining variable.
struct ResidualPlot {
  std::string title;                  // "cable elasticity (Hooke, ~F*L), one EA for all cables"
  std::string effect_id;              // candidate id, "" when no candidate
  std::string variable;               // "tension x loaded length"
  std::string unit;                   // "N m"
  std::vector<double> x;              // one per (pose, cable) with a finite residual
  std::vector<int> cable;             // 0-based
  std::vector<double> before, after;  // normalised residuals; `after` empty without a refit
};

// Residual RMS per cable in sigmas (NaN where the cable has no residual).
struct CableMisfit {
  std::vector<double> before, after;  // `after` empty without a refit
};

// The explaining variable of a candidate family ("elasticity", "compliance", "drum scale", ...):
// its name and unit. Families without one give the pose index.
struct ExplainingVariable {
  std::string name, unit;
};
ExplainingVariable explaining_variable(const std::string& family);

// Plots for each accepted effect, else the top candidate (refitted, else screened), else one
// plot against the pose index.
std::vector<ResidualPlot> residual_plots(const Diagnosis& d, const MeasurementSet& set);
CableMisfit cable_misfit(const Diagnosis& d, int num_cables);

// "no_mismatch", "mismatch_named", "mismatch_unexplained", "inconclusive".
std::string verdict_key(Diagnosis::Verdict v);

nlohmann::json diagnosis_json(const Diagnosis& d, const DiagnoseContext& c,
                              const CableMisfit& misfit);
std::string diagnosis_text(const Diagnosis& d, const DiagnoseContext& c);
std::string diagnosis_html(const Diagnosis& d, const DiagnoseContext& c,
                           const std::vector<ResidualPlot>& plots, const CableMisfit& misfit);

// Text for HTML element content and attribute values (& < > " ').
std::string html_escape(const std::string& s);

}  // namespace cdpr::fit
