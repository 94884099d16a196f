#include "cdpr/sim/physics.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

#include "cdpr/calibration/catenary.hpp"
#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/force_sensor.hpp"
#include "cdpr/calibration/forward_kinematics.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"

namespace cdpr::sim {
namespace {

double scaled_max(const Wrench& w, double rho) {
  return std::max(w.head<3>().cwiseAbs().maxCoeff(), w.tail<3>().cwiseAbs().maxCoeff() / rho);
}

double scaled_norm2(const Wrench& w, double rho) {
  return w.head<3>().squaredNorm() + w.tail<3>().squaredNorm() / (rho * rho);
}

// Graded-order index of the term s^(d - j) t^j of a polynomial surface.
constexpr std::size_t term(int d, int j) {
  return static_cast<std::size_t>(d * (d + 1) / 2 + j);
}

}  // namespace

std::string_view to_string(LaserStatus s) {
  switch (s) {
    case LaserStatus::kOk:
      return "ok";
    case LaserStatus::kNoTarget:
      return "no target";
    case LaserStatus::kOutOfRange:
      return "out of range";
  }
  return "unknown";
}

Physics::Physics(RobotModel truth, const Scenario& scenario, std::uint64_t seed,
                 const PhysicsOptions& options)
    : truth_(std::move(truth)),
      work_(truth_),
      scenario_(scenario),
      options_(options),
      rng_(seed),
      data_(truth_.num_cables()),
      lengths_(Eigen::VectorXd::Zero(truth_.num_cables())),
      sag_tensions_(Eigen::VectorXd::Zero(truth_.num_cables())),
      sag_trial_tensions_(Eigen::VectorXd::Zero(truth_.num_cables())),
      rho_(truth_.platform_radius()) {
  const int m = truth_.num_cables();
  const HiddenEffects& e = scenario_.effects;
  // True lasers: mount offset and tilt (platform frame), target plane tilt and offset (world).
  for (const LaserModel& nominal_laser : truth_.lasers) {
    LaserModel l = nominal_laser;
    l.origin += e.laser_mount_offset;
    l.direction = (rotation_exp(e.laser_mount_tilt) * l.direction).normalized();
    l.plane_normal = (rotation_exp(e.plane_tilt) * l.plane_normal).normalized();
    l.plane_point += e.plane_offset * l.plane_normal;
    lasers_.push_back(l);
  }
  for (int i = 0; i < m; ++i) {
    ForceSensorModel s = truth_.force_sensors[static_cast<std::size_t>(i)];
    s.gain *= 1.0 + e.force_gain_error.at(i);
    s.offset += e.force_offset_error.at(i);
    sensors_.push_back(s);
  }
  base_sensors_ = sensors_;
  base_frame_anchors_ = truth_.frame_anchors;
  // Creep on a polynomial surface adds c g(t) F L, a degree-2 term: pad the surface to order 2.
  for (int i = 0; i < m; ++i) {
    CableModel& c = work_.cables[static_cast<std::size_t>(i)];
    if (c.elongation == ElongationKind::kPolynomial && e.creep && c.polynomial.order < 2) {
      c.polynomial.coefficients.resize(static_cast<std::size_t>(polynomial_surface_size(2)), 0.0);
      c.polynomial.order = 2;
    }
    base_coefficients_.push_back(c.polynomial.coefficients);
  }
  state_.counts = Eigen::VectorXd::Zero(m);
  state_.unstretched_lengths = Eigen::VectorXd::Zero(m);
  state_.tensions = Eigen::VectorXd::Zero(m);
  state_.encoder_counts = Eigen::VectorXd::Zero(m);
  state_.force_raw = Eigen::VectorXd::Zero(m);
  state_.lasers.resize(lasers_.size());
  state_.overloaded.assign(static_cast<std::size_t>(m), false);
  state_.last_move = Eigen::VectorXd::Zero(m);
  state_.pose = truth_.home;
  state_.rotation = rotation_from_rpy<double>(truth_.home.rpy);
}

Result<Physics> Physics::create(RobotModel truth, const Scenario& scenario, std::uint64_t seed,
                                const PhysicsOptions& options) {
  const int m = truth.num_cables();
  if (m < 1 || truth.platform_anchors.cols() != m || static_cast<int>(truth.pulleys.size()) != m ||
      static_cast<int>(truth.winches.size()) != m || static_cast<int>(truth.cables.size()) != m ||
      static_cast<int>(truth.force_sensors.size()) != m) {
    return Status(ErrorCode::kInvalidArgument, "sim physics: inconsistent true robot model sizes");
  }
  CDPR_RETURN_IF_ERROR(check_against(scenario, m));
  for (int i = 0; i < m; ++i) {
    if (truth.cables[static_cast<std::size_t>(i)].elongation == ElongationKind::kRigid) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "sim physics: cable %d of the true robot is rigid (resolve_truth gives "
                           "it a stiff Hooke law)",
                           i + 1);
    }
    if (truth.force_sensors[static_cast<std::size_t>(i)].gain == 0.0) {
      return Status::error(ErrorCode::kInvalidArgument, "sim physics: force sensor %d has gain 0",
                           i + 1);
    }
  }
  if (!(options.wrench_tolerance > 0.0) || options.max_iterations < 1) {
    return Status(ErrorCode::kInvalidArgument, "sim physics: bad options");
  }
  return Physics(std::move(truth), scenario, seed, options);
}

