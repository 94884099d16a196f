// In-service monitoring on the virtual MINI (docs/monitoring.md): per slow hidden change, the time
// and the platform's travel from the change's start to the first alarm, the effect named and its
// estimated size against the truth; and the false alarms of a clean run against the stated rates.
//
//   build/ci/bench/monitoring_bench [--clean-hours H] [--change-hours H] [--calibrated-hours H]
//                                   [--only-calibrated] [--seed S]
//
// In-process, no CAN, no daemon: cdpr-sim's quasi-static physics (sim/physics.hpp) is the true
// robot, config/mini.yaml both the truth at t = 0 and the calibrated model (an exact calibration:
// the monitor's model uncertainty is zero), with the scenario noise of mini-calibration.yaml
// (encoder 2 counts, force 0.2 raw = 0.1 N, laser 0.1 mm). The robot repeats a cycle through the
// nine poses of a 160 mm cube (its corners and centre): a 10 s move, then a 20 s hold. Every second
// the commanded pose (sampled on the straight line during moves) goes through the nominal planner
// and compensated IK to integer counts (sim::nominal_counts), the physics steps there, and the
// monitor gets one sample: the encoder counts through the nominal winch model, the raw forces
// through the nominal sensor model, the laser.
// Then the same clean cycle after a real calibration (calibrated_clean_run): the main job's robot
// calibrated on 25 designed poses (virtual_calibration.hpp), watched without and with a reference
// phase (MonitorOptions::reference_s). --only-calibrated runs that part alone.
#include <Eigen/Core>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "cdpr/calibration/force_sensor.hpp"
#include "cdpr/calibration/monitoring.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"
#include "virtual_calibration.hpp"

