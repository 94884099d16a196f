// The concealed-effect benchmark of the mismatch locator (issue 7). See docs/mismatch-benchmark.md
// and bench/mismatch.cmake for the command line.
//
// Data come from the virtual robot's physics (sim/physics.hpp): the true robot differs from the
// nominal one in the frame anchors (the standard calibration case) and in ONE hidden effect (or a
// pair, or none), the encoders are homed with the nominal model, and run_lockstep commands the
// designed poses (25 tilted up to 15 degrees as cdprd's default set; --poses and --max-angle-deg
// for others) with the NOMINAL model and reads the channels through the nominal
// reading models.
// diagnose(nominal, recording) runs blind; the benchmark maps what it names (effect families) to
// the effect that was switched on (kEffects below: the one mapping table) and counts.
//
// Magnitudes. Every effect is stated by its physical value at a realistic size and by the residual
// it leaves after the standard identification, in multiples of the sensor noise: noise-free data
// with the effect, the standard identification, the RMS of the normalised residuals of the most
// affected channel (cable lengths, laser, equilibrium). The SMALL size scales the effect's
// parameter so that this residual is about 3 (secant steps on the scale). An effect whose
// realistic residual is below 0.5 sigma is "absorbed" by the standard calibration.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <map>
#include <mutex>
#include <numbers>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_util.hpp"
#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/daemon_config.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/report/report.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"
#include "testing/identification_scenario.hpp"

