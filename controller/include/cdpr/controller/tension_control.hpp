// Tension control: a stage of the RT cycle (rt_controller.hpp, control_tensions) that trims the
// cable length targets from the measured tensions so that every cable stays in the band
// [lo, hi] = [f_min + margin, f_max - margin], moving only the internal forces, not the pose.
// Each cycle, with the readings low-passed (f), the plan p and the structure matrix A^T (6 x m)
// and the cable compliances c (m/N, at the plan) of the pose commanded last:
//
//   target  t = clamp(p, lo + d, hi - d)       (d: deadband; the plan where it is in the band);
//           an edge cable (outside [lo, hi], until back inside [lo + d, hi - d]):
//           t = clamp(f, lo + d, hi - d), the nearest point of the shrunk band
//   error   e = t - f                          for every taut cable; a slack one (f below
//                                              slack_below) is taken up on its own instead
//   kernel  df = e - W^-1 A (A^T W^-1 A)^-1 A^T e  the internal-force change (A^T df = 0)
//           nearest to e, weights W: kEdgeWeight for an edge cable, for the others 1 rising
//           quadratically to kEdgeWeight as the cable comes within `guard` of the band's
//           edges (the internal force is spent first where a cable is closest to its limit),
//           kSlackWeight (left alone) for a slack cable; only the part of df beyond d/2 (its
//           largest cable, direction kept) is used: at the optimum the noise moves nothing
//   state   phi += gain * dt * df              the internal-force correction, N; projected
//           onto the kernel of the current pose every cycle (the correction a pose needs is
//           carried into the next as a force, never as lengths of another pose)
//   trims   trim = -c .* phi + take_up         counts; A^T K trim = -A^T phi = 0: the pose
//                                              does not move to first order
//
// The step of the trims is scaled to max_rate (one scale: the direction stays in the kernel);
// the trims are bounded by max_trim by scaling phi and the take-up together (anti-windup: the
// state is the integrator and never winds up past the bound). `hold` keeps the trims where they
// are (a pose being measured: the identification sees one consistent length/tension pair).
//
// Readings: a stale reading (none fresh for stale_s), a non-finite one, no tension channel, or a
// latched force fault freezes the correction (phi and the take-up; a move still maps phi onto its
// poses) for hold_s, then it decays towards 0 (time constant decay_s, within the rate limit):
// back to pure position control with the feed-forward plan. state() reports which. step()
// allocates, locks, logs and throws nothing.
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
  double gain = 0.0;         // 1/s, integral gain on the tension error in the kernel; 0: off
  double margin = 10.0;      // N, target band [f_min + margin, f_max - margin]
  double deadband = 3.0;     // N, the target is the plan clamped this far inside the band
  double max_rate = 0.005;   // m/s of cable, largest trim rate of any cable
  double max_trim = 0.03;    // m of cable, largest trim of any cable
  double stale_s = 0.05;     // s without a fresh reading before the trims freeze
  double hold_s = 0.5;       // s frozen before the trims decay
  double decay_s = 2.0;      // s, time constant of the decay towards 0
  double filter_s = 0.02;    // s, time constant of the low-pass on the readings; 0: none
  double slack_below = 1.0;  // N, a (filtered) reading below this is a slack cable
  // N: a cable this close to the band's edges weighs more (above); RtController plans the
  // tensions this far inside the band where the pose allows it (headroom for what the geometry's
  // error adds along a move before the integral catches up).
  double guard = 20.0;
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
  double largest_error = 0.0;  // N, largest |t - f| of this cycle (t: the target, see above)
  std::array<double, kMaxAxes> trim_counts{};
};

class TensionControl {
 public:
  // Weight of a cable outside its band [lo, hi] against one inside it (1).
  static constexpr double kEdgeWeight = 1000.0;
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
  double guard_weight(double f, double lo, double hi) const noexcept;
  bool readings_usable(bool sensor_fault, const RobotReading& in, int m) noexcept;
  // Low-passes the readings; targets, errors and weights of this cycle; the band status.
  void measure(const RobotReading& in, const RobotModel& model, const CommandData& data) noexcept;
  // This cycle's integration step (phi in N, take-up in counts); false: no kinematics.
  bool follow(const RobotModel& model, const CommandData& data) noexcept;
  // trim = -c .* phi + take_up at this pose, phi first projected onto its kernel; bounded.
  // `rebase`: phi keeps its projection (active); otherwise only the trims use it (frozen).
  void map_trims(const RobotModel& model, const CommandData& data, bool rebase) noexcept;
  // cpn_: each cable's compliance (m/N) at the plan of `data` in counts per newton (0 if
  // unusable), once per cycle; false: `data` holds no kinematics of this robot.
  bool update_compliances(const RobotModel& model, const CommandData& data) noexcept;
  // Adds a step of phi (N) and of the take-up (counts), scaled to the rate limit.
  void integrate(const RobotModel& model, const std::array<double, kMaxAxes>& df,
                 const std::array<double, kMaxAxes>& dt) noexcept;
  // The weighted projection onto the kernel of A^T: v -= W^-1 A (A^T W^-1 A)^-1 A^T v. False
  // (v unchanged) without a kernel (m <= 6, rank < 6).
  bool project(const CommandData& data, int m, const std::array<double, kMaxAxes>& w,
               std::array<double, kMaxAxes>& v) const noexcept;

  TensionControlOptions options_;
  double cycle_s_ = 0.004;
  TensionControlStatus status_;
  std::uint64_t updates_seen_ = 0;
  bool seen_any_ = false;
  int stale_cycles_ = 0;                     // cycles since the last fresh, finite reading
  int unusable_cycles_ = 0;                  // cycles the readings could not be used
  std::array<double, kMaxAxes> filtered_{};  // N, the low-passed readings
  bool filtered_valid_ = false;
  std::array<double, kMaxAxes> error_{};    // N, t - f of this cycle (0 for a slack cable)
  std::array<double, kMaxAxes> weight_{};   // the projection's weights of this cycle
  std::array<bool, kMaxAxes> slack_{};      // below slack_below this cycle
  std::array<bool, kMaxAxes> edge_{};       // outside the band, not yet back inside [tlo, thi]
  std::array<double, kMaxAxes> force_{};    // N, phi: the internal-force correction
  std::array<double, kMaxAxes> take_up_{};  // counts, slack cables shortened on their own
  std::array<double, kMaxAxes> cpn_{};      // counts per N of each cable this cycle
  std::uint64_t cycles_ = 0;                // steps taken
  std::uint64_t compliances_cycle_ = 0;     // the step cpn_ belongs to (0: none)
};

}  // namespace cdpr::controller
