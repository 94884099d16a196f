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

// What one HTML page shows: an identification, a diagnosis, or both (html_page.cc).
struct PageInput {
  std::string heading = "Calibration report";
  const RobotModel* before = nullptr;              // required: the model identified from
  const CalibratedModel* after = nullptr;          // required: the proposed model
  const IdentificationReport* standard = nullptr;  // the standard identification (null: none ran)
  const IdentificationReport* fit = nullptr;       // the final fit (standard, or with the effects)
  const Diagnosis* diagnosis = nullptr;            // optional
  const MeasurementSet* set = nullptr;             // required
  const ReportContext* context = nullptr;          // required
};
// The whole page: the decision summary on the first screen, then the plots, then the tables and
// the details.
std::string html_page(const PageInput& in);

}  // namespace cdpr::report