namespace {

using cdpr::CalibratedModel;
using cdpr::Diagnosis;
using cdpr::MeasurementSet;
using cdpr::Pose;
using cdpr::RobotModel;
using cdpr::sim::HiddenEffects;

constexpr double kDeg = std::numbers::pi / 180.0;
constexpr double kDwellS = 20.0;  // scenario time per pose (settle + record), s: 25 poses = 500 s

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

using cdpr::bench::must;

// --laser-sigma-mm: the laser's noise per pose (the product averages measuring.laser_samples
// readings per pose); 0 keeps mini_noise()'s 1 mm.
double g_laser_sigma = 0.0;
// The pose design is cdprd's (MeasuringSettings: tilts in half steps, the laser's beam direction
// emphasised), as the daemon designs the poses it measures; --library-design takes
// PoseDesignOptions' defaults (the plain full-angle design of cdpr-fit design-poses).
// --design-emphasis W: PoseDesignOptions::emphasis_weight (the laser's beam direction's weight).
double g_design_emphasis = cdpr::controller::MeasuringSettings{}.design_emphasis_weight;
// --angle-steps N: PoseDesignOptions::angle_steps.
int g_angle_steps = cdpr::controller::MeasuringSettings{}.design_angle_steps;

cdpr::SensorNoise bench_noise() {
  cdpr::SensorNoise n = cdpr::bench::mini_noise();
  if (g_laser_sigma > 0.0) n.sigma_laser = g_laser_sigma;
  return n;
}

// ------------------------------------------------------------------------------------------------
// The robots.
// ------------------------------------------------------------------------------------------------

struct Robot {
  std::string name;
  CalibratedModel nominal;
  RobotModel truth;  // true anchors, encoder zeros homed with the nominal model (winch offsets)
  std::vector<Pose> poses;
  double recording_s = 0.0;  // scenario time of the whole recording
  // Realistic sizes that depend on the robot.
  double heavy_mass_per_length = 0.0;  // kg/m (sag)
  double pulley_radius_error = 0.0;    // m
  double thermal_alpha = 0.0;          // 1/K
  double hysteresis = 0.0;             // m, cable hysteresis of cables 2 and 5
  double friction = 0.0;               // N, pulley friction of cables 2 and 5
  // Encoder counts the nominal controller commands at the home pose (where the robot is homed).
  Eigen::VectorXd home_counts;
};

// Folds the homing offsets (truth.readings.length_offsets) into the true winches, so that the
// physics' encoders read what a robot homed with the nominal model reads (the sim has no homing).
RobotModel physics_truth(const CalibratedModel& homed) {
  RobotModel t = homed.robot;
  for (int i = 0; i < t.num_cables(); ++i) {
    t.winches[static_cast<std::size_t>(i)].length_offset += homed.readings.length_offsets(i);
  }
  return t;
}

// `design_estimate`: --estimate words the pose design also maximises the information about
// (beside what the identification estimates), e.g. laser-direction for the candidate effects.
Robot make_robot(const std::string& which, bool quick, int num_poses,
                 const std::vector<std::string>& design_estimate, double max_angle_deg,
                 double tension_margin) {
  Robot r;
  cdpr::PoseDesignOptions d;
  d.noise = bench_noise();
  d.num_poses = num_poses;
  if (max_angle_deg > 0.0) d.max_angle = max_angle_deg * kDeg;
  d.tension_margin = tension_margin;
  for (const std::string& w : design_estimate) {
    const cdpr::EstimateItem* item = cdpr::find_estimate_item(w);
    if (item == nullptr) {
      std::fprintf(stderr, "--design-estimate: unknown word '%s'\n", w.c_str());
      std::exit(2);
    }
    item->set(d.identification, true);
  }
  d.emphasis_weight = g_design_emphasis;
  d.angle_steps = g_angle_steps;
  if (which == "mini") {
    const cdpr::scenario::Scenario s = cdpr::scenario::mini_config_scenario();
    r.name = "MINI";
    r.nominal = s.nominal;
    r.truth = physics_truth(s.truth);
    d.half_extent = Eigen::Vector3d::Constant(0.156);
    d.exchange_passes = quick ? 1 : 4;
    r.heavy_mass_per_length = 0.010;  // 1.5 mm steel wire rope
    r.pulley_radius_error = 0.002;    // 25 mm nominal, 27 mm effective
    r.thermal_alpha = -1.2e-5;        // Dyneema-like polymer
    r.hysteresis = 5e-4;              // polymer cable, ~10 % of its elastic elongation
    r.friction = 3.0;                 // ~2 % of a 150 N tension
  } else {
    const cdpr::scenario::Scenario s = cdpr::scenario::large_scenario();
    r.name = "LARGE";
    r.nominal = s.nominal;
    r.truth = physics_truth(s.truth);
    d.half_extent = Eigen::Vector3d(4.0, 2.8, 1.0);
    d.exchange_passes = quick ? 1 : 2;
    r.heavy_mass_per_length = 0.10;  // 5 mm steel wire rope
    r.pulley_radius_error = 0.005;   // 100 mm nominal, 105 mm effective
    r.thermal_alpha = 1.2e-5;        // steel
    r.hysteresis = 2e-3;             // ~2 % of the elastic elongation (100 mm at 6 kN)
    r.friction = 30.0;               // ~1 % of a 3 kN tension
  }
  r.home_counts = must(cdpr::sim::nominal_counts(r.nominal.robot, r.nominal.robot.home),
                       "nominal counts at home");
  const auto t0 = std::chrono::steady_clock::now();
  const cdpr::PoseDesign design = must(cdpr::design_poses(r.nominal, d), "pose design");
  r.poses = design.poses;
  r.recording_s = kDwellS * static_cast<double>(r.poses.size());
  std::printf("[%s] pose design: %zu poses from %d candidates, %.1f s\n", r.name.c_str(),
              r.poses.size(), design.candidates, seconds_since(t0));
  {
    cdpr::PredictedAccuracyOptions po;
    po.box.center = r.nominal.robot.home.position;
    po.box.half_extent = d.half_extent;
    const auto pa = cdpr::predict_accuracy(r.nominal, r.poses, bench_noise(), po);
    if (pa.ok()) {
      std::printf("[%s] predicted: anchors %.3f mm RMS std, position %.3f mm RMS over the box\n",
                  r.name.c_str(), 1e3 * pa->anchor_rms_std_m, 1e3 * pa->position_rms_m);
    }
  }
  return r;
}

// ------------------------------------------------------------------------------------------------
// The effects, and THE mapping table: which families named by diagnose() count as the effect.
// ------------------------------------------------------------------------------------------------

// One true parameter to compare with a fitted one: EffectParameter::name equal to one of `names`
// (shared) or to one of them + "_" + a 1-based cable number (per cable).
struct TrueParameter {
  std::vector<std::string> names;
  std::function<double(int cable)> value;  // cable -1: shared
};

// -2: no match; -1: shared; else the 0-based cable.
int match_parameter(const std::string& fitted, const TrueParameter& tp) {
  for (const std::string& n : tp.names) {
    if (fitted == n) return -1;
    if (fitted.size() > n.size() + 1 && fitted.compare(0, n.size(), n) == 0 &&
        fitted[n.size()] == '_' && std::isdigit(static_cast<unsigned char>(fitted[n.size() + 1]))) {
      return std::atoi(fitted.c_str() + n.size() + 1) - 1;
    }
  }
  return -2;
}

struct Effect {
  std::string key;                    // command line name
  std::string title;                  // in words
  std::vector<std::string> families;  // diagnose() families that name it (mapping table)
  // Puts the effect at `scale` x its realistic size into the hidden effects / true robot.
  std::function<void(const Robot&, double scale, HiddenEffects&, RobotModel&)> apply;
  // The physical value at `scale`, for people.
  std::function<std::string(const Robot&, double scale)> describe;
  // The true parameter at `scale` (no names: no comparison).
  std::function<TrueParameter(const Robot&, double scale)> truth;
};

// Per-cable sign patterns (fixed, so every seed sees the same truth).
constexpr double kPattern[8] = {1.0, -1.0, 0.75, -0.5, -1.0, 1.0, -0.75, 0.5};
double pattern(int i) {
  return kPattern[i % 8];
}

std::vector<double> per_cable(int m, double amplitude) {
  std::vector<double> v(static_cast<std::size_t>(m));
  for (int i = 0; i < m; ++i) v[static_cast<std::size_t>(i)] = amplitude * pattern(i);
  return v;
}

std::string fmt(const char* f, auto... a) {
  char buf[256];
  std::snprintf(buf, sizeof buf, f, a...);
  return buf;
}

const std::vector<Effect>& effects() {
  static const std::vector<Effect> list = [] {
    std::vector<Effect> e;
    // Hooke: the true EA is 25 % below the nominal (data sheet) value.
    e.push_back({"hooke",
                 "cable elasticity (Hooke EA)",
                 {"elasticity"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel& t) {
                   const double ea = t.cables[0].ea;
                   h.hooke_ea.values = {1.0 / (1.0 / ea + s * (1.0 / (0.75 * ea) - 1.0 / ea))};
                 },
                 [](const Robot& r, double s) {
                   const double ea = r.truth.cables[0].ea;
                   const double t = 1.0 / (1.0 / ea + s * (1.0 / (0.75 * ea) - 1.0 / ea));
                   return fmt("EA %.1f kN (nominal %.1f kN)", t / 1e3, ea / 1e3);
                 },
                 [](const Robot& r, double s) {
                   const double ea = r.truth.cables[0].ea;
                   const double t = 1.0 / (1.0 / ea + s * (1.0 / (0.75 * ea) - 1.0 / ea));
                   return TrueParameter{{"EA"}, [t](int) { return t; }};
                 }});
    // Polynomial (nonlinear) polymer elongation: dL = Hooke + beta F^2 L, the tangent compliance
    // 20 % higher at f_max than at zero load (beta > 0 keeps the law increasing for every F > 0).
    e.push_back({"polynomial",
                 "nonlinear cable elongation (polynomial)",
                 {"nonlinear elasticity"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel& t) {
                   const double ea = t.cables[0].ea, fmax = t.cables[0].f_max;
                   cdpr::PolynomialSurface p;
                   // Hooke's F L / (EA + F) to third order in F / EA (exact to < 2 um on LARGE)
                   // plus the nonlinear term: no difference from the nominal law at beta = 0.
                   p.order = 4;
                   p.coefficients.assign(15, 0.0);
                   p.coefficients[4] = 1.0 / ea;                                  // L F
                   p.coefficients[8] = -1.0 / (ea * ea) + s * 0.1 / (ea * fmax);  // L F^2
                   p.coefficients[13] = 1.0 / (ea * ea * ea);                     // L F^3
                   h.polynomial = p;
                 },
                 [](const Robot& r, double s) {
                   return fmt("tangent compliance +%.0f %% at %.0f N vs 0 N", 20.0 * s,
                              r.truth.cables[0].f_max);
                 },
                 [](const Robot& r, double s) {
                   const double k2 = s * 0.1 / (r.truth.cables[0].ea * r.truth.cables[0].f_max);
                   return TrueParameter{{"k2"}, [k2](int) { return k2; }};
                 }});
    // Creep: the compliance grows by 10 % of 1/EA over the recording (log law, tau 10 s).
    e.push_back({"creep",
                 "cable creep",
                 {"creep", "transmission drift", "encoder drift"},
                 [](const Robot& r, double s, HiddenEffects& h, RobotModel& t) {
                   const double ea = t.cables[0].ea;
                   cdpr::sim::CreepEffect c;
                   c.tau_s = 10.0;
                   c.coefficient = s * 0.1 / (ea * std::log1p(r.recording_s / c.tau_s));
                   h.creep = c;
                 },
                 [](const Robot&, double s) {
                   return fmt("compliance +%.1f %% of 1/EA over the recording (tau 10 s)",
                              10.0 * s);
                 },
                 [](const Robot&, double) { return TrueParameter{}; }});
    // Sag of a heavy (steel) cable: the truth's cables get its mass per length.
    e.push_back({"sag",
                 "cable sag (heavy cable)",
                 {"sag"},
                 [](const Robot& r, double s, HiddenEffects& h, RobotModel& t) {
                   h.sag = true;
                   for (auto& c : t.cables) c.mass_per_length = s * r.heavy_mass_per_length;
                 },
                 [](const Robot& r, double s) {
                   return fmt("%.1f g/m (nominal %.1f g/m)", 1e3 * s * r.heavy_mass_per_length,
                              1e3 * r.nominal.robot.cables[0].mass_per_length);
                 },
                 [](const Robot& r, double s) {
                   const double v = s * r.heavy_mass_per_length;
                   return TrueParameter{{"mass_per_length"}, [v](int) { return v; }};
                 }});
    e.push_back({"pulley",
                 "pulley radius",
                 {"pulley radius", "pulley"},
                 [](const Robot& r, double s, HiddenEffects& h, RobotModel& t) {
                   h.pulley_radius.values = {t.pulleys[0].radius + s * r.pulley_radius_error};
                 },
                 [](const Robot& r, double s) {
                   return fmt("%.1f mm (nominal %.1f mm)",
                              1e3 * (r.truth.pulleys[0].radius + s * r.pulley_radius_error),
                              1e3 * r.truth.pulleys[0].radius);
                 },
                 [](const Robot&, double) { return TrueParameter{}; }});
    // Drum transmission scale: 0.2 % on every drum, signs and sizes per cable (kPattern).
    e.push_back(
        {"drum",
         "drum transmission scale",
         {"drum scale"},
         [](const Robot& r, double s, HiddenEffects& h, RobotModel& t) {
           h.transmission_scale.values = per_cable(t.num_cables(), s * 0.002);
           // Homing zeroes the encoders at the home pose, so a transmission error scales the
           // length paid out FROM home: without this the platform would settle away from home
           // when home is commanded (by s L_home, ~10 mm on LARGE), which no homed robot does.
           for (int i = 0; i < t.num_cables(); ++i) {
             auto& w = t.winches[static_cast<std::size_t>(i)];
             w.length_offset -= h.transmission_scale.at(i) *
                                cdpr::winch_length_change<double>(w, r.home_counts(i));
           }
         },
         [](const Robot&, double s) { return fmt("up to %.3f %% per drum (pattern +-)", 0.2 * s); },
         [](const Robot&, double s) {
           return TrueParameter{{"s"}, [s](int i) { return s * 0.002 * pattern(i); }};
         }});
    e.push_back({"encoder",
                 "encoder zero offsets",
                 {"encoder offset"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel& t) {
                   h.encoder_zero_offset.values = per_cable(t.num_cables(), s * 0.002);
                 },
                 [](const Robot&, double s) { return fmt("up to %.2f mm per cable", 2.0 * s); },
                 [](const Robot&, double) { return TrueParameter{}; }});
    e.push_back({"force_gain",
                 "force sensor gain",
                 {"force sensor gain"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel& t) {
                   h.force_gain_error.values = per_cable(t.num_cables(), s * 0.02);
                 },
                 [](const Robot&, double s) { return fmt("up to %.2f %% per sensor", 2.0 * s); },
                 [](const Robot&, double s) {
                   return TrueParameter{{"g", "gain", "force_gain"},
                                        [s](int i) { return s * 0.02 * pattern(i); }};
                 }});
    e.push_back({"laser_offset",
                 "laser mount offset",
                 {"laser mounting"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel&) {
                   h.laser_mount_offset = s * Eigen::Vector3d(0.002, -0.002, 0.002);
                 },
                 [](const Robot&, double s) { return fmt("%.2f mm on each axis", 2.0 * s); },
                 [](const Robot&, double) { return TrueParameter{}; }});
    e.push_back({"laser_tilt",
                 "laser mount tilt",
                 {"laser mounting"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel&) {
                   h.laser_mount_tilt = s * Eigen::Vector3d(0.5 * kDeg, -0.5 * kDeg, 0.0);
                 },
                 [](const Robot&, double s) { return fmt("%.2f deg about x and y", 0.5 * s); },
                 [](const Robot&, double) { return TrueParameter{}; }});
    e.push_back({"plane_tilt",
                 "target plane tilt",
                 {"laser plane"},
                 [](const Robot&, double s, HiddenEffects& h, RobotModel&) {
                   h.plane_tilt = s * Eigen::Vector3d(0.2 * kDeg, 0.0, 0.0);
                 },
                 [](const Robot&, double s) { return fmt("%.2f deg", 0.2 * s); },
                 [](const Robot&, double) { return TrueParameter{}; }});
    // Thermal drift: 3 K warming over the recording.
    e.push_back({"thermal",
                 "thermal drift",
                 {"thermal drift", "transmission drift", "encoder drift"},
                 [](const Robot& r, double s, HiddenEffects& h, RobotModel&) {
                   cdpr::sim::ThermalEffect th;
                   th.alpha = r.thermal_alpha;
                   th.rate_k_per_s = s * 3.0 / r.recording_s;
                   h.thermal = th;
                 },
                 [](const Robot& r, double s) {
                   return fmt("alpha %.1e /K, %.2f K over the recording", r.thermal_alpha, 3.0 * s);
                 },
                 [](const Robot&, double) { return TrueParameter{}; }});
    // Direction-dependent effects on cables 2 and 5 (0-based 1 and 4): sim/ tracks the direction
    // of each cable's last move; the locator derives it from the recorded lengths.
    auto cables_2_and_5 = [](int m, double v) {
      std::vector<double> x;
      for (int i = 0; i < m; ++i) x.push_back(i == 1 || i == 4 ? v : 0.0);
      return x;
    };
    e.push_back({"hysteresis",
                 "cable hysteresis (cables 2 and 5)",
                 {"cable hysteresis"},
                 [cables_2_and_5](const Robot& r, double s, HiddenEffects& h, RobotModel& t) {
                   h.cable_hysteresis.values = cables_2_and_5(t.num_cables(), s * r.hysteresis);
                 },
                 [](const Robot& r, double s) {
                   return fmt("+-%.2f mm by the last move, cables 2 and 5", 1e3 * s * r.hysteresis);
                 },
                 [](const Robot& r, double s) {
                   const double v = s * r.hysteresis;
                   return TrueParameter{{"h"}, [v](int i) { return i == 1 || i == 4 ? v : 0.0; }};
                 }});
    e.push_back({"friction",
                 "pulley friction (cables 2 and 5)",
                 {"pulley friction"},
                 [cables_2_and_5](const Robot& r, double s, HiddenEffects& h, RobotModel& t) {
                   h.pulley_friction.values = cables_2_and_5(t.num_cables(), s * r.friction);
                 },
                 [](const Robot& r, double s) {
                   return fmt("+-%.1f N by the last move, cables 2 and 5", s * r.friction);
                 },
                 [](const Robot& r, double s) {
                   const double v = s * r.friction;
                   return TrueParameter{{"f"}, [v](int i) { return i == 1 || i == 4 ? v : 0.0; }};
                 }});
    return e;
  }();
  return list;
}

const Effect* find_effect(const std::string& key) {
  for (const Effect& e : effects())
    if (e.key == key) return &e;
  return nullptr;
}

// Which true effect (key) a named family stands for, given the effects that are present; "" when
// it names none of them.
std::string true_effect_named(const std::string& family, const std::vector<std::string>& present) {
  for (const std::string& k : present) {
    const Effect* e = find_effect(k);
    if (e && std::find(e->families.begin(), e->families.end(), family) != e->families.end()) {
      return k;
    }
  }
  return "";
}

// ------------------------------------------------------------------------------------------------
// Cases and data.
// ------------------------------------------------------------------------------------------------

struct Component {
  std::string key;
  double scale = 1.0;
};

struct Case {
  std::string label;  // "hooke @realistic", "hooke+drum", "null"
  std::string group;  // "realistic", "3x noise", "pair", "null", "absorbed"
  std::vector<Component> parts;
  // Components that the standard calibration absorbs (< 0.5 sigma at this size): naming them is
  // not a false finding, and not naming them is not a miss.
  std::vector<std::string> absorbed;
  // Out of the library: diagnose() runs without the direction-dependent candidates
  // (MismatchOptions::direction_candidates off), and the run is correct when it names nothing and
  // its verdict describes the unexplained structure: "the direction of the last move of cables
  // 2 and 5".
  bool out_of_library = false;
  std::vector<std::string> keys() const {
    std::vector<std::string> k;
    for (const auto& p : parts) k.push_back(p.key);
    return k;
  }
  std::vector<std::string> required() const {
    std::vector<std::string> k;
    for (const auto& p : parts)
      if (std::find(absorbed.begin(), absorbed.end(), p.key) == absorbed.end()) k.push_back(p.key);
    return k;
  }
};

struct TruthSetup {
  cdpr::sim::Scenario scenario;
  RobotModel truth;
};

cdpr::Result<TruthSetup> make_truth(const Robot& r, const std::vector<Component>& parts,
                                    bool noise) {
  TruthSetup t;
  cdpr::sim::Scenario& s = t.scenario;
  s.name = r.name;
  if (noise) {
    const RobotModel& nom = r.nominal.robot;
    s.noise.encoder_counts =
        bench_noise().sigma_length / cdpr::winch_metres_per_count(nom.winches[0]);
    s.noise.force_raw = bench_noise().sigma_force * std::abs(nom.force_sensors[0].gain);
    s.noise.laser = bench_noise().sigma_laser;
  }
  RobotModel base = r.truth;
  for (const Component& c : parts) find_effect(c.key)->apply(r, c.scale, s.effects, base);
  auto truth = cdpr::sim::resolve_truth(s, base);
  if (!truth.ok()) return truth.status();
  t.truth = std::move(*truth);
  // Homing with the effects in place: a real robot is homed on the robot as it is, so the reading
  // at the home pose is the nominal length there whatever the cables' law, mass or pulleys
  // (r.truth was homed without them). Without this, an effect that changes the unstretched
  // length at home (a softer cable: 5 mm on LARGE) makes the platform settle away from home,
  // which breaks the home-pose gauge that every calibration here assumes.
  cdpr::sim::Scenario plain;
  plain.name = r.name;
  auto anchors_only = cdpr::sim::resolve_truth(plain, r.truth);
  if (!anchors_only.ok()) return anchors_only.status();
  const double f_ref = cdpr::default_reference_tension(r.nominal.robot);
  auto homed = cdpr::homing_offsets(t.truth, r.nominal.robot, f_ref);
  if (!homed.ok()) return homed.status();
  auto before = cdpr::homing_offsets(*anchors_only, r.nominal.robot, f_ref);
  if (!before.ok()) return before.status();
  for (int i = 0; i < t.truth.num_cables(); ++i) {
    t.truth.winches[static_cast<std::size_t>(i)].length_offset += (*homed)(i) - (*before)(i);
  }
  return t;
}

cdpr::Result<MeasurementSet> record(const Robot& r, const TruthSetup& t,
                                    const std::vector<Pose>& poses, std::uint64_t seed) {
  auto physics = cdpr::sim::Physics::create(t.truth, t.scenario, seed);
  if (!physics.ok()) return physics.status();
  cdpr::sim::LockstepOptions lo;
  lo.dwell_s = kDwellS;
  auto samples = cdpr::sim::run_lockstep(*physics, r.nominal.robot, poses, lo);
  if (!samples.ok()) return samples.status();
  auto rec = cdpr::sim::make_recording(*samples, r.nominal.robot, t.scenario,
                                       cdpr::sim::RecordingProvenance{});
  if (!rec.ok()) return rec.status();
  auto set = cdpr::recording::to_measurement_set(*rec, bench_noise());
  if (!set.ok()) return set.status();
  set->noise = bench_noise();  // the stated sensor noise (also for noise-free calibration runs)
  return set;
}

// The residual the effect leaves after the standard identification, noise-free, in sigmas: RMS of
// the normalised residuals of the most affected channel.
struct Residual {
  double sigmas = 0.0;
  std::string channel;
  // Sum of the squared normalised residuals over every channel: the noncentrality of the test of
  // this effect's exact shape (noise-free, after the standard identification).
  double noncentrality = 0.0;
  bool ok = false;
  std::string error;
};

Residual leftover(const Robot& r, const std::vector<Component>& parts) {
  Residual out;
  auto t = make_truth(r, parts, /*noise=*/false);
  if (!t.ok()) {
    out.error = t.status().to_string();
    return out;
  }
  auto set = record(r, *t, r.poses, 1);
  if (!set.ok()) {
    out.error = set.status().to_string();
    return out;
  }
  auto rep = cdpr::identify(r.nominal, *set, cdpr::IdentificationOptions{});
  if (!rep.ok()) {
    out.error = rep.status().to_string();
    return out;
  }
  double ss[3] = {0, 0, 0};
  int n[3] = {0, 0, 0};
  auto add = [&](int c, const auto& v) {
    for (Eigen::Index k = 0; k < v.size(); ++k) {
      if (std::isfinite(v(k))) {
        ss[c] += v(k) * v(k);
        ++n[c];
      }
    }
  };
  for (const auto& p : rep->residuals) {
    add(0, p.length_normalized);
    add(1, p.laser_normalized);
    add(2, p.wrench_normalized);
  }
  const char* names[3] = {"lengths", "laser", "equilibrium"};
  out.noncentrality = ss[0] + ss[1] + ss[2];
  for (int c = 0; c < 3; ++c) {
    const double rms = n[c] ? std::sqrt(ss[c] / n[c]) : 0.0;
    if (rms >= out.sigmas) {
      out.sigmas = rms;
      out.channel = names[c];
    }
  }
  out.ok = true;
  return out;
}

struct Magnitude {
  std::string key;
  Residual realistic;
  double small_scale = 0.0;  // scale at ~3 sigma
  Residual small;
  bool absorbed = false;
};

Magnitude calibrate_magnitude(const Robot& r, const std::string& key) {
  Magnitude m;
  m.key = key;
  m.realistic = leftover(r, {{key, 1.0}});
  if (!m.realistic.ok) return m;
  if (m.realistic.sigmas < 0.5) {
    m.absorbed = true;
    return m;
  }
  // Secant steps on the scale (the residual is close to linear in it for small effects).
  double scale = 3.0 / m.realistic.sigmas;
  double prev_scale = 1.0, prev_res = m.realistic.sigmas;
  for (int it = 0; it < 4; ++it) {
    m.small = leftover(r, {{key, scale}});
    m.small_scale = scale;
    if (!m.small.ok || std::abs(m.small.sigmas - 3.0) < 0.15) break;
    const double slope = (m.small.sigmas - prev_res) / (scale - prev_scale);
    double next = (slope > 0 && std::isfinite(slope)) ? scale + (3.0 - m.small.sigmas) / slope
                                                      : scale * 3.0 / m.small.sigmas;
    if (!(next > 0)) next = scale * 3.0 / std::max(m.small.sigmas, 1e-6);
    prev_scale = scale;
    prev_res = m.small.sigmas;
    scale = next;
  }
  return m;
}

// ------------------------------------------------------------------------------------------------
// One blind run.
// ------------------------------------------------------------------------------------------------

// The diagnosis as the reports render it (drivers/report), for --verbose.
std::string diagnosis_text(const Diagnosis& d, const cdpr::RobotModel& nominal,
                           const cdpr::MeasurementSet& set) {
  cdpr::report::ReportContext c;
  c.title = "mismatch_bench";
  std::string text = cdpr::report::diagnosis_text(d, nominal, set, c);
  if (d.screen_after) {
    text += "\nThe last screen, on the model with the named effects (locate_mismatch):\n" +
            d.screen_after->text();
  }
  return text;
}

struct RunResult {
  bool ok = false;
  std::string error;
  std::vector<std::string> named_families;   // accepted, after the separation check if any
  std::vector<std::string> screen_families;  // locate_mismatch's significant top candidate
  Diagnosis::Verdict verdict = Diagnosis::Verdict::kNoMismatch;
  bool all_true_named = false, any_true_named = false, extra_named = false;
  bool confounded = false, separation_tried = false, separated = false;
  // A suspect with no effect named: its follow-up poses appended, the re-run decides.
  bool follow_up = false, follow_up_named = false;
  std::string follow_up_error;   // the follow-up poses could not be measured or diagnosed
  std::string separation_error;  // the separating poses could not be measured or diagnosed
  // The first diagnosis's most significant unmodelled screen candidate (the suspect when nothing
  // is named and it passes DiagnosisOptions::suspect_p): its p-values before / after Holm.
  std::string top_id;
  double top_p = 1.0, top_p_adjusted = 1.0;
  bool first_named = false;     // the first diagnosis (before any appended poses) named an effect
  std::string screen_channels;  // the screen's overall and per-channel misfit p-values
  bool described = false;       // out of the library: the structure described, nothing named
  double held_before = 0, held_after = 0;
  double len_rms_before = 0, len_rms_after = 0;  // "cable lengths" channel, m
  double param_error = std::nan("");             // RMS relative error of the fitted parameters
  double seconds = 0;
  std::string text;  // the diagnosis's text report (printed with --verbose)
};

std::vector<std::string> accepted_families(const Diagnosis& d) {
  std::vector<std::string> f;
  for (const auto& a : d.accepted)
    if (std::find(f.begin(), f.end(), a.family) == f.end()) f.push_back(a.family);
  return f;
}

double parameter_error(const Diagnosis& d, const Robot& r, const Case& c) {
  double ss = 0;
  int n = 0;
  for (const Component& part : c.parts) {
    const TrueParameter tp = find_effect(part.key)->truth(r, part.scale);
    if (tp.names.empty()) continue;
    for (const auto& a : d.accepted) {
      for (const auto& p : a.parameters) {
        const int cable = match_parameter(p.name, tp);
        if (cable == -2) continue;
        const double t = tp.value(cable);
        if (!std::isfinite(t) || t == 0.0) continue;
        const double e = (p.value - t) / t;
        ss += e * e;
        ++n;
      }
    }
  }
  return n ? std::sqrt(ss / n) : std::nan("");
}

// Scores the named families against the case: every required (not absorbed) effect named, and
// nothing named that is not present.
void score(RunResult& out, const std::vector<std::string>& families, const Case& c) {
  const std::vector<std::string> present = c.keys(), required = c.required();
  std::set<std::string> hit;
  out.extra_named = false;
  for (const auto& f : families) {
    const std::string k = true_effect_named(f, present);
    if (k.empty())
      out.extra_named = true;
    else
      hit.insert(k);
  }
  out.any_true_named = !hit.empty();
  out.all_true_named = !required.empty();
  for (const auto& k : required) out.all_true_named = out.all_true_named && hit.count(k) > 0;
}

// --noise-free: the recordings of every run carry no sensor noise (the stated noise still weights
// the fit), to check that the model with the true effects represents the data exactly.
bool g_noise_free = false;
// --follow-up-full-rerun clears it: the re-run after a suspect's follow-up poses beside named
// effects screens the whole library instead of the named effects' and the suspect's groups.
bool g_confirmatory_follow_up = true;

RunResult run_case(const Robot& r, const Case& c, int seed, const cdpr::DiagnosisOptions& dopt) {
  RunResult out;
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Component> parts;
  for (const auto& p : c.parts) parts.push_back(p);
  auto t = make_truth(r, parts, /*noise=*/!g_noise_free);
  if (!t.ok()) {
    out.error = t.status().to_string();
    return out;
  }
  const std::uint64_t noise_seed = 1000 + static_cast<std::uint64_t>(seed);
  auto set = record(r, *t, r.poses, noise_seed);
  if (!set.ok()) {
    out.error = "simulation: " + set.status().to_string();
    return out;
  }
  cdpr::DiagnosisOptions run_opt = dopt;
  if (c.out_of_library) run_opt.screen.direction_candidates = false;
  auto d = cdpr::diagnose(r.nominal, *set, nullptr, cdpr::IdentificationOptions{}, run_opt);
  if (!d.ok()) {
    out.error = "diagnose: " + d.status().to_string();
    return out;
  }
  out.ok = true;
  out.text = diagnosis_text(*d, r.nominal.robot, *set);
  out.verdict = d->verdict;
  out.held_before = d->held_out_rms_before;
  out.held_after = d->held_out_rms_after;
  for (const auto& ch : d->channels) {
    if (ch.channel == "cable lengths") {
      out.len_rms_before = ch.before;
      out.len_rms_after = ch.after;
    }
  }
  if (const cdpr::CandidateScreen* b = d->screen.best()) out.screen_families = {b->family};
  for (const auto& cs : d->screen.candidates) {
    if (cs.modelled || cs.rank == 0 || !(cs.p_value < out.top_p)) continue;
    out.top_id = cs.id;
    out.top_p = cs.p_value;
    out.top_p_adjusted = cs.p_adjusted;
  }
  out.first_named = !d->accepted.empty();
  out.screen_channels = fmt("overall p %.3g", d->screen.p_value);
  for (const auto& ch : d->screen.channels) {
    out.screen_channels += fmt(", %s p %.3g", ch.name.c_str(), ch.p_value);
  }
  out.named_families = accepted_families(*d);
  out.param_error = parameter_error(*d, r, c);
  const std::vector<std::string> present = c.keys();
  score(out, out.named_families, c);
  if (c.out_of_library) {
    // Scored on the first diagnosis: its verdict already tells the operator what to look at.
    out.described =
        d->accepted.empty() && d->verdict == Diagnosis::Verdict::kMismatchUnexplained &&
        d->headline.find("direction of the last move of cables 2 and 5") != std::string::npos;
    out.all_true_named = out.described;
    out.any_true_named = out.described;
    out.extra_named = !d->accepted.empty();
    out.seconds = seconds_since(t0);
    return out;
  }

  // "A or B, confounded": correct only if A or B is true AND the proposed separating poses,
  // simulated with the same truth and appended, make the re-run name the true one.
  // Only a finding counts: with the verdict "no mismatch" the listed pairs are not a finding.
  out.confounded = d->mismatch_found() && !d->confounded.empty();
  // A pair matters when exactly one side is a present effect: when both are (the two drift families
  // of thermal drift, or the two effects of a pair case), "A or B" is right either way.
  auto matters = [&](const cdpr::ConfoundedFinding& cf) {
    const bool a = !true_effect_named(cf.first_fit.family, present).empty();
    const bool b = !true_effect_named(cf.second_fit.family, present).empty();
    return a != b;
  };
  // The follow-up poses appended to `base`, measured (same truth, same noise seed) and diagnosed
  // once more (no further follow-up): the re-run's verdict and naming replace the run's.
  // Beside named effects the re-run is confirmatory (cdpr::follow_up_groups) unless
  // --follow-up-full-rerun.
  auto run_follow_up = [&](std::vector<Pose> base, const Diagnosis& first) {
    const cdpr::FollowUp& fu = *first.follow_up;
    base.insert(base.end(), fu.poses.begin(), fu.poses.end());
    auto set2 = record(r, *t, base, noise_seed);
    cdpr::DiagnosisOptions once = dopt;
    once.follow_up_poses = 0;
    if (g_confirmatory_follow_up) {
      once.screen.only_groups = cdpr::follow_up_groups(first);
      if (fu.held_back) once.confirm_suspect = fu.suspect;
    }
    auto d2 = set2.ok()
                  ? cdpr::diagnose(r.nominal, *set2, nullptr, cdpr::IdentificationOptions{}, once)
                  : cdpr::Result<Diagnosis>(set2.status());
    if (!d2.ok()) {
      out.follow_up_error = d2.status().to_string();
      return false;
    }
    out.follow_up = true;
    RunResult again;
    const std::vector<std::string> fam2 = accepted_families(*d2);
    score(again, fam2, c);
    out.named_families = fam2;
    out.all_true_named = again.all_true_named;
    out.any_true_named = again.any_true_named;
    out.extra_named = again.extra_named;
    out.follow_up_named = !fam2.empty();
    out.verdict = d2->verdict;
    out.param_error = parameter_error(*d2, r, c);
    if (!d2->accepted.empty()) {
      // The held-out figures of the run that named the effect (on the longer recording).
      out.held_before = d2->held_out_rms_before;
      out.held_after = d2->held_out_rms_after;
    }
    out.text +=
        "\n--- after the follow-up poses ---\n" + diagnosis_text(*d2, r.nominal.robot, *set2);
    return true;
  };
  for (const cdpr::ConfoundedFinding& cf : d->confounded) {
    if (!out.confounded) break;
    if (!matters(cf) || cf.separating_poses.empty()) continue;
    out.separation_tried = true;
    std::vector<Pose> more = r.poses;
    more.insert(more.end(), cf.separating_poses.begin(), cf.separating_poses.end());
    // A suspect held back beside the named effects (DiagnosisOptions::weak_step_bic):
    // its follow-up poses are measured in the same round and the re-run is confirmatory, as
    // cdprd does.
    cdpr::DiagnosisOptions sep = dopt;
    if (d->follow_up && d->follow_up->held_back) {
      more.insert(more.end(), d->follow_up->poses.begin(), d->follow_up->poses.end());
      sep.screen.only_groups = cdpr::follow_up_groups(*d);
      sep.confirm_suspect = d->follow_up->suspect;
      out.follow_up = true;
    }
    auto set2 = record(r, *t, more, noise_seed);
    if (!set2.ok()) {  // the separating poses cannot be measured: not separated
      out.separation_error = "simulation: " + set2.status().to_string();
      break;
    }
    auto d2 = cdpr::diagnose(r.nominal, *set2, nullptr, cdpr::IdentificationOptions{}, sep);
    if (!d2.ok()) {
      out.separation_error = "diagnose: " + d2.status().to_string();
      break;
    }
    RunResult again;
    const std::vector<std::string> fam2 = accepted_families(*d2);
    score(again, fam2, c);
    out.separated = again.any_true_named && !again.extra_named;
    out.param_error = parameter_error(*d2, r, c);  // the fit of the re-run names the effect
    out.named_families = fam2;
    out.all_true_named = again.all_true_named;
    out.any_true_named = again.any_true_named;
    out.extra_named = again.extra_named;
    out.text +=
        "\n--- after the separating poses ---\n" + diagnosis_text(*d2, r.nominal.robot, *set2);
    // A second round (measuring.extra_pose_rounds 2): the re-run's suspect beside the named
    // effects gets its follow-up poses (held back for weak evidence, or follow_up_beside_named).
    if (d2->follow_up && !d2->follow_up->poses.empty() &&
        (dopt.follow_up_beside_named || d2->follow_up->held_back) && run_follow_up(more, *d2)) {
      out.separated = out.any_true_named && !out.extra_named;
    }
    break;
  }
  if (out.confounded && !out.separated) {
    // A confounded finding whose separation failed (or was never proposed) is not correct.
    bool involves_true = false;
    for (const auto& cf : d->confounded) involves_true = involves_true || matters(cf);
    if (involves_true) out.all_true_named = out.any_true_named = false;
  }

  // "Suspected, not proven" (with nothing named, or beside the named effects): the proposed
  // follow-up poses are measured (same truth, same noise seed, appended) and the re-run's verdict
  // and naming replace the first ones, as the operator would do. One round only; a run whose
  // separating poses were already measured keeps that re-run.
  if (!out.separation_tried && d->follow_up && !d->follow_up->poses.empty()) {
    run_follow_up(r.poses, *d);
  }
  out.seconds = seconds_since(t0);
  return out;
}

// ------------------------------------------------------------------------------------------------
// A pool of worker threads over a job list.
// ------------------------------------------------------------------------------------------------

void parallel_for(int n, int workers, const std::function<void(int)>& job) {
  std::atomic<int> next{0};
  std::vector<std::thread> pool;
  for (int w = 0; w < workers; ++w) {
    pool.emplace_back([&] {
      for (int i = next++; i < n; i = next++) job(i);
    });
  }
  for (auto& t : pool) t.join();
}

// ------------------------------------------------------------------------------------------------
// Printing.
// ------------------------------------------------------------------------------------------------

struct CaseStats {
  const Case* c = nullptr;
  std::vector<RunResult> runs;
  int ok() const {
    int n = 0;
    for (const auto& r : runs) n += r.ok;
    return n;
  }
};

double pct(int a, int b) {
  return b > 0 ? 100.0 * a / b : std::nan("");
}

double median(std::vector<double> v) {
  v.erase(std::remove_if(v.begin(), v.end(), [](double x) { return !std::isfinite(x); }), v.end());
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const std::size_t h = v.size() / 2;
  return v.size() % 2 ? v[h] : 0.5 * (v[h - 1] + v[h]);
}

// The reduction (%) of the held-out RMS in excess of the noise: the null run of the same seed
// (same poses, same noise draws, no effect) gives the floor; sqrt(held^2 - floor^2) is the
// held-out misfit the effect causes. NaN without a null run or without an excess before.
double excess_reduction(const RunResult& run, const RunResult* null) {
  if (null == nullptr || !null->ok || !run.ok) return std::nan("");
  const double floor2 = null->held_before * null->held_before;
  const double before2 = run.held_before * run.held_before - floor2;
  const double after2 = std::max(run.held_after * run.held_after - floor2, 0.0);
  if (!(before2 > 0)) return std::nan("");
  return 100.0 * (1.0 - std::sqrt(after2 / before2));
}

void print_robot(const Robot& r, const Residual& baseline, const std::vector<Magnitude>& mags,
                 const std::vector<CaseStats>& stats, double seconds, int seeds) {
  auto null_run = [&](std::size_t seed) -> const RunResult* {
    for (const auto& s : stats) {
      if (s.c->parts.empty() && seed < s.runs.size()) return &s.runs[seed];
    }
    return nullptr;
  };
  std::printf(
      "\n== %s: magnitudes (residual left after the standard identification, noise-free, "
      "in sigmas of the most affected channel) ==\n",
      r.name.c_str());
  std::printf("  %-13s %-52s %9s %-12s %7s %9s\n", "effect", "realistic value", "residual",
              "channel", "3x scale", "residual");
  std::printf("  %-13s %-52s %8.2fs %-12s\n", "(none)", "anchors only: the floor of the method",
              baseline.sigmas, baseline.channel.c_str());
  for (const Magnitude& m : mags) {
    const Effect* e = find_effect(m.key);
    if (!m.realistic.ok) {
      std::printf("  %-13s %-52s failed: %s\n", m.key.c_str(), e->describe(r, 1.0).c_str(),
                  m.realistic.error.c_str());
      continue;
    }
    if (m.absorbed) {
      std::printf("  %-13s %-52s %8.2fs %-12s absorbed\n", m.key.c_str(),
                  e->describe(r, 1.0).c_str(), m.realistic.sigmas, m.realistic.channel.c_str());
    } else {
      std::printf("  %-13s %-52s %8.2fs %-12s %7.3f %8.2fs  (%s)\n", m.key.c_str(),
                  e->describe(r, 1.0).c_str(), m.realistic.sigmas, m.realistic.channel.c_str(),
                  m.small_scale, m.small.sigmas, e->describe(r, m.small_scale).c_str());
    }
  }

  // The detection bound: a test that knows the effect's exact shape and sign (Neyman-Pearson, one
  // parameter) at a 5 % false-alarm rate names it with probability Phi(sqrt(lambda) - 1.645); no
  // method with that false-alarm rate does better, and diagnose() also has to find the shape
  // among its candidates and correct for their number.
  std::printf(
      "  detection bound at the realistic size (lambda = sum of squared normalised residuals "
      "left; best test at 5 %% false alarms names it in Phi(sqrt(lambda) - 1.645)):\n   ");
  for (const Magnitude& m : mags) {
    if (!m.realistic.ok) continue;
    const double lambda = m.realistic.noncentrality;
    const double power = 0.5 * std::erfc(-(std::sqrt(lambda) - 1.6448536) / std::sqrt(2.0));
    std::printf(" %s lambda %.1f: %.0f %%;", m.key.c_str(), lambda, 100.0 * power);
  }
  std::printf("\n");

  // Confusion matrix: rows = cases, columns = named families.
  std::set<std::string> cols;
  for (const auto& s : stats)
    for (const auto& run : s.runs)
      for (const auto& f : run.named_families) cols.insert(f);
  std::printf("\n== %s: confusion matrix (runs naming each family; a run may name several) ==\n",
              r.name.c_str());
  std::printf("  %-38s %4s %5s", "true effect", "runs", "none");
  std::vector<std::string> colv(cols.begin(), cols.end());
  for (std::size_t j = 0; j < colv.size(); ++j) std::printf(" %5s", fmt("F%zu", j + 1).c_str());
  std::printf(" %5s %5s\n", "fail", "conf");
  for (const auto& s : stats) {
    int none = 0, fail = 0, conf = 0;
    std::vector<int> cnt(colv.size(), 0);
    for (const auto& run : s.runs) {
      if (!run.ok) {
        ++fail;
        continue;
      }
      if (run.named_families.empty()) ++none;
      conf += run.confounded;
      for (const auto& f : run.named_families) {
        cnt[static_cast<std::size_t>(std::find(colv.begin(), colv.end(), f) - colv.begin())]++;
      }
    }
    std::printf("  %-38s %4zu %5d", s.c->label.c_str(), s.runs.size(), none);
    for (int v : cnt) std::printf(" %5d", v);
    std::printf(" %5d %5d\n", fail, conf);
  }
  for (std::size_t j = 0; j < colv.size(); ++j)
    std::printf("    F%zu = %s\n", j + 1, colv[j].c_str());

  // Per-case detail.
  std::printf("\n== %s: per case (medians over the runs) ==\n", r.name.c_str());
  std::printf("  %-38s %7s %7s %7s %7s %5s %7s %7s %9s %9s %9s %9s %7s %7s %8s %6s\n", "case",
              "named%", "any%", "extra%", "screen%", "conf", "sep ok", "fu nmd", "len b mm",
              "len a mm", "held b mm", "held a mm", "reduc%", "xs red%", "par err%", "s/run");
  for (const auto& s : stats) {
    int ok = 0, all = 0, any = 0, extra = 0, scr = 0, conf = 0, tried = 0, sep = 0, unexpl = 0;
    int fu = 0, fu_named = 0;
    std::vector<double> lb, la, hb, ha, red, xred, pe, sec;
    for (std::size_t seed = 0; seed < s.runs.size(); ++seed) {
      const RunResult& run = s.runs[seed];
      if (!run.ok) continue;
      xred.push_back(excess_reduction(run, null_run(seed)));
      ++ok;
      conf += run.confounded;
      unexpl += run.extra_named || run.verdict == Diagnosis::Verdict::kMismatchUnexplained;
      tried += run.separation_tried;
      sep += run.separated;
      fu += run.follow_up;
      fu_named += run.follow_up_named;
      all += run.all_true_named && !run.extra_named;
      any += run.any_true_named;
      extra += run.extra_named;
      RunResult tmp;
      score(tmp, run.screen_families, *s.c);
      scr += s.c->parts.empty() ? run.screen_families.empty() : tmp.any_true_named;
      lb.push_back(1e3 * run.len_rms_before);
      la.push_back(1e3 * run.len_rms_after);
      hb.push_back(1e3 * run.held_before);
      ha.push_back(1e3 * run.held_after);
      red.push_back(run.held_before > 0 ? 100.0 * (1.0 - run.held_after / run.held_before)
                                        : std::nan(""));
      pe.push_back(100.0 * run.param_error);
      sec.push_back(run.seconds);
    }
    // Null data: correct = nothing named and no "mismatch unexplained" verdict.
    const double named = s.c->parts.empty() ? pct(ok - unexpl, ok) : pct(all, ok);
    std::printf(
        "  %-38s %7.0f %7.0f %7.0f %7.0f %5d %7s %7s %9.4f %9.4f %9.4f %9.4f %7.1f %7.1f %8.1f "
        "%6.1f\n",
        s.c->label.c_str(), named, pct(any, ok), pct(extra, ok), pct(scr, ok), conf,
        fmt("%d/%d", sep, tried).c_str(), fmt("%d/%d", fu_named, fu).c_str(), median(lb),
        median(la), median(hb), median(ha), median(red), median(xred), median(pe), median(sec));
  }
  std::printf(
      "  named%% = exactly the true effect(s) named (null: nothing named, no unexplained "
      "mismatch); any%% = a true "
      "effect among the named; extra%% = a family that is not present named; screen%% = "
      "locate_mismatch's top significant candidate alone (null: none significant); conf = runs "
      "with a "
      "confounded pair; sep ok = separations proven by the appended poses / tried; fu nmd = runs "
      "whose re-run with the proposed follow-up poses named an effect / runs with a suspect; "
      "reduc%% = "
      "held-out RMS reduction; xs red%% = reduction of the held-out misfit in excess of the noise "
      "(the null run of the same seed: same poses and noise, no effect)\n");

  // Summary against the targets.
  auto rate = [&](const std::string& group, bool null_case) {
    int ok = 0, good = 0;
    for (const auto& s : stats) {
      if (s.c->group != group) continue;
      for (const auto& run : s.runs) {
        if (!run.ok) continue;
        ++ok;
        good += null_case
                    ? run.extra_named || run.verdict == Diagnosis::Verdict::kMismatchUnexplained
                    : run.all_true_named && !run.extra_named;
      }
    }
    return std::make_pair(good, ok);
  };
  auto reduction = [&](bool excess) {
    std::vector<double> red;
    for (const auto& s : stats) {
      if (s.c->group != "realistic" && s.c->group != "pair") continue;
      for (std::size_t seed = 0; seed < s.runs.size(); ++seed) {
        const RunResult& run = s.runs[seed];
        if (!run.ok || !(run.held_before > 0)) continue;
        red.push_back(excess ? excess_reduction(run, null_run(seed))
                             : 100.0 * (1.0 - run.held_after / run.held_before));
      }
    }
    return median(red);
  };
  const auto real = rate("realistic", false), small = rate("3x noise", false),
             pair = rate("pair", false), null = rate("null", true);
  std::printf("\n== %s: summary (%d seeds, %.0f s) ==\n", r.name.c_str(), seeds, seconds);
  std::printf("  named correctly at realistic magnitude  %6.1f %%  (%d/%d)   target >= 95 %%\n",
              pct(real.first, real.second), real.first, real.second);
  std::printf("  named correctly at 3x noise             %6.1f %%  (%d/%d)   target >= 80 %%\n",
              pct(small.first, small.second), small.first, small.second);
  std::printf("  pairs: both named, nothing else         %6.1f %%  (%d/%d)\n",
              pct(pair.first, pair.second), pair.first, pair.second);
  std::printf("  false findings on null data             %6.1f %%  (%d/%d)   target <= 5 %%\n",
              pct(null.first, null.second), null.first, null.second);
  // Suspects on null data: each costs DiagnosisOptions::follow_up_poses poses of robot time.
  int null_runs = 0, null_suspects = 0;
  for (const auto& s : stats) {
    if (s.c->group != "null") continue;
    for (const auto& run : s.runs) {
      if (!run.ok) continue;
      ++null_runs;
      null_suspects += run.follow_up || !run.follow_up_error.empty() ? 1 : 0;
    }
  }
  std::printf("  suspects (follow-up poses) on null data %6.1f %%  (%d/%d)   target <= 20 %%\n",
              pct(null_suspects, null_runs), null_suspects, null_runs);
  const auto compound = rate("compound", false);
  const std::pair<int, int> all_multi{pair.first + compound.first, pair.second + compound.second};
  if (compound.second > 0) {
    std::printf(
        "  compound effects named (pairs and triples: every present effect named, no absent one) "
        "%6.1f %%  (%d/%d)   target >= 90 %%\n",
        pct(all_multi.first, all_multi.second), all_multi.first, all_multi.second);
  }
  const auto ool = rate("out of library", false);
  if (ool.second > 0) {
    std::printf(
        "  out-of-library structure described (direction of the last move of cables 2 and 5, "
        "nothing named) %6.1f %%  (%d/%d)\n",
        pct(ool.first, ool.second), ool.first, ool.second);
  }
  std::printf("  held-out RMS reduction (effect present, median) %6.1f %%   target >= 80 %%\n",
              reduction(false));
  std::printf("  held-out misfit in excess of the noise, reduction (median) %6.1f %%\n",
              reduction(true));
  // The benchmark's own failures: appended (separating or follow-up) poses that the virtual robot
  // could not measure or that diagnose refused. Such a run counts as not separated.
  int appended_failed = 0, runs_ok = 0;
  for (const auto& s : stats) {
    for (const auto& run : s.runs) {
      if (!run.ok) continue;
      ++runs_ok;
      appended_failed += !run.separation_error.empty() || !run.follow_up_error.empty() ? 1 : 0;
    }
  }
  std::printf("  runs whose appended poses could not be measured or diagnosed   %d of %d\n",
              appended_failed, runs_ok);
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty()) out.push_back(item);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 20;
  bool quick = false;
  std::string robots = "both";
  std::vector<std::string> only;
  int workers = 2;
  bool verbose = false;
  bool verdicts = false;  // one deterministic line per case and seed at the end of each robot
  bool force_candidates = cdpr::MismatchOptions{}.force_sensor_candidates;
  int folds = cdpr::DiagnosisOptions{}.cv_folds;  // 0: leave one pose out
  bool beside = cdpr::DiagnosisOptions{}.follow_up_beside_named;
  bool skip_confounded = cdpr::DiagnosisOptions{}.follow_up_skips_confounded_with_named;
  bool bic_rows = cdpr::DiagnosisOptions{}.bic_informing_rows;
  bool polish = cdpr::DiagnosisOptions{}.polish_gauss_newton;
  bool gn_force_noise = cdpr::DiagnosisOptions{}.gauss_newton_force_noise;
  double refinement_gate = cdpr::DiagnosisOptions{}.refinement_gate_p;
  double second_round_evidence = cdpr::DiagnosisOptions{}.second_round_min_evidence;
  double weak_step = cdpr::DiagnosisOptions{}.weak_step_bic;
  int first_seed = 0;  // seeds first_seed .. first_seed + seeds - 1
  // The pose set of cdprd's defaults (MeasuringSettings: 25 poses tilted up to 15 degrees).
  int num_poses = 25;
  std::vector<std::string> design_estimate;
  double max_angle_deg = 0.0;   // 0: PoseDesignOptions' default, 0.2618 rad
  double tension_margin = 0.0;  // N, PoseDesignOptions::tension_margin
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--seeds" && i + 1 < argc) {
      seeds = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--quick") {
      quick = true;
    } else if (a == "--verbose") {
      verbose = true;
    } else if (a == "--verdicts") {
      verdicts = true;
    } else if (a == "--force-sensor-candidates" && i + 1 < argc) {
      force_candidates = std::strcmp(argv[++i], "on") == 0;
    } else if (a == "--robot" && i + 1 < argc) {
      robots = argv[++i];
    } else if (a == "--effects" && i + 1 < argc) {
      only = split(argv[++i]);
    } else if (a == "--workers" && i + 1 < argc) {
      workers = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--first-seed" && i + 1 < argc) {
      first_seed = std::max(0, std::atoi(argv[++i]));
    } else if (a == "--bic-informing-rows") {
      bic_rows = true;
    } else if (a == "--bic-all-rows") {
      bic_rows = false;
    } else if (a == "--polish") {
      polish = true;
    } else if (a == "--no-polish") {
      polish = false;
    } else if (a == "--gn-force-noise") {
      gn_force_noise = true;
    } else if (a == "--no-gn-force-noise") {
      gn_force_noise = false;
    } else if (a == "--refinement-gate-p" && i + 1 < argc) {
      refinement_gate = std::max(0.0, std::atof(argv[++i]));
    } else if (a == "--second-round-evidence" && i + 1 < argc) {
      second_round_evidence = std::max(0.0, std::atof(argv[++i]));
    } else if (a == "--weak-step-bic" && i + 1 < argc) {
      weak_step = std::max(0.0, std::atof(argv[++i]));
    } else if (a == "--follow-up-beside-named") {
      beside = true;
    } else if (a == "--follow-up-confounded-too") {
      skip_confounded = false;
    } else if (a == "--follow-up-full-rerun") {
      g_confirmatory_follow_up = false;
    } else if (a == "--laser-sigma-mm" && i + 1 < argc) {
      char* end = nullptr;
      const double mm = std::strtod(argv[++i], &end);
      if (end == argv[i] || *end != '\0' || !(mm > 0.0 && mm <= 100.0)) {
        std::fprintf(stderr, "--laser-sigma-mm needs a noise in mm in (0, 100], got '%s'\n",
                     argv[i]);
        return 2;
      }
      g_laser_sigma = mm * 1e-3;
    } else if (a == "--noise-free") {
      g_noise_free = true;
    } else if (a == "--poses" && i + 1 < argc) {
      num_poses = std::max(8, std::atoi(argv[++i]));
    } else if (a == "--max-angle-deg" && i + 1 < argc) {
      max_angle_deg = std::clamp(std::atof(argv[++i]), 1.0, 45.0);
    } else if (a == "--tension-margin" && i + 1 < argc) {
      tension_margin = std::max(0.0, std::atof(argv[++i]));
    } else if (a == "--angle-steps" && i + 1 < argc) {
      g_angle_steps = std::clamp(std::atoi(argv[++i]), 1, 10);
    } else if (a == "--library-design") {
      g_angle_steps = cdpr::PoseDesignOptions{}.angle_steps;
      g_design_emphasis = cdpr::PoseDesignOptions{}.emphasis_weight;
    } else if (a == "--design-emphasis" && i + 1 < argc) {
      g_design_emphasis = std::max(0.0, std::atof(argv[++i]));
    } else if (a == "--design-estimate" && i + 1 < argc) {
      design_estimate = split(argv[++i]);
    } else if (a == "--folds" && i + 1 < argc) {
      folds = std::atoi(argv[++i]);
    } else {
      std::fprintf(
          stderr,
          "usage: mismatch_bench [--seeds N] [--quick] [--robot mini|large|both] "
          "[--effects a,b,...] [--workers N] [--verbose] [--verdicts] "
          "[--force-sensor-candidates on|off] [--folds K (0: leave one pose out)] "
          "[--follow-up-beside-named] [--follow-up-confounded-too] [--follow-up-full-rerun] "
          "[--bic-informing-rows|--bic-all-rows] [--polish|--no-polish] "
          "[--gn-force-noise|--no-gn-force-noise] [--refinement-gate-p P (0: off)] "
          "[--second-round-evidence B] [--weak-step-bic B (0: off)] "
          "[--first-seed S] [--poses N] [--noise-free] [--laser-sigma-mm S] "
          "[--design-estimate word,...] [--library-design] [--design-emphasis W] [--angle-steps N] "
          "[--max-angle-deg "
          "A] [--tension-margin N]\n"
          "  effects:");
      for (const Effect& e : effects()) std::fprintf(stderr, " %s", e.key.c_str());
      std::fprintf(stderr,
                   " null hooke+drum encoder+force_gain sag+hooke force_gain+creep sag+laser_tilt "
                   "thermal+encoder hooke+drum+force_gain creep+drum+laser_tilt "
                   "sag+hooke+force_gain out_of_library\n");
      return 2;
    }
  }
  bool seeds_given = false;
  for (int i = 1; i < argc; ++i) seeds_given = seeds_given || std::strcmp(argv[i], "--seeds") == 0;
  if (quick && !seeds_given) seeds = 3;
  if (folds < 0 || folds == 1) {
    std::fprintf(stderr, "--folds must be 0 (leave one pose out) or at least 2, got %d\n", folds);
    return 2;
  }
  if (robots != "mini" && robots != "large" && robots != "both") {
    std::fprintf(stderr, "--robot must be mini, large or both, got %s\n", robots.c_str());
    return 2;
  }
  const std::vector<std::pair<std::string, std::string>> pairs = {
      {"hooke", "drum"}, {"encoder", "force_gain"}, {"sag", "hooke"}};
  // Compound effects (issue 15 item 4): pairs and triples drawn from the realistic set, each
  // effect at its realistic size.
  const std::vector<std::vector<std::string>> compounds = {
      {"force_gain", "creep"},         {"sag", "laser_tilt"},
      {"thermal", "encoder"},          {"hooke", "drum", "force_gain"},
      {"creep", "drum", "laser_tilt"}, {"sag", "hooke", "force_gain"}};
  auto wanted = [&](const std::string& k) {
    return only.empty() || std::find(only.begin(), only.end(), k) != only.end();
  };
  for (const auto& k : only) {
    bool known = find_effect(k) != nullptr || k == "null";
    for (const auto& p : pairs) known = known || k == p.first + "+" + p.second;
    for (const auto& g : compounds) {
      std::string label;
      for (const auto& x : g) label += (label.empty() ? "" : "+") + x;
      known = known || k == label;
    }
    known = known || k == "out_of_library";
    if (!known) {
      std::fprintf(stderr, "unknown effect '%s' (see --help)\n", k.c_str());
      return 2;
    }
  }

  std::printf(
      "cdpr concealed-effect benchmark of the mismatch locator (seeds %d%s, %d workers, %s, BIC "
      "over %s%s%s%s%s)\n",
      seeds, quick ? ", quick" : "", workers,
      folds == 0 ? "leave-one-pose-out CV" : (std::to_string(folds) + "-fold CV").c_str(),
      bic_rows ? "the readings each effect acts on" : "all readings",
      polish ? ", Gauss-Newton effects refitted beside later ones" : "",
      gn_force_noise ? ", their force noise in the length sigmas" : "",
      refinement_gate > 0.0 ? "" : ", refinements not gated",
      !beside ? ""
              : (std::string(", follow-up poses beside named effects (") +
                 (skip_confounded ? "not for a suspect confounded with one" : "any suspect") +
                 (g_confirmatory_follow_up ? "; confirmatory re-run)" : "; full re-run)"))
                    .c_str());
  std::printf(
      "noise%s: laser %.3g mm, encoder 0.1 mm, force 1 N; %d designed poses tilted up to %.0f "
      "deg in %d step%s, the laser's beam direction at weight %.3g%s%s; "
      "lock-step physics (cdpr-sim), %.0f s per pose\n",
      g_noise_free ? " (stated; the recordings are noise-free)" : "",
      bench_noise().sigma_laser * 1e3, num_poses,
      max_angle_deg > 0.0 ? max_angle_deg : cdpr::PoseDesignOptions{}.max_angle / kDeg,
      g_angle_steps, g_angle_steps == 1 ? "" : "s", g_design_emphasis,
      g_angle_steps == cdpr::controller::MeasuringSettings{}.design_angle_steps &&
              g_design_emphasis == cdpr::controller::MeasuringSettings{}.design_emphasis_weight
          ? " (cdprd's design)"
          : "",
      design_estimate.empty() ? "" : " (design for more parameters)", kDwellS);
  if (weak_step > 0.0) {
    std::printf(
        "an effect added beside named ones with BIC above -%.3g is held back as a suspect: its "
        "follow-up poses measured, the confirmatory re-run names it only below -%.3g\n",
        weak_step, weak_step);
  }
  if (second_round_evidence > 0.0) {
    std::printf("the second screening round names an effect only with BIC below -%.3g\n",
                second_round_evidence);
  }
  std::printf("mapping (true effect -> families of diagnose() that count as naming it):\n");
  for (const Effect& e : effects()) {
    std::string f;
    for (const auto& x : e.families) f += (f.empty() ? "" : ", ") + x;
    std::printf("  %-13s %-40s -> %s\n", e.key.c_str(), e.title.c_str(), f.c_str());
  }
  std::fflush(stdout);

  cdpr::DiagnosisOptions dopt;  // the product's defaults: the analysis runs blind
  dopt.screen.force_sensor_candidates = force_candidates;
  dopt.cv_folds = folds;
  dopt.follow_up_beside_named = beside;
  dopt.follow_up_skips_confounded_with_named = skip_confounded;
  dopt.bic_informing_rows = bic_rows;
  dopt.polish_gauss_newton = polish;
  dopt.gauss_newton_force_noise = gn_force_noise;
  dopt.refinement_gate_p = refinement_gate;
  dopt.second_round_min_evidence = second_round_evidence;
  dopt.weak_step_bic = weak_step;
  const auto t_all = std::chrono::steady_clock::now();
  std::vector<std::string> which;
  if (robots != "large") which.push_back("mini");
  if (robots != "mini") which.push_back("large");
  for (const std::string& w : which) {
    const auto t_robot = std::chrono::steady_clock::now();
    const Robot r = make_robot(w, quick, num_poses, design_estimate, max_angle_deg, tension_margin);

    // Magnitudes (pool over effects).
    std::vector<std::string> keys;
    for (const Effect& e : effects()) {
      bool in_pair = false;
      for (const auto& p : pairs)
        in_pair = in_pair ||
                  (wanted(p.first + "+" + p.second) && (p.first == e.key || p.second == e.key));
      for (const auto& g : compounds) {
        std::string label;
        for (const auto& x : g) label += (label.empty() ? "" : "+") + x;
        in_pair = in_pair || (wanted(label) && std::find(g.begin(), g.end(), e.key) != g.end());
      }
      in_pair =
          in_pair || (wanted("out_of_library") && (e.key == "hysteresis" || e.key == "friction"));
      if (wanted(e.key) || in_pair) keys.push_back(e.key);
    }
    const Residual baseline = leftover(r, {});
    if (!baseline.ok)
      std::printf("[%s] baseline failed: %s\n", r.name.c_str(), baseline.error.c_str());
    std::vector<Magnitude> mags(keys.size());
    std::mutex print_mutex;
    parallel_for(static_cast<int>(keys.size()), workers, [&](int i) {
      mags[static_cast<std::size_t>(i)] = calibrate_magnitude(r, keys[static_cast<std::size_t>(i)]);
      std::lock_guard<std::mutex> lock(print_mutex);
      const Magnitude& m = mags[static_cast<std::size_t>(i)];
      std::printf("[%s] magnitude %-13s realistic %.2f sigma (%s)%s\n", r.name.c_str(),
                  m.key.c_str(), m.realistic.sigmas, m.realistic.channel.c_str(),
                  m.absorbed
                      ? ", absorbed"
                      : fmt(", 3x noise at scale %.3f (%.2f sigma)", m.small_scale, m.small.sigmas)
                            .c_str());
      if (!m.realistic.ok) std::printf("    error: %s\n", m.realistic.error.c_str());
      std::fflush(stdout);
    });

    // Cases.
    std::vector<Case> cases;
    for (const Magnitude& m : mags) {
      if (!wanted(m.key) || !m.realistic.ok) continue;
      if (m.absorbed) {
        cases.push_back({m.key + " (absorbed)", "absorbed", {{m.key, 1.0}}, {m.key}});
        continue;
      }
      cases.push_back({m.key + " @realistic", "realistic", {{m.key, 1.0}}, {}});
      if (m.small.ok)
        cases.push_back({m.key + " @3x noise", "3x noise", {{m.key, m.small_scale}}, {}});
    }
    for (const auto& p : pairs) {
      if (wanted(p.first + "+" + p.second)) {
        Case c{p.first + "+" + p.second, "pair", {{p.first, 1.0}, {p.second, 1.0}}, {}};
        for (const Magnitude& m : mags)
          if (m.absorbed && (m.key == p.first || m.key == p.second)) c.absorbed.push_back(m.key);
        if (!c.absorbed.empty()) c.label += " (" + c.absorbed.front() + " absorbed)";
        cases.push_back(c);
      }
    }
    for (const auto& g : compounds) {
      std::string label;
      for (const auto& k : g) label += (label.empty() ? "" : "+") + k;
      if (!wanted(label)) continue;
      Case c{label, "compound", {}, {}};
      for (const auto& k : g) c.parts.push_back({k, 1.0});
      for (const Magnitude& m : mags) {
        if (m.absorbed && std::find(g.begin(), g.end(), m.key) != g.end()) {
          c.absorbed.push_back(m.key);
        }
      }
      if (c.absorbed.size() == g.size()) continue;  // nothing left to name
      for (const auto& a : c.absorbed) c.label += " (" + a + " absorbed)";
      cases.push_back(c);
    }
    if (wanted("out_of_library")) {
      cases.push_back({"hysteresis+friction (out of library)",
                       "out of library",
                       {{"hysteresis", 1.0}, {"friction", 1.0}},
                       {},
                       true});
    }
    if (wanted("null")) cases.push_back({"null", "null", {}, {}});

    std::vector<CaseStats> stats(cases.size());
    struct Job {
      int c, seed;
    };
    std::vector<Job> jobs;
    for (std::size_t c = 0; c < cases.size(); ++c) {
      stats[c].c = &cases[c];
      stats[c].runs.resize(static_cast<std::size_t>(seeds));
      for (int s = first_seed; s < first_seed + seeds; ++s)
        jobs.push_back({static_cast<int>(c), s});
    }
    std::atomic<int> done{0};
    const auto t_runs = std::chrono::steady_clock::now();
    parallel_for(static_cast<int>(jobs.size()), workers, [&](int i) {
      const Job& j = jobs[static_cast<std::size_t>(i)];
      RunResult res = run_case(r, cases[static_cast<std::size_t>(j.c)], j.seed, dopt);
      std::lock_guard<std::mutex> lock(print_mutex);
      const int n = ++done;
      std::string named;
      for (const auto& f : res.named_families) named += (named.empty() ? "" : ", ") + f;
      if (!res.ok) named = "ERROR " + res.error;
      const double elapsed = seconds_since(t_runs);
      std::printf("[%s] %4d/%zu %-38s seed %2d: %-20s %s (%.1f s, ETA %.0f s)\n", r.name.c_str(), n,
                  jobs.size(), cases[static_cast<std::size_t>(j.c)].label.c_str(), j.seed,
                  res.ok ? cdpr::to_string(res.verdict) : "failed",
                  named.empty() ? "-" : named.c_str(), res.seconds,
                  elapsed / n * static_cast<double>(static_cast<int>(jobs.size()) - n));
      if (res.separation_tried) {
        std::printf("        confounded: separating poses appended, re-run %s%s%s\n",
                    res.separated ? "separated the true effect" : "did not separate",
                    res.separation_error.empty() ? "" : ": ", res.separation_error.c_str());
      }
      if (!res.follow_up_error.empty()) {
        std::printf("        suspect: the follow-up failed (%s)\n", res.follow_up_error.c_str());
      }
      if (res.follow_up) {
        std::printf("        suspect: follow-up poses appended, re-run %s\n",
                    res.follow_up_named ? "named an effect" : "named nothing");
      }
      if (res.ok) {
        std::printf("        screen top: %s p %.4g, Holm %.4g, first run %s\n",
                    res.top_id.empty() ? "-" : res.top_id.c_str(), res.top_p, res.top_p_adjusted,
                    res.first_named ? "named" : "named nothing");
        std::printf("        screen misfit: %s\n", res.screen_channels.c_str());
      }
      if (verbose && res.ok) std::printf("%s\n", res.text.c_str());
      std::fflush(stdout);
      stats[static_cast<std::size_t>(j.c)].runs[static_cast<std::size_t>(j.seed - first_seed)] =
          std::move(res);
    });
    if (verdicts) {
      // Every seed's verdict in case order, free of timings and worker order: two runs of the
      // same build (or of a behaviour-preserving change) print the same lines.
      std::printf("\n== %s: verdict of every seed ==\n", r.name.c_str());
      for (const CaseStats& s : stats) {
        for (std::size_t seed = 0; seed < s.runs.size(); ++seed) {
          const RunResult& res = s.runs[seed];
          std::string named;
          for (const auto& f : res.named_families) named += (named.empty() ? "" : ", ") + f;
          std::printf(
              "verdict [%s] %s seed %zu: %s | named %s | all %d any %d extra %d | conf %d sep "
              "%d/%d%s | follow-up %d named %d%s | first named %d | top %s p %.6g Holm %.6g | "
              "held %.6g -> %.6g | %s\n",
              r.name.c_str(), s.c->label.c_str(), seed + static_cast<std::size_t>(first_seed),
              res.ok ? cdpr::to_string(res.verdict) : ("failed: " + res.error).c_str(),
              named.empty() ? "-" : named.c_str(), res.all_true_named, res.any_true_named,
              res.extra_named, res.confounded, res.separated, res.separation_tried,
              res.separation_error.empty() ? "" : (" error " + res.separation_error).c_str(),
              res.follow_up, res.follow_up_named,
              res.follow_up_error.empty() ? "" : (" error " + res.follow_up_error).c_str(),
              res.first_named, res.top_id.empty() ? "-" : res.top_id.c_str(), res.top_p,
              res.top_p_adjusted, res.held_before, res.held_after, res.screen_channels.c_str());
        }
      }
    }
    print_robot(r, baseline, mags, stats, seconds_since(t_robot), seeds);
    std::fflush(stdout);
  }
  std::printf("\ntotal runtime %.0f s\n", seconds_since(t_all));
  return 0;
}
