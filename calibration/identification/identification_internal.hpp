// Helpers shared by the identification sources (not installed).
#pragma once

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

}  // namespace cdpr::ident_detail
