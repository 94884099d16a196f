// The physics of the virtual robot: from the motor encoder counts of the m winches to where the
// platform really is, what the cables really pull and what the sensors read, with the scenario's
// hidden effects (scenario.hpp, docs/sim-scenarios.md). Quasi-static: at every step (SYNC) the
// platform is at its elasto-static equilibrium for the current cable state; there are no dynamics.
//
// One step, for time t and counts c_i:
//   1. winch (TRUE model, with the hidden transmission scale s_i and encoder-zero offset o_i):
//        l_i = length_offset_i + o_i + (1 + s_i) * direction_i * c_i * metres_per_count_i
//      (an encoder_slip drift adds its counts to c_i: the drum turned further than reported)
//      thermal drift: l_i += alpha * (routing_length_i + l_i) * dT(t)
//      hysteresis: l_i += h_i * d_i, d_i the direction of cable i's last move (+1: its length
//      command grew, i.e. paid out; -1: reeled in; 0 before its first move), updated at every
//      step whose counts differ from the previous step's
//   2. cable law (TRUE: config, stiff, Hooke EA or polynomial surface) with creep as a
//      time-dependent extra compliance c * log(1 + t / tau) (Hooke: 1/EA_eff = 1/EA + c g(t);
//      polynomial: dL += c g(t) F L)
//   3. equilibrium (TRUE geometry with its pulleys, frame anchors moved by pulley_move drifts):
//   elastostatics.hpp, warm-started from the
//      previous pose (a Newton on elastostatic_wrench, falling back to solve_elastostatics); with
//      sag on, each free span is an elastic catenary (catenary.hpp) and the equilibrium is found
//      by Newton with a finite-difference Jacobian.
//   4. sensors: encoder = c_i + noise (rounded), force raw = true_gain * (F_i + f_i d_i) +
//      true_offset + noise (F_i at the frame-side end of the free span, f_i the pulley friction),
//      laser = ray-plane distance at the true pose with the mount and plane errors, plus noise, out
//      of range -> status kOutOfRange.
// Noise is drawn from one std::mt19937_64 seeded explicitly, in a fixed order (encoders, force
// sensors, lasers), so a run is reproducible from its seed.
//
// Lock-step (offline): run_lockstep commands a list of poses as the daemon would (NOMINAL IK with
// its elongation compensation and planned tensions, NOMINAL winch model -> counts), steps the
// physics to the equilibrium at each, and returns the "measured" channels through the NOMINAL
// reading models: the source of recordings whose physics the calibration does not know.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <random>
#include <span>
#include <vector>

#include "cdpr/calibration/elastostatics.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/sim/scenario.hpp"
#include "cdpr/status.hpp"

namespace cdpr::sim {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

enum class LaserStatus : std::uint8_t {
  kOk,
  kNoTarget,    // the beam misses the plane (parallel or pointing away)
  kOutOfRange,  // outside [range_min, range_max] of the laser
};
std::string_view to_string(LaserStatus s);

struct LaserChannel {
  double true_distance = kNaN;  // ray-plane distance at the true pose without noise, m
  double reading = kNaN;        // with noise; NaN unless status is kOk
  LaserStatus status = LaserStatus::kNoTarget;
};

struct PhysicsOptions {
  // Equilibrium tolerance on the net wrench (forces in N, moments / platform radius in N).
  double wrench_tolerance = 1e-7;
  int max_iterations = 50;
};

// Everything one step produced.
struct PhysicsState {
  double time_s = 0.0;
  Eigen::VectorXd counts;               // motor positions given to the step
  Eigen::VectorXd unstretched_lengths;  // true length commands after winch + thermal, m
  Pose pose;                            // true platform pose
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::VectorXd tensions;        // true cable tensions, N
  Eigen::VectorXd encoder_counts;  // reported positions (noise, rounded to integers), counts
  Eigen::VectorXd force_raw;       // force sensor raw readings
  std::vector<LaserChannel> lasers;
  std::vector<bool> overloaded;  // latched cable_overload trips (drive should fault)
  // Direction of each cable's last move: +1 paid out, -1 reeled in, 0 not moved yet (step 1).
  Eigen::VectorXd last_move;
  int iterations = 0;
  bool converged = false;
  int steps = 0;  // steps taken so far
};

class Physics {
 public:
  // `truth` from resolve_truth(scenario, nominal). Checks the scenario against it.
  static Result<Physics> create(RobotModel truth, const Scenario& scenario, std::uint64_t seed,
                                const PhysicsOptions& options = {});

  // One SYNC: the equilibrium at time `time_s` (s, scenario time, non-decreasing) for motor
  // positions `counts` (one per cable). On failure (no equilibrium) the state keeps the previous
  // pose and tensions, converged = false, and the reason is returned.
  Status step(const Eigen::Ref<const Eigen::VectorXd>& counts, double time_s);

  const PhysicsState& state() const { return state_; }
  const RobotModel& truth() const { return truth_; }
  const Scenario& scenario() const { return scenario_; }

  // True unstretched length command of cable i for `counts` at time t (steps 1 of the file
  // comment), m.
  double unstretched_length(int cable, double counts, double time_s) const;
  // Noise-free distance of laser k (true mount and plane) at `pose`, with its status.
  LaserChannel laser_at(int laser, const Eigen::Vector3d& position,
                        const Eigen::Matrix3d& rotation) const;
  // A fresh noisy reading of laser k at the current pose (for averaging several readings).
  LaserChannel sample_laser(int laser);
  // The true lasers (mount and plane errors applied).
  const std::vector<LaserModel>& true_lasers() const { return lasers_; }

