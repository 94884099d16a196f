// The locator's extra-pose design (diagnosis_internal.hpp): a feasible candidate grid appended to
// the recording, the poses that separate confounded pairs and the follow-up poses for a suspect.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <utility>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/model_validation.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "diagnosis_internal.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr::diagnosis_detail {

using mismatch_detail::column_basis;
using mismatch_detail::format;
using mismatch_detail::kNaN;

namespace {

// When an extra pose measured right after the recording would be read: time and temperature
// (NaN where the recording has none).
PoseMeasurement next_reading_slot(const MeasurementSet& set) {
  PoseMeasurement next;
  double first = kNaN, last = kNaN;
  int timed = 0;
  for (const PoseMeasurement& pm : set.poses) {
    if (std::isfinite(pm.time)) {
      if (!std::isfinite(first)) first = pm.time;
      last = pm.time;
      ++timed;
    }
    if (std::isfinite(pm.temperature)) next.temperature = pm.temperature;
  }
  if (timed >= 2) next.time = last + (last - first) / static_cast<double>(timed - 1);
  // One time stamp, or times so large that the next one overflows: the last one.
  if (timed >= 1 && !std::isfinite(next.time)) next.time = last;
  return next;
}

}  // namespace

ExtraPoseGrid extra_pose_grid(const RobotModel& robot, const IdentificationReport& before,
                              const MeasurementSet& set,
                              const IdentificationOptions& identification,
                              const DiagnosisOptions& options) {
  ExtraPoseGrid out;
  std::vector<Pose>& cand = out.poses;
  std::vector<double>& cand_pretension = out.pretensions;
  std::optional<MismatchDesign>& aug = out.design;
  {
    // The region the recording has already visited (the robot held the platform there with
    // this model's commands), capped by the pose-design box of the robot: near the edge of the
    // model's wrench-feasible workspace the real robot may not hold the platform (cables go
    // slack where the anchors differ from the model).
    PoseDesignOptions box;
    fit_design_box_to_robot(robot, box);
    Eigen::Vector3d he = Eigen::Vector3d::Zero();
    double tilt = 0.0;
    for (const Pose& p : before.poses) {
      he = he.cwiseMax((p.position - robot.home.position).cwiseAbs());
      tilt = std::max(
          {tilt, std::abs(p.rpy(0) - robot.home.rpy(0)), std::abs(p.rpy(1) - robot.home.rpy(1))});
    }
    he = options.separating_half_extent_scale * he.cwiseMin(box.half_extent);
    tilt = std::min(tilt, 0.2);
    const double f_ref = default_reference_tension(before.estimate.robot);
    std::vector<Pose> grid;
    const int ppa = 4;
    const std::vector<Eigen::Vector3d> rpys = {
        Eigen::Vector3d::Zero(), Eigen::Vector3d(tilt, 0, 0), Eigen::Vector3d(-tilt, 0, 0),
        Eigen::Vector3d(0, tilt, 0), Eigen::Vector3d(0, -tilt, 0)};
    for (int ix = 0; ix < ppa; ++ix) {
      for (int iy = 0; iy < ppa; ++iy) {
        for (int iz = 0; iz < ppa; ++iz) {
          for (const auto& rpy : rpys) {
            Pose p;
            p.position =
                robot.home.position + he.cwiseProduct(Eigen::Vector3d(-1.0 + 2.0 * ix / (ppa - 1),
                                                                      -1.0 + 2.0 * iy / (ppa - 1),
                                                                      -1.0 + 2.0 * iz / (ppa - 1)));
            p.rpy = robot.home.rpy + rpy;
            // Feasible for the estimate and for the model the recording was commanded with.
            if (simple_tension_distribution(before.estimate.robot, p, f_ref) &&
                simple_tension_distribution(robot, p, f_ref)) {
              grid.push_back(p);
            }
          }
        }
      }
    }
    // The extra poses are measured after the recording: their time is the next pose's (the
    // recording's mean spacing after its last pose), their temperature the last one read. The
    // time-dependent candidates (creep, drifts) are evaluated there, not where the simulation
    // below would put them (pose g at g seconds, as if at the start: a creep column near zero
    // on those made 6 extra poses seem to separate creep from elasticity, canonical correlation
    // 0.95 -> 0.11, which the poses measured after the recording did not).
    const PoseMeasurement next = next_reading_slot(set);
    MeasurementSet all = set;
    std::vector<Pose> all_poses = before.poses;
    for (const double level : {f_ref, 2.0 * f_ref}) {
      std::vector<Pose> ok;
      for (const Pose& p : grid) {
        if (level == f_ref || (simple_tension_distribution(before.estimate.robot, p, level) &&
                               simple_tension_distribution(robot, p, level))) {
          ok.push_back(p);
        }
      }
      SimulationOptions so;
      so.add_noise = false;
      so.reference_tension = level;
      auto sim = simulate_measurements(before.estimate, ok, set.noise, 1, so);
      if (!sim) continue;
      for (std::size_t g = 0; g < ok.size(); ++g) {
        all.poses.push_back(sim->set.poses[g]);
        all.poses.back().time = next.time;
        all.poses.back().temperature = next.temperature;
        all_poses.push_back(ok[g]);
        cand.push_back(ok[g]);
        cand_pretension.push_back(level);
      }
    }
    if (!cand.empty()) {
      auto des =
          mismatch_design(before.estimate, all, all_poses, nullptr, identification, options.screen);
      if (des) aug = std::move(*des);
    }
  }
  return out;
}

