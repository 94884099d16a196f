// A scenario of the virtual robot cdpr-sim (docs/sim-scenarios.md): what the TRUE robot is, which
// hidden effects it has, how noisy its sensors are and which faults happen when. It is separate
// from the nominal robot description the daemon uses (drivers/config), and the daemon never sees
// it: the calibration has to discover its effects from the measurements.
//
//   Result<Scenario> s = load_scenario("config/scenarios/mini-hooke.yaml");
//   Result<RobotModel> truth = resolve_truth(*s, nominal);   // true geometry and cable law
//
// Loading never throws; every error names the file, line and field, e.g.
//   config/scenarios/x.yaml:12: effects.hooke.ea: expected a positive number (N), got -3
// Per-cable values accept a scalar (same for every cable) or a list of m values; m is only known
// once the robot is, so lists are checked against it by resolve_truth / Physics::create.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/sim/drift.hpp"
#include "cdpr/status.hpp"

namespace cdpr::sim {

inline constexpr double kForever = std::numeric_limits<double>::infinity();

// A per-cable number: one value for every cable, or one per cable.
struct PerCable {
  std::vector<double> values;  // empty: not given; size 1: every cable; size m: per cable
  int line = 0;                // where it was given (for messages)

  bool given() const { return !values.empty(); }
  double at(int cable) const {
    if (values.empty()) return 0.0;
    return values.size() == 1 ? values[0] : values[static_cast<std::size_t>(cable)];
  }
  // ok when empty, one value, or exactly m values.
  bool fits(int m) const { return values.size() <= 1 || static_cast<int>(values.size()) == m; }
};

// Where the true geometry comes from.
struct TruthSource {
  // A robot description file (path resolved relative to the scenario file). Empty: the nominal
  // description (--config) is the starting point.
  std::string config_path;
  // Seeded Gaussian perturbation of the starting point (applied after loading config_path, if
  // any): std dev per anchor coordinate, m.
  PerCable frame_anchor_std;     // frame anchors a_i (world)
  PerCable platform_anchor_std;  // platform anchors b_i (platform frame)
  std::uint64_t perturb_seed = 1;
};

struct SensorNoiseLevels {
  double encoder_counts = 0.0;  // std dev of the encoder reading, counts
  double force_raw = 0.0;       // std dev of the force sensors' raw reading, raw units
  double laser = 0.0;           // std dev of the laser distance, m
};

// The base cable law of the true robot when neither `hooke` nor `polynomial` is given.
enum class BaseCableLaw {
  kConfig,  // as the true robot description says (elongation kind, EA, surface)
  kStiff,   // "no elasticity": Hooke with stiff_ea (rigid cables have no elasto-static solution)
};

struct CreepEffect {
  // Time-hardening logarithmic creep: dL_creep = coefficient * F * L0 * log(1 + t / tau), t the
  // scenario time. 1/N, s.
  double coefficient = 0.0;
  double tau_s = 1.0;
};

struct ThermalEffect {
  // Unstretched length grows by alpha * L0 * dT(t), dT(t) = min(rate * t, max_delta) (a ramp).
  double alpha = 0.0;                // 1/K (polymer cables: negative)
  double rate_k_per_s = 0.0;         // K/s
  double max_delta_k = kForever;     // K, |dT| is capped here
  double delta_at(double t) const {  // K
    const double d = rate_k_per_s * t;
    if (d > max_delta_k) return max_delta_k;
    if (d < -max_delta_k) return -max_delta_k;
    return d;
  }
};

struct HiddenEffects {
  BaseCableLaw base_law = BaseCableLaw::kConfig;
  double stiff_ea = 1.0e8;                      // N, for kStiff
  PerCable hooke_ea;                            // N: the true cables are Hooke with this EA
  std::optional<PolynomialSurface> polynomial;  // the true cables follow this surface
  std::optional<CreepEffect> creep;
  bool sag = false;              // elastic catenary of each free span (Hooke law only)
  PerCable pulley_radius;        // m: true swivel pulley radius
  PerCable transmission_scale;   // s_i: true metres per count = nominal * (1 + s_i)
  PerCable encoder_zero_offset;  // m: added to the true unstretched length at any count
  PerCable force_gain_error;     // relative: true gain = gain * (1 + e)
  PerCable force_offset_error;   // raw units: true offset = offset + e
  // Direction-dependent effects (Physics::step tracks the direction of each cable's last move:
  // +1 paid out, -1 reeled in, 0 before its first move).
  // Cable hysteresis, m: the true unstretched length is longer by h_i * direction (a polymer
  // cable that was last paid out is longer at the same count than one that was last reeled in).
  PerCable cable_hysteresis;
  // Pulley friction, N: the force sensor sits on the winch side of the last pulley, where the
  // tension differs from the free span's by f_i * direction (friction opposes the cable's motion).
  PerCable pulley_friction;
  Eigen::Vector3d laser_mount_offset = Eigen::Vector3d::Zero();  // m, platform frame
  Eigen::Vector3d laser_mount_tilt = Eigen::Vector3d::Zero();    // rad, rotation vector, platform
  Eigen::Vector3d plane_tilt = Eigen::Vector3d::Zero();          // rad, rotation vector, world
  double plane_offset = 0.0;  // m, target plane moved along its normal
  std::optional<ThermalEffect> thermal;
};

enum class FaultKind {
  kDriveFault,       // CAN: the drive goes to FAULT and sends EMCY `emcy_code`
  kDriveSilent,      // CAN: the drive stops sending heartbeats and answering (for `duration`)
  kSdoAbort,         // CAN: SDO access to object:subindex is aborted with `abort_code`
  kBusOff,           // CAN: a burst of bus-off (the bus is unusable for `duration`)
  kLaserTimeout,     // Modbus: the laser does not answer
  kLaserGarbage,     // Modbus: the laser answers with garbage (sentinel or random registers)
  kLaserOutOfRange,  // Modbus: the laser reports a distance beyond its range
  kCableOverload,    // physics: tension above `tension_limit` trips the drive (EMCY emcy_code)
};
std::string_view to_string(FaultKind k);

struct Fault {
  FaultKind kind = FaultKind::kDriveFault;
  double at_s = 0.0;             // scenario time it starts, s
  double duration_s = kForever;  // s; kForever: until the end
  int cable = -1;                // 0-based cable (drive) index, -1: not applicable
  std::uint16_t emcy_code = 0;   // kDriveFault, kCableOverload
  std::uint16_t object = 0;      // kSdoAbort: index
  std::uint8_t subindex = 0;     // kSdoAbort
  std::uint32_t abort_code = 0;
  double tension_limit = 0.0;  // N, kCableOverload
  int line = 0;                // in the scenario file

