#include "cdpr/calibration/model_plausibility.hpp"

#include <cmath>
#include <cstdio>
#include <string>

#include "cdpr/calibration/kinematics.hpp"

namespace cdpr {
namespace {

// A unit hint when the value would fit the range in another unit (x 1000: mm for m, g for kg).
std::string unit_hint(double v, double lo, double hi, const char* unit) {
  const std::string u(unit);
  const double k = std::abs(v) / 1000.0;
  if (!(std::abs(v) > hi && k >= lo && k <= hi)) return "";
  if (u == "m") return " (looks like mm, expected m)";
  if (u == "kg") return " (looks like g, expected kg)";
  if (u == "m/s^2") return " (looks like mm/s^2, expected m/s^2)";
  return "";
}

// "<field>: <what> <v> <unit>, outside the plausible range [lo, hi] <unit> (<hint>)".
void check(std::vector<Status>& out, const std::string& field, const char* what, double v,
           double lo, double hi, const char* unit) {
  if (v >= lo && v <= hi) return;
  out.push_back(Status::error(
      ErrorCode::kInvalidArgument, "%s: %s %.6g %s, outside the plausible range [%.6g, %.6g] %s%s",
      field.c_str(), what, v, unit, lo, hi, unit, unit_hint(v, lo, hi, unit).c_str()));
}

std::string cable(int i, const char* key) {
  return "cables[" + std::to_string(i) + "]." + key;
}

// The largest distance between two frame anchors, and the anchor that has it.
double frame_span(const RobotModel& model, int& at) {
  double span = 0.0;
  at = 0;
  for (int i = 0; i < model.num_cables(); ++i) {
    for (int j = i + 1; j < model.num_cables(); ++j) {
      const double d = (model.frame_anchors.col(i) - model.frame_anchors.col(j)).norm();
      if (d > span) {
        span = d;
        at = i;
      }
    }
  }
  return span;
}

void check_cable(std::vector<Status>& out, const RobotModel& model, int i, double span,
                 const ModelPlausibility& l) {
  const auto k = static_cast<std::size_t>(i);
  const double far = l.length_frame_multiple * span;
  check(out, cable(i, "platform_anchor"), "the platform anchor is",
        model.platform_anchors.col(i).norm(), 0.0, span, "m");
  check(out, cable(i, "pulley.radius"), "the pulley radius is", model.pulleys[k].radius, 0.0,
        l.max_pulley_radius_m, "m");
  const WinchModel& w = model.winches[k];
  check(out, cable(i, "winch.drum_diameter"), "the drum diameter is", w.drum_diameter, 1e-4,
        l.max_drum_diameter_m, "m");
  check(out, cable(i, "winch.drum_pitch"), "the groove pitch is", w.drum_pitch, 0.0,
        w.drum_diameter, "m");
  check(out, cable(i, "winch.length_offset"), "the length offset is", std::abs(w.length_offset),
        0.0, far, "m");
  const CableModel& c = model.cables[k];
  check(out, cable(i, "routing_length"), "the routing length is", c.routing_length, 0.0, far, "m");
  check(out, cable(i, "ea"), "the axial stiffness is", c.ea, l.min_ea_n, l.max_ea_n, "N");
  check(out, cable(i, "mass_per_length"), "the mass per length is", c.mass_per_length, 0.0,
        l.max_mass_per_length_kg_m, "kg/m");
  check(out, cable(i, "f_max"), "the maximum tension is", c.f_max, 0.0, l.max_tension_n, "N");
  if (!(c.f_max > c.f_min)) {
    out.push_back(Status::error(ErrorCode::kInvalidArgument,
                                "%s: the tension range [%g, %g] N is empty: f_max must exceed "
                                "f_min",
                                cable(i, "f_max").c_str(), c.f_min, c.f_max));
  }
}

// The platform's weight must be within what the cables can hold together.
void check_weight(std::vector<Status>& out, const RobotModel& model) {
  double sum_f_max = 0.0;
  for (const CableModel& c : model.cables) sum_f_max += c.f_max;
  const double weight = model.platform.mass * model.gravity;
  if (weight <= sum_f_max) return;
  out.push_back(Status::error(ErrorCode::kInvalidArgument,
                              "platform.mass: a weight of %.6g N is more than every cable at "
                              "f_max holds together (%.6g N)",
                              weight, sum_f_max));
}

// The cable lengths at the home pose: within the frame's reach.
void check_home_lengths(std::vector<Status>& out, const RobotModel& model, double span,
                        const ModelPlausibility& l) {
  KinematicsData kin(model.num_cables());
  if (!inverse_kinematics(model, model.home, kin)) return;  // check_model names it
  for (int i = 0; i < model.num_cables(); ++i) {
    check(out, cable(i, "frame_anchor"), "the cable length at home is", kin.lengths(i), 0.0,
          l.length_frame_multiple * span, "m");
  }
}

}  // namespace

std::vector<Status> check_model_plausible(const RobotModel& model, const ModelPlausibility& l) {
  std::vector<Status> out;
  const int m = model.num_cables();
  if (m == 0 || static_cast<int>(model.winches.size()) != m ||
      static_cast<int>(model.cables.size()) != m || static_cast<int>(model.pulleys.size()) != m ||
      model.platform_anchors.cols() != m) {
    return out;  // not a complete model: check_model names it
  }
  int at = 0;
  const double span = frame_span(model, at);
  check(out, cable(at, "frame_anchor"), "the frame anchors span", span, l.min_frame_m,
        l.max_frame_m, "m");
  if (!out.empty()) return out;  // every length below is measured against the frame
  check(out, "platform.mass", "the platform mass is", model.platform.mass, l.min_mass_kg,
        l.max_mass_kg, "kg");
  check(out, "gravity", "gravity is", model.gravity, l.min_gravity, l.max_gravity, "m/s^2");
  for (int i = 0; i < m; ++i) check_cable(out, model, i, span, l);
  check_weight(out, model);
  check_home_lengths(out, model, span, l);
  return out;
}

}  // namespace cdpr
