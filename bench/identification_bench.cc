// Identification benchmark (printed figures). See bench/identification.cmake for the command.
//
// MINI as shipped (scenario::mini_config_scenario, identical to config/mini.yaml as nominal and
// config/mini-measured.yaml as truth; tests/fit checks the equality): truth = Table 1 "measured"
// anchors, nominal = SolidWorks anchors, elastic cables, encoders homed with the nominal model;
// the measurements are simulated with the elastic physics (the nominal controller commands
// lengths, the true robot settles), laser 1 mm, encoder 0.1 mm, force 1 N. 25 designed poses.
//
// Anchor errors are given two ways: per coordinate (RMS over the 24 coordinates) and per cable
// (RMS over the 8 anchors of the 3-D distance |a_i - a_true,i|, what `cdpr-fit calibrate
// --truth` prints); the second is sqrt(3) times the first for isotropic errors.
#include <algorithm>
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
#include "cdpr/calibration/paper_method.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace {

using cdpr::CalibratedModel;
using cdpr::Pose;

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// RMS over the coordinates.
double anchor_rms_error(const CalibratedModel& est, const CalibratedModel& truth) {
  const Eigen::Matrix3Xd d = est.robot.frame_anchors - truth.robot.frame_anchors;
  return std::sqrt(d.squaredNorm() / static_cast<double>(d.size()));
}

// RMS over the cables of the 3-D anchor distance (cdpr-fit's figure).
double anchor_rms_3d(const CalibratedModel& est, const CalibratedModel& truth) {
  const Eigen::Matrix3Xd d = est.robot.frame_anchors - truth.robot.frame_anchors;
  return std::sqrt(d.squaredNorm() / static_cast<double>(d.cols()));
}

using cdpr::bench::must;

// The noise levels; --sigma-force and --rigid change them for diagnosis runs.
double g_sigma_force = 1.0;
bool g_elastic = true;
bool g_position_design = true;
double g_ea = 0.0;
double g_design_half = 0.2;  // --design-half m: half side of the candidate cube (test box: 0.156)
double g_design_angle = 0.2618;  // --design-angle rad  // --ea N: override the cable EA (diagnosis
                                 // of the force-noise pathways)  //
                                 // --d-optimal: the plain D-optimal design

cdpr::SensorNoise bench_noise() {
  cdpr::SensorNoise n = cdpr::bench::mini_noise();
  n.sigma_force = g_sigma_force;
  return n;
}

cdpr::SimulationOptions simulation_options(const cdpr::scenario::Scenario& s, bool elastic = true) {
  cdpr::SimulationOptions so;
  so.physics = elastic && g_elastic ? cdpr::SimulationOptions::Physics::kElastic
                                    : cdpr::SimulationOptions::Physics::kRigid;
  so.controller = &s.nominal;
  return so;
}

cdpr::SimulatedMeasurements simulate(const cdpr::scenario::Scenario& s,
                                     const std::vector<Pose>& poses, std::uint64_t seed,
                                     bool elastic = true) {
  return must(cdpr::simulate_measurements(s.truth, poses, bench_noise(), seed,
                                          simulation_options(s, elastic)),
              "simulate");
}

// The paper's set-up: coordinates outside V known (measured), laser plane known. With
// `rest_true` false the coordinates outside V stay at their nominal values (what `cdpr-fit
// calibrate --method paper` does, and the real situation without a measuring arm).
CalibratedModel paper_start(const cdpr::scenario::Scenario& s, bool rest_true = true) {
  CalibratedModel start = s.nominal;
  if (!rest_true) return start;
  const cdpr::AnchorMask V = cdpr::paper_anchor_mask();
  for (int i = 0; i < 8; ++i) {
    for (int q = 0; q < 3; ++q) {
      if (!V(q, i)) start.robot.frame_anchors(q, i) = s.truth.robot.frame_anchors(q, i);
    }
  }
  start.robot.lasers = s.truth.robot.lasers;
  return start;
}

