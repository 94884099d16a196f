#include "cdpr/calibration/pose_design.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <optional>
#include <random>

#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/predicted_accuracy.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"

namespace cdpr {

namespace {

double log_det(const Eigen::MatrixXd& M) {
  const Eigen::LLT<Eigen::MatrixXd> llt(M);
  if (llt.info() != Eigen::Success) return -std::numeric_limits<double>::infinity();
  return 2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
}

// log det of the information about `keep` with `others` profiled out (the Schur complement);
// -infinity when a block is not positive definite.
double profiled_log_det(const Eigen::MatrixXd& X, const std::vector<int>& keep,
                        const std::vector<int>& others) {
  const Eigen::LLT<Eigen::MatrixXd> llt(X(others, others));
  if (llt.info() != Eigen::Success) return -std::numeric_limits<double>::infinity();
  return log_det(X(keep, keep) - X(keep, others) * llt.solve(X(others, keep)));
}

double pose_distance(const Pose& a, const Pose& b, double w) {
  return (a.position - b.position).norm() + w * (a.rpy - b.rpy).norm();
}

std::vector<Pose> candidate_grid(const PoseDesignOptions& o) {
  std::vector<Eigen::Vector3d> orientations{Eigen::Vector3d::Zero()};
  const int steps = o.angle_steps;  // >= 1, checked by design_poses
  for (int k = 0; k < 3; ++k) {
    for (int j = steps; j >= 1; --j) {
      for (double s : {-1.0, 1.0}) {
        Eigen::Vector3d r = Eigen::Vector3d::Zero();
        r(k) = s * o.max_angle * j / steps;
        orientations.push_back(r);
      }
    }
  }
  AccuracyBox box;
  box.center = o.center;
  box.half_extent = o.half_extent;
  box.points_per_axis = o.points_per_axis;
  std::vector<Pose> out;
  for (const Pose& p : box.grid()) {
    for (const Eigen::Vector3d& r : orientations) out.push_back(Pose{p.position, r});
  }
  return out;
}

// Mean squared position error over the box for the information M (normalised parameters):
// tr(Wn M^-1); infinity when M is not positive definite.
double i_value(const Eigen::MatrixXd& M, const Eigen::MatrixXd& Wn) {
  const Eigen::LLT<Eigen::MatrixXd> llt(M);
  if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return llt.solve(Wn).trace();
}

// W = (1 / grid points) sum over the feasible box grid of G^T G (P x P, unnormalised parameters),
// G = top three rows of -pinv(J_pose) J_geometry of the cable lengths at the grid point: the
// position error a parameter error causes when the controller commands that point.
Result<Eigen::MatrixXd> position_weight(const CalibratedModel& model,
                                        const PoseDesignOptions& options, double f_ref,
                                        const GeometryInformation& gi) {
  auto sens = pose_sensitivities(model, options.accuracy_box, f_ref, options.noise,
                                 options.identification, gi.ids);
  if (!sens) return sens.status();
  if (sens->empty()) return Eigen::MatrixXd(Eigen::MatrixXd::Zero(0, 0));
  const auto P = static_cast<Eigen::Index>(gi.ids.size());
  Eigen::MatrixXd W = Eigen::MatrixXd::Zero(P, P);
  for (const Eigen::MatrixXd& G : *sens) W += G.topRows<3>().transpose() * G.topRows<3>();
  return Eigen::MatrixXd(W / static_cast<double>(sens->size()));
}

// Ordered tour: nearest neighbour from index 0, then 2-opt (index 0 stays first).
std::vector<Pose> order_path(std::vector<Pose> poses, double w, double* length) {
  const std::size_t n = poses.size();
  if (n < 2) {
    if (length) *length = 0.0;
    return poses;
  }
  std::vector<Pose> tour{poses[0]};
  std::vector<char> used(n, 0);
  for (std::size_t k = 1; k < n; ++k) {
    std::size_t best = 0;
    double bd = std::numeric_limits<double>::infinity();
    for (std::size_t c = 0; c < n; ++c) {
      if (c == 0 || used[c]) continue;
      const double d = pose_distance(tour.back(), poses[c], w);
      if (d < bd) {
        bd = d;
        best = c;
      }
    }
    used[best] = 1;
    tour.push_back(poses[best]);
  }
  bool improved = true;
  while (improved) {
    improved = false;
    for (std::size_t i = 1; i + 1 < n; ++i) {
      for (std::size_t j = i + 1; j < n; ++j) {
        const double before = pose_distance(tour[i - 1], tour[i], w) +
                              (j + 1 < n ? pose_distance(tour[j], tour[j + 1], w) : 0.0);
        const double after = pose_distance(tour[i - 1], tour[j], w) +
                             (j + 1 < n ? pose_distance(tour[i], tour[j + 1], w) : 0.0);
        if (after < before - 1e-12) {
          std::reverse(tour.begin() + static_cast<long>(i),
                       tour.begin() + static_cast<long>(j) + 1);
          improved = true;
        }
      }
    }
  }
  double L = 0.0;
  for (std::size_t k = 1; k < n; ++k) L += pose_distance(tour[k - 1], tour[k], w);
  if (length) *length = L;
  return tour;
}

}  // namespace

void fit_design_box_to_robot(const RobotModel& robot, PoseDesignOptions& options, double fraction) {
  options.center = robot.home.position;
  if (robot.frame_anchors.cols() == 0) return;
  const Eigen::Vector3d lo = robot.frame_anchors.rowwise().minCoeff();
  const Eigen::Vector3d hi = robot.frame_anchors.rowwise().maxCoeff();
  options.half_extent = 0.5 * fraction * (hi - lo);
  if (robot.suspended) {
    // The anchors of a crane are all up high: the vertical extent is the drop below them.
    const double drop = robot.frame_anchors.row(2).mean() - robot.home.position.z();
    options.half_extent.z() = std::max(options.half_extent.z(), 0.5 * fraction * drop);
  }
}

std::optional<Pose> feasible_design_pose(const RobotModel& robot, const Pose& candidate,
                                         double reference_tension) {
  if (robot.suspended && robot.num_cables() < 6) {
    // A suspended robot hangs where the statics put it: keep the candidate's position and yaw,
    // take roll and pitch from the equilibrium, and keep it if every tension is within limits.
    const Result<SuspendedState> eq = suspended_equilibrium_pose(robot, candidate);
    if (!eq || !simple_tension_distribution(robot, eq->pose, reference_tension)) {
      return std::nullopt;
    }
    return eq->pose;
  }
  if (!simple_tension_distribution(robot, candidate, reference_tension)) return std::nullopt;
  return candidate;
}

Result<RobotModel> narrow_tension_limits(const RobotModel& robot, double margin) {
  if (!(std::isfinite(margin) && margin >= 0.0)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "tension_margin must be finite and >= 0 (got %g)", margin);
  }
  RobotModel narrowed = robot;
  for (std::size_t i = 0; i < narrowed.cables.size(); ++i) {
    CableModel& cable = narrowed.cables[i];
    cable.f_min += margin;
    cable.f_max -= margin;
    if (cable.f_min >= cable.f_max) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "tension_margin %g N leaves cable %zu no tension range (f_min %g N, "
                           "f_max %g N)",
                           margin, i + 1, robot.cables[i].f_min, robot.cables[i].f_max);
    }
  }
  return narrowed;
}