double Physics::unstretched_length(int i, double counts, double time_s) const {
  const auto k = static_cast<std::size_t>(i);
  const WinchModel& w = truth_.winches[k];
  const HiddenEffects& e = scenario_.effects;
  double slip = 0.0;  // drifts: the drum turned further than the encoder reports
  for (const Drift& d : scenario_.drifts) {
    if (d.kind == DriftKind::kEncoderSlip && d.cable == i) slip += d.counts * d.fraction_at(time_s);
  }
  double l = w.length_offset + e.encoder_zero_offset.at(i) +
             (1.0 + e.transmission_scale.at(i)) * winch_length_change<double>(w, counts + slip);
  if (e.thermal) {
    l += e.thermal->alpha * (truth_.cables[k].routing_length + l) * e.thermal->delta_at(time_s);
  }
  return l;
}

void Physics::apply_drifts(double time_s) {
  if (scenario_.drifts.empty()) return;
  truth_.frame_anchors = base_frame_anchors_;
  sensors_ = base_sensors_;
  for (const Drift& d : scenario_.drifts) {
    const double f = d.fraction_at(time_s);
    const auto k = static_cast<std::size_t>(d.cable);
    if (d.kind == DriftKind::kPulleyMove) {
      truth_.frame_anchors.col(d.cable) += f * d.by;
    } else if (d.kind == DriftKind::kForceSensor) {
      sensors_[k].gain *= 1.0 + f * d.gain;
      sensors_[k].offset += f * d.offset;
    }
  }
  work_.frame_anchors = truth_.frame_anchors;
}

void Physics::update_cable_laws(double time_s) {
  const auto& creep = scenario_.effects.creep;
  if (!creep) return;
  const double g = creep->coefficient * std::log1p(std::max(time_s, 0.0) / creep->tau_s);
  for (int i = 0; i < truth_.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    CableModel& c = work_.cables[k];
    if (c.elongation == ElongationKind::kHooke) {
      c.ea = 1.0 / (1.0 / truth_.cables[k].ea + g);
    } else if (c.elongation == ElongationKind::kPolynomial) {
      // F L = (ls s + lc)(ts t + tc) in the surface's scaled variables s, t.
      const PolynomialSurface& p = c.polynomial;
      const double ls = p.length_scale, lc = p.length_center;
      const double ts = p.tension_scale, tc = p.tension_center;
      std::vector<double>& co = c.polynomial.coefficients;
      const std::vector<double>& base = base_coefficients_[k];
      std::copy(base.begin(), base.end(), co.begin());
      co[term(0, 0)] += g * lc * tc;
      co[term(1, 0)] += g * ls * tc;
      co[term(1, 1)] += g * lc * ts;
      co[term(2, 1)] += g * ls * ts;
    }
  }
}

