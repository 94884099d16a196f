// The sag of heavy cables as a candidate's columns at a given mass per length (sag_effect,
// mismatch.hpp): the exact elastic catenary of each free span at its tension reading.
#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <optional>

#include "cdpr/calibration/catenary.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/mismatch.hpp"
#include "mismatch_internal.hpp"

namespace cdpr {
namespace {

// The catenary of a free span (platform anchor at the origin, exit point at (span, height)) whose
// tension at the exit point is T: its unstretched length by the secant method (the tension falls
// as it grows), started from the straight cable plus the small-sag arc. nullopt: no solution.
struct SpanSolution : CatenarySolution {
  double unstretched_length = 0.0;
};

std::optional<SpanSolution> catenary_for_tension(double span, double height, double chord, double w,
                                                 double ea, double T) {
  auto tension_at = [&](double l0, CatenarySolution* sol) {
    auto r = solve_elastic_catenary(span, height, l0, w, ea);
    if (!r.ok()) return std::numeric_limits<double>::quiet_NaN();
    if (sol != nullptr) *sol = *r;
    return r->tension_b - T;
  };
  const double arc = sag_arc_minus_chord(w, span, chord, T) * ea / (ea + T);
  double x0 = chord * ea / (ea + T) + arc, x1 = x0 + 1e-3 * arc + 1e-12 * x0;
  double f0 = tension_at(x0, nullptr), f1 = tension_at(x1, nullptr);
  SpanSolution out;
  for (int it = 0; it < 40 && std::isfinite(f0) && std::isfinite(f1); ++it) {
    bool done = std::abs(f1) <= 1e-10 * (1.0 + T);
    if (!done) {
      if (f1 == f0) return std::nullopt;
      double x2 = x1 - f1 * (x1 - x0) / (f1 - f0);
      if (!(x2 > 0.0)) x2 = 0.5 * x1;
      // Converged in L0 (a stiff cable: the tension cannot be matched closer in double).
      done = std::abs(x2 - x1) <= 1e-14 * x1;
      x0 = x1;
      f0 = f1;
      x1 = x2;
      f1 = done ? 0.0 : tension_at(x1, nullptr);
    }
    if (done) {
      if (!std::isfinite(tension_at(x1, &out))) return std::nullopt;
      out.unstretched_length = x1;
      return out;
    }
  }
  return std::nullopt;
}

}  // namespace

Result<CandidateColumns> sag_effect(const CalibratedModel& model, const MeasurementSet& set,
                                    const std::vector<Pose>& poses, const MismatchDesign& d,
                                    const IdentificationOptions& options, double mass_per_length,
                                    Eigen::VectorXd* compliance) {
  const RobotModel& robot = model.robot;
  const int m = robot.num_cables();
  const int np = d.num_poses();
  if (static_cast<int>(poses.size()) != np || set.num_poses() != np ||
      d.sigma_length.size() != d.num_rows()) {
    return Status(ErrorCode::kInvalidArgument, "sag effect: poses, recording and design differ");
  }
  CandidateColumns out;
  out.id = "sag_shared";
  out.family = std::string(find_effect(out.id)->family);
  out.X = Eigen::MatrixXd::Zero(d.num_rows(), 1);
  out.si = Eigen::MatrixXd::Zero(d.num_rows(), 1);
  if (compliance != nullptr) *compliance = Eigen::VectorXd::Zero(d.num_rows());
  if (!(mass_per_length > 0.0)) return out;
  const double w = mass_per_length * robot.gravity;
  const double slack = slack_threshold(options, set.noise);
  const double sf2 = set.noise.sigma_force * set.noise.sigma_force;
  const double sl2 = set.noise.sigma_length * set.noise.sigma_length;
  KinematicsData kin(robot);
  for (int j = 0; j < np; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    if (pm.tensions.size() != m || !inverse_kinematics(robot, poses[uj], kin)) continue;
    std::vector<int> length_row(static_cast<std::size_t>(m), -1);
    int kw = -1;
    for (int k = d.pose_start[uj]; k < d.pose_start[uj + 1]; ++k) {
      const auto uk = static_cast<std::size_t>(k);
      if (d.kind[uk] == ResidualKind::kLength)
        length_row[static_cast<std::size_t>(d.index[uk])] = k;
      if (d.kind[uk] == ResidualKind::kWrench && kw < 0) kw = k;
    }
    Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
    for (int i = 0; i < m; ++i) {
      const auto ui = static_cast<std::size_t>(i);
      const Eigen::Vector3d u = kin.unit_vectors.col(i);
      const Eigen::Vector3d rb = kin.platform_points.col(i) - poses[uj].position;
      Eigen::Matrix<double, 6, 1> a;
      a << u, rb.cross(u);
      const int kl = length_row[ui];
      const double s2 = kl >= 0 ? d.sigma_length(kl) * d.sigma_length(kl) : sl2;
      cov += sf2 * (sl2 / s2) * a * a.transpose();
      const double T = pm.tensions(i);
      if (!(T >= slack) || !std::isfinite(T)) continue;
      const double free = kin.free_lengths(i);
      const Eigen::Vector3d chord = free * u;  // platform anchor -> exit point
      const double span = std::hypot(chord.x(), chord.y());
      if (!(span > 1e-6) || !(free > 0.0)) continue;
      const CableModel& c = robot.cables[ui];
      // A rigid model cable: stiff enough that the stretch is negligible, not so stiff that the
      // catenary's tension cannot be resolved in double precision.
      const double ea = c.elongation == ElongationKind::kRigid || !(c.ea > 0.0) ? 1e8 : c.ea;
      const double l_straight = free * ea / (ea + T);
      const std::optional<SpanSolution> sol = catenary_for_tension(span, chord.z(), free, w, ea, T);
      if (!sol) continue;
      const double x1 = sol->unstretched_length;
      if (kl >= 0) {
        out.si(kl, 0) = l_straight - x1;
        out.X(kl, 0) = (l_straight - x1) / d.sigma_length(kl);
        if (compliance != nullptr) {
          // d(effect)/dT: how the tension noise reaches the corrected length residual.
          const double dt = 1e-4 * T + 1e-6;
          const std::optional<SpanSolution> up =
              catenary_for_tension(span, chord.z(), free, w, ea, T + dt);
          if (up) {
            const double l2 = free * ea / (ea + T + dt);
            (*compliance)(kl) = ((l2 - up->unstretched_length) - (l_straight - x1)) / dt;
          }
        }
      }
      // The sagging cable pulls the platform with (H e_h, V_a) (catenary.hpp: end A); the model
      // has T u. The residual (model - truth) of the net wrench gets T u - F.
      const Eigen::Vector3d e_h(chord.x() / span, chord.y() / span, 0.0);
      const Eigen::Vector3d f =
          sol->horizontal_force * e_h + sol->vertical_force_a * Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d v = T * u - f;
      delta.head<3>() += v;
      delta.tail<3>() += rb.cross(v);
    }
    if (kw >= 0) mismatch_detail::put_wrench_effect(cov, delta, kw, 0, out);
  }
  return out;
}

}  // namespace cdpr