// The Cramer-Rao bound of the anchors where the estimator really works: the Fisher information
// at the TRUE parameters, the true (settled) poses and the true tensions of a noise-free elastic
// run of the same commands (predict_accuracy evaluates it at the nominal model and the commanded
// poses, which is what a designer knows beforehand). The Monte Carlo compares with this one.
double crb_at_truth(const cdpr::scenario::Scenario& s, const std::vector<Pose>& commands) {
  cdpr::SimulationOptions so;
  so.physics = g_elastic ? cdpr::SimulationOptions::Physics::kElastic
                         : cdpr::SimulationOptions::Physics::kRigid;
  so.controller = &s.nominal;
  so.add_noise = false;
  const cdpr::SimulatedMeasurements sim =
      must(cdpr::simulate_measurements(s.truth, commands, bench_noise(), 0, so), "simulate");
  const cdpr::GeometryInformation gi = must(
      cdpr::geometry_information(s.truth, sim.set, sim.true_poses, cdpr::IdentificationOptions{}),
      "information at the truth");
  return cdpr::bench::anchor_crb_rms(gi);
}

struct RobotRun {
  std::string name;
  double crb_anchor_rms = 0, crb_position_rms = 0;
  double crb_truth_anchor_rms = 0;  // the bound at the true parameters and true poses
  double ours_anchor_rms = 0, paper_anchor_rms = 0, nominal_anchor_rms = 0;
  double ours_pos_rms = 0, ours_pos_max = 0, paper_pos_rms = 0, paper_pos_max = 0;
  double nominal_pos_rms = 0;
  double ours_anchor_3d = 0, paper_anchor_3d = 0, nominal_anchor_3d = 0;
  double paper_nom_anchor_rms = 0, paper_nom_anchor_3d = 0, paper_nom_pos_rms = 0,
         paper_nom_pos_max = 0;
  double ours_chi2 = 0;
  int ours_dof = 0;
  std::string paper_nom_brief;
  double ours_ms = 0, paper_ms = 0, paper_nom_ms = 0;
  int paper_nom_iterations = 0;
  int ours_iterations = 0, paper_iterations = 0;
  std::string ours_brief, paper_brief;
};

RobotRun run_robot(const std::string& name, const cdpr::scenario::Scenario& s,
                   const cdpr::PoseDesignOptions& design_options, const cdpr::AccuracyBox& box,
                   bool run_paper, std::vector<Pose>* designed_out) {
  RobotRun r;
  r.name = name;
  auto t0 = std::chrono::steady_clock::now();
  const cdpr::PoseDesign design = must(cdpr::design_poses(s.nominal, design_options), "design");
  std::printf("[%s] pose design: %d feasible candidates, %d exchanges, path %.2f, %.2f s\n",
              name.c_str(), design.candidates, design.exchanges, design.path_length,
              seconds_since(t0));
  if (design_options.criterion == cdpr::DesignCriterion::kPositionAccuracy) {
    std::printf(
        "[%s] designed for position accuracy over the box: predicted RMS %.3f mm "
        "(D-optimal start %.3f mm)\n",
        name.c_str(), 1e3 * design.position_rms_m, 1e3 * design.position_rms_d_optimal_m);
  }
  if (designed_out) *designed_out = design.poses;
  const cdpr::SimulatedMeasurements sim = simulate(s, design.poses, 1);
  cdpr::PredictedAccuracyOptions po;
  po.box = box;
  const cdpr::PredictedAccuracy crb =
      must(cdpr::predict_accuracy(s.nominal, design.poses, bench_noise(), po), "predict");
  r.crb_anchor_rms = crb.anchor_rms_std_m;
  r.crb_truth_anchor_rms = crb_at_truth(s, design.poses);
  r.crb_position_rms = crb.position_rms_m;

  const cdpr::IdentificationReport ours =
      must(cdpr::identify(s.nominal, sim.set, cdpr::IdentificationOptions{}), "identify");
  r.ours_ms = 1e3 * ours.total_time_s;
  r.ours_iterations = ours.iterations;
  r.ours_anchor_rms = anchor_rms_error(ours.estimate, s.truth);
  r.ours_anchor_3d = anchor_rms_3d(ours.estimate, s.truth);
  r.ours_chi2 = ours.chi2;
  r.ours_dof = ours.dof;
  r.ours_brief = ours.brief_report();
  for (const std::string& w : ours.warnings)
    std::printf("[%s]   warning: %s\n", name.c_str(), w.c_str());
  const cdpr::RealizedAccuracy acc_ours =
      must(cdpr::measure_position_accuracy(s.truth, ours.estimate, box), "accuracy ours");
  r.ours_pos_rms = acc_ours.position_rms_m;
  r.ours_pos_max = acc_ours.position_max_m;
  const cdpr::RealizedAccuracy acc_nom =
      must(cdpr::measure_position_accuracy(s.truth, s.nominal, box), "accuracy nominal");
  r.nominal_pos_rms = acc_nom.position_rms_m;
  r.nominal_anchor_rms = anchor_rms_error(s.nominal, s.truth);
  r.nominal_anchor_3d = anchor_rms_3d(s.nominal, s.truth);
  if (run_paper) {
    const CalibratedModel start = paper_start(s);
    const cdpr::PaperMethodReport paper =
        must(cdpr::paper_method(start, sim.set, cdpr::PaperMethodOptions{}), "paper method");
    r.paper_ms = 1e3 * paper.time_s;
    r.paper_iterations = paper.iterations;
    r.paper_anchor_rms = anchor_rms_error(paper.estimate, s.truth);
    r.paper_brief = paper.summary();
    const cdpr::RealizedAccuracy acc_paper =
        must(cdpr::measure_position_accuracy(s.truth, paper.estimate, box), "accuracy paper");
    r.paper_pos_rms = acc_paper.position_rms_m;
    r.paper_pos_max = acc_paper.position_max_m;
    r.paper_anchor_3d = anchor_rms_3d(paper.estimate, s.truth);
    const cdpr::PaperMethodReport paper_nom =
        must(cdpr::paper_method(paper_start(s, false), sim.set, cdpr::PaperMethodOptions{}),
             "paper method (rest nominal)");
    r.paper_nom_brief = paper_nom.summary();
    r.paper_nom_ms = 1e3 * paper_nom.time_s;
    r.paper_nom_iterations = paper_nom.iterations;
    r.paper_nom_anchor_rms = anchor_rms_error(paper_nom.estimate, s.truth);
    r.paper_nom_anchor_3d = anchor_rms_3d(paper_nom.estimate, s.truth);
    const cdpr::RealizedAccuracy acc_pn = must(
        cdpr::measure_position_accuracy(s.truth, paper_nom.estimate, box), "accuracy paper nom");
    r.paper_nom_pos_rms = acc_pn.position_rms_m;
    r.paper_nom_pos_max = acc_pn.position_max_m;
  }
  return r;
}