bool Physics::solve_newton(const Eigen::VectorXd& l, Eigen::Vector3d& r, Eigen::Matrix3d& R,
                           int& iters) {
  const Wrench zero = Wrench::Zero();
  Wrench w;
  Matrix6d K;
  if (!elastostatic_wrench(work_, r, R, l, zero, data_, w, &K)) return false;
  double cost = scaled_norm2(w, rho_);
  bool data_at_pose = true;
  for (iters = 0; iters < options_.max_iterations; ++iters) {
    if (scaled_max(w, rho_) <= options_.wrench_tolerance) {
      if (!data_at_pose) elastostatic_wrench(work_, r, R, l, zero, data_, w, nullptr);
      return true;
    }
    const Wrench dx = K.partialPivLu().solve(-w);
    if (!dx.allFinite()) return false;
    bool accepted = false;
    double alpha = 1.0;
    for (int ls = 0; ls < 12 && !accepted; ++ls, alpha *= 0.5) {
      const Eigen::Vector3d r_t = r + alpha * dx.head<3>();
      const Eigen::Matrix3d R_t = rotation_exp(alpha * dx.tail<3>()) * R;
      Wrench w_t;
      Matrix6d K_t;
      const bool ok = elastostatic_wrench(work_, r_t, R_t, l, zero, data_, w_t, &K_t);
      data_at_pose = false;
      if (ok && scaled_norm2(w_t, rho_) < cost) {
        r = r_t;
        R = R_t;
        w = w_t;
        K = K_t;
        cost = scaled_norm2(w, rho_);
        accepted = true;
        data_at_pose = true;
      }
    }
    if (!accepted) return false;
  }
  return false;
}

bool Physics::sag_wrench(const Eigen::VectorXd& l, const Eigen::Vector3d& r,
                         const Eigen::Matrix3d& R, Wrench& w, Eigen::VectorXd& tensions) {
  w.setZero();
  const int m = truth_.num_cables();
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const CableModel& c = work_.cables[k];
    const PulleyModel& pulley = truth_.pulleys[k];
    const Eigen::Vector3d rb = R * truth_.platform_anchors.col(i);
    const Eigen::Vector3d P = r + rb;
    const CableGeometry<double> g =
        cable_geometry<double>(truth_.frame_anchors.col(i), pulley.frame, pulley.radius, P);
    if (!g.valid) return false;
    const double wrap = g.length - g.free_length;  // arc on the pulley, m
    const double weight = c.mass_per_length * truth_.gravity;
    const Eigen::Vector3d d = g.exit_point - P;
    const double span = std::hypot(d.x(), d.y());
    const double unstretched_total = c.routing_length + l(i);
    double F = tensions(i);
    if (!(F > 0.0)) F = std::max(c.ea * (g.length - l(i)) / unstretched_total, 1e-3);
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    // phi(F): the frame-side tension of the free span when the routing and the pulley arc carry
    // F (Hooke) and take up their stretched share of the unstretched total. The tension is the
    // fixed point F = phi(F), found by the secant method on phi(F) - F (plain fixed-point
    // iteration contracts slowly for stiff cables and leaves noise in the wrench).
    bool bad = false;
    auto phi = [&](double f) {
      const double l0 = unstretched_total - (c.routing_length + wrap) * c.ea / (c.ea + f);
      if (!(l0 > 0.0)) {
        bad = true;
        return 0.0;
      }
      if (span >= 1e-9 && weight > 0.0) {
        const Result<CatenarySolution> s = solve_elastic_catenary(span, d.z(), l0, weight, c.ea);
        if (s.ok()) {
          const Eigen::Vector3d e_h(d.x() / span, d.y() / span, 0.0);
          force = s->horizontal_force * e_h + Eigen::Vector3d(0.0, 0.0, s->vertical_force_a);
          return s->tension_b;
        }
      }
      // Vertical span, weightless cable, or no catenary found (a very slack span): the straight
      // unilateral cable; a slack span's own weight (grams) is neglected.
      const double t = std::max(0.0, c.ea * (g.free_length - l0) / l0);
      force = t * g.unit;
      return t;
    };
    double f0 = F;
    double r0 = phi(f0) - f0;
    double f1 = std::max(0.0, f0 + r0);
    for (int it = 0; it < 50 && !bad; ++it) {
      const double r1 = phi(f1) - f1;
      if (std::abs(r1) <= 1e-11 * (1.0 + f1)) break;
      const double slope = (r1 - r0) / (f1 - f0);
      double f2 = (std::isfinite(slope) && slope != 0.0) ? f1 - r1 / slope : f1 + r1;
      if (!(f2 >= 0.0)) f2 = 0.5 * f1;
      f0 = f1;
      r0 = r1;
      f1 = f2;
    }
    if (bad) return false;
    F = phi(f1);  // also leaves `force` at the converged tension
    tensions(i) = F;
    w.head<3>() += force;
    w.tail<3>() += rb.cross(force);
  }
  const Eigen::Vector3d G(0.0, 0.0, -truth_.platform.mass * truth_.gravity);
  const Eigen::Vector3d cm = R * truth_.platform.center_of_mass;
  w.head<3>() += G;
  w.tail<3>() += cm.cross(G);
  return w.allFinite();
}