Result<PoseDesign> design_poses(const CalibratedModel& model, const PoseDesignOptions& options) {
  if (options.num_poses < 2) {
    return Status(ErrorCode::kInvalidArgument, "pose design: at least 2 poses are needed");
  }
  if (options.angle_steps < 1) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "pose design: angle_steps must be at least 1, got %d",
                         options.angle_steps);
  }
  if (!(options.emphasis_weight >= 0.0) || !std::isfinite(options.emphasis_weight)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "pose design: emphasis_weight must be finite and >= 0, got %g",
                         options.emphasis_weight);
  }
  if (Status s =
          check_estimates_for_channels(model.robot, options.channels, options.identification);
      !s.ok()) {
    return Status::error(s.code(), "pose design: %s", std::string(s.message()).c_str());
  }
  const double f_ref = std::isnan(options.reference_tension)
                           ? default_reference_tension(model.robot)
                           : options.reference_tension;
  // The candidates' feasibility is judged with the limits narrowed by the margin.
  const Result<RobotModel> narrowed = narrow_tension_limits(model.robot, options.tension_margin);
  if (!narrowed) {
    return Status::error(narrowed.status().code(), "pose design: %s",
                         std::string(narrowed.status().message()).c_str());
  }
  std::vector<Pose> cands{model.robot.home};  // index 0: home (the gauge pose)
  for (const Pose& grid_pose : candidate_grid(options)) {
    const std::optional<Pose> p = feasible_design_pose(*narrowed, grid_pose, f_ref);
    if (!p) continue;
    const bool seen = std::any_of(cands.begin(), cands.end(), [&](const Pose& c) {
      return (p->vector() - c.vector()).norm() < 1e-12;
    });
    if (!seen) cands.push_back(*p);
  }
  const int C = static_cast<int>(cands.size()) - 1;
  if (C < options.num_poses - 1) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "pose design: only %d feasible candidates for %d poses", C,
                         options.num_poses - 1);
  }
  SimulationOptions so;
  so.add_noise = false;
  so.reference_tension = f_ref;
  so.use_channels(options.channels);
  auto sim = simulate_measurements(model, cands, options.noise, 0, so);
  if (!sim) return sim.status();
  // The emphasised kinds the calibration does not estimate are added to the information the design
  // judges (those the recorded channels cannot observe are left out), and kept out of log_det.
  IdentificationOptions judged = options.identification;
  std::vector<ParameterKind> emphasised, added;
  if (options.emphasis_weight > 0.0) {
    for (ParameterKind kind : options.emphasis) {
      const EstimateItem* item = estimate_item_of(kind);
      if (item == nullptr) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "pose design: emphasis on a parameter kind no --estimate word "
                             "estimates alone (%s)",
                             parameter_name(ParameterId{kind, 0, -1}).c_str());
      }
      if (item->is_set(judged)) {
        emphasised.push_back(kind);
        continue;
      }
      IdentificationOptions with = judged;
      item->set(with, true);
      if (!check_estimates_for_channels(model.robot, options.channels, with).ok()) continue;
      judged = with;
      emphasised.push_back(kind);
      added.push_back(kind);
    }
  }
  auto gi = geometry_information(model, sim->set, cands, judged);
  if (!gi) return gi.status();
  const int P = static_cast<int>(gi->information.rows());
  // Column scaling from the whole candidate set.
  Eigen::VectorXd d(P);
  for (int q = 0; q < P; ++q) {
    d(q) = gi->information(q, q) > 0 ? 1.0 / std::sqrt(gi->information(q, q)) : 1.0;
  }
  std::vector<Eigen::MatrixXd> S(cands.size());
  for (std::size_t c = 0; c < cands.size(); ++c) {
    S[c] = d.asDiagonal() * gi->per_pose[c] * d.asDiagonal();
  }
  const double ridge = 1e-9;
  const Eigen::MatrixXd R = ridge * Eigen::MatrixXd::Identity(P, P);
  // The criterion: log det of the information, plus emphasis_weight x the log det of the
  // emphasised parameters' information with the others profiled out (a compound D / Ds design).
  std::vector<int> emph, rest, estimated;
  for (int q = 0; q < P; ++q) {
    const ParameterKind kind = gi->ids[static_cast<std::size_t>(q)].kind;
    auto in = [kind](const std::vector<ParameterKind>& v) {
      return std::find(v.begin(), v.end(), kind) != v.end();
    };
    (in(emphasised) ? emph : rest).push_back(q);
    if (!in(added)) estimated.push_back(q);
  }
  // A kind without a column (the laser's on a robot without one) is neither judged nor reported.
  std::erase_if(emphasised, [&](ParameterKind kind) {
    return std::none_of(emph.begin(), emph.end(),
                        [&](int q) { return gi->ids[static_cast<std::size_t>(q)].kind == kind; });
  });
  const bool compound = !emph.empty() && !rest.empty();
  auto design_value = [&](const Eigen::MatrixXd& X) {
    const double full = log_det(X);
    if (!compound || !std::isfinite(full)) return full;
    const double ds = profiled_log_det(X, emph, rest);
    return std::isfinite(ds) ? full + options.emphasis_weight * ds : full;
  };
  std::vector<int> sel;
  Eigen::MatrixXd M = S[0] + R;
  Eigen::VectorXi chosen = Eigen::VectorXi::Zero(static_cast<Eigen::Index>(cands.size()));
  for (int k = 1; k < options.num_poses; ++k) {
    int best = -1;
    double bv = -std::numeric_limits<double>::infinity();
    for (int c = 1; c <= C; ++c) {
      if (chosen(c)) continue;
      const double v = design_value(M + S[static_cast<std::size_t>(c)]);
      if (v > bv) {
        bv = v;
        best = c;
      }
    }
    if (best < 0) break;
    chosen(best) = 1;
    sel.push_back(best);
    M += S[static_cast<std::size_t>(best)];
    if (options.progress) options.progress("poses designed", k + 1, options.num_poses);
  }
  PoseDesign out;
  out.candidates = C;
  // Fedorov exchange: swap a selected pose (never home) for an unused candidate while the
  // criterion (larger is better) improves by more than `margin` (relative); returns the final
  // value.
  auto exchange = [&](auto&& criterion, double margin) {
    double current = criterion(M);
    for (int pass = 0; pass < options.exchange_passes; ++pass) {
      if (options.progress) options.progress("exchange passes", pass, options.exchange_passes);
      bool any = false;
      for (std::size_t s = 0; s < sel.size(); ++s) {
        const Eigen::MatrixXd without = M - S[static_cast<std::size_t>(sel[s])];
        int best = -1;
        double bv = current;
        for (int c = 1; c <= C; ++c) {
          if (chosen(c)) continue;
          const double v = criterion(without + S[static_cast<std::size_t>(c)]);
          if (v > bv + margin * std::abs(bv)) {
            bv = v;
            best = c;
          }
        }
        if (best >= 0) {
          chosen(sel[s]) = 0;
          chosen(best) = 1;
          M = without + S[static_cast<std::size_t>(best)];
          sel[s] = best;
          current = bv;
          ++out.exchanges;
          any = true;
        }
      }
      if (!any) break;
    }
    return current;
  };
  exchange(design_value, 1e-9);
  if (options.criterion == DesignCriterion::kPositionAccuracy) {
    auto W = position_weight(model, options, f_ref, *gi);
    if (!W) return W.status();
    if (W->size() > 0) {
      const Eigen::MatrixXd Wn = d.asDiagonal() * (*W) * d.asDiagonal();
      auto neg_i = [&Wn](const Eigen::MatrixXd& X) { return -i_value(X, Wn); };
      out.position_rms_d_optimal_m = std::sqrt(std::max(0.0, -neg_i(M)));
      out.position_rms_m = std::sqrt(std::max(0.0, -exchange(neg_i, 1e-9)));
    }
  }
  const Eigen::MatrixXd F = M - R;
  out.log_det = log_det(F(estimated, estimated));
  out.emphasis_log_det = compound ? profiled_log_det(F, emph, rest) : 0.0;
  out.emphasised = emphasised;
  std::vector<Pose> poses{cands[0]};
  for (int c : sel) poses.push_back(cands[static_cast<std::size_t>(c)]);
  out.poses = order_path(poses, options.angle_weight, &out.path_length);
  return out;
}