std::vector<ConfoundedFinding> separate(const std::vector<ConfoundedPair>& found,
                                        const std::vector<Trial>& trials, const ExtraPoseGrid& grid,
                                        int np, const DiagnosisOptions& options) {
  std::vector<ConfoundedFinding> out;
  {
    for (const auto& p : found) {
      ConfoundedFinding cf;
      cf.first = p.first;
      cf.second = p.second;
      cf.correlation = p.correlation;
      cf.correlation_with_extra = p.correlation;
      cf.description = p.description;
      if (const EffectFit* f = trial_fit(trials, p.first)) cf.first_fit = *f;
      if (const EffectFit* f = trial_fit(trials, p.second)) cf.second_fit = *f;
      const CandidateColumns* ca = grid.design ? find_columns(*grid.design, p.first) : nullptr;
      const CandidateColumns* cb = grid.design ? find_columns(*grid.design, p.second) : nullptr;
      if (ca != nullptr && cb != nullptr) {
        const PoseGrams g = pose_grams(*grid.design, {&ca->X, &cb->X}, true, false);
        const int ka = g.block_size[0], kb = g.block_size[1];
        auto corr = [&](const Eigen::MatrixXd& M) {
          const Eigen::MatrixXd S = reduce_geometry(M, g.geometry);
          return canonical_correlation(S.topLeftCorner(ka, ka), S.block(ka, ka, kb, kb),
                                       S.block(0, ka, ka, kb));
        };
        Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
        for (int j = 0; j < np; ++j) M += g.M[static_cast<std::size_t>(j)];
        // Lowest canonical correlation: maximise its negative, only while it falls.
        const std::vector<int> chosen = greedy_extra_poses(
            g, np, options.separating_poses, [](int) { return true; },
            [&](const Eigen::MatrixXd& Mq) { return -corr(Mq); }, -corr(M), M);
        for (int q : chosen) {
          cf.separating_poses.push_back(grid.poses[static_cast<std::size_t>(q)]);
          cf.separating_pretensions.push_back(grid.pretensions[static_cast<std::size_t>(q)]);
        }
        const double rho = corr(M);
        cf.correlation_with_extra = rho;
      }
      out.push_back(std::move(cf));
    }
  }
  return out;
}

std::optional<FollowUp> follow_up_for(const CandidateScreen& suspect, const RobotModel& estimate,
                                      const ExtraPoseGrid& grid, int np,
                                      const DiagnosisOptions& options) {
  const CandidateColumns* cs = grid.design ? find_columns(*grid.design, suspect.id) : nullptr;
  if (cs == nullptr) return std::nullopt;
  const PoseGrams g = pose_grams(*grid.design, {&cs->X}, true, false);
  const int k = g.block_size[0];
  auto logdet = [&](const Eigen::MatrixXd& M) {
    const Eigen::MatrixXd S = reduce_geometry(M, g.geometry).topLeftCorner(k, k);
    const double ridge = 1e-9 * std::max(S.trace(), 1e-300);
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(S + ridge * Eigen::MatrixXd::Identity(k, k));
    return ldlt.vectorD().array().max(ridge).log().sum();
  };
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(g.total, g.total);
  for (int j = 0; j < np; ++j) M += g.M[static_cast<std::size_t>(j)];
  const double f_ref = default_reference_tension(estimate);
  FollowUp fu;
  fu.suspect = suspect.id;
  fu.name = suspect.name;
  fu.p_value = suspect.p_value;
  fu.p_adjusted = suspect.p_adjusted;
  fu.parameters = k;
  fu.information_before = logdet(M);
  const std::vector<int> chosen = greedy_extra_poses(
      g, np, options.follow_up_poses,
      [&](int q) { return grid.pretensions[static_cast<std::size_t>(q)] == f_ref; }, logdet,
      -std::numeric_limits<double>::infinity(), M);
  for (int q : chosen) {
    fu.poses.push_back(grid.poses[static_cast<std::size_t>(q)]);
    fu.pretensions.push_back(grid.pretensions[static_cast<std::size_t>(q)]);
  }
  fu.information_after = logdet(M);
  if (fu.poses.empty()) return std::nullopt;
  return fu;
}

std::optional<FollowUp> follow_up(const MismatchSummary& screen, const RobotModel& estimate,
                                  const std::function<const ExtraPoseGrid&()>& grid_of, int np,
                                  const DiagnosisOptions& options, bool misfit_clause,
                                  const std::vector<std::string>& not_suspects) {
  const bool unexplained_misfit = misfit_clause && screen.p_value < options.screen.alpha;
  const CandidateScreen* suspect = nullptr;
  for (const auto& cs : screen.candidates) {
    if (cs.modelled || cs.rank == 0) continue;
    if (std::find(not_suspects.begin(), not_suspects.end(), cs.id) != not_suspects.end()) continue;
    if (proxy_for_structure(screen, cs.id, options.screen_gate_p)) continue;
    if (!(cs.p_adjusted < options.suspect_p) && !unexplained_misfit) continue;
    if (suspect == nullptr || cs.p_value < suspect->p_value) suspect = &cs;
  }
  if (suspect == nullptr) return std::nullopt;
  return follow_up_for(*suspect, estimate, grid_of(), np, options);
}

}  // namespace cdpr::diagnosis_detail
