// ISO 9283 figures of the virtual MINI (docs/motion.md "ISO 9283 on the virtual robot"): pose
// accuracy and repeatability AP, RP at the five points of the test cube's diagonal plane (30
// cycles) and path accuracy and repeatability AT, RT on a line and a circle (10 cycles), from the
// virtual robot's TRUE pose, commanding (a) with the nominal geometry config/mini.yaml and (b) with
// the geometry calibrated from a simulated recording of the same virtual robot. Printed beside the
// paper's figures (+58 % position accuracy, path accuracy 1.284 mm, path repeatability 0.18 mm).
//
//   build/ci/bench/iso9283_bench [--scenario FILE] [--cycles N] [--path-cycles N] [--seed S]
//                                [--calibration cdprd|cdpr-fit] [--daemon-config FILE]
//                                [--stiffness fixed|shared|per-cable] [--out FILE]
//
// --calibration cdprd (default): the calibration cdprd with --daemon-config (default
// config/cdprd.yaml) makes (bench/cdprd_calibration.hpp); cdpr-fit: cdpr-fit calibrate's
// identify() with --stiffness (bench/virtual_calibration.hpp).
//
// --out FILE also writes the figures as the calibration report reads them
// (cdpr/report/iso9283.hpp; the daemon config's report.iso9283_measured).
//
// The virtual robot is cdpr-sim's quasi-static physics (sim/physics.hpp) with the scenario's hidden
// effects, homed on its reference platform at home (the true platform at home at the pretension
// cdprd holds there, the nominal model's home counts: as the daemon's cell powers on). Each 4 ms
// cycle the commanding model's compensated inverse kinematics with its planned tensions
// (command_counts) turns the sampled pose into integer encoder targets; the drives' position loops
// hold them within their encoder noise (the scenario's encoder sigma, a fresh draw per drive and
// cycle), and the physics settles to the equilibrium of those motor positions.
#include <Eigen/Core>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/path.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/report/iso9283.hpp"
#include "cdpr/sim/lockstep_io.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"
#include "cdprd_calibration.hpp"
#include "virtual_calibration.hpp"

namespace {

using cdpr::Pose;
using cdpr::RobotModel;
using Clock = std::chrono::steady_clock;

constexpr double kCycle = 0.004;  // s, the network's SYNC period (config/cdprd.yaml)
constexpr double kPaperPositionGain = 100.0 * cdpr::report::kPaperPositionAccuracyGain;  // %
constexpr double kPaperAT = cdpr::report::kPaperPathAccuracyM;
constexpr double kPaperRT = cdpr::report::kPaperPathRepeatabilityM;

template <typename T>
T must(cdpr::Result<T> r, const char* what) {
  if (!r.ok()) {
    std::fprintf(stderr, "iso9283_bench: %s: %s\n", what, r.status().to_string().c_str());
    std::exit(1);
  }
  return std::move(*r);
}

void must(const cdpr::Status& s, const char* what) {
  if (!s.ok()) {
    std::fprintf(stderr, "iso9283_bench: %s: %s\n", what, s.to_string().c_str());
    std::exit(1);
  }
}

Pose at(const Eigen::Vector3d& p) {
  Pose q;
  q.position = p;
  return q;
}

// The virtual robot commanded by one model.
class Cell {
 public:
  Cell(const RobotModel& truth, const cdpr::sim::Scenario& scenario, const RobotModel& command,
       std::uint64_t seed)
      : physics_(must(cdpr::sim::Physics::create(truth, scenario, seed), "physics")),
        command_(command),
        reference_(cdpr::default_reference_tension(command)),
        data_(command),
        rng_(seed ^ 0x9283),
        sigma_counts_(scenario.noise.encoder_counts),
        counts_(command.num_cables()) {
    Eigen::Vector3d attained;
    step(command.home, attained);
  }

  // One cycle at the commanded pose; the true position after it.
  void step(const Pose& pose, Eigen::Vector3d& attained) {
    must(cdpr::command_counts(command_, pose, reference_, data_), "command");
    for (int i = 0; i < counts_.size(); ++i) {
      counts_(i) = data_.cable.counts_rounded(i) + sigma_counts_ * normal_(rng_);
    }
    const auto t0 = Clock::now();
    must(physics_.step(counts_, time_), "physics step");
    physics_time_ += std::chrono::duration<double>(Clock::now() - t0).count();
    ++steps_;
    time_ += kCycle;
    attained = physics_.state().pose.position;
    commanded_ = pose;
  }

