// Tension control: a stage of the RT cycle (rt_controller.hpp, control_tensions) that trims the
// cable length targets from the measured tensions so that every cable stays in the band
// [lo, hi] = [f_min + margin, f_max - margin]. Each cycle, with the readings low-passed (f):
//
//   a cable acts once f is outside [lo, hi], until f is back in [lo + d, hi - d] (d: deadband);
//   its error e = clamp(f, lo + d, hi - d) - f (0 for a cable not acting)
//   an acting cable: dl = -c .* e on its own (c: compliance at the plan, m/N); the platform
//   yields to the part of the change outside the true kernel of A^T
//   the others: the weighted projection of their errors onto the nominal kernel of A^T,
//   df = e - W^-1 A (A^T W^-1 A)^-1 A^T e, dl = -c .* df (none while their errors are 0)
//   trim += clamp_rate(gain * dt * dl)    counts; the whole step scaled to the rate limit
//   trim  = clamp(trim, -max_trim, max_trim)   (anti-windup: the trim is the integrator)
//
// Inside the band nothing moves (no trim on the readings' noise while a pose settles). `hold`
// keeps the trims where they are (a pose being measured).
//
// Readings: a stale reading (none fresh for stale_s), a non-finite one, no tension channel, or a
// latched force fault freezes the trims for hold_s, then they decay towards 0 (time constant
// decay_s, within the rate limit): back to pure position control with the feed-forward plan.
// state() reports which. step() allocates, locks, logs and throws nothing.
#pragma once

#include <array>
#include <cstdint>

#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/controller/motion_command.hpp"
#include "cdpr/controller/robot_io.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

struct TensionControlOptions {
  double gain = 0.0;         // 1/s, integral gain on the projected tension error; 0: off
  double margin = 10.0;      // N, target band [f_min + margin, f_max - margin]
  double deadband = 3.0;     // N, hysteresis: a cable acts from outside the band to this inside it
  double max_rate = 0.005;   // m/s of cable, largest trim rate of any cable
  double max_trim = 0.03;    // m of cable, largest trim of any cable
  double stale_s = 0.05;     // s without a fresh reading before the trims freeze
  double hold_s = 0.5;       // s frozen before the trims decay
  double decay_s = 2.0;      // s, time constant of the decay towards 0
  double filter_s = 0.02;    // s, time constant of the low-pass on the readings; 0: none
  double slack_below = 1.0;  // N, a (filtered) reading below this is a slack cable
};

enum class TensionControlState : std::uint8_t {
  kOff,       // not enabled, or the robot is not holding or moving: no trims
  kActive,    // the trims follow the readings
  kHeld,      // asked to hold (a pose being measured): the trims stay, the band is watched
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
  // Weight of a slack cable: the kernel step leaves it (all but) alone.
  static constexpr double kSlackWeight = 1e6;
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
  // One cycle. `run`: the robot holds or moves (otherwise the trims are reset). `hold`: the
  // trims stay where they are (kHeld) while the readings are usable. `sensor_fault`:
  // a force fault is latched (the readings are not trusted). `data` is the plan and the
  // kinematics at the commanded pose (command_counts).
  void step(bool run, bool hold, bool sensor_fault, const RobotReading& in, const RobotModel& model,
            const CommandData& data) noexcept;

  double trim(int i) const noexcept { return status_.trim_counts[static_cast<std::size_t>(i)]; }
  const TensionControlStatus& status() const noexcept { return status_; }

 private:
  bool readings_usable(bool sensor_fault, const RobotReading& in, int m) noexcept;
  // This cycle's trim step (counts) from the filtered readings; false: no step.
  bool follow(const RobotReading& in, const RobotModel& model, const CommandData& data,
              std::array<double, kMaxAxes>& step) noexcept;
  void decay(const RobotModel& model) noexcept;
  // Adds `step` (counts) scaled to the rate limit, then bounds each trim.
  void apply(std::array<double, kMaxAxes>& step, const RobotModel& model) noexcept;

  TensionControlOptions options_;
  double cycle_s_ = 0.004;
  TensionControlStatus status_;
  std::uint64_t updates_seen_ = 0;
  bool seen_any_ = false;
  int stale_cycles_ = 0;                     // cycles since the last fresh, finite reading
  int unusable_cycles_ = 0;                  // cycles the readings could not be used
  std::array<double, kMaxAxes> filtered_{};  // N, the low-passed readings
  bool filtered_valid_ = false;
  std::array<bool, kMaxAxes> acting_{};  // outside the band, not yet back inside the deadband
};

}  // namespace cdpr::controller
