// Issue 18 benchmark: what each sensor configuration buys (printed figures, not a test).
//
// Scenarios (--robot mini|large):
// - MINI as shipped with swivel encoders, an inclinometer and hidden mounting errors
//   (scenario::mini_sensor_scenario): nominal = config/mini.yaml, truth = config/mini-measured.yaml
//   plus swivel-encoder zeros and an inclinometer tilt. Accuracy box: the ISO 9283 312 mm cube;
//   candidate cube 0.2 m half side.
// - LARGE (scenario::large_sensor_scenario, as bench/mismatch_bench.cc's large robot): the
//   IPAnema-3-like 8-cable robot, anchors perturbed by up to 30 mm, the same sensors and mounting
//   errors. Accuracy box 5 x 3.5 x 1.2 m (identification_bench's); candidate box 8 x 5.6 x 2 m.
// Elastic simulation (the nominal controller commands lengths, the true robot settles); encoder
// 0.1 mm, force 1 N, laser 1 mm, swivel 1 mrad, inclinometer 0.5 mrad; 25 poses designed for
// position accuracy FOR EACH CONFIGURATION'S CHANNELS (design_poses with its SensorChannels; with
// --laser-poses the poses designed with the laser are used for every configuration, as issue 18's
// first part did); the same seeds, and the lengths and forces of a seed are the same in every
// configuration (SimulationOptions: the new channels draw from their own stream).
//
// Configurations:
//   laser                 lengths + forces + laser; anchors, offsets, laser plane
//   swivel+inclinometer   lengths + forces + swivel angles + inclinometer, no laser; anchors,
//                         offsets, swivel zeros, inclinometer mounting (roll, pitch)
//   nothing extra         lengths + forces only (self-calibration); anchors, offsets
//   all                   laser + swivel + inclinometer
// (the estimated parameters follow the channels: fit_estimates_to_channels).
// Figures per configuration: anchor RMS error per coordinate over the seeds, the Cramer-Rao bound
// at the truth (true parameters, settled poses and tensions of a noise-free run), the design's
// prediction (predict_accuracy at the nominal model: anchor std and box position RMS), the
// reported std, the coverage of the 95 % intervals, the bias (RMS over the coordinates of the mean
// error), the box position error (RMS over the seeds of
// each run's RMS over the 125 box points, and the largest point error) and chi2/dof.
//   build/<dir>/bench/sensors_bench [--seeds N] [--robot mini|large] [--laser-poses]
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

  cdpr::SensorChannels channels() const {
    cdpr::SensorChannels c;
    c.laser = laser;
    c.swivel = swivel;
    c.inclinometer = inclinometer;
    return c;
  }
};

cdpr::SimulationOptions sim_options(const cdpr::scenario::Scenario& s, const Config& c,
                                    bool noise) {
  cdpr::SimulationOptions so;
  so.physics = cdpr::SimulationOptions::Physics::kElastic;
  so.controller = &s.nominal;
  so.add_noise = noise;
  so.use_channels(c.channels());
  return so;
}

cdpr::IdentificationOptions ident_options(const Config& c) {
  cdpr::IdentificationOptions o;
  cdpr::fit_estimates_to_channels(c.channels(), &o);
  return o;
}

// The robot of a run: scenario, design options (channels set per configuration) and test box.
struct Robot {
  const char* name;
  cdpr::scenario::Scenario s;
  cdpr::PoseDesignOptions design;
  cdpr::AccuracyBox box;
};

Robot make_robot(const std::string& which) {
  Robot r;
  r.design.noise = bench_noise();
  r.design.max_angle = 0.2618;
  r.design.criterion = cdpr::DesignCriterion::kPositionAccuracy;
  if (which == "large") {
    r.name = "LARGE";
    r.s = cdpr::scenario::large_sensor_scenario();
    r.design.half_extent = Eigen::Vector3d(4.0, 2.8, 1.0);
    r.design.exchange_passes = 2;
    r.box.half_extent = Eigen::Vector3d(2.5, 1.75, 0.6);
  } else {
    r.name = "MINI";
    r.s = cdpr::scenario::mini_sensor_scenario();
    r.design.half_extent = Eigen::Vector3d::Constant(0.2);
    r.design.exchange_passes = 4;
  }
  r.design.accuracy_box = r.box;
  return r;
}