 private:
  Physics(RobotModel truth, const Scenario& scenario, std::uint64_t seed,
          const PhysicsOptions& options);
  void update_cable_laws(double time_s);
  void apply_drifts(double time_s);  // scenario drifts at time_s: frame anchors, force sensors
  bool solve_newton(const Eigen::VectorXd& l, Eigen::Vector3d& r, Eigen::Matrix3d& R, int& iters);
  bool solve_sag(const Eigen::VectorXd& l, Eigen::Vector3d& r, Eigen::Matrix3d& R, int& iters);
  Status solve_weightless(Eigen::Vector3d& r, Eigen::Matrix3d& R, int& iters);
  bool sag_wrench(const Eigen::VectorXd& l, const Eigen::Vector3d& r, const Eigen::Matrix3d& R,
                  Wrench& w, Eigen::VectorXd& tensions);

  RobotModel truth_;  // the true robot as resolved (cable laws without creep), frame anchors moved
                      // by the drifts at the last step
  RobotModel work_;   // the cable laws in force at the current time (creep applied)
  Scenario scenario_;
  PhysicsOptions options_;
  std::vector<LaserModel> lasers_;
  std::vector<ForceSensorModel> sensors_;               // true force sensors (drifts applied)
  std::vector<ForceSensorModel> base_sensors_;          // true force sensors without drifts
  Eigen::Matrix3Xd base_frame_anchors_;                 // true frame anchors without drifts
  std::vector<std::vector<double>> base_coefficients_;  // polynomial, padded to order >= 2
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  ElastostaticData data_;
  Eigen::VectorXd lengths_;
  Eigen::VectorXd sag_tensions_;
  Eigen::VectorXd sag_trial_tensions_;
  double rho_ = 1.0;
  bool have_pose_ = false;
  PhysicsState state_;
};

// ---------------------------------------------------------------------------------------------
// Commands as the daemon makes them, and the lock-step offline mode.
// ---------------------------------------------------------------------------------------------

// Encoder targets (fractional counts) for `pose` from the NOMINAL model: planned tensions by
// simple_tension_distribution (pretension `reference_tension`, NaN: the model's default), IK
// with elongation compensation, nominal winch model.
Result<Eigen::VectorXd> nominal_counts(const RobotModel& nominal, const Pose& pose,
                                       double reference_tension = kNaN);

// The pretension (N) at which the NOMINAL planner plans the home pose keeping `margin` inside
// every cable's [f_min, f_max] (its choice of 1x, 2x or 4x default_reference_tension; NaN when
// none does). cdprd's tension control holds home at its margin plus guard: a robot homed at
// other tensions moves off home where the geometry is still wrong, since internal force in the
// nominal null space is not in the true one (docs/daemon.md "Tension control").
double home_reference_tension(const RobotModel& nominal, double margin);

// Motor counts (fractional) that put the TRUE platform at `pose` with the tensions the true
// robot's planner gives there (pretension `reference_tension`, NaN: default_reference_tension of
// the truth), the hidden winch effects included: the state of a robot whose platform stands on
// its reference platform at home when the drives are switched on (cdpr-sim --home reference).
Result<Eigen::VectorXd> true_pose_counts(const Physics& physics, const Pose& pose,
                                         double reference_tension = kNaN);

struct LockstepOptions {
  double start_time_s = 0.0;
  double dwell_s = 2.0;   // scenario time spent per pose (creep and thermal drift go on), s
  int substeps = 10;      // SYNC steps per pose (counts move linearly to the new targets)
  int laser_samples = 1;  // laser readings averaged per pose (each with fresh noise)
  double reference_tension = kNaN;  // N, the nominal planner's pretension; NaN: its default
  // Issue 18 channels, read at the TRUE pose through the TRUE robot's swivel encoders and
  // inclinometer (robot_model.hpp; their zeros and mounting are the config's), with Gaussian
  // noise of these sigmas (0: none) drawn from a stream of its own (seed `channel_seed`), so the
  // physics' own draws are the same with and without them.
  bool swivel = false;
  bool inclinometer = false;
  bool imu_yaw = false;
  double sigma_swivel = 1e-3;       // rad
  double sigma_inclination = 5e-4;  // rad
  double sigma_imu_yaw = 1e-2;      // rad
  std::uint64_t channel_seed = 1;
};

struct LockstepSample {
  Pose commanded;
  double time_s = 0.0;
  Eigen::VectorXd counts;    // commanded encoder targets (integers)
  Eigen::VectorXd lengths;   // measured: nominal winch model of the reported counts, m
  Eigen::VectorXd tensions;  // measured: nominal force-sensor calibration of the raw readings, N
  Eigen::VectorXd lasers;    // measured: mean of the ok readings, m (NaN when none is ok)
  std::vector<LaserStatus> laser_status;  // of the last reading
  Eigen::VectorXd swivels;                // rad, m entries when LockstepOptions::swivel
  Eigen::Vector2d inclination = Eigen::Vector2d::Constant(kNaN);  // rad (roll, pitch)
  double imu_yaw = kNaN;                                          // rad
  Pose true_pose;                 // hidden truth, for tests and reports
  Eigen::VectorXd true_tensions;  // N
  bool converged = false;
};

// Steps `physics` through `poses` (see the file comment). Fails on the first pose that the
// nominal planner cannot command or where no equilibrium is found (the message names the pose).
Result<std::vector<LockstepSample>> run_lockstep(Physics& physics, const RobotModel& nominal,
                                                 std::span<const Pose> poses,
                                                 const LockstepOptions& options = {});

}  // namespace cdpr::sim