  // Follows `path` cycle by cycle, its end included; the attained positions when asked.
  void run(const cdpr::Path& path, std::vector<Eigen::Vector3d>* attained) {
    const int n = static_cast<int>(std::ceil(path.duration() / kCycle));
    Pose p;
    Eigen::Vector3d a;
    for (int k = 0; k <= n; ++k) {
      const auto t0 = Clock::now();
      path.sample(std::min(k * kCycle, path.duration()), p);
      sample_time_ += std::chrono::duration<double>(Clock::now() - t0).count();
      ++samples_;
      step(p, a);
      if (attained != nullptr) attained->push_back(a);
    }
  }

  cdpr::Path line_to(const Eigen::Vector3d& target) const {
    cdpr::PathSegment s;
    s.target = at(target);
    return must(cdpr::Path::plan(commanded_, std::vector<cdpr::PathSegment>{s}, cdpr::PathLimits{}),
                "line");
  }

  const Pose& commanded() const { return commanded_; }
  double physics_us() const { return 1e6 * physics_time_ / steps_; }
  double sample_us() const { return samples_ ? 1e6 * sample_time_ / samples_ : 0.0; }

 private:
  cdpr::sim::Physics physics_;
  RobotModel command_;
  double reference_;
  cdpr::CommandData data_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  double sigma_counts_;
  Eigen::VectorXd counts_;
  Pose commanded_;
  double time_ = 0.0;
  double physics_time_ = 0.0, sample_time_ = 0.0;
  long steps_ = 0, samples_ = 0;
};

// ISO 9283 repeatability of a cluster: mean distance to the barycentre + 3 standard deviations.
double repeatability(const std::vector<Eigen::Vector3d>& x, const Eigen::Vector3d& bary) {
  const double n = static_cast<double>(x.size());
  double mean = 0.0;
  for (const auto& p : x) mean += (p - bary).norm() / n;
  double var = 0.0;
  for (const auto& p : x) var += std::pow((p - bary).norm() - mean, 2) / (n - 1.0);
  return mean + 3.0 * std::sqrt(var);
}

Eigen::Vector3d barycentre(const std::vector<Eigen::Vector3d>& x) {
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (const auto& p : x) b += p / static_cast<double>(x.size());
  return b;
}

struct PoseFigures {
  double ap = 0.0, rp = 0.0;  // m, largest over the five points
};

// AP, RP: cycles P1 -> P2 -> ... -> P5 (jerk-limited lines), the attained position at each.
PoseFigures pose_test(Cell& cell, const std::vector<Eigen::Vector3d>& points, int cycles) {
  std::vector<std::vector<Eigen::Vector3d>> attained(points.size());
  for (int c = 0; c < cycles; ++c) {
    for (std::size_t k = 0; k < points.size(); ++k) {
      std::vector<Eigen::Vector3d> trace;
      cell.run(cell.line_to(points[k]), &trace);
      attained[k].push_back(trace.back());
    }
  }
  PoseFigures f;
  for (std::size_t k = 0; k < points.size(); ++k) {
    const Eigen::Vector3d b = barycentre(attained[k]);
    f.ap = std::max(f.ap, (b - points[k]).norm());
    f.rp = std::max(f.rp, repeatability(attained[k], b));
  }
  return f;
}

struct PathFigures {
  double at = 0.0, rt = 0.0;  // m
  double duration = 0.0;      // s, one cycle
  double peak_speed = 0.0;    // m/s, commanded
};

// Where the attained polyline crosses the plane through c normal to the unit tangent t, nearest
// to c (false when it never crosses).
bool crossing(const std::vector<Eigen::Vector3d>& a, const Eigen::Vector3d& c,
              const Eigen::Vector3d& t, Eigen::Vector3d& out) {
  double best = 1e300;
  for (std::size_t j = 0; j + 1 < a.size(); ++j) {
    const double d0 = (a[j] - c).dot(t), d1 = (a[j + 1] - c).dot(t);
    if ((d0 > 0.0) == (d1 > 0.0) || d0 == d1) continue;
    const Eigen::Vector3d x = a[j] + (d0 / (d0 - d1)) * (a[j + 1] - a[j]);
    if ((x - c).norm() < best) {
      best = (x - c).norm();
      out = x;
    }
  }
  return best < 1e300;
}

// AT, RT of `path` (started where the cell is): `cycles` runs, each from the path's start, at 100
// commanded points spread evenly over the path's length (ends excluded), each compared with the
// attained paths' crossings of its normal plane.
PathFigures path_test(Cell& cell, const cdpr::Path& path, int cycles) {
  PathFigures f;
  f.duration = path.duration();
  for (double t = 0.0; t <= path.duration(); t += kCycle) {
    Pose p;
    cdpr::TaskVelocity v;
    path.sample(t, p, &v);
    f.peak_speed = std::max(f.peak_speed, v.linear.norm());
  }
  std::vector<std::vector<Eigen::Vector3d>> runs(static_cast<std::size_t>(cycles));
  for (auto& run : runs) {
    cell.run(cell.line_to(path.start().position), nullptr);
    cell.run(path, &run);
  }
  constexpr int kPoints = 100;
  for (int k = 0; k < kPoints; ++k) {
    Eigen::Vector3d c, t;
    Eigen::Matrix3d R;
    path.path_point(path.length() * (k + 0.5) / kPoints, c, R, &t);
    std::vector<Eigen::Vector3d> hits;
    for (const auto& run : runs) {
      Eigen::Vector3d x;
      if (crossing(run, c, t, x)) hits.push_back(x);
    }
    if (hits.size() < 2) continue;
    const Eigen::Vector3d b = barycentre(hits);
    f.at = std::max(f.at, (b - c).norm());
    f.rt = std::max(f.rt, repeatability(hits, b));
  }
  return f;
}

struct Args {
  std::string scenario;
  int cycles = 30;
  int path_cycles = 10;
  std::uint64_t seed = 7;
  std::string calibration = "cdprd";  // cdprd's calibration, or cdpr-fit calibrate's
  std::string daemon_config;          // the cdprd config whose calibration is reproduced
  std::string stiffness = "fixed";    // cdpr-fit: what the identification does with EA
  std::string out;                    // the figures as JSON for the calibration report; "" = none
};

struct Calibrated {
  RobotModel model;
  std::string how;  // one line: which calibration, what it named
};

// The calibrated geometry from a calibration of `truth` (homed on its reference platform):
// cdprd's (bench/cdprd_calibration.hpp: the daemon config's pose design, identification, mismatch
// locator and extra poses), or cdpr-fit calibrate's library calls (identify with its default
// options, --stiffness also estimates EA, on cdpr-fit design-poses' 25 poses).
Calibrated calibrate(const RobotModel& nominal, const RobotModel& truth,
                     const cdpr::sim::Scenario& scenario, const cdpr::controller::DaemonConfig& dc,
                     const Args& args) {
  if (args.calibration == "cdprd") {
    const cdpr::bench::CdprdCalibration c =
        cdpr::bench::calibrate_as_cdprd(nominal, truth, scenario, args.seed + 1, dc,
                                        cdpr::bench::cdprd_home_pretension(dc, nominal));
    std::string named;
    for (const std::string& e : c.named_effects) named += (named.empty() ? "" : ", ") + e;
    return {c.model, "cdprd's (" + args.daemon_config + "): " + std::to_string(c.poses) +
                         " poses, " + std::to_string(c.dropped) +
                         " designed poses dropped; named: " + (named.empty() ? "nothing" : named) +
                         "; gates " + (c.gates_passed ? "passed" : "failed")};
  }
  cdpr::IdentificationOptions io;
  io.estimate_stiffness = args.stiffness == "shared"      ? cdpr::StiffnessEstimate::kShared
                          : args.stiffness == "per-cable" ? cdpr::StiffnessEstimate::kPerCable
                                                          : cdpr::StiffnessEstimate::kFixed;
  return {cdpr::bench::calibrate_virtual_robot(nominal, truth, scenario, args.seed + 1, io)
              .estimate.robot,
          "cdpr-fit calibrate's identify, stiffness " + args.stiffness};
}

Args parse(int argc, char** argv) {
  Args a;
  a.scenario = std::string(CDPR_SOURCE_DIR) + "/config/scenarios/mini-calibration.yaml";
  a.daemon_config = std::string(CDPR_SOURCE_DIR) + "/config/cdprd.yaml";
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    const bool has = i + 1 < argc;
    if (k == "--scenario" && has) {
      a.scenario = argv[++i];
    } else if (k == "--cycles" && has) {
      a.cycles = std::max(2, std::atoi(argv[++i]));
    } else if (k == "--path-cycles" && has) {
      a.path_cycles = std::max(2, std::atoi(argv[++i]));
    } else if (k == "--seed" && has) {
      a.seed = std::strtoull(argv[++i], nullptr, 10);
    } else if (k == "--calibration" && has &&
               (std::strcmp(argv[i + 1], "cdprd") == 0 ||
                std::strcmp(argv[i + 1], "cdpr-fit") == 0)) {
      a.calibration = argv[++i];
    } else if (k == "--daemon-config" && has) {
      a.daemon_config = argv[++i];
    } else if (k == "--stiffness" && has &&
               (std::strcmp(argv[i + 1], "fixed") == 0 || std::strcmp(argv[i + 1], "shared") == 0 ||
                std::strcmp(argv[i + 1], "per-cable") == 0)) {
      a.stiffness = argv[++i];
    } else if (k == "--out" && has) {
      a.out = argv[++i];
    } else {
      std::fprintf(stderr,
                   "usage: iso9283_bench [--scenario FILE] [--cycles N] [--path-cycles N] "
                   "[--seed S] [--calibration cdprd|cdpr-fit] [--daemon-config FILE] "
                   "[--stiffness fixed|shared|per-cable] [--out FILE]\n");
      std::exit(2);
    }
  }
  return a;
}