  bool active_at(double t) const { return t >= at_s && t < at_s + duration_s; }
  bool is_can() const {
    return kind == FaultKind::kDriveFault || kind == FaultKind::kDriveSilent ||
           kind == FaultKind::kSdoAbort || kind == FaultKind::kBusOff;
  }
};

// How the laser slave presents itself (register map, Modbus address, serial settings).
struct LaserServing {
  std::string register_map_path;  // relative paths resolved against the scenario file
  int slave_id = 1;
  int baud = 115200;
  char parity = 'N';
};

struct Scenario {
  std::string name;
  std::string file;  // where it was loaded from ("" for text)
  TruthSource truth;
  SensorNoiseLevels noise;
  HiddenEffects effects;
  std::vector<Drift> drifts;  // slow hidden changes during the run, in file order
  std::vector<Fault> faults;  // in file order
  LaserServing laser;

  // The laser fault active at time t (the first in file order), if any.
  const Fault* laser_fault_at(double t) const;
};

// Reads a scenario file. Errors: kNotFound/kIoError (file), kParseError (YAML syntax),
// kInvalidArgument (a field; the message is "<file>:<line>: <field>: <reason>").
Result<Scenario> load_scenario(const std::string& path);
// The same from text; `name` stands for the file in messages, relative paths resolve against
// `base_dir`.
Result<Scenario> parse_scenario(std::string_view text, std::string_view name,
                                std::string_view base_dir = ".");

// The true robot: the truth source applied to `nominal` (loading the truth config when given,
// then the seeded perturbation), then the geometry/cable-law effects (pulley radius, Hooke EA,
// polynomial surface, stiff base law). Sensor/reading effects are applied by Physics. Checks the
// per-cable lists against the robot's cable count.
Result<RobotModel> resolve_truth(const Scenario& scenario, const RobotModel& nominal);

// Checks every per-cable list and cable index against m cables; names the field and line.
Status check_against(const Scenario& scenario, int num_cables);

}  // namespace cdpr::sim
