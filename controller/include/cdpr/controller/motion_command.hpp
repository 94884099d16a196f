// What the daemon's supervisor hands to the RT loop: an immutable geometry, and motion commands
// (a trajectory to follow, a pose to hold, or a re-reference under a new geometry).
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <optional>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/calibration/trajectory.hpp"

namespace cdpr::controller {

inline constexpr int kMaxAxes = 16;

// An immutable robot geometry the RT loop commands with (a hot swap hands over a new one).
struct Geometry {
  int version = 0;
  RobotModel model;
  double reference_tension = 0.0;  // N, pretension of the tension planner
};

struct MotionCommand {
  enum class Type : std::uint8_t {
    kMove,       // follow `trajectory` (from the current commanded pose), then hold its end
    kReference,  // hold `pose` under `geometry` (nullptr: the active one); the targets start
                 // where they are (or at the actual positions with from_actual) and slew there
    kTrim,       // while holding: per-cable length trims (counts) on top of the inverse
                 // kinematics, for tension regulation; rate-limited; they fade out over the
                 // next move
  };
  Type type = Type::kMove;
  std::uint64_t seq = 0;  // increasing; the RT snapshot reports which one is active and done
  std::optional<PoseTrajectory> trajectory;  // kMove
  // kMove: pretension of the tension planner at the end of the move (it changes linearly along
  // the move), N; NaN: the geometry's reference tension.
  double reference_tension = std::numeric_limits<double>::quiet_NaN();
  Pose pose;
  const Geometry* geometry = nullptr;
  bool from_actual = false;
  std::array<double, kMaxAxes> trim{};  // kTrim: counts per cable
};

}  // namespace cdpr::controller
