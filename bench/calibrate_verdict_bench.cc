// The fit test of `cdpr-fit calibrate` (judge_calibration, calibration_verdict.hpp) on MINI as
// shipped: nominal = config/mini.yaml's model, truth = the measured anchors, encoders homed with
// the nominal model, 25 poses designed on the nominal model (D-optimal), elastic simulation,
// noise laser 1 mm, encoder 0.1 mm, force 1 N. A drum (transmission) scale error of size s on
// every winch, signs + - + - - + - +, acts on the length paid out from home. For each size the
// program prints, over the seeds, the fraction of calibrations that fail (and why), the median
// chi^2 / dof and p-value. Seeds 2000.. as in calibration_verdict_test.cc.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "cdpr/calibration/calibration_verdict.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/identification_scenario.hpp"

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 40;
  double alpha = 0.01;
  for (int k = 1; k < argc; ++k) {
    if (std::strcmp(argv[k], "--seeds") == 0 && k + 1 < argc) seeds = std::atoi(argv[++k]);
    if (std::strcmp(argv[k], "--alpha") == 0 && k + 1 < argc) alpha = std::atof(argv[++k]);
  }
  const cdpr::scenario::Scenario s = cdpr::scenario::mini_config_scenario();
  cdpr::PoseDesignOptions po;
  po.num_poses = 25;
  auto design = cdpr::design_poses(s.nominal, po);
  if (!design.ok()) {
    std::fprintf(stderr, "design: %s\n", design.status().to_string().c_str());
    return 1;
  }
  const cdpr::RobotModel& nom = s.nominal.robot;
  auto f = cdpr::simple_tension_distribution(nom, nom.home, cdpr::default_reference_tension(nom));
  auto r_home = f.ok() ? cdpr::unstretched_lengths(nom, nom.home, *f)
                       : cdpr::Result<Eigen::VectorXd>(f.status());
  if (!r_home.ok()) return 1;
  const double signs[8] = {1, -1, 1, -1, -1, 1, -1, 1};
  cdpr::CalibrationVerdictOptions vo;
  vo.alpha = alpha;
  std::printf(
      "MINI, 25 designed poses, elastic simulation, noise 1 mm / 0.1 mm / 1 N, %d seeds, "
      "alpha %.3g\n",
      seeds, alpha);
  std::printf("%-18s %8s %8s %8s %12s %10s\n", "drum scale", "failed", "exit 3", "exit 4",
              "chi2/dof", "median p");
  for (double scale : {0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003}) {
    cdpr::CalibratedModel truth = s.truth;
    for (int i = 0; i < truth.robot.num_cables(); ++i) {
      const double si = scale * signs[i % 8];
      truth.readings.length_scales(i) += si;
      truth.readings.length_offsets(i) -= si * (*r_home)(i);
    }
    int failed = 0, rejected = 0, untrusted = 0;
    std::vector<double> ratio, p;
    for (int k = 0; k < seeds; ++k) {
      cdpr::SimulationOptions so;
      so.physics = cdpr::SimulationOptions::Physics::kElastic;
      so.controller = &s.nominal;
      auto sim = cdpr::simulate_measurements(truth, design->poses, cdpr::SensorNoise{},
                                             2000 + static_cast<std::uint64_t>(k), so);
      if (!sim.ok()) continue;
      auto rep = cdpr::identify(s.nominal, sim->set);
      if (!rep.ok()) continue;
      const cdpr::CalibrationVerdict v = cdpr::judge_calibration(*rep, vo);
      failed += v.passed() ? 0 : 1;
      rejected += v.kind == cdpr::CalibrationVerdict::Kind::kFitRejected ? 1 : 0;
      untrusted += v.kind == cdpr::CalibrationVerdict::Kind::kNotTrustworthy ? 1 : 0;
      ratio.push_back(v.chi2 / std::max(1, v.dof));
      p.push_back(v.p_value);
    }
    std::printf("%-18s %7.1f%% %8d %8d %12.3f %10.3g\n",
                scale == 0.0 ? "none (null data)" : (std::to_string(100 * scale) + " %").c_str(),
                100.0 * failed / seeds, rejected, untrusted, median(ratio), median(p));
    std::fflush(stdout);
  }
  return 0;
}