void print_run(const RobotRun& r) {
  std::printf("\n== %s: accuracy (25 designed poses, one noise draw) ==\n", r.name.c_str());
  std::printf("  %s\n", r.ours_brief.c_str());
  std::printf("  ours: chi2 %.1f on %d dof (chi2/dof %.3f)\n", r.ours_chi2, r.ours_dof,
              r.ours_chi2 / std::max(1, r.ours_dof));
  if (!r.paper_brief.empty()) std::printf("  rest known: %s\n", r.paper_brief.c_str());
  if (!r.paper_nom_brief.empty()) std::printf("  rest nominal: %s\n", r.paper_nom_brief.c_str());
  std::printf("  %-44s %14s %14s %13s %13s\n", "", "anchor RMS err", "(per cable 3D)",
              "box pos RMS", "box pos max");
  std::printf("  %-44s %11.3f mm %11.3f mm %10.3f mm %13s\n", "nominal (SolidWorks / uncalibrated)",
              1e3 * r.nominal_anchor_rms, 1e3 * r.nominal_anchor_3d, 1e3 * r.nominal_pos_rms, "");
  std::printf("  %-44s %11.3f mm %14s %10.3f mm %13s\n", "Cramer-Rao bound (predicted std)",
              1e3 * r.crb_anchor_rms, "", 1e3 * r.crb_position_rms, "");
  std::printf("  %-44s %11.3f mm %11.3f mm %10.3f mm %10.3f mm\n",
              "ours (joint LSQ, 24 anchors + offsets)", 1e3 * r.ours_anchor_rms,
              1e3 * r.ours_anchor_3d, 1e3 * r.ours_pos_rms, 1e3 * r.ours_pos_max);
  if (!r.paper_brief.empty()) {
    std::printf("  %-44s %11.3f mm %11.3f mm %10.3f mm %10.3f mm\n",
                "paper method (16 of 24, rest TRUE values)", 1e3 * r.paper_anchor_rms,
                1e3 * r.paper_anchor_3d, 1e3 * r.paper_pos_rms, 1e3 * r.paper_pos_max);
    std::printf("  %-44s %11.3f mm %11.3f mm %10.3f mm %10.3f mm\n",
                "paper method (16 of 24, rest nominal = CLI)", 1e3 * r.paper_nom_anchor_rms,
                1e3 * r.paper_nom_anchor_3d, 1e3 * r.paper_nom_pos_rms, 1e3 * r.paper_nom_pos_max);
  }
  std::printf(
      "  paper (Jin et al. 2018, real robot): 0.92 mm position accuracy, 1.28 mm path "
      "accuracy\n");
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 200;
  bool quick = false;
  bool mc_only = false;
  for (int k = 1; k < argc; ++k) {
    if (std::strcmp(argv[k], "--seeds") == 0 && k + 1 < argc) seeds = std::atoi(argv[++k]);
    if (std::strcmp(argv[k], "--quick") == 0) quick = true;
    if (std::strcmp(argv[k], "--sigma-force") == 0 && k + 1 < argc) {
      g_sigma_force = std::atof(argv[++k]);
    }
    if (std::strcmp(argv[k], "--rigid") == 0) g_elastic = false;
    if (std::strcmp(argv[k], "--d-optimal") == 0) g_position_design = false;
    if (std::strcmp(argv[k], "--ea") == 0 && k + 1 < argc) g_ea = std::atof(argv[++k]);
    if (std::strcmp(argv[k], "--design-half") == 0 && k + 1 < argc) {
      g_design_half = std::atof(argv[++k]);
    }
    if (std::strcmp(argv[k], "--design-angle") == 0 && k + 1 < argc) {
      g_design_angle = std::atof(argv[++k]);
    }
    if (std::strcmp(argv[k], "--mc-only") == 0) mc_only = true;
  }
  if (quick && seeds == 200) seeds = 20;
  std::printf("cdpr identification benchmark (seeds %d%s)\n", seeds, quick ? ", quick" : "");
  std::printf("noise: laser 1 mm, encoder 0.1 mm, force %g N; %s simulation\n", g_sigma_force,
              g_elastic ? "elastic" : "rigid");

  // ---------------- MINI ----------------
  cdpr::scenario::Scenario mini = cdpr::scenario::mini_config_scenario();
  if (g_ea > 0.0) {  // --ea: another cable stiffness in both models (truth re-homed)
    for (auto* m : {&mini.nominal, &mini.truth}) {
      for (auto& c : m->robot.cables) c.ea = g_ea;
    }
    mini.truth = must(cdpr::homed_truth(mini.truth.robot, mini.nominal.robot), "homing");
  }
  cdpr::PoseDesignOptions dmini;
  dmini.noise = bench_noise();
  dmini.half_extent = Eigen::Vector3d::Constant(g_design_half);
  dmini.max_angle = g_design_angle;
  dmini.exchange_passes = quick ? 1 : 4;
  cdpr::AccuracyBox iso;  // 312 mm cube, 5 x 5 x 5
  if (g_position_design) dmini.criterion = cdpr::DesignCriterion::kPositionAccuracy;
  dmini.accuracy_box = iso;
  std::vector<Pose> designed;
  const RobotRun rm = run_robot("MINI", mini, dmini, iso, !mc_only, &designed);
  print_run(rm);

  // Pose set comparison (predicted).
  if (!mc_only) {
    auto cmp = must(cdpr::compare_pose_sets(mini.nominal, dmini, iso, 5), "compare");
    std::printf("\n== MINI: pose sets (predicted, 25 poses) ==\n");
    std::printf("  %-34s %18s %18s %12s\n", "set", "anchor CRB RMS", "box pos RMS (CRB)", "cond");
    for (const auto& c : cmp) {
      std::printf("  %-34s %15.3f mm %15.3f mm %12.3g\n", c.label.c_str(), 1e3 * c.anchor_rms_std_m,
                  1e3 * c.position_rms_m, c.condition_number);
    }
  }

  // ---------------- Speed ----------------
  if (!mc_only) {
    std::printf("\n== Speed (same 25 poses) ==\n");
    // Both start from the nominal config (what cdpr-fit calibrate does with either method); the
    // second line gives the paper's method the 8 coordinates outside V at their true values.
    std::printf(
        "  ours %.1f ms (%d iterations), paper method from the same nominal config %.1f ms (%d "
        "iterations): ours is %.0fx faster\n",
        rm.ours_ms, rm.ours_iterations, rm.paper_nom_ms, rm.paper_nom_iterations,
        rm.paper_nom_ms / rm.ours_ms);
    std::printf(
        "  paper method given the 8 coordinates outside V: %.1f ms (%d iterations): %.0fx\n",
        rm.paper_ms, rm.paper_iterations, rm.paper_ms / rm.ours_ms);
    std::printf("  %-10s %14s %14s\n", "poses", "ours (ms)", "per pose (ms)");
    for (int n : {25, 250, 2500}) {
      if (quick && n > 250) break;
      const std::vector<Pose> poses = cdpr::scenario::random_feasible_poses(
          mini.nominal.robot, mini.box, n, 99, &mini.truth.robot);
      const cdpr::SimulatedMeasurements sim = simulate(mini, poses, 2, /*elastic=*/false);
      const auto t0 = std::chrono::steady_clock::now();
      const cdpr::IdentificationReport rep =
          must(cdpr::identify(mini.nominal, sim.set, cdpr::IdentificationOptions{}), "identify");
      const double ms = 1e3 * seconds_since(t0);
      std::printf("  %-10d %14.1f %14.3f   (%d iterations, chi2/dof %.3f)\n", n, ms, ms / n,
                  rep.iterations, rep.chi2 / rep.dof);
    }
  }

  // ---------------- Monte Carlo ----------------
  {
    std::printf("\n== MINI: Monte Carlo over %d seeds (designed poses) ==\n", seeds);
    const auto t0 = std::chrono::steady_clock::now();
    const cdpr::bench::MonteCarlo mc = cdpr::bench::monte_carlo(
        seeds, mini.truth, mini.nominal, designed, bench_noise(), simulation_options(mini),
        cdpr::IdentificationOptions{}, [&](const cdpr::CalibratedModel& estimate) {
          return cdpr::bench::realized_box_error(mini.truth, estimate, iso);
        });
    const int ok = mc.ok;
    const double rms_err = mc.anchors.rms();
    const double rms_std = mc.anchors.reported_std();
    std::printf("  converged runs                 %d / %d (%.1f s)\n", ok, seeds,
                seconds_since(t0));
    std::printf("  anchor RMS error               %.4f mm\n", 1e3 * rms_err);
    std::printf("  reported std (RMS)             %.4f mm\n", 1e3 * rms_std);
    std::printf(
        "  Cramer-Rao bound at nominal    %.4f mm   error / CRB = %.3f (the design's prediction)\n",
        1e3 * rm.crb_anchor_rms, rms_err / rm.crb_anchor_rms);
    std::printf(
        "  Cramer-Rao bound at the truth   %.4f mm   error / CRB = %.3f (target within 15 %%)\n",
        1e3 * rm.crb_truth_anchor_rms, rms_err / rm.crb_truth_anchor_rms);
    std::printf(
        "  box position RMS over runs     %.4f mm (mean of per-run RMS %.4f mm; target "
        "<= 0.5 mm), nominal %.4f mm\n",
        1e3 * mc.box_rms(), 1e3 * mc.box_mean(), 1e3 * rm.nominal_pos_rms);
    std::printf("  bias: RMS over coords %.4f mm, max %.4f mm (std of the mean %.4f mm)\n",
                1e3 * mc.anchors.bias(), 1e3 * mc.anchors.bias_max(),
                1e3 * rms_err / std::sqrt(std::max(1, ok)));
    std::printf("  chi2/dof (mean over runs)      %.3f\n", mc.chi2_dof());
    std::printf("  coverage of the 95 %% interval  %.1f %% (target 90-98 %%)\n",
                mc.anchors.coverage_percent());
  }

  // ---------------- Large robot ----------------
  if (!quick && !mc_only) {
    const cdpr::scenario::Scenario large = cdpr::scenario::large_scenario();
    cdpr::PoseDesignOptions dl;
    dl.noise = bench_noise();
    dl.half_extent = Eigen::Vector3d(4.0, 2.8, 1.0);
    dl.exchange_passes = 2;
    cdpr::AccuracyBox lbox;
    lbox.half_extent = Eigen::Vector3d(2.5, 1.75, 0.6);
    const RobotRun rl = run_robot("LARGE", large, dl, lbox, true, nullptr);
    print_run(rl);
    std::printf("  speed: ours %.1f ms, paper from nominal %.1f ms (%.0fx)\n", rl.ours_ms,
                rl.paper_nom_ms, rl.paper_nom_ms / rl.ours_ms);
    std::printf("  speed: ours %.1f ms, paper given the rest %.1f ms (%.0fx)\n", rl.ours_ms,
                rl.paper_ms, rl.paper_ms / rl.ours_ms);
  }
  return 0;
}
