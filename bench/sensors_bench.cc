// Issue 18 benchmark: what each sensor configuration buys on MINI (printed figures, not a test).
//
// Scenario: MINI as shipped with swivel encoders, an inclinometer and hidden mounting errors
// (scenario::mini_sensor_scenario): nominal = config/mini.yaml, truth = config/mini-measured.yaml
// plus swivel-encoder zeros and an inclinometer tilt; elastic simulation (the nominal controller
// commands lengths, the true robot settles); encoder 0.1 mm, force 1 N, laser 1 mm, swivel 1 mrad,
// inclinometer 0.5 mrad; 25 poses designed for position accuracy with the laser (the same poses
// for every configuration); the same seeds, and the lengths and forces of a seed are the same in
// every configuration (SimulationOptions: the new channels draw from their own stream).
//
// Configurations:
//   laser                 lengths + forces + laser; anchors, offsets, laser plane
//   swivel+inclinometer   lengths + forces + swivel angles + inclinometer, no laser; anchors,
//                         offsets, swivel zeros, inclinometer mounting (roll, pitch)
//   nothing extra         lengths + forces only (self-calibration); anchors, offsets
//   all                   laser + swivel + inclinometer
// Figures per configuration: anchor RMS error per coordinate over the seeds, the Cramer-Rao bound
// at the truth (true parameters, settled poses and tensions of a noise-free run), the reported
// std, the coverage of the 95 % intervals, the ISO 9283 box position error (312 mm cube, 125
// points) and chi2/dof.
//   build/<dir>/bench/sensors_bench [--seeds N]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench_util.hpp"
#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace {

using cdpr::bench::must;

cdpr::SensorNoise bench_noise() {
  cdpr::SensorNoise n = cdpr::bench::mini_noise();
  n.sigma_swivel = 1e-3;
  n.sigma_inclination = 5e-4;
  return n;
}

struct Config {
  const char* name;
  bool laser, swivel, inclinometer;
};

cdpr::SimulationOptions sim_options(const cdpr::scenario::Scenario& s, const Config& c,
                                    bool noise) {
  cdpr::SimulationOptions so;
  so.physics = cdpr::SimulationOptions::Physics::kElastic;
  so.controller = &s.nominal;
  so.add_noise = noise;
  so.laser = c.laser;
  so.swivel = c.swivel;
  so.inclinometer = c.inclinometer;
  return so;
}

cdpr::IdentificationOptions ident_options(const Config& c) {
  cdpr::IdentificationOptions o;
  o.estimate_laser_plane = c.laser;
  o.estimate_swivel_zeros = c.swivel;
  o.estimate_inclinometer_mounting = c.inclinometer;
  return o;
}