namespace {

using cdpr::Monitor;
using cdpr::MonitorSample;
using cdpr::Pose;
using cdpr::RobotModel;

constexpr double kStep = 1.0;     // s between samples (and physics steps)
constexpr int kMoveSteps = 10;    // s per move
constexpr int kHoldSteps = 20;    // s per hold
constexpr double kHalf = 0.08;    // m, half the cube
constexpr double kStart = 600.0;  // s, when each change starts (10 clean minutes first)
constexpr double kNoise[] = {2.0, 0.2, 1e-4};  // encoder counts, force raw, laser m

template <typename T>
T must(cdpr::Result<T> r, const char* what) {
  if (!r.ok()) {
    std::fprintf(stderr, "monitoring_bench: %s: %s\n", what, r.status().to_string().c_str());
    std::exit(1);
  }
  return std::move(*r);
}

std::vector<Pose> cycle_poses() {
  std::vector<Pose> out{Pose{}};
  for (double x : {-kHalf, kHalf}) {
    for (double y : {-kHalf, kHalf}) {
      for (double z : {-kHalf, kHalf}) out.push_back(Pose{Eigen::Vector3d(x, y, z), {0, 0, 0}});
    }
  }
  return out;
}

// The commanded pose at step k of the repeated cycle (moves then holds).
Pose commanded(int k, const std::vector<Pose>& poses) {
  const int per = kMoveSteps + kHoldSteps;
  const int leg = k / per, in = k % per;
  const Pose& to = poses[static_cast<std::size_t>((leg + 1) % poses.size())];
  const Pose& from = poses[static_cast<std::size_t>(leg % poses.size())];
  const double s = in >= kMoveSteps ? 1.0 : static_cast<double>(in) / kMoveSteps;
  return Pose{from.position + s * (to.position - from.position),
              from.rpy + s * (to.rpy - from.rpy)};
}

struct Change {
  const char* name;
  const char* yaml;  // scenario lines
  // The true size at time t, in the monitor's SI terms (what assess() estimates).
  Eigen::VectorXd (*truth)(double t, const RobotModel& nominal);
  const char* expected_id;
  int expected_cable;  // 0-based, -1 shared
};

Eigen::VectorXd v1(double x) {
  return Eigen::VectorXd::Constant(1, x);
}

double ramp(double t, double duration) {
  return t < kStart ? 0.0 : std::min(1.0, (t - kStart) / duration);
}

const Change kChanges[] = {
    {"pulley 3 moved 5 mm in 1 h",
     "drifts: [{type: pulley_move, cable: 3, at: 600, duration: 3600, by: [0.003, 0.004, 0]}]\n",
     [](double t, const RobotModel&) {
       Eigen::VectorXd v(3);
       v << 0.003, 0.004, 0.0;
       return Eigen::VectorXd(v * ramp(t, 3600.0));
     },
     "frame_anchor", 2},
    {"thermal growth (-1.2e-5/K, 10 K/h)",
     "effects: {thermal: {alpha: -1.2e-5, rate: 0.0027778, max_delta: 10}}\n",
     [](double t, const RobotModel&) { return v1(-1.2e-5 * std::min(10.0, 0.0027778 * t)); },
     "thermal_growth", -1},
    {"force sensor 2 drifts 2.5 N in 1 h",
     "drifts: [{type: force_sensor, cable: 2, at: 600, duration: 3600, offset: 5}]\n",
     [](double t, const RobotModel& n) {
       return v1(5.0 * ramp(t, 3600.0) / n.force_sensors[1].gain);
     },
     "force_offset_per_cable", 1},
    {"creeping cables (2e-6/N, tau 600 s)", "effects: {creep: {coefficient: 2.0e-6, tau: 600}}\n",
     [](double t, const RobotModel&) { return v1(2.0e-6 * std::log1p(t / 600.0)); }, "creep_shared",
     -1},
    {"encoder 6 slips 500 counts",
     "drifts: [{type: encoder_slip, cable: 6, at: 600, counts: 500}]\n",
     [](double t, const RobotModel& n) {
       const double mpc = cdpr::winch_metres_per_count(n.winches[5]) * n.winches[5].direction;
       return v1(t < kStart ? 0.0 : 500.0 * mpc);
     },
     "encoder_offset_per_cable", 5},
};

struct Run {
  RobotModel nominal;
  cdpr::sim::Physics physics;
  std::vector<Pose> poses = cycle_poses();
  int step = 0;
  double travel = 0.0;  // m, commanded platform path since t = 0
  Pose last;
};

cdpr::sim::Scenario bench_scenario(const std::string& extra) {
  char noise[160];
  std::snprintf(noise, sizeof noise, "noise: {encoder_counts: %g, force_raw: %g, laser: %g}\n",
                kNoise[0], kNoise[1], kNoise[2]);
  const std::string text = std::string("name: monitoring\n") + noise + extra;
  return must(cdpr::sim::parse_scenario(text, "bench.yaml"), "scenario");
}

// `model` commands the robot and reads its sensors (the calibrated model); the scenario's truth
// (resolved against `nominal`) is the robot.
Run make_run(const RobotModel& model, const RobotModel& nominal, const cdpr::sim::Scenario& s,
             std::uint64_t seed) {
  RobotModel truth = must(cdpr::sim::resolve_truth(s, nominal), "truth");
  return Run{model,         must(cdpr::sim::Physics::create(truth, s, seed), "physics"),
             cycle_poses(), 0,
             0.0,           Pose{}};
}

Run make_run(const RobotModel& nominal, const std::string& extra, std::uint64_t seed) {
  return make_run(nominal, nominal, bench_scenario(extra), seed);
}

// One step of the run: the commanded pose, the physics, the sample.
MonitorSample next(Run& r) {
  const Pose p = commanded(r.step, r.poses);
  r.travel += (p.position - r.last.position).norm();
  r.last = p;
  const double t = r.step * kStep;
  ++r.step;
  Eigen::VectorXd counts = must(cdpr::sim::nominal_counts(r.nominal, p), "nominal counts");
  counts = counts.array().round().matrix();
  const cdpr::Status st = r.physics.step(counts, t);
  if (!st.ok()) {
    std::fprintf(stderr, "monitoring_bench: physics at t = %g s: %s\n", t, st.to_string().c_str());
    std::exit(1);
  }
  const cdpr::sim::PhysicsState& ps = r.physics.state();
  MonitorSample s;
  s.time_s = t;
  s.pose = p;
  for (int i = 0; i < r.nominal.num_cables(); ++i) {
    const auto u = static_cast<std::size_t>(i);
    s.lengths[u] = cdpr::winch_counts_to_length<double>(r.nominal.winches[u], ps.encoder_counts(i));
    s.tensions[u] = cdpr::force_sensor_tension<double>(r.nominal.force_sensors[u], ps.force_raw(i));
  }
  for (std::size_t k = 0; k < ps.lasers.size() && k < s.lasers.size(); ++k) {
    if (ps.lasers[k].status == cdpr::sim::LaserStatus::kOk) s.lasers[k] = ps.lasers[k].reading;
  }
  return s;
}

cdpr::MonitorOptions monitor_options(const RobotModel& nominal, double rate_per_hour) {
  cdpr::MonitorOptions o;
  const double mpc = cdpr::winch_metres_per_count(nominal.winches[0]);
  o.noise.sigma_length = std::sqrt(kNoise[0] * kNoise[0] + 1.0 / 12.0) * mpc;  // with rounding
  o.noise.sigma_force = kNoise[1] / nominal.force_sensors[0].gain;
  o.noise.sigma_laser = kNoise[2];
  o.false_alarms_per_hour = rate_per_hour;
  o.samples_per_hour = 3600.0 / kStep;
  o.window_s = 600.0;
  o.box.half_extent = Eigen::Vector3d::Constant(kHalf);
  o.box.points_per_axis = 3;
  return o;
}

cdpr::SensorNoise sensor_noise(const cdpr::MonitorOptions& o) {
  cdpr::SensorNoise n;
  n.sigma_length = o.noise.sigma_length;
  n.sigma_force = o.noise.sigma_force;
  n.sigma_laser = o.noise.sigma_laser;
  return n;
}

// predict_accuracy of a calibration of `model` on the box grid with the bench's noise.
cdpr::PredictedAccuracy box_accuracy(const cdpr::CalibratedModel& model,
                                     const cdpr::MonitorOptions& o) {
  cdpr::PredictedAccuracyOptions po;
  po.box = o.box;
  return must(cdpr::predict_accuracy(model, o.box.grid(), sensor_noise(o), po), "accuracy");
}

// The acceptance figure of an exact calibration.
double acceptance_rms(const RobotModel& nominal, const cdpr::MonitorOptions& o) {
  return box_accuracy(cdpr::CalibratedModel::from_robot(nominal), o).position_rms_m;
}

// Hours of clean running (no change) with monitors at stated rates of 10, 1 and 0.1 false alarms
// per hour: how many alarms each raised. `run` holds the robot and the model the monitors watch.
void clean_run(Run run, const cdpr::MonitorOptions& base, double hours) {
  const double rates[] = {10.0, 1.0, 0.1};
  std::vector<Monitor> monitors;
  for (double r : rates) {
    cdpr::MonitorOptions o = base;
    o.false_alarms_per_hour = r;
    monitors.push_back(
        must(Monitor::create(cdpr::CalibratedModel::from_robot(run.nominal), o), "monitor"));
  }
  const int steps = static_cast<int>(hours * 3600.0 / kStep);
  const auto t0 = std::chrono::steady_clock::now();
  double add_seconds = 0.0;
  for (int k = 0; k < steps; ++k) {
    const MonitorSample s = next(run);
    const auto a0 = std::chrono::steady_clock::now();
    for (Monitor& m : monitors) m.add(s);
    add_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - a0).count();
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf(
      "  %.1f h simulated (%d samples at %.0f per hour, %.0f m travelled), %.1f s "
      "wall, Monitor::add %.1f us per sample\n",
      hours, steps, 3600.0 / kStep, run.travel, wall,
      1e6 * add_seconds / (steps * monitors.size()));
  std::printf("  %-22s %-10s %-12s %-12s %s\n", "stated false alarms/h", "threshold", "alarms",
              "measured /h", "measured/stated");
  for (std::size_t j = 0; j < monitors.size(); ++j) {
    const double measured = monitors[j].alarms() / hours;
    std::printf("  %-22.2f %-10.2f %-12d %-12.3f %.2f\n", rates[j], monitors[j].threshold(),
                monitors[j].alarms(), measured, measured / rates[j]);
  }
  const cdpr::MonitorAssessment a = must(monitors.back().assess(), "assess");
  std::printf("  assessment at the end (stated 0.1/h): %s%s\n",
              a.changed ? a.effects.front().words.c_str() : "no change named",
              a.reference_consistent ? "" : " (reference beyond the stated uncertainty)");
}

// The same clean running after a real calibration: the true robot is the main job's
// (config/scenarios/mini-calibration.yaml: measured anchors, softer cables, encoder zeros, its
// noise), calibrated from the nominal config on 25 designed poses (cdpr-fit calibrate's library
// calls) with EA fixed or estimated. The monitors watch the calibrated model, its predicted
// accuracy the model uncertainty: as noise per sample (no reference phase), or as the prior of a
// reference phase of `reference_s` (MonitorOptions::reference_s).
void calibrated_clean_run(const RobotModel& nominal, cdpr::StiffnessEstimate stiffness,
                          const char* label, double hours, std::uint64_t seed) {
  const cdpr::sim::Scenario scenario =
      must(cdpr::sim::load_scenario(std::string(CDPR_SOURCE_DIR) +
                                    "/config/scenarios/mini-calibration.yaml"),
           "mini-calibration.yaml");
  const RobotModel truth = must(cdpr::sim::resolve_truth(scenario, nominal), "truth");
  cdpr::IdentificationOptions io;
  io.estimate_stiffness = stiffness;
  const cdpr::IdentificationReport rep =
      cdpr::bench::calibrate_virtual_robot(nominal, truth, scenario, seed, io);
  const RobotModel& model = rep.estimate.robot;
  cdpr::MonitorOptions o = monitor_options(model, 0.1);
  const cdpr::PredictedAccuracy pa = box_accuracy(rep.estimate, o);
  o.noise = cdpr::monitor_noise(sensor_noise(o), &pa);
  o.acceptance_position_rms_m = pa.position_rms_m;
  for (double reference : {0.0, 600.0, 3600.0}) {
    o.reference_s = reference;
    std::printf(
        "after a real calibration (%s; chi2/dof %.2f, model length uncertainty %.4f mm), "
        "reference phase %.0f s (0: none):\n",
        label, rep.chi2 / std::max(1, rep.dof), 1e3 * o.noise.model_length, reference);
    clean_run(make_run(model, nominal, scenario, seed + 2000), o, hours);
  }
}

bool is_drift(const Change& c) {
  return std::strncmp(c.yaml, "drifts", 6) == 0;
}

void print_estimate(const char* when, const Change& c, const cdpr::MonitorAssessment& a,
                    const Eigen::VectorXd& truth) {
  if (!a.changed || a.effects.empty()) {
    std::printf("    %s: no change named\n", when);
    return;
  }
  const cdpr::EffectEstimate& e = a.effects.front();
  const bool right = e.id == c.expected_id && e.cable == c.expected_cable;
  std::printf("    %s: %s [%s]; estimated", when, e.words.c_str(), right ? "right" : "WRONG");
  for (Eigen::Index j = 0; j < e.value.size(); ++j) std::printf(" %.3g", e.value(j));
  std::printf(", true");
  for (Eigen::Index j = 0; j < truth.size(); ++j) std::printf(" %.3g", truth(j));
  std::printf(" (SI)\n");
}

// One long run with the change: the first alarm after its start (time, travel), the first
// assessment that names a change, and the assessment at the end of the run.
void change_run(const RobotModel& nominal, const Change& c, double hours, std::uint64_t seed,
                double acceptance) {
  cdpr::MonitorOptions o = monitor_options(nominal, 0.1);
  o.acceptance_position_rms_m = acceptance;
  Monitor monitor = must(Monitor::create(cdpr::CalibratedModel::from_robot(nominal), o), "monitor");
  Run run = make_run(nominal, c.yaml, seed);
  const int steps = static_cast<int>(hours * 3600.0 / kStep);
  const double start = is_drift(c) ? kStart : 0.0;  // thermal and creep act from t = 0
  double travel_at_start = 0.0, alarm_t = -1.0;
  int early_alarms = 0;
  bool named = false;
  std::printf("%s\n", c.name);
  for (int k = 0; k < steps; ++k) {
    const MonitorSample s = next(run);
    if (s.time_s < start) travel_at_start = run.travel;
    if (!monitor.add(s)) continue;
    if (s.time_s < start) {
      ++early_alarms;
      continue;
    }
    if (alarm_t < 0.0) {
      alarm_t = s.time_s;
      std::printf(
          "    first alarm %.0f s after the change started, %.1f m of platform travel, "
          "channel %s\n",
          s.time_s - start, run.travel - travel_at_start,
          monitor.row_name(monitor.first_alarm_row()).c_str());
    }
    if (named) continue;
    const cdpr::MonitorAssessment a = must(monitor.assess(), "assess");
    if (!a.changed) continue;
    named = true;
    char when[96];
    std::snprintf(when, sizeof when, "named at %.0f s", s.time_s - start);
    print_estimate(when, c, a, c.truth(s.time_s, nominal));
  }
  if (alarm_t < 0.0) std::printf("    no alarm in %.1f h\n", hours);
  const cdpr::MonitorAssessment a = must(monitor.assess(), "assess");
  const double t_end = (steps - 1) * kStep;
  char when[96];
  std::snprintf(when, sizeof when, "at the end (%.0f s)", t_end - start);
  print_estimate(when, c, a, c.truth(t_end, nominal));
  std::printf("    position error over the box %.3f mm now vs %.3f mm at acceptance\n",
              a.position_rms_now_m * 1e3, a.position_rms_acceptance_m * 1e3);
  if (a.proposal.needed) std::printf("    proposal: %s\n", a.proposal.stopping_rule.c_str());
  if (early_alarms > 0) std::printf("    (%d false alarms before the change)\n", early_alarms);
}

}  // namespace