bool Physics::solve_sag(const Eigen::VectorXd& l, Eigen::Vector3d& r, Eigen::Matrix3d& R,
                        int& iters) {
  const double tolerance = std::max(options_.wrench_tolerance, 1e-6);
  Wrench w;
  if (!sag_wrench(l, r, R, w, sag_tensions_)) return false;
  double cost = scaled_norm2(w, rho_);
  for (iters = 0; iters < options_.max_iterations; ++iters) {
    if (scaled_max(w, rho_) <= tolerance) return true;
    Matrix6d J;
    for (int j = 0; j < 6; ++j) {
      const double h = j < 3 ? 1e-7 : 1e-7 / rho_;
      Wrench dx = Wrench::Zero();
      dx(j) = h;
      Wrench w_j;
      sag_trial_tensions_ = sag_tensions_;
      if (!sag_wrench(l, r + dx.head<3>(), rotation_exp(dx.tail<3>()) * R, w_j,
                      sag_trial_tensions_)) {
        return false;
      }
      J.col(j) = (w_j - w) / h;
    }
    const Wrench dx = J.partialPivLu().solve(-w);
    if (!dx.allFinite()) return false;
    bool accepted = false;
    double alpha = 1.0;
    for (int ls = 0; ls < 12 && !accepted; ++ls, alpha *= 0.5) {
      const Eigen::Vector3d r_t = r + alpha * dx.head<3>();
      const Eigen::Matrix3d R_t = rotation_exp(alpha * dx.tail<3>()) * R;
      Wrench w_t;
      sag_trial_tensions_ = sag_tensions_;
      if (sag_wrench(l, r_t, R_t, w_t, sag_trial_tensions_) && scaled_norm2(w_t, rho_) < cost) {
        r = r_t;
        R = R_t;
        w = w_t;
        sag_tensions_ = sag_trial_tensions_;
        cost = scaled_norm2(w, rho_);
        accepted = true;
      }
    }
    if (!accepted) {
      return scaled_max(w, rho_) <= 10.0 * tolerance;
    }
  }
  return false;
}

// Robust path for cables without their weight: the library solver from the previous pose, from
// the rigid FK of the commands, then from poses below the start (with exact commands every cable
// is slack at the rigid FK pose, and a platform hanging in slack cables gives the solver no
// stiffness to work with). Leaves the tensions in data_.
Status Physics::solve_weightless(Eigen::Vector3d& r, Eigen::Matrix3d& R, int& iters) {
  ElastostaticOptions eo;
  eo.wrench_tolerance = options_.wrench_tolerance;
  eo.max_iterations = std::max(options_.max_iterations, 100);
  std::vector<std::optional<Pose>> starts;
  if (have_pose_) starts.emplace_back(state_.pose);
  starts.emplace_back(std::nullopt);
  // Below the previous pose, and below the rigid FK of the new commands: after a long move
  // (extra poses appended to a recording) the previous pose is far from the new one.
  std::vector<Pose> bases;
  if (have_pose_) bases.push_back(state_.pose);
  ForwardKinematicsOptions fo;
  fo.max_residual = std::numeric_limits<double>::infinity();
  const ForwardKinematicsSummary fk = forward_kinematics(work_, lengths_, fo, data_.fk);
  if (fk.pose.vector().allFinite()) bases.push_back(fk.pose);
  if (bases.empty()) bases.push_back(state_.pose);
  for (const Pose& base : bases) {
    for (const double drop : {1e-5, 1e-4, 1e-3, 1e-2, 3e-2}) {
      Pose p = base;
      p.position.z() -= drop;
      starts.emplace_back(p);
    }
  }
  ElastostaticSummary s;
  for (const std::optional<Pose>& start : starts) {
    eo.initial_pose = start;
    s = solve_elastostatics(work_, lengths_, eo, data_);
    iters += s.iterations;
    if (s.success()) break;
  }
  if (!s.success()) {
    return s.status.ok() ? Status(ErrorCode::kNumericalFailure, "no elasto-static equilibrium")
                         : s.status;
  }
  r = s.pose.position;
  R = s.rotation;
  return Status::success();
}

