// Multi-segment task-space paths for applications: straight lines, circular (or helical) arcs and
// C2 splines through waypoints, with the orientation interpolated on SO(3), timed jerk-limited
// along the path. Pure math: Path::plan runs outside the RT loop (it allocates and validates);
// Path::sample is allocation-free and noexcept, so the RT cycle can call it every period.
//
// Geometry. The path is a chain of pieces over one path parameter sigma (metres of "path
// length"). A piece k spans sigma in [s_k, s_k + len_k]; with tau = sigma - s_k, u = tau / len_k:
//   line:   p = p0 + u d                         R = R0 exp(u w)    (w = log(R0^T R1), geodesic)
//   arc:    p = c + r cos(phi u) e1 + r sin(phi u) e2 + u h n       R = R0 exp(u w)
//           (centre c, axis n, e2 = n x e1, swept angle phi > 0 counter-clockwise about n, helix
//           rise h along n; phi = 2 pi when the end is the start: a full circle)
//   spline: p = a + b tau + c tau^2 + d tau^3   R = R_ref exp(q(tau)), q a cubic in tau too
//           (the natural cubic spline through the waypoints' positions and rotation vectors
//           q_i = log(R_ref^T R_i), R_ref the first waypoint's rotation, knots at the chord
//           lengths: C2 in sigma at the interior waypoints; the waypoints must stay within pi of
//           R_ref)
// len_k = max(L_k, rho theta_k) (L_k the piece's length, theta_k its rotation angle, rho =
// v_lin / v_ang): sigma advances at least as fast as the position moves and as rho times the
// rotation.
//
// Timing. Consecutive pieces whose position, its first two sigma-derivatives and the angular
// rate per sigma agree (C2: collinear lines, arcs continuing on the same circle, the interior
// knots of a spline) form one motion; at any other junction (a corner, a curvature jump) and at
// a dwell the platform stops, because passing a jump of the path's acceleration at speed would
// need infinite jerk. Each motion is one rest-to-rest double-S profile sigma(t) (trajectory.hpp)
// whose limits v, a, j on sigma bound, with c1, c2, c3 the largest |dp/dsigma|, |d2p/dsigma2|,
// |d3p/dsigma3| over the motion (constant on lines and arcs; sampled at plan time and +1 % on
// splines):
//   |p'| = |p_s| v <= c1 v,  |p''| <= c2 v^2 + c1 a,  |p'''| <= c3 v^3 + 3 c2 v a + c1 j
// (time derivatives of p(sigma(t))). With curvature (c2 or c3 > 0) a and j get half and a third of
// the limit and v is also bounded so that c2 v^2 <= a_lim / 2, c3 v^3 <= j_lim / 3,
// 3 c2 v a <= j_lim / 3; on straight motions the whole limit goes to a and j, which makes a line
// exactly PoseTrajectory's time-optimal profile. The same bounds with the angular limits hold for
// the rotation: exactly for lines and arcs (a fixed rotation axis), and for splines on the
// derivatives of the rotation vector q (|omega| <= |q'| exactly; the higher orders to first
// order). The feed F of a piece caps v at F / c1; the cable speed limit caps v at
// v_cable / max |dl_i/dsigma| (finite differences of the model's inverse kinematics at the same
// samples).
#pragma once

#include <Eigen/Core>
#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/calibration/trajectory.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

// One instruction of a path (what a path file's line says, path_file.hpp).
struct PathSegment {
  enum class Kind {
    kLine,    // straight to `target`
    kArc,     // about `center` and `axis` (counter-clockwise, right-handed) to `target`
    kSpline,  // waypoint `target`; consecutive kSpline segments form one spline
    kDwell,   // hold for `dwell` seconds
  };
  Kind kind = Kind::kLine;
  Pose target;                                       // end pose (world, m and rad)
  Eigen::Vector3d center = Eigen::Vector3d::Zero();  // kArc: a point of the arc's axis, m
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();   // kArc: the axis (need not be unit)
  // Largest linear speed on this segment, m/s; NaN: only the limits.
  double feed = std::numeric_limits<double>::quiet_NaN();
  double dwell = 0.0;  // kDwell: s, >= 0
  int line = 0;        // where it came from (a path file's line), for messages; 0: none
};

