// Issue 18, second part: Monte Carlo of the 4-cable suspended crane (config/crane4.yaml) calibrated
// from encoders, load cells, swivel angles and an inclinometer (printed figures, not a test).
//
// Scenario (scenario::crane_scenario): nominal = the shipped crane; truth = frame anchors off by up
// to 10 mm per coordinate, hidden swivel encoder zeros (up to 0.05 rad) and an inclinometer tilted
// on its mount (-0.015 / 0.011 rad); homed where the true crane hangs at the home position and
// heading. Elastic simulation: the nominal controller commands the lengths of equilibrium poses
// of its model, the true crane settles where its elastic cables balance the weight. Noise:
// encoder 0.1 mm, load cells 1 N, swivel 1 mrad, inclinometer 0.5 mrad. 25 poses: home and
// random equilibrium poses over 0.9 x 1.1 x 0.6 m (scenario::random_hanging_poses), the same in
// every configuration and seed.
//
// Figures per configuration: anchor RMS error per coordinate over the seeds, the Cramer-Rao bound
// at the truth (true parameters, settled poses and tensions of a noise-free run), the reported
// std, the coverage of the 95 % intervals, chi2/dof, and the box position error: over a
// 0.6 x 0.8 x 0.4 m box around home (5 x 5 x 5 targets, yaw 0), the controller with the
// calibrated model commands the equilibrium pose of each target, the true crane settles, and the
// error is the settled position minus the target (RMS and max; the nominal model for reference).
//   build/<dir>/bench/crane_bench [--seeds N]
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
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "testing/identification_scenario.hpp"

namespace {

using cdpr::bench::must;

cdpr::SensorNoise bench_noise() {
  cdpr::SensorNoise n;
  n.sigma_length = 1e-4;
  n.sigma_force = 1.0;
  n.sigma_swivel = 1e-3;
  n.sigma_inclination = 5e-4;
  return n;
}

struct Config {
  const char* name;
  bool swivel, inclinometer;
};

cdpr::SimulationOptions sim_options(const cdpr::scenario::Scenario& s, const Config& c,
                                    bool noise) {
  cdpr::SimulationOptions so;
  so.physics = cdpr::SimulationOptions::Physics::kElastic;
  so.controller = &s.nominal;
  so.add_noise = noise;
  so.laser = false;
  so.swivel = c.swivel;
  so.inclinometer = c.inclinometer;
  return so;
}

cdpr::IdentificationOptions ident_options(const Config& c) {
  cdpr::IdentificationOptions o;
  o.estimate_laser_plane = false;
  o.estimate_swivel_zeros = c.swivel;
  o.estimate_inclinometer_mounting = c.inclinometer;
  return o;
}

using cdpr::bench::BoxError;

// The controller `ctrl` commands the equilibrium pose of each target; the true crane settles.
BoxError box_error(const cdpr::CalibratedModel& truth, const cdpr::CalibratedModel& ctrl,
                   const cdpr::AccuracyBox& box) {
  BoxError out;
  double sum = 0.0;
  for (const cdpr::Pose& target : box.grid()) {
    auto eq = cdpr::suspended_equilibrium_pose(ctrl.robot, target);
    if (!eq) continue;
    auto f = cdpr::simple_tension_distribution(ctrl.robot, eq->pose, 0.0);
    if (!f) continue;
    auto u_cmd = cdpr::unstretched_lengths(ctrl.robot, eq->pose, *f);
    if (!u_cmd) continue;
    const Eigen::VectorXd reading = ((u_cmd->array() - ctrl.readings.length_offsets.array()) /
                                     (1.0 + ctrl.readings.length_scales.array()))
                                        .matrix();
    const Eigen::VectorXd u_true = ((1.0 + truth.readings.length_scales.array()) * reading.array() +
                                    truth.readings.length_offsets.array())
                                       .matrix();
    auto settled = cdpr::settle_platform(truth.robot, u_true, eq->pose);
    if (!settled) continue;
    const double e = (settled->position - target.position).norm();
    sum += e * e;
    out.max = std::max(out.max, e);
    ++out.points;
  }
  out.rms = std::sqrt(sum / std::max(1, out.points));
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 100;
  for (int k = 1; k < argc; ++k) {
    if (std::strcmp(argv[k], "--seeds") == 0 && k + 1 < argc) seeds = std::atoi(argv[++k]);
  }
  const cdpr::scenario::Scenario crane = cdpr::scenario::crane_scenario();
  const std::vector<cdpr::Pose> poses =
      cdpr::scenario::random_hanging_poses(crane.nominal.robot, crane.box, 25, 21);
  cdpr::AccuracyBox box;
  box.center = crane.nominal.robot.home.position;
  box.half_extent = Eigen::Vector3d(0.3, 0.4, 0.2);
  const BoxError nominal = box_error(crane.truth, crane.nominal, box);
  std::printf("cdpr crane benchmark: CRANE4 (4 cables, suspended), %zu poses, %d seeds, elastic\n",
              poses.size(), seeds);
  std::printf("noise: encoder 0.1 mm, load cells 1 N, swivel 1 mrad, inclinometer 0.5 mrad\n");
  std::printf("nominal model: box position RMS %.3f mm, max %.3f mm (%d targets)\n\n",
              1e3 * nominal.rms, 1e3 * nominal.max, nominal.points);
  const Config configs[] = {
      {"swivel+incl.+load cells", true, true},
      {"swivel+load cells", true, false},
      {"incl.+load cells", false, true},
      {"load cells only", false, false},
  };
  std::printf("%-24s %9s %9s %8s %9s %9s %9s %9s %8s %6s\n", "configuration", "anchor", "CRB",
              "err/CRB", "rep. std", "coverage", "box RMS", "box max", "chi2/dof", "runs");
  std::printf("%-24s %9s %9s %8s %9s %9s %9s %9s %8s %6s\n", "", "RMS mm", "mm", "", "mm", "%",
              "mm", "mm", "", "");
  std::vector<std::string> summaries;
  for (const Config& c : configs) {
    const auto t0 = std::chrono::steady_clock::now();
    std::string summary;
    const double crb =
        cdpr::bench::crb_at_truth(crane.truth, poses, bench_noise(), sim_options(crane, c, false),
                                  ident_options(c), &summary);
    summaries.push_back(std::string(c.name) + ":\n" + summary);
    const cdpr::bench::MonteCarlo mc = cdpr::bench::monte_carlo(
        seeds, crane.truth, crane.nominal, poses, bench_noise(), sim_options(crane, c, true),
        ident_options(c), [&](const cdpr::CalibratedModel& estimate) {
          return box_error(crane.truth, estimate, box);
        });
    if (mc.ok == 0) {
      std::printf("%-24s refused or failed in every run (%d refused)\n", c.name, mc.refused);
      continue;
    }
    const double rms = mc.anchors.rms();
    std::printf("%-24s %9.3f %9.3f %8.3f %9.3f %9.1f %9.3f %9.3f %8.3f %6d  (%.0f s)\n", c.name,
                1e3 * rms, 1e3 * crb, rms / crb, 1e3 * mc.anchors.reported_std(),
                mc.anchors.coverage_percent(), 1e3 * mc.box_rms(), 1e3 * mc.box_max, mc.chi2_dof(),
                mc.ok,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    std::fflush(stdout);
  }
  std::printf("\nIdentifiability at the truth (per configuration):\n");
  for (const std::string& s : summaries) std::printf("%s\n", s.c_str());
  return 0;
}