Status Physics::step(const Eigen::Ref<const Eigen::VectorXd>& counts, double time_s) {
  const int m = truth_.num_cables();
  if (counts.size() != m || !counts.allFinite()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "sim physics: %d finite counts expected (one per cable), got %d", m,
                         static_cast<int>(counts.size()));
  }
  if (!std::isfinite(time_s) || (state_.steps > 0 && time_s < state_.time_s)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "sim physics: time %.9g s goes backwards (last step at %.9g s)", time_s,
                         state_.time_s);
  }
  update_cable_laws(time_s);
  apply_drifts(time_s);
  // Direction of the last move (hysteresis, pulley friction): kept while the counts stand still.
  Eigen::VectorXd last_move = state_.last_move;
  if (state_.steps > 0) {
    for (int i = 0; i < m; ++i) {
      const double change = winch_length_change<double>(truth_.winches[static_cast<std::size_t>(i)],
                                                        counts(i) - state_.counts(i));
      if (change != 0.0) last_move(i) = change > 0.0 ? 1.0 : -1.0;
    }
  }
  for (int i = 0; i < m; ++i) {
    lengths_(i) = unstretched_length(i, counts(i), time_s) +
                  scenario_.effects.cable_hysteresis.at(i) * last_move(i);
  }

  Eigen::Vector3d r = state_.pose.position;
  Eigen::Matrix3d R = state_.rotation;
  bool ok = false;
  int iters = 0;
  if (have_pose_ && !scenario_.effects.sag) ok = solve_newton(lengths_, r, R, iters);
  if (!ok && (!scenario_.effects.sag || !have_pose_)) {
    const Status st = solve_weightless(r, R, iters);
    ok = st.ok();
    if (!ok && !scenario_.effects.sag) {
      state_.converged = false;
      return Status::error(ErrorCode::kNumericalFailure, "sim physics at t = %.6g s: %.*s", time_s,
                           static_cast<int>(st.message().size()), st.message().data());
    }
  }
  Eigen::VectorXd tensions = data_.tensions;
  if (scenario_.effects.sag) {
    if (!have_pose_) sag_tensions_ = data_.tensions;
    int sag_iters = 0;
    ok = solve_sag(lengths_, r, R, sag_iters);
    iters += sag_iters;
    if (!ok && have_pose_) {
      // From the previous pose the sag solver can stall (on a long move some cables go nearly
      // slack on the way and the line search finds no descent): again from the equilibrium of
      // the cables without their weight.
      r = state_.pose.position;
      R = state_.rotation;
      if (solve_weightless(r, R, iters).ok()) {
        sag_tensions_ = data_.tensions;
        ok = solve_sag(lengths_, r, R, sag_iters);
        iters += sag_iters;
      }
    }
    if (!ok) {
      state_.converged = false;
      return Status::error(ErrorCode::kNumericalFailure,
                           "sim physics at t = %.6g s: no equilibrium with sagging cables", time_s);
    }
    tensions = sag_tensions_;
  }

  have_pose_ = true;
  state_.time_s = time_s;
  state_.counts = counts;
  state_.last_move = last_move;
  state_.unstretched_lengths = lengths_;
  state_.pose = Pose{r, rpy_from_rotation(R)};
  state_.rotation = R;
  state_.tensions = tensions;
  state_.iterations = iters;
  state_.converged = true;
  ++state_.steps;

  // Sensors, in a fixed order: encoders, force sensors, lasers.
  const SensorNoiseLevels& noise = scenario_.noise;
  for (int i = 0; i < m; ++i) {
    state_.encoder_counts(i) = std::round(counts(i) + noise.encoder_counts * normal_(rng_));
  }
  for (int i = 0; i < m; ++i) {
    state_.force_raw(i) =
        force_sensor_raw<double>(
            sensors_[static_cast<std::size_t>(i)],
            tensions(i) + scenario_.effects.pulley_friction.at(i) * last_move(i)) +
        noise.force_raw * normal_(rng_);
  }
  for (std::size_t k = 0; k < lasers_.size(); ++k) {
    state_.lasers[k] = sample_laser(static_cast<int>(k));
  }
  // Cable overload faults (latched: the drive trips and stays in FAULT).
  for (const Fault& f : scenario_.faults) {
    if (f.kind == FaultKind::kCableOverload && time_s >= f.at_s && f.active_at(time_s) &&
        tensions(f.cable) > f.tension_limit) {
      state_.overloaded[static_cast<std::size_t>(f.cable)] = true;
    }
  }
  return Status::success();
}