Result<std::vector<PoseSetComparison>> compare_pose_sets(const CalibratedModel& model,
                                                         const PoseDesignOptions& options,
                                                         const AccuracyBox& box,
                                                         std::uint64_t seed) {
  auto design = design_poses(model, options);
  if (!design) return design.status();
  const double f_ref = std::isnan(options.reference_tension)
                           ? default_reference_tension(model.robot)
                           : options.reference_tension;
  // Random feasible set.
  std::vector<Pose> random{model.robot.home};
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int guard = 0; static_cast<int>(random.size()) < options.num_poses && guard < 100000;
       ++guard) {
    Pose p;
    for (int k = 0; k < 3; ++k) {
      p.position(k) = options.center(k) + options.half_extent(k) * u(rng);
      p.rpy(k) = options.max_angle * u(rng);
    }
    if (simple_tension_distribution(model.robot, p, f_ref)) random.push_back(p);
  }
  // Box corners at several orientations.
  std::vector<Pose> corners{model.robot.home};
  const std::vector<Eigen::Vector3d> orient{Eigen::Vector3d::Zero(),
                                            Eigen::Vector3d(options.max_angle, 0, 0),
                                            Eigen::Vector3d(0, options.max_angle, 0),
                                            Eigen::Vector3d(0, 0, options.max_angle),
                                            Eigen::Vector3d(-options.max_angle, 0, 0),
                                            Eigen::Vector3d(0, -options.max_angle, 0),
                                            Eigen::Vector3d(0, 0, -options.max_angle)};
  for (double scale : {1.0, 0.8, 0.5}) {
    for (const Eigen::Vector3d& r : orient) {
      for (int c = 0; c < 8 && static_cast<int>(corners.size()) < options.num_poses; ++c) {
        Pose p;
        p.position = options.center +
                     scale * Eigen::Vector3d((c & 1) ? 1 : -1, (c & 2) ? 1 : -1, (c & 4) ? 1 : -1)
                                 .cwiseProduct(options.half_extent);
        p.rpy = r;
        if (simple_tension_distribution(model.robot, p, f_ref)) corners.push_back(p);
      }
    }
  }
  PredictedAccuracyOptions po;
  po.identification = options.identification;
  po.box = box;
  po.reference_tension = f_ref;
  po.channels = options.channels;
  std::vector<PoseSetComparison> out;
  const std::vector<std::pair<std::string, std::vector<Pose>>> sets{
      {"designed (D-optimal + exchange)", design->poses},
      {"random", random},
      {"box corners", corners}};
  for (const auto& [label, poses] : sets) {
    auto pa = predict_accuracy(model, poses, options.noise, po);
    if (!pa) return pa.status();
    SimulationOptions so;
    so.add_noise = false;
    so.reference_tension = f_ref;
    so.use_channels(options.channels);
    auto sim = simulate_measurements(model, poses, options.noise, 0, so);
    if (!sim) return sim.status();
    auto ir = analyze_identifiability(model, sim->set, options.identification);
    PoseSetComparison c;
    c.label = label;
    c.num_poses = static_cast<int>(poses.size());
    c.anchor_rms_std_m = pa->anchor_rms_std_m;
    c.position_rms_m = pa->position_rms_m;
    c.condition_number = ir ? ir->condition_number : std::numeric_limits<double>::quiet_NaN();
    out.push_back(c);
  }
  return out;
}

}  // namespace cdpr