struct PathLimits {
  MotionLimits motion;  // task-space limits (Euclidean norms)
  // Largest speed of any cable's length, m/s; infinity: none (needs the model in Path::plan).
  double max_cable_velocity = std::numeric_limits<double>::infinity();
};

// One motion of a path: rest to rest over sigma in [sigma_begin, sigma_end].
struct PathMotion {
  double sigma_begin = 0.0, sigma_end = 0.0;
  double t_begin = 0.0;  // s, when it starts
  DoubleSProfile profile;
  // Bounds over the motion: largest |dp/dsigma| and angular rate per sigma (rad per m).
  double max_linear_rate = 0.0, max_angular_rate = 0.0;
  int first_piece = 0, last_piece = 0;  // pieces it covers
};

class Path {
 public:
  // Plans the path from `start` through `segments`. kInvalidArgument naming the segment (its
  // `line` when > 0, `source` in front) for a non-finite pose or feed, an arc whose end is not on
  // its circle (more than 0.1 mm off its radius) or whose axis is zero or in the plane of its
  // start, a spline through two equal waypoints, a negative dwell, invalid limits, or a cable
  // speed limit without a model. `model` (optional) is used only for the cable speed limit.
  static Result<Path> plan(const Pose& start, std::span<const PathSegment> segments,
                           const PathLimits& limits, const RobotModel* model = nullptr,
                           std::string_view source = "path");

  double duration() const { return duration_; }
  double length() const { return sigma_total_; }  // sigma at the end
  const Pose& start() const { return start_; }
  const Pose& end() const { return end_; }
  std::span<const PathMotion> motions() const { return motions_; }
  int pieces() const { return static_cast<int>(pieces_.size()); }
  // The path file line of the piece at sigma (0 when none was given).
  int line_at(double sigma) const noexcept;

  // Pose (and optionally twist) at time t; t <= 0 gives `start()`, t >= duration() `end()`.
  // The rpy comes from the interpolated rotation with roll and yaw unwrapped near each piece's
  // start (continuous while a piece turns less than pi in roll and yaw). Allocation-free,
  // noexcept.
  void sample(double t, Pose& pose, TaskVelocity* velocity = nullptr) const noexcept;
  // The path parameter at time t (clamped).
  double sigma_at(double t) const noexcept;
  // The geometric path at sigma (clamped to [0, length()]): position, rotation and the unit
  // tangent of the position (zero where the position does not move). Allocation-free.
  void path_point(double sigma, Eigen::Vector3d& position, Eigen::Matrix3d& rotation,
                  Eigen::Vector3d* tangent = nullptr) const noexcept;

  // Internal: one piece of the geometry (see the file comment).
  struct Piece {
    enum class Kind { kLine, kArc, kCubic } kind = Kind::kLine;
    double s0 = 0.0, len = 0.0;
    Eigen::Vector3d p0 = Eigen::Vector3d::Zero(), d = Eigen::Vector3d::Zero();  // line
    Eigen::Vector3d c = Eigen::Vector3d::Zero(), e1 = Eigen::Vector3d::Zero(),
                    e2 = Eigen::Vector3d::Zero(), n = Eigen::Vector3d::Zero();  // arc
    double r = 0.0, phi = 0.0, h = 0.0;                                         // arc
    Eigen::Matrix<double, 6, 4> cubic = Eigen::Matrix<double, 6, 4>::Zero();    // spline: p; q
    Eigen::Matrix3d R0 = Eigen::Matrix3d::Identity();  // start rotation, or R_ref of a spline
    Eigen::Vector3d w = Eigen::Vector3d::Zero();       // geodesic rotation vector (line, arc)
    Eigen::Vector3d rpy0 = Eigen::Vector3d::Zero();    // rpy at the start, unwrapped
    int spline = -1;                                   // spline id (cubic pieces)
    int line = 0;
  };

 private:
  Pose start_, end_;
  std::vector<Piece> pieces_;
  std::vector<double> piece_begin_;  // s0 of each piece (for the search)
  std::vector<PathMotion> motions_;
  // Time line: entry i starts at times_[i]; motion index or -1 for a hold at hold_sigma_[i].
  std::vector<double> times_;
  std::vector<int> entry_motion_;
  std::vector<double> hold_sigma_;
  double duration_ = 0.0;
  double sigma_total_ = 0.0;

  friend struct PathBuilder;
};

}  // namespace cdpr