LaserChannel Physics::laser_at(int laser, const Eigen::Vector3d& position,
                               const Eigen::Matrix3d& rotation) const {
  const LaserModel& l = lasers_[static_cast<std::size_t>(laser)];
  LaserChannel c;
  const Eigen::Vector3d o = position + rotation * l.origin;
  const Eigen::Vector3d d = rotation * l.direction;
  const double denom = l.plane_normal.dot(d);
  if (std::abs(denom) < 1e-12) return c;
  const double t = l.plane_normal.dot(l.plane_point - o) / denom;
  if (!(t > 0.0)) return c;
  c.true_distance = t;
  c.status = (t < l.range_min || t > l.range_max) ? LaserStatus::kOutOfRange : LaserStatus::kOk;
  return c;
}

LaserChannel Physics::sample_laser(int laser) {
  LaserChannel c = laser_at(laser, state_.pose.position, state_.rotation);
  const double n = scenario_.noise.laser * normal_(rng_);  // drawn even when unused
  if (c.status == LaserStatus::kOk) {
    c.reading = c.true_distance + n;
    const LaserModel& l = lasers_[static_cast<std::size_t>(laser)];
    if (c.reading < l.range_min || c.reading > l.range_max) {
      c.status = LaserStatus::kOutOfRange;
      c.reading = kNaN;
    }
  }
  return c;
}

// ---------------------------------------------------------------------------------------------

Result<Eigen::VectorXd> nominal_counts(const RobotModel& nominal, const Pose& pose,
                                       double reference_tension) {
  const double f_ref =
      std::isnan(reference_tension) ? default_reference_tension(nominal) : reference_tension;
  Result<Eigen::VectorXd> f = simple_tension_distribution(nominal, pose, f_ref);
  if (!f.ok()) return f.status();
  CableCommandData data(nominal);
  if (!inverse_kinematics_compensated(nominal, pose, *f, data)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "nominal inverse kinematics: cable %d is degenerate at the pose",
                         data.kinematics.invalid_cable + 1);
  }
  return Eigen::VectorXd(data.counts);
}

double home_reference_tension(const RobotModel& nominal, double margin) {
  CommandData data(nominal);
  if (!command_counts(nominal, nominal.home, default_reference_tension(nominal), data, margin)
           .ok()) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  return data.plan.reference;
}

Result<Eigen::VectorXd> true_pose_counts(const Physics& physics, const Pose& pose,
                                         double reference_tension) {
  const RobotModel& truth = physics.truth();
  const double f_ref =
      std::isnan(reference_tension) ? default_reference_tension(truth) : reference_tension;
  Result<Eigen::VectorXd> f = simple_tension_distribution(truth, pose, f_ref);
  if (!f.ok()) return f.status();
  Result<Eigen::VectorXd> u = unstretched_lengths(truth, pose, *f);
  if (!u.ok()) return u.status();
  const HiddenEffects& e = physics.scenario().effects;
  Eigen::VectorXd counts(truth.num_cables());
  for (int i = 0; i < truth.num_cables(); ++i) {
    const WinchModel& w = truth.winches[static_cast<std::size_t>(i)];
    // unstretched_length(i, c, 0) = length_offset + o_i + (1 + s_i) * change(c) (no thermal
    // drift at t = 0), solved for c.
    const double change = ((*u)(i)-w.length_offset - e.encoder_zero_offset.at(i)) /
                          (1.0 + e.transmission_scale.at(i));
    counts(i) = winch_counts_change<double>(w, change);
  }
  return counts;
}

