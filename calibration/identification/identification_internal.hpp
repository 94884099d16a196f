// Helpers shared by the identification sources (not installed).
#pragma once

#include <vector>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/robot_model.hpp"

namespace cdpr::ident_detail {

// The loaded length whose stretch the elongation model describes (elongation.hpp).
using cdpr::loaded_length;

// geometry_information without the per-pose matrices (GeometryInformation::per_pose stays empty):
// what analyze_identifiability needs, without n P x P doubles (a gigabyte on 100,000 poses).
Result<GeometryInformation> total_geometry_information(const CalibratedModel& model,
                                                       const MeasurementSet& set,
                                                       const std::vector<Pose>& poses,
                                                       const IdentificationOptions& options);

}  // namespace cdpr::ident_detail