int main(int argc, char** argv) {
  double clean_hours = 100.0, change_hours = 2.0, calibrated_hours = 10.0;
  std::uint64_t seed = 1;
  bool only_calibrated = false;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--clean-hours") && i + 1 < argc) {
      clean_hours = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--change-hours") && i + 1 < argc) {
      change_hours = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--calibrated-hours") && i + 1 < argc) {
      calibrated_hours = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--only-calibrated")) {
      only_calibrated = true;
    } else if (!std::strcmp(argv[i], "--seed") && i + 1 < argc) {
      seed = std::strtoull(argv[++i], nullptr, 10);
    } else {
      std::fprintf(
          stderr,
          "usage: monitoring_bench [--clean-hours H] [--change-hours H] [--calibrated-hours H] "
          "[--only-calibrated] [--seed S]\n");
      return 2;
    }
  }
  if (!(clean_hours >= 1.0) || !(change_hours > kStart / 3600.0)) {
    std::fprintf(stderr, "monitoring_bench: --clean-hours >= 1 and --change-hours > 0.17\n");
    return 2;
  }
  const RobotModel nominal =
      must(cdpr::config::load_robot_config(std::string(CDPR_SOURCE_DIR) + "/config/mini.yaml"),
           "config/mini.yaml");
  const double acceptance = acceptance_rms(nominal, monitor_options(nominal, 0.1));
  std::printf(
      "virtual MINI (cdpr-sim physics, truth = config/mini.yaml), seed %llu, one sample per "
      "%.0f s, stated rate 0.1 false alarms per hour for the changes\n",
      static_cast<unsigned long long>(seed), kStep);
  if (!only_calibrated) {
    for (const Change& c : kChanges) change_run(nominal, c, change_hours, seed, acceptance);
    std::printf("clean run (exact calibration):\n");
    clean_run(make_run(nominal, "", seed + 1000), monitor_options(nominal, 0.1), clean_hours);
  }
  calibrated_clean_run(nominal, cdpr::StiffnessEstimate::kPerCable, "EA per cable estimated",
                       calibrated_hours, seed);
  calibrated_clean_run(nominal, cdpr::StiffnessEstimate::kFixed, "EA fixed at the nominal",
                       calibrated_hours, seed);
  return 0;
}