cdpr::PoseDesign design_for(const Robot& r, const Config& c) {
  cdpr::PoseDesignOptions d = r.design;
  d.channels = c.channels();
  d.identification = ident_options(c);
  return must(cdpr::design_poses(r.s.nominal, d), "design");
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 100;
  std::string which = "mini";
  bool laser_poses = false;
  for (int k = 1; k < argc; ++k) {
    if (std::strcmp(argv[k], "--seeds") == 0 && k + 1 < argc) {
      seeds = std::atoi(argv[++k]);
    } else if (std::strcmp(argv[k], "--robot") == 0 && k + 1 < argc) {
      which = argv[++k];
    } else if (std::strcmp(argv[k], "--laser-poses") == 0) {
      laser_poses = true;
    } else {
      std::fprintf(stderr,
                   "usage: sensors_bench [--seeds N] [--robot mini|large] [--laser-poses]\n");
      return 2;
    }
  }
  if (which != "mini" && which != "large") {
    std::fprintf(stderr, "--robot must be mini or large, got %s\n", which.c_str());
    return 2;
  }
  const Robot robot = make_robot(which);
  const cdpr::scenario::Scenario& s = robot.s;
  const cdpr::AccuracyBox& box = robot.box;
  const double nominal_pos =
      must(cdpr::measure_position_accuracy(s.truth, s.nominal, box), "nominal accuracy")
          .position_rms_m;
  std::printf("cdpr sensor-channel benchmark: %s, %d poses designed %s, %d seeds, elastic\n",
              robot.name, robot.design.num_poses,
              laser_poses ? "with the laser (the same for every configuration)"
                          : "for each configuration's channels",
              seeds);
  std::printf(
      "noise: encoder 0.1 mm, force 1 N, laser 1 mm, swivel 1 mrad, inclinometer 0.5 mrad\n");
  std::printf(
      "accuracy box: +-%.3f x %.3f x %.3f m, %d points; nominal model: box position RMS "
      "%.3f mm\n\n",
      box.half_extent.x(), box.half_extent.y(), box.half_extent.z(),
      box.points_per_axis * box.points_per_axis * box.points_per_axis, 1e3 * nominal_pos);

  const Config configs[] = {
      {"laser", true, false, false},
      {"swivel+inclinometer", false, true, true},
      {"nothing extra", false, false, false},
      {"all (laser+swivel+incl.)", true, true, true},
  };
  std::vector<cdpr::Pose> shared;
  if (laser_poses) shared = design_for(robot, configs[0]).poses;
  std::printf("%-26s %8s %8s %7s %8s %8s %8s %8s %8s %8s %8s %6s\n", "configuration", "anchor",
              "CRB", "err/CRB", "pred.", "rep.std", "coverage", "box RMS", "pred.box", "box max",
              "chi2/dof", "runs");
  std::printf("%-26s %8s %8s %7s %8s %8s %8s %8s %8s %8s %8s %6s\n", "", "RMS mm", "mm", "",
              "std mm", "mm", "%", "mm", "RMS mm", "mm", "", "");
  std::vector<std::string> summaries;
  for (const Config& c : configs) {
    const auto t0 = std::chrono::steady_clock::now();
    const std::vector<cdpr::Pose> poses = laser_poses ? shared : design_for(robot, c).poses;
    const double design_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    cdpr::PredictedAccuracyOptions po;
    po.identification = ident_options(c);
    po.box = box;
    po.channels = c.channels();
    const cdpr::PredictedAccuracy predicted =
        must(cdpr::predict_accuracy(s.nominal, poses, bench_noise(), po), "prediction");
    std::string summary;
    const double crb = cdpr::bench::crb_at_truth(
        s.truth, poses, bench_noise(), sim_options(s, c, false), ident_options(c), &summary);
    summaries.push_back(std::string(c.name) + ":\n" + summary);
    const cdpr::bench::MonteCarlo mc = cdpr::bench::monte_carlo(
        seeds, s.truth, s.nominal, poses, bench_noise(), sim_options(s, c, true), ident_options(c),
        [&](const cdpr::CalibratedModel& estimate) {
          return cdpr::bench::realized_box_error(s.truth, estimate, box);
        });
    const double rms = mc.anchors.rms();
    std::printf(
        "%-26s %8.3f %8.3f %7.3f %8.3f %8.3f %8.1f %8.3f %8.3f %8.3f %8.3f %6d  (bias %.3f mm, "
        "noise floor %.3f mm; design %.0f s, %.0f s)\n",
        c.name, 1e3 * rms, 1e3 * crb, rms / crb, 1e3 * predicted.anchor_rms_std_m,
        1e3 * mc.anchors.reported_std(), mc.anchors.coverage_percent(), 1e3 * mc.box_rms(),
        1e3 * predicted.position_rms_m, 1e3 * mc.box_max, mc.chi2_dof(), mc.ok,
        1e3 * mc.anchors.bias(), 1e3 * rms / std::sqrt(std::max(1, mc.ok)), design_s,
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    std::fflush(stdout);
  }
  std::printf("\nIdentifiability at the truth (per configuration):\n");
  for (const std::string& line : summaries) std::printf("%s\n", line.c_str());
  return 0;
}