struct Figures {
  PoseFigures pose;
  PathFigures line, circle;
  double physics_us = 0.0, sample_us = 0.0;
};

}  // namespace

int main(int argc, char** argv) {
  const Args args = parse(argc, argv);
  const auto wall0 = Clock::now();
  const std::string src = CDPR_SOURCE_DIR;
  const RobotModel nominal =
      must(cdpr::config::load_robot_config(src + "/config/mini.yaml"), "mini");
  const cdpr::sim::Scenario scenario = must(cdpr::sim::load_scenario(args.scenario), "scenario");
  const cdpr::controller::DaemonConfig dc =
      must(cdpr::controller::load_daemon_config(args.daemon_config), "--daemon-config");
  // Homed on its reference platform at the pretension cdprd holds home at (the cell's drives
  // power on there; cdprd's reference homing).
  const RobotModel truth = cdpr::bench::homed_on_reference(
      must(cdpr::sim::resolve_truth(scenario, nominal), "truth"), nominal, scenario,
      cdpr::bench::cdprd_home_pretension(dc, nominal));
  const Calibrated cal = calibrate(nominal, truth, scenario, dc, args);
  const RobotModel& calibrated = cal.model;
  const double calib_s = std::chrono::duration<double>(Clock::now() - wall0).count();
  auto anchor_rms = [&](const RobotModel& m) {
    return std::sqrt((m.frame_anchors - truth.frame_anchors).squaredNorm() / truth.num_cables());
  };
  double ea_error = 0.0;  // largest relative EA error of the calibrated model
  for (int i = 0; i < truth.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    ea_error = std::max(ea_error, std::abs(calibrated.cables[k].ea / truth.cables[k].ea - 1.0));
  }

  // The test cube: 312 mm centred at the origin (the paper's MINI box); the diagonal plane through
  // the edges (x, z) = (-a, -a) and (+a, +a); P2..P5 at 10 % of the plane's diagonals from its
  // corners.
  const cdpr::AccuracyBox box;  // MINI's 312 mm cube at the origin
  const double a = box.half_extent.x();
  const std::vector<Eigen::Vector3d> points = cdpr::iso9283_points(box);
  // Test paths in the same plane: its diagonal P2 -> P4, and a circle about P1 of diameter 80 % of
  // the cube's edge, both at rotation 0 (as in the paper).
  const Eigen::Vector3d u = Eigen::Vector3d(1, 0, 1).normalized(), v = Eigen::Vector3d::UnitY();
  const double r = 0.8 * a;
  cdpr::PathSegment diag;
  diag.target = at(points[3]);
  cdpr::PathSegment circle;
  circle.kind = cdpr::PathSegment::Kind::kArc;
  circle.target = at(r * u);
  circle.center = Eigen::Vector3d::Zero();
  circle.axis = u.cross(v);
  const cdpr::Path line_path =
      must(cdpr::Path::plan(at(points[1]), std::vector<cdpr::PathSegment>{diag}, {}), "line path");
  const cdpr::Path circle_path =
      must(cdpr::Path::plan(at(r * u), std::vector<cdpr::PathSegment>{circle}, {}), "circle path");
  for (const Eigen::Vector3d& p : points) {
    must(cdpr::check_pose(nominal, at(p)), "ISO point");
  }
  must(cdpr::check_path(nominal, line_path), "line path");
  must(cdpr::check_path(nominal, circle_path), "circle path");

  Figures fig[2];
  const RobotModel* models[2] = {&nominal, &calibrated};
  for (int m = 0; m < 2; ++m) {
    Cell cell(truth, scenario, *models[m], args.seed + 10);
    fig[m].pose = pose_test(cell, points, args.cycles);
    fig[m].line = path_test(cell, line_path, args.path_cycles);
    fig[m].circle = path_test(cell, circle_path, args.path_cycles);
    fig[m].physics_us = cell.physics_us();
    fig[m].sample_us = cell.sample_us();
  }
  const double wall = std::chrono::duration<double>(Clock::now() - wall0).count();

  std::printf("ISO 9283 on the virtual MINI: truth %s (homed with config/mini.yaml)\n",
              args.scenario.c_str());
  std::printf(
      "cube 312 mm at the origin, P1..P5 on its diagonal plane x = z; %d pose cycles, %d "
      "path cycles; line P2 -> P4 (%.0f mm), circle r = %.1f mm about P1 in that plane\n\n",
      args.cycles, args.path_cycles, 1e3 * (points[3] - points[1]).norm(), 1e3 * r);
  std::printf(
      "| figure | nominal geometry | calibrated geometry | calibrated / nominal | paper "
      "(calibrated) | calibrated / paper |\n| --- | ---: | ---: | ---: | ---: | ---: |\n");
  const double gain = 100.0 * (1.0 - fig[1].pose.ap / fig[0].pose.ap);
  std::printf(
      "| AP (largest of P1..P5), mm | %.3f | %.3f | %.2f (%+.0f %% accuracy) | +%.0f %% "
      "position accuracy | %.2f (of the gain) |\n",
      1e3 * fig[0].pose.ap, 1e3 * fig[1].pose.ap, fig[1].pose.ap / fig[0].pose.ap, gain,
      kPaperPositionGain, gain / kPaperPositionGain);
  std::printf("| RP, mm | %.4f | %.4f | %.2f | | |\n", 1e3 * fig[0].pose.rp, 1e3 * fig[1].pose.rp,
              fig[1].pose.rp / fig[0].pose.rp);
  auto row = [](const char* name, double n, double c, double paper) {
    std::printf("| %s, mm | %.4f | %.4f | %.2f | %.3f | %.3f |\n", name, 1e3 * n, 1e3 * c, c / n,
                1e3 * paper, c / paper);
  };
  row("AT line", fig[0].line.at, fig[1].line.at, kPaperAT);
  row("AT circle", fig[0].circle.at, fig[1].circle.at, kPaperAT);
  row("RT line", fig[0].line.rt, fig[1].line.rt, kPaperRT);
  row("RT circle", fig[0].circle.rt, fig[1].circle.rt, kPaperRT);
  std::printf(
      "\ncalibration %s\n  frame anchors %.2f mm RMS from the truth (nominal %.2f mm), largest "
      "EA error %.1f %%\n",
      cal.how.c_str(), 1e3 * anchor_rms(calibrated), 1e3 * anchor_rms(nominal), 100.0 * ea_error);
  std::printf("speed: line %.2f s (peak %.3f m/s), circle %.2f s (peak %.3f m/s), 4 ms cycles\n",
              fig[0].line.duration, fig[0].line.peak_speed, fig[0].circle.duration,
              fig[0].circle.peak_speed);
  std::printf(
      "cost: Path::sample %.2f us, physics step %.1f us per cycle; calibration %.1f s, "
      "whole bench %.1f s\n",
      0.5 * (fig[0].sample_us + fig[1].sample_us), 0.5 * (fig[0].physics_us + fig[1].physics_us),
      calib_s, wall);
  if (!args.out.empty()) {
    cdpr::report::Iso9283Measured m;
    char setup[512];
    std::snprintf(setup, sizeof setup,
                  "iso9283_bench: virtual MINI, truth %s, seed %llu, %d pose cycles, %d path "
                  "cycles, calibration %s",
                  args.scenario.c_str(), static_cast<unsigned long long>(args.seed), args.cycles,
                  args.path_cycles, cal.how.c_str());
    m.setup = setup;
    cdpr::report::Iso9283Figures* columns[2] = {&m.nominal, &m.calibrated};
    for (int k = 0; k < 2; ++k) {
      *columns[k] = {fig[k].pose.ap,   fig[k].pose.rp, fig[k].line.at,
                     fig[k].circle.at, fig[k].line.rt, fig[k].circle.rt};
    }
    must(cdpr::io::write_file_atomically(args.out, cdpr::report::iso9283_json(m).dump(2) + "\n"),
         "--out");
    std::printf("figures written to %s\n", args.out.c_str());
  }
  return 0;
}
