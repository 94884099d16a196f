#include "cdpr/calibration/residual_explanation.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"

namespace cdpr {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The family of a candidate id, from the refitted candidates or the screen.
std::string family_of(const Diagnosis& d, const std::string& id) {
  for (const EffectFit& e : d.candidates) {
    if (e.id == id) return e.family;
  }
  if (const CandidateScreen* c = d.screen.find(id)) return c->family;
  return "";
}

}  // namespace

std::vector<ExplainedResiduals> explained_residuals(const Diagnosis& d, const MeasurementSet& set) {
  // The effects to plot: accepted ones, else the top refitted candidate, else the top screened.
  std::vector<std::pair<std::string, std::string>> effects;  // id, name
  for (const EffectFit& e : d.accepted) effects.push_back({e.id, e.name});
  if (effects.empty() && !d.candidates.empty()) {
    effects.push_back({d.candidates.front().id, d.candidates.front().name});
  }
  if (effects.empty() && !d.screen.candidates.empty() && !d.screen.candidates.front().modelled) {
    effects.push_back({d.screen.candidates.front().id, d.screen.candidates.front().name});
  }
  if (effects.empty()) effects.push_back({"", "length residuals"});

  const RobotModel& robot = d.before.estimate.robot;
  const int m = robot.num_cables();
  const Eigen::MatrixXd move = last_move_directions(set);
  KinematicsData kin(m);
  std::vector<ExplainedResiduals> plots;
  for (const auto& [id, name] : effects) {
    ExplainedResiduals p;
    p.effect_id = id;
    p.title = id.empty() ? name : name + " [" + id + "]";
    const ExplainingVariable var = explaining_variable(family_of(d, id));
    p.variable = var.name;
    p.unit = var.unit;
    const bool have_after =
        d.after.has_value() && d.after->residuals.size() == d.before.residuals.size();
    const std::size_t n = std::min(set.poses.size(), d.before.residuals.size());
    for (std::size_t j = 0; j < n; ++j) {
      const PoseMeasurement& meas = set.poses[j];
      const bool ik_ok =
          j < d.before.poses.size() && inverse_kinematics(robot, d.before.poses[j], kin);
      const Eigen::VectorXd& rb = d.before.residuals[j].length_normalized;
      for (int i = 0; i < m && i < rb.size(); ++i) {
        if (!std::isfinite(rb(i))) continue;
        const double tension = meas.tensions.size() > i ? meas.tensions(i) : kNaN;
        const double loaded =
            ik_ok ? loaded_length(robot.cables[static_cast<std::size_t>(i)], kin.lengths(i)) : kNaN;
        double x = static_cast<double>(j);
        if (var.name == "tension x loaded length") {
          x = tension * loaded;
        } else if (var.name == "tension") {
          x = tension;
        } else if (var.name == "loaded length") {
          x = loaded;
        } else if (var.name == "time") {
          x = std::isfinite(meas.time) ? meas.time : kNaN;
        } else if (var.name == "direction of the last move") {
          x = i < move.cols() ? move(static_cast<Eigen::Index>(j), i) : kNaN;
        }
        if (!std::isfinite(x)) continue;
        p.x.push_back(x);
        p.cable.push_back(i);
        p.before.push_back(rb(i));
        if (have_after) {
          const Eigen::VectorXd& ra = d.after->residuals[j].length_normalized;
          p.after.push_back(i < ra.size() ? ra(i) : kNaN);
        }
      }
    }
    if (p.x.empty() && var.name != "pose index") {
      // The variable is not available (no tensions, no time): fall back to the pose index.
      ExplainedResiduals q;
      q.effect_id = p.effect_id;
      q.title = p.title + " (" + var.name + " not recorded)";
      q.variable = "pose index";
      for (std::size_t j = 0; j < n; ++j) {
        const Eigen::VectorXd& rb = d.before.residuals[j].length_normalized;
        for (int i = 0; i < rb.size(); ++i) {
          if (!std::isfinite(rb(i))) continue;
          q.x.push_back(static_cast<double>(j));
          q.cable.push_back(i);
          q.before.push_back(rb(i));
          if (have_after) {
            const Eigen::VectorXd& ra = d.after->residuals[j].length_normalized;
            q.after.push_back(i < ra.size() ? ra(i) : kNaN);
          }
        }
      }
      p = std::move(q);
    }
    plots.push_back(std::move(p));
  }
  return plots;
}

}  // namespace cdpr
