// Pieces shared by the identification and diagnosis renderings (internal to cdpr_report).
#pragma once

#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/report/report.hpp"

namespace cdpr::report {

// RMS of the normalised cable-length residuals per cable (NaN where a cable has none).
std::vector<double> cable_rms(const std::vector<PoseResiduals>& residuals, int num_cables);

// "<!DOCTYPE html>...<body>" of a report page with the reports' style.
std::string page_head(const std::string& title);
// Table cells with escaped text; `numeric` right-aligns.
std::string td(const std::string& text, bool numeric = false);
std::string th(const std::string& text);

// The diagnosis sections of an HTML page (verdict to warnings), without the page around them.
std::string diagnosis_html_body(const Diagnosis& d, const RobotModel& nominal,
                                const MeasurementSet& set, const ReportContext& c);

}  // namespace cdpr::report