Result<std::vector<LockstepSample>> run_lockstep(Physics& physics, const RobotModel& nominal,
                                                 std::span<const Pose> poses,
                                                 const LockstepOptions& options) {
  const int m = nominal.num_cables();
  if (m != physics.truth().num_cables()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "lock-step: the nominal robot has %d cables, the true one %d", m,
                         physics.truth().num_cables());
  }
  if (options.substeps < 1 || options.laser_samples < 1 || !(options.dwell_s > 0.0)) {
    return Status(ErrorCode::kInvalidArgument,
                  "lock-step: substeps and laser_samples must be >= 1, dwell > 0");
  }
  std::vector<LockstepSample> out;
  out.reserve(poses.size());
  Eigen::VectorXd previous;
  if (physics.state().steps > 0) previous = physics.state().counts;
  const int k = static_cast<int>(physics.true_lasers().size());
  std::mt19937_64 channel_rng(options.channel_seed);
  std::normal_distribution<double> channel_normal(0.0, 1.0);
  auto channel_noise = [&](double sigma) {
    return sigma > 0.0 ? sigma * channel_normal(channel_rng) : 0.0;
  };
  auto wrap = [](double x) { return std::atan2(std::sin(x), std::cos(x)); };
  for (std::size_t j = 0; j < poses.size(); ++j) {
    Result<Eigen::VectorXd> target = nominal_counts(nominal, poses[j], options.reference_tension);
    if (!target.ok()) {
      Status s = target.status();
      return Status::error(s.code(), "lock-step pose %d: %.*s", static_cast<int>(j),
                           static_cast<int>(s.message().size()), s.message().data());
    }
    const Eigen::VectorXd goal = target->array().round().matrix();  // drives take integers
    if (previous.size() != m) previous = goal;
    const double t0 = options.start_time_s + static_cast<double>(j) * options.dwell_s;
    for (int s = 1; s <= options.substeps; ++s) {
      const double a = static_cast<double>(s) / options.substeps;
      const Eigen::VectorXd c = previous + a * (goal - previous);
      const Status st = physics.step(c, t0 + a * options.dwell_s);
      if (!st.ok()) {
        return Status::error(st.code(), "lock-step pose %d: %.*s", static_cast<int>(j),
                             static_cast<int>(st.message().size()), st.message().data());
      }
    }
    previous = goal;
    const PhysicsState& state = physics.state();
    LockstepSample sample;
    sample.commanded = poses[j];
    sample.time_s = state.time_s;
    sample.counts = goal;
    sample.lengths.resize(m);
    sample.tensions.resize(m);
    for (int i = 0; i < m; ++i) {
      const auto ki = static_cast<std::size_t>(i);
      sample.lengths(i) =
          winch_counts_to_length<double>(nominal.winches[ki], state.encoder_counts(i));
      sample.tensions(i) =
          force_sensor_tension<double>(nominal.force_sensors[ki], state.force_raw(i));
    }
    sample.lasers = Eigen::VectorXd::Constant(k, kNaN);
    for (int q = 0; q < k; ++q) {
      double sum = 0.0;
      int used = 0;
      LaserChannel c = state.lasers[static_cast<std::size_t>(q)];
      for (int n = 0; n < options.laser_samples; ++n) {
        if (n > 0) c = physics.sample_laser(q);
        if (c.status == LaserStatus::kOk) {
          sum += c.reading;
          ++used;
        }
      }
      if (used > 0) sample.lasers(q) = sum / used;
      sample.laser_status.push_back(c.status);
    }
    const RobotModel& truth = physics.truth();
    if (options.swivel) {
      sample.swivels.resize(m);
      for (int i = 0; i < m; ++i) {
        const double g = swivel_reading(truth, i, state.pose);
        sample.swivels(i) = std::isnan(g) ? g : wrap(g + channel_noise(options.sigma_swivel));
      }
    }
    if (options.inclinometer) {
      const Eigen::Vector2d rp = inclinometer_reading(truth, state.pose);
      for (int q = 0; q < 2; ++q) {
        sample.inclination(q) = wrap(rp(q) + channel_noise(options.sigma_inclination));
      }
    }
    if (options.imu_yaw) {
      sample.imu_yaw =
          wrap(imu_yaw_reading(truth, state.pose) + channel_noise(options.sigma_imu_yaw));
    }
    sample.true_pose = state.pose;
    sample.true_tensions = state.tensions;
    sample.converged = state.converged;
    out.push_back(std::move(sample));
  }
  return out;
}

}  // namespace cdpr::sim