// RMS over the anchor coordinates of the Cramer-Rao std at the truth.
double crb_at_truth(const cdpr::scenario::Scenario& s, const std::vector<cdpr::Pose>& commands,
                    const Config& c, std::string* summary) {
  const cdpr::SimulatedMeasurements sim = must(
      cdpr::simulate_measurements(s.truth, commands, bench_noise(), 0, sim_options(s, c, false)),
      "simulate");
  const cdpr::GeometryInformation gi =
      must(cdpr::geometry_information(s.truth, sim.set, sim.true_poses, ident_options(c)), "info");
  const double rms = cdpr::bench::anchor_crb_rms(gi);
  if (summary) {
    auto ir = cdpr::analyze_identifiability(s.truth, sim.set, ident_options(c));
    *summary = ir.ok() ? ir->summary() : std::string(ir.status().message());
  }
  return rms;
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 100;
  for (int k = 1; k < argc; ++k) {
    if (std::strcmp(argv[k], "--seeds") == 0 && k + 1 < argc) seeds = std::atoi(argv[++k]);
  }
  const cdpr::scenario::Scenario mini = cdpr::scenario::mini_sensor_scenario();
  cdpr::PoseDesignOptions design;
  design.noise = bench_noise();
  design.half_extent = Eigen::Vector3d::Constant(0.2);
  design.max_angle = 0.2618;
  design.exchange_passes = 4;
  cdpr::AccuracyBox iso;
  design.criterion = cdpr::DesignCriterion::kPositionAccuracy;
  design.accuracy_box = iso;
  const cdpr::PoseDesign poses = must(cdpr::design_poses(mini.nominal, design), "design");
  const double nominal_pos =
      must(cdpr::measure_position_accuracy(mini.truth, mini.nominal, iso), "nominal accuracy")
          .position_rms_m;
  std::printf("cdpr sensor-channel benchmark: MINI, %zu designed poses, %d seeds, elastic\n",
              poses.poses.size(), seeds);
  std::printf(
      "noise: encoder 0.1 mm, force 1 N, laser 1 mm, swivel 1 mrad, inclinometer 0.5 mrad\n");
  std::printf("nominal model: box position RMS %.3f mm\n\n", 1e3 * nominal_pos);

  const Config configs[] = {
      {"laser", true, false, false},
      {"swivel+inclinometer", false, true, true},
      {"nothing extra", false, false, false},
      {"all (laser+swivel+incl.)", true, true, true},
  };
  std::printf("%-26s %9s %9s %8s %9s %9s %9s %9s %8s %6s\n", "configuration", "anchor", "CRB",
              "err/CRB", "rep. std", "coverage", "box RMS", "box max", "chi2/dof", "runs");
  std::printf("%-26s %9s %9s %8s %9s %9s %9s %9s %8s %6s\n", "", "RMS mm", "mm", "", "mm", "%",
              "mm", "mm", "", "");
  std::vector<std::string> summaries;
  for (const Config& c : configs) {
    const auto t0 = std::chrono::steady_clock::now();
    std::string summary;
    const double crb = crb_at_truth(mini, poses.poses, c, &summary);
    summaries.push_back(std::string(c.name) + ":\n" + summary);
    double sum_sq = 0.0, sum_std2 = 0.0, sum_chi2 = 0.0, sum_pos2 = 0.0, pos_max = 0.0;
    long covered = 0, total = 0;
    int ok = 0;
    for (int seed = 0; seed < seeds; ++seed) {
      auto sim = cdpr::simulate_measurements(mini.truth, poses.poses, bench_noise(), 1000 + seed,
                                             sim_options(mini, c, true));
      if (!sim.ok()) continue;
      auto rep = cdpr::identify(mini.nominal, sim->set, ident_options(c));
      if (!rep.ok() || !rep->converged) continue;
      ++ok;
      sum_chi2 += rep->chi2 / std::max(1, rep->dof);
      const cdpr::RealizedAccuracy acc =
          must(cdpr::measure_position_accuracy(mini.truth, rep->estimate, iso), "accuracy");
      sum_pos2 += acc.position_rms_m * acc.position_rms_m;
      pos_max = std::max(pos_max, acc.position_max_m);
      for (const cdpr::ParameterEstimate& p : rep->parameters) {
        if (p.name.rfind("a_", 0) != 0) continue;
        const int cable = std::stoi(p.name.substr(2, p.name.find('.') - 2)) - 1;
        const int axis = p.name.back() - 'x';
        const double e = p.value - mini.truth.robot.frame_anchors(axis, cable);
        sum_sq += e * e;
        sum_std2 += p.std_dev * p.std_dev;
        covered += std::abs(e) <= 1.96 * p.std_dev ? 1 : 0;
        ++total;
      }
    }
    const double rms = std::sqrt(sum_sq / std::max<long>(1, total));
    std::printf(
        "%-26s %9.3f %9.3f %8.3f %9.3f %9.1f %9.3f %9.3f %8.3f %6d  (%.0f s)\n", c.name, 1e3 * rms,
        1e3 * crb, rms / crb, 1e3 * std::sqrt(sum_std2 / std::max<long>(1, total)),
        100.0 * static_cast<double>(covered) / static_cast<double>(std::max<long>(1, total)),
        1e3 * std::sqrt(sum_pos2 / std::max(1, ok)), 1e3 * pos_max, sum_chi2 / std::max(1, ok), ok,
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    std::fflush(stdout);
  }
  std::printf("\nIdentifiability at the truth (per configuration):\n");
  for (const std::string& s : summaries) std::printf("%s\n", s.c_str());
  return 0;
}
