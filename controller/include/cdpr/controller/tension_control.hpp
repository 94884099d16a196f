// Tension control in the null space of the structure matrix: a stage of the RT cycle
// (rt_controller.hpp, control_tensions) that trims the cable length targets from the measured
// tensions so that every cable goes towards its planned tension clamped into the band
// [f_min + margin, f_max - margin], while the platform stays where it is.
//
// An over-constrained robot (m > 6 cables) has an (m - 6)-dimensional kernel of its structure
// matrix A^T (6 x m): tension changes df with A^T df = 0 change only the internal forces. Each
// cycle, with the measured tensions f and the plan p at the commanded pose:
//
//   e   = clamp(p, lo + d, hi - d) - f, each entry shrunk by the deadband d (0 inside it);
//         a cable outside [lo, hi] keeps its whole error, with weight kEdgeWeight
//   df  = e - W^-1 A (A^T W^-1 A)^-1 A^T e    the change in ker A^T nearest to e (weights W):
//         the plan's internal forces cannot always all be met, the band comes first
//   dl  = -c .* df                        c_i: cable i's compliance (m/N) at its plan
//   trim += clamp_rate(gain * dt * dl)    counts; the whole step scaled to the rate limit
//   trim  = clamp(trim, -max_trim, max_trim)   (anti-windup: the trim is the integrator)
//
// Lengthening cable i by dl_i = -df_i / k_i with df in ker A^T leaves the platform in
// equilibrium where it is (to first order) and changes the tensions by df: the trims act on the
// internal forces only, during holds and moves alike. A robot with 6 cables has no kernel: the
// stage trims nothing.
//
// Readings: a stale reading (none fresh for stale_s), a non-finite one, no tension channel, or a
// latched force fault freezes the trims for hold_s, then they decay towards 0 (time constant
// decay_s, within the rate limit): back to pure position control with the feed-forward plan.
// state() reports which. step() allocates, locks, logs and throws nothing.
#pragma once

#include <array>
#include <cstdint>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/controller/motion_command.hpp"
#include "cdpr/controller/path_check.hpp"
#include "cdpr/controller/robot_io.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

struct TensionControlOptions {
  double gain = 0.0;        // 1/s, integral gain on the projected tension error; 0: off
  double margin = 10.0;     // N, target band [f_min + margin, f_max - margin]
  double deadband = 1.0;    // N, tension errors within this are left alone
  double max_rate = 0.005;  // m/s of cable, largest trim rate of any cable
  double max_trim = 0.03;   // m of cable, largest trim of any cable
  double stale_s = 0.05;    // s without a fresh reading before the trims freeze
  double hold_s = 0.5;      // s frozen before the trims decay
  double decay_s = 2.0;     // s, time constant of the decay towards 0
};

enum class TensionControlState : std::uint8_t {
  kOff,       // not enabled, or the robot is not holding or moving: no trims
  kActive,    // the trims follow the readings
  kFrozen,    // the readings are stale or faulty: the trims stay where they are
  kDecaying,  // stale or faulty for longer than hold_s: the trims decay towards 0
};
const char* to_string(TensionControlState s);

// What the stage reports (in RtSnapshot).
struct TensionControlStatus {
  TensionControlState state = TensionControlState::kOff;
  bool in_band = false;        // every measured tension in [f_min + margin, f_max - margin]
  bool saturated = false;      // some trim is at max_trim
  double largest_error = 0.0;  // N, largest |clamp(p, lo + d, hi - d) - f| of this cycle
  std::array<double, kMaxAxes> trim_counts{};
};

class TensionControl {
 public:
  // Weight of a cable outside its band [lo, hi] against one inside it (1).
  static constexpr double kEdgeWeight = 10.0;
  // Checks the options (finite, non-negative, positive times); cycle_s > 0.
  static Status validate(const TensionControlOptions& o, double cycle_s);
  void configure(const TensionControlOptions& o, double cycle_s) noexcept {
    options_ = o;
    cycle_s_ = cycle_s;
  }
  bool enabled() const noexcept { return options_.gain > 0.0; }
  const TensionControlOptions& options() const noexcept { return options_; }

  // Trims back to 0 and the reading watch reset (a re-reference, a disabled robot).
  void reset() noexcept;
  // One cycle. `run`: the robot holds or moves (otherwise the trims are reset). `sensor_fault`:
  // a force fault is latched (the readings are not trusted). `data` is the plan and the
  // kinematics at the commanded pose (command_counts).
  void step(bool run, bool sensor_fault, const RobotReading& in, const RobotModel& model,
            const CommandData& data) noexcept;

  double trim(int i) const noexcept { return status_.trim_counts[static_cast<std::size_t>(i)]; }
  const TensionControlStatus& status() const noexcept { return status_; }

 private:
  bool readings_usable(bool sensor_fault, const RobotReading& in, int m) noexcept;
  void follow(const RobotReading& in, const RobotModel& model, const CommandData& data) noexcept;
  void decay(const RobotModel& model) noexcept;
  // Adds `step` (counts) scaled to the rate limit, then bounds each trim.
  void apply(std::array<double, kMaxAxes>& step, const RobotModel& model) noexcept;

  TensionControlOptions options_;
  double cycle_s_ = 0.004;
  TensionControlStatus status_;
  std::uint64_t updates_seen_ = 0;
  bool seen_any_ = false;
  int stale_cycles_ = 0;     // cycles since the last fresh, finite reading
  int unusable_cycles_ = 0;  // cycles the readings could not be used
};

}  // namespace cdpr::controller
