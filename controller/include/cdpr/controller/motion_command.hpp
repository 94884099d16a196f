// What the daemon's supervisor hands to the RT loop: an immutable geometry, and motion commands
// (a trajectory to follow, a pose to hold, or a re-reference under a new geometry).
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <optional>

#include "cdpr/calibration/path.hpp"
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
    kStream,     // while holding: follow the setpoint stream (RtController::push_setpoint)
                 // until a stop request, a refused setpoint or a fault; then hold
  };
  Type type = Type::kMove;
  std::uint64_t seq = 0;  // increasing; the RT snapshot reports which one is active and done
  std::optional<PoseTrajectory> trajectory;  // kMove
  std::optional<Path> path;                  // kMove: a path (run) instead of `trajectory`
  // kMove: pretension of the tension planner at the end of the move (it changes linearly along
  // the move), N; NaN: the geometry's reference tension.
  double reference_tension = std::numeric_limits<double>::quiet_NaN();
  Pose pose;
  const Geometry* geometry = nullptr;
  bool from_actual = false;
  // kReference: no slew. The targets stay at the drives' actual positions (nothing moves); with
  // a `pose` the inverse kinematics can solve, the loop holds that pose with the difference
  // between the actual positions and its targets as trims (they fade out over the next move);
  // otherwise, or with counts_only, it holds the counts without kinematics
  // (RtMode::kHoldingCounts).
  bool hold_actual = false;
  bool counts_only = false;
  // hold_actual: the encoder offsets (counts per cable) from this cycle on (a homing).
  std::optional<std::array<double, kMaxAxes>> offsets;
  std::array<double, kMaxAxes> trim{};  // kTrim: counts per cable
};

// One setpoint of the stream (setpoint_stream.hpp), as the receiving thread hands it to the RT
// loop (trivially copyable; an SPSC ring between the two).
struct StreamSetpoint {
  enum class Verdict : std::uint8_t {
    kOk,
    kRefused,  // the receiver's check failed (box, tensions, cable lengths): the stream ends
  };
  std::uint64_t seq = 0;
  std::int64_t sent_ns = 0;      // the sender's timestamp (CLOCK_MONOTONIC), ns
  std::int64_t received_ns = 0;  // the receiver's (the daemon's clock), ns
  std::array<double, 6> pose{};  // x, y, z (m), roll, pitch, yaw (rad)
  Verdict verdict = Verdict::kOk;
};

}  // namespace cdpr::controller
