// Helpers shared by the identification sources (not installed).
#pragma once

#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/robot_model.hpp"

namespace cdpr::ident_detail {

// The loaded length whose stretch the elongation model describes: the kinematic length plus the
// routing length between winch and frame anchor when the model has one.
template <typename T, typename Cable>
T loaded_length(const Cable& cable, const T& kinematic_length) {
  if constexpr (requires { cable.routing_length; }) {
    return kinematic_length + T(cable.routing_length);
  } else {
    return kinematic_length;
  }
}

// geometry_information without the per-pose matrices (GeometryInformation::per_pose stays empty):
// what analyze_identifiability needs, without n P x P doubles (a gigabyte on 100,000 poses).
Result<GeometryInformation> total_geometry_information(const CalibratedModel& model,
                                                       const MeasurementSet& set,
                                                       const std::vector<Pose>& poses,
                                                       const IdentificationOptions& options);

}  // namespace cdpr::ident_detail
