// What a robot description of a cable robot that moves can hold, in SI units (cdprd
// --check-config): a file in millimetres (anchors x 1000), a platform of 2000 kg, a drum of 40 m.
// check_model (model_check.hpp) finds what makes the model unusable; this finds what is usable
// but implausible, the way recording::check_plausible does for recordings.
//
// Every finding starts with the field's name in the config-file notation, then ": " (as
// check_model's messages, so drivers/config maps it to a line):
//   "cables[0].frame_anchor: the frame anchors span 1538.31 m, outside the plausible range
//    [0.1, 200] m (looks like mm, expected m)"
// Pure: no I/O.
#pragma once

#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct ModelPlausibility {
  double min_frame_m = 0.1, max_frame_m = 200.0;  // span of the frame anchors
  double min_mass_kg = 1e-3, max_mass_kg = 1e4;   // platform
  double max_tension_n = 1e6;                     // f_max (recording::PlausibilityLimits)
  double max_drum_diameter_m = 2.0;               // winch drum
  double max_pulley_radius_m = 1.0;               // swivel pulley
  double length_frame_multiple = 10.0;            // routing, offsets, cable lengths at home
  double min_ea_n = 1.0, max_ea_n = 1e10;         // axial stiffness
  double max_mass_per_length_kg_m = 10.0;         // cable
  double min_gravity = 0.0, max_gravity = 20.0;   // m/s^2
};

// Every finding (empty: plausible). Use on a model that check_model accepts.
std::vector<Status> check_model_plausible(const RobotModel& model,
                                          const ModelPlausibility& limits = {});

}  // namespace cdpr
