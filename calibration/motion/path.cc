#include "cdpr/calibration/path.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <string>

#include "cdpr/calibration/kinematics.hpp"

namespace cdpr {

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;
constexpr double kArcRadiusTolerance = 1e-4;  // m: the end of an arc off its circle
constexpr int kBoundSamples = 32;             // per piece, for the derivative bounds
constexpr double kBoundSafety = 1.01;

// Value and sigma-derivatives of a piece at tau.
struct PieceState {
  Eigen::Vector3d p, p1, p2, p3;  // position and its sigma-derivatives
  Eigen::Matrix3d R;              // rotation
  Eigen::Vector3d omega;          // world angular rate per sigma (rad/m)
  double r1 = 0, r2 = 0, r3 = 0;  // norms of the rotation's sigma-derivatives (bounds)
};

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d K;
  K << 0.0, -v(2), v(1), v(2), 0.0, -v(0), -v(1), v(0), 0.0;
  return K;
}

// Right Jacobian of SO(3): body angular velocity = J_r(q) dq/dt for R = exp(q).
Eigen::Matrix3d right_jacobian(const Eigen::Vector3d& q) {
  const double t2 = q.squaredNorm();
  double b, c;  // (1 - cos t) / t^2, (t - sin t) / t^3
  if (t2 < 1e-8) {
    b = 0.5 - t2 / 24.0;
    c = 1.0 / 6.0 - t2 / 120.0;
  } else {
    const double t = std::sqrt(t2);
    b = (1.0 - std::cos(t)) / t2;
    c = (t - std::sin(t)) / (t2 * t);
  }
  const Eigen::Matrix3d K = skew(q);
  return Eigen::Matrix3d::Identity() - b * K + c * (K * K);
}

void evaluate(const Path::Piece& pc, double tau, PieceState& st, bool derivatives) {
  const double len = pc.len;
  switch (pc.kind) {
    case Path::Piece::Kind::kLine:
    case Path::Piece::Kind::kArc: {
      const double u = len > 0.0 ? tau / len : 0.0;
      if (pc.kind == Path::Piece::Kind::kLine) {
        st.p = pc.p0 + u * pc.d;
        st.p1 = pc.d / len;
        st.p2.setZero();
        st.p3.setZero();
      } else {
        const double a = pc.phi * u, ca = std::cos(a), sa = std::sin(a);
        st.p = pc.c + pc.r * (ca * pc.e1 + sa * pc.e2) + u * pc.h * pc.n;
        const double f = pc.phi / len;
        st.p1 = pc.r * f * (-sa * pc.e1 + ca * pc.e2) + (pc.h / len) * pc.n;
        if (derivatives) {
          st.p2 = -pc.r * f * f * (ca * pc.e1 + sa * pc.e2);
          st.p3 = pc.r * f * f * f * (sa * pc.e1 - ca * pc.e2);
        }
      }
      st.R = pc.R0 * rotation_exp(u * pc.w);
      st.omega = pc.R0 * pc.w / len;
      st.r1 = pc.w.norm() / len;
      st.r2 = st.r3 = 0.0;
      return;
    }
    case Path::Piece::Kind::kCubic: {
      const Eigen::Vector4d b0(1.0, tau, tau * tau, tau * tau * tau);
      const Eigen::Matrix<double, 6, 1> y = pc.cubic * b0;
      st.p = y.head<3>();
      st.R = pc.R0 * rotation_exp(y.tail<3>());
      const Eigen::Vector4d b1(0.0, 1.0, 2.0 * tau, 3.0 * tau * tau);
      const Eigen::Matrix<double, 6, 1> y1 = pc.cubic * b1;
      st.p1 = y1.head<3>();
      st.omega = st.R * (right_jacobian(y.tail<3>()) * y1.tail<3>());
      if (derivatives) {
        const Eigen::Matrix<double, 6, 1> y2 = pc.cubic * Eigen::Vector4d(0.0, 0.0, 2.0, 6.0 * tau);
        const Eigen::Matrix<double, 6, 1> y3 = pc.cubic * Eigen::Vector4d(0.0, 0.0, 0.0, 6.0);
        st.p2 = y2.head<3>();
        st.p3 = y3.head<3>();
        st.r1 = y1.tail<3>().norm();
        st.r2 = y2.tail<3>().norm();
        st.r3 = y3.tail<3>().norm();
      }
      return;
    }
  }
}

double unwrap_near(double x, double ref) {
  return x + kTwoPi * std::round((ref - x) / kTwoPi);
}

Eigen::Vector3d rpy_near(const Eigen::Matrix3d& R, const Eigen::Vector3d& ref) {
  Eigen::Vector3d rpy = rpy_from_rotation(R);
  rpy(0) = unwrap_near(rpy(0), ref(0));
  rpy(2) = unwrap_near(rpy(2), ref(2));
  return rpy;
}

bool finite_pose(const Pose& p) {
  return p.position.allFinite() && p.rpy.allFinite();
}

}  // namespace

// Builds the pieces, motions and time line of a Path.
struct PathBuilder {
  Path& path;
  const PathLimits& limits;
  const RobotModel* model;
  std::string_view source;
  double rho = 1.0;  // m per rad
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d rpy = Eigen::Vector3d::Zero();
  std::vector<double> dwell_before{};  // per piece: dwell before it (s)
  std::vector<bool> stop_before{};     // per piece: a dwell (even of 0 s) before it: a stop
  std::vector<double> feed{};          // per piece, m/s (NaN: none)
  double end_dwell = 0.0;
  bool pending_break = false;
  double pending_dwell = 0.0;
  int spline_count = 0;

  Status fail(const PathSegment& s, int index, const char* what) const {
    if (s.line > 0) {
      return Status::error(ErrorCode::kInvalidArgument, "%.*s:%d: %s",
                           static_cast<int>(source.size()), source.data(), s.line, what);
    }
    return Status::error(ErrorCode::kInvalidArgument, "%.*s: segment %d: %s",
                         static_cast<int>(source.size()), source.data(), index + 1, what);
  }

  void add(Path::Piece pc, double piece_feed) {
    pc.s0 = path.sigma_total_;
    pc.rpy0 = rpy;
    path.sigma_total_ += pc.len;
    PieceState st;
    evaluate(pc, pc.len, st, false);
    position = st.p;
    rotation = st.R;
    rpy = rpy_near(st.R, rpy);
    path.pieces_.push_back(pc);
    dwell_before.push_back(pending_dwell);
    stop_before.push_back(pending_break);
    feed.push_back(piece_feed);
    pending_dwell = 0.0;
    pending_break = false;
  }

  // Line or arc: the geodesic rotation to `target`; len from the length L.
  void add_geodesic(Path::Piece pc, double length, const Pose& target, double piece_feed) {
    const Eigen::Matrix3d Rt = rotation_from_rpy<double>(target.rpy);
    pc.R0 = rotation;
    pc.w = rotation_log(rotation.transpose() * Rt);
    pc.len = std::max(length, rho * pc.w.norm());
    if (pc.len <= 0.0) return;  // no motion
    add(pc, piece_feed);
  }

  Status line(const PathSegment& s) {
    Path::Piece pc;
    pc.kind = Path::Piece::Kind::kLine;
    pc.p0 = position;
    pc.d = s.target.position - position;
    pc.line = s.line;
    add_geodesic(pc, pc.d.norm(), s.target, s.feed);
    return Status::success();
  }

  Status arc(const PathSegment& s, int index) {
    if (!s.center.allFinite() || !s.axis.allFinite() || s.axis.norm() == 0.0) {
      return fail(s, index, "arc: the centre and the axis must be finite, the axis not zero");
    }
    Path::Piece pc;
    pc.kind = Path::Piece::Kind::kArc;
    pc.line = s.line;
    pc.n = s.axis.normalized();
    const Eigen::Vector3d rel = position - s.center;
    pc.c = s.center + rel.dot(pc.n) * pc.n;
    const Eigen::Vector3d radial = position - pc.c;
    pc.r = radial.norm();
    if (pc.r < kArcRadiusTolerance) return fail(s, index, "arc: the start is on the arc's axis");
    pc.e1 = radial / pc.r;
    pc.e2 = pc.n.cross(pc.e1);
    const Eigen::Vector3d v = s.target.position - pc.c;
    pc.h = v.dot(pc.n);
    const Eigen::Vector3d vp = v - pc.h * pc.n;
    if (std::abs(vp.norm() - pc.r) > kArcRadiusTolerance) {
      char buf[160];
      std::snprintf(buf, sizeof buf,
                    "arc: the end is %.4f m from the axis, the start %.4f m (more than %.1f mm "
                    "apart)",
                    vp.norm(), pc.r, kArcRadiusTolerance * 1e3);
      return fail(s, index, buf);
    }
    pc.phi = std::atan2(vp.dot(pc.e2), vp.dot(pc.e1));
    if (pc.phi <= 1e-9) pc.phi += kTwoPi;  // counter-clockwise; the start itself: a full circle
    add_geodesic(pc, std::hypot(pc.r * pc.phi, pc.h), s.target, s.feed);
    return Status::success();
  }

  // The natural cubic spline from the current pose through segments[first, last].
  Status spline(std::span<const PathSegment> segs, int first, int last) {
    const int n = last - first + 1;  // intervals
    std::vector<Eigen::Matrix<double, 6, 1>> y(static_cast<std::size_t>(n + 1));
    const Eigen::Matrix3d Rref = rotation;
    y[0] << position, Eigen::Vector3d::Zero();
    std::vector<double> h(static_cast<std::size_t>(n));
    for (int k = 1; k <= n; ++k) {
      const PathSegment& s = segs[static_cast<std::size_t>(first + k - 1)];
      const Eigen::Vector3d q =
          rotation_log(Rref.transpose() * rotation_from_rpy<double>(s.target.rpy));
      if (q.norm() > 0.99 * std::numbers::pi) {
        return fail(s, first + k - 1, "spline: a waypoint turns nearly pi or more from the first");
      }
      y[static_cast<std::size_t>(k)] << s.target.position, q;
      const auto dy = y[static_ckey(k)] - y[static_ckey(k - 1)];
      h[static_ckey(k - 1)] = std::max(dy.head<3>().norm(), rho * dy.tail<3>().norm());
      if (!(h[static_ckey(k - 1)] > 1e-9)) {
        return fail(s, first + k - 1, "spline: the waypoint equals the one before");
      }
    }
    // Second derivatives M (natural: M_0 = M_n = 0) by the Thomas algorithm.
    std::vector<Eigen::Matrix<double, 6, 1>> M(static_cast<std::size_t>(n + 1),
                                               Eigen::Matrix<double, 6, 1>::Zero());
    std::vector<double> cp(static_cast<std::size_t>(n + 1), 0.0);
    std::vector<Eigen::Matrix<double, 6, 1>> dp(static_cast<std::size_t>(n + 1),
                                                Eigen::Matrix<double, 6, 1>::Zero());
    for (int i = 1; i < n; ++i) {
      const double a = h[static_ckey(i - 1)], c = h[static_ckey(i)];
      const double b = 2.0 * (a + c) - a * cp[static_ckey(i - 1)];
      const Eigen::Matrix<double, 6, 1> r =
          6.0 * ((y[static_ckey(i + 1)] - y[static_ckey(i)]) / c -
                 (y[static_ckey(i)] - y[static_ckey(i - 1)]) / a) -
          a * dp[static_ckey(i - 1)];
      cp[static_ckey(i)] = c / b;
      dp[static_ckey(i)] = r / b;
    }
    for (int i = n - 1; i >= 1; --i) {
      M[static_ckey(i)] = dp[static_ckey(i)] - cp[static_ckey(i)] * M[static_ckey(i + 1)];
    }
    const int id = spline_count++;
    for (int k = 0; k < n; ++k) {
      const PathSegment& s = segs[static_cast<std::size_t>(first + k)];
      const double hk = h[static_ckey(k)];
      const auto& Mk = M[static_ckey(k)];
      const auto& Mk1 = M[static_ckey(k + 1)];
      Path::Piece pc;
      pc.kind = Path::Piece::Kind::kCubic;
      pc.line = s.line;
      pc.spline = id;
      pc.R0 = Rref;
      pc.len = hk;
      pc.cubic.col(0) = y[static_ckey(k)];
      pc.cubic.col(1) =
          (y[static_ckey(k + 1)] - y[static_ckey(k)]) / hk - hk * (2.0 * Mk + Mk1) / 6.0;
      pc.cubic.col(2) = Mk / 2.0;
      pc.cubic.col(3) = (Mk1 - Mk) / (6.0 * hk);
      add(pc, s.feed);
    }
    return Status::success();
  }

  static std::size_t static_ckey(int i) { return static_cast<std::size_t>(i); }

  // Whether pieces a and b join without a stop (C2 in position, continuous angular rate with no
  // jump of its derivative).
  static bool joins(const Path::Piece& a, const Path::Piece& b) {
    if (a.kind == Path::Piece::Kind::kCubic || b.kind == Path::Piece::Kind::kCubic) {
      return a.spline >= 0 && a.spline == b.spline;
    }
    PieceState ea, sb;
    evaluate(a, a.len, ea, true);
    evaluate(b, 0.0, sb, true);
    const double scale2 = 1.0 + std::max(ea.p2.norm(), sb.p2.norm());
    return (ea.p1 - sb.p1).norm() < 1e-7 && (ea.p2 - sb.p2).norm() < 1e-6 * scale2 &&
           (ea.omega - sb.omega).norm() < 1e-7 * (1.0 + ea.omega.norm());
  }

  // Derivative bounds and the double-S profile of one motion.
  Status time_motion(PathMotion& m, double& t) {
    double c1 = 0, c2 = 0, c3 = 0, r1 = 0, r2 = 0, r3 = 0, cable = 0;
    double feed_cap = std::numeric_limits<double>::infinity();
    const bool cables = std::isfinite(limits.max_cable_velocity);
    std::optional<KinematicsData> k0, k1;
    if (cables) {
      k0.emplace(*model);
      k1.emplace(*model);
    }
    for (int i = m.first_piece; i <= m.last_piece; ++i) {
      const Path::Piece& pc = path.pieces_[static_cast<std::size_t>(i)];
      if (std::isfinite(feed[static_cast<std::size_t>(i)])) {
        feed_cap = std::min(feed_cap, feed[static_cast<std::size_t>(i)]);
      }
      for (int k = 0; k <= kBoundSamples; ++k) {
        const double tau = pc.len * k / kBoundSamples;
        PieceState st;
        evaluate(pc, tau, st, true);
        c1 = std::max(c1, st.p1.norm());
        c2 = std::max(c2, st.p2.norm());
        c3 = std::max(c3, st.p3.norm());
        r1 = std::max({r1, st.r1, st.omega.norm()});
        r2 = std::max(r2, st.r2);
        r3 = std::max(r3, st.r3);
        if (!cables) continue;
        const double dt = 1e-6 * pc.len * (k == kBoundSamples ? -1.0 : 1.0);
        PieceState s2;
        evaluate(pc, tau + dt, s2, false);
        if (!inverse_kinematics(*model, st.p, st.R, *k0) ||
            !inverse_kinematics(*model, s2.p, s2.R, *k1)) {
          return Status::error(ErrorCode::kNumericalFailure,
                               "%.*s:%d: a cable is degenerate along the path",
                               static_cast<int>(source.size()), source.data(), pc.line);
        }
        cable = std::max(cable, ((k1->lengths - k0->lengths) / dt).cwiseAbs().maxCoeff());
      }
    }
    // Lines and arcs have constant derivative norms (exact bounds); samples of a spline's may
    // miss its largest by a little.
    bool sampled = false;
    for (int i = m.first_piece; i <= m.last_piece; ++i) {
      sampled |= path.pieces_[static_cast<std::size_t>(i)].kind == Path::Piece::Kind::kCubic;
    }
    if (sampled) {
      c1 *= kBoundSafety, c2 *= kBoundSafety, c3 *= kBoundSafety;
      r1 *= kBoundSafety, r2 *= kBoundSafety, r3 *= kBoundSafety;
    }
    const MotionLimits& L = limits.motion;
    const bool curved = c2 > 1e-12 || c3 > 1e-12 || r2 > 1e-12 || r3 > 1e-12;
    const double fa = curved ? 0.5 : 1.0, fj = curved ? 1.0 / 3.0 : 1.0;
    double v = std::numeric_limits<double>::infinity(), a = v, j = v;
    auto bound = [&](double b1, double b2, double b3, double V, double A, double J) {
      if (b1 > 0.0) {
        v = std::min(v, V / b1);
        a = std::min(a, fa * A / b1);
        j = std::min(j, fj * J / b1);
      }
      if (b2 > 1e-12) v = std::min(v, std::sqrt(A / (2.0 * b2)));
      if (b3 > 1e-12) v = std::min(v, std::cbrt(J / (3.0 * b3)));
    };
    bound(c1, c2, c3, L.max_linear_velocity, L.max_linear_acceleration, L.max_linear_jerk);
    bound(r1, r2, r3, L.max_angular_velocity, L.max_angular_acceleration, L.max_angular_jerk);
    if (c2 > 1e-12) v = std::min(v, L.max_linear_jerk / (9.0 * c2 * a));
    if (r2 > 1e-12) v = std::min(v, L.max_angular_jerk / (9.0 * r2 * a));
    if (c1 > 0.0) v = std::min(v, feed_cap / c1);
    if (cable > 0.0) v = std::min(v, limits.max_cable_velocity / (kBoundSafety * cable));
    m.max_linear_rate = c1;
    m.max_angular_rate = r1;
    auto profile = DoubleSProfile::plan(m.sigma_end - m.sigma_begin, v, a, j);
    if (!profile.ok()) return profile.status();
    m.profile = *profile;
    m.t_begin = t;
    t += m.profile.duration();
    return Status::success();
  }

  void hold(double& t, double sigma, double seconds) {
    if (!(seconds > 0.0)) return;
    path.times_.push_back(t);
    path.entry_motion_.push_back(-1);
    path.hold_sigma_.push_back(sigma);
    t += seconds;
  }

  Status time_line() {
    double t = 0.0;
    const int n = static_cast<int>(path.pieces_.size());
    int first = 0;
    for (int i = 1; i <= n; ++i) {
      const bool split = i == n || stop_before[static_cast<std::size_t>(i)] ||
                         !joins(path.pieces_[static_cast<std::size_t>(i - 1)],
                                path.pieces_[static_cast<std::size_t>(i)]);
      if (!split) continue;
      PathMotion m;
      m.first_piece = first;
      m.last_piece = i - 1;
      m.sigma_begin = path.pieces_[static_cast<std::size_t>(first)].s0;
      m.sigma_end = i == n ? path.sigma_total_ : path.pieces_[static_cast<std::size_t>(i)].s0;
      hold(t, m.sigma_begin, dwell_before[static_cast<std::size_t>(first)]);
      if (Status s = time_motion(m, t); !s.ok()) return s;
      path.times_.push_back(m.t_begin);
      path.entry_motion_.push_back(static_cast<int>(path.motions_.size()));
      path.hold_sigma_.push_back(m.sigma_begin);
      path.motions_.push_back(m);
      first = i;
    }
    hold(t, path.sigma_total_, end_dwell + (n == 0 ? pending_dwell : 0.0));
    path.duration_ = t;
    return Status::success();
  }
};

Result<Path> Path::plan(const Pose& start, std::span<const PathSegment> segments,
                        const PathLimits& limits, const RobotModel* model,
                        std::string_view source) {
  if (Status s = limits.motion.validate(); !s.ok()) return s.prepend("path: ");
  if (!(limits.max_cable_velocity > 0.0)) {
    return Status(ErrorCode::kInvalidArgument, "path: max_cable_velocity must be > 0");
  }
  if (std::isfinite(limits.max_cable_velocity) && model == nullptr) {
    return Status(ErrorCode::kInvalidArgument, "path: a cable speed limit needs the robot model");
  }
  if (!finite_pose(start)) return Status(ErrorCode::kInvalidArgument, "path: start not finite");
  Path path;
  path.start_ = start;
  PathBuilder b{path, limits, model, source};
  b.rho = limits.motion.max_linear_velocity / limits.motion.max_angular_velocity;
  b.position = start.position;
  b.rotation = rotation_from_rpy<double>(start.rpy);
  b.rpy = start.rpy;
  const int n = static_cast<int>(segments.size());
  for (int i = 0; i < n; ++i) {
    const PathSegment& s = segments[static_cast<std::size_t>(i)];
    if (!finite_pose(s.target)) return b.fail(s, i, "the target pose is not finite");
    if (!(std::isnan(s.feed) || (std::isfinite(s.feed) && s.feed > 0.0))) {
      return b.fail(s, i, "the feed must be finite and > 0");
    }
    switch (s.kind) {
      case PathSegment::Kind::kLine:
        if (Status st = b.line(s); !st.ok()) return st;
        break;
      case PathSegment::Kind::kArc:
        if (Status st = b.arc(s, i); !st.ok()) return st;
        break;
      case PathSegment::Kind::kSpline: {
        int last = i;
        while (last + 1 < n &&
               segments[static_cast<std::size_t>(last + 1)].kind == PathSegment::Kind::kSpline) {
          ++last;
          const PathSegment& w = segments[static_cast<std::size_t>(last)];
          if (!finite_pose(w.target)) return b.fail(w, last, "the target pose is not finite");
          if (!(std::isnan(w.feed) || (std::isfinite(w.feed) && w.feed > 0.0))) {
            return b.fail(w, last, "the feed must be finite and > 0");
          }
        }
        if (Status st = b.spline(segments, i, last); !st.ok()) return st;
        i = last;
        break;
      }
      case PathSegment::Kind::kDwell:
        if (!(std::isfinite(s.dwell) && s.dwell >= 0.0)) {
          return b.fail(s, i, "the dwell must be finite and >= 0 s");
        }
        b.pending_dwell += s.dwell;
        b.pending_break = true;
        break;
    }
  }
  b.end_dwell = path.pieces_.empty() ? 0.0 : b.pending_dwell;
  path.piece_begin_.reserve(path.pieces_.size());
  for (const Piece& pc : path.pieces_) path.piece_begin_.push_back(pc.s0);
  if (Status s = b.time_line(); !s.ok()) return s;
  path.end_ = Pose{b.position, b.rpy};
  return path;
}

double Path::sigma_at(double t) const noexcept {
  if (times_.empty() || t <= 0.0) return 0.0;
  if (t >= duration_) return sigma_total_;
  const auto it = std::upper_bound(times_.begin(), times_.end(), t);
  const std::size_t i =
      static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, it - times_.begin() - 1));
  const int m = entry_motion_[i];
  if (m < 0) return hold_sigma_[i];
  const PathMotion& mo = motions_[static_cast<std::size_t>(m)];
  return std::min(mo.sigma_begin + mo.profile.sample(t - times_[i]).s, mo.sigma_end);
}

int Path::line_at(double sigma) const noexcept {
  if (pieces_.empty()) return 0;
  const auto it = std::upper_bound(piece_begin_.begin(), piece_begin_.end(), sigma);
  const std::size_t k =
      static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, it - piece_begin_.begin() - 1));
  return pieces_[k].line;
}

void Path::path_point(double sigma, Eigen::Vector3d& position, Eigen::Matrix3d& rotation,
                      Eigen::Vector3d* tangent) const noexcept {
  if (pieces_.empty()) {
    position = start_.position;
    rotation = rotation_from_rpy<double>(start_.rpy);
    if (tangent != nullptr) tangent->setZero();
    return;
  }
  sigma = std::clamp(sigma, 0.0, sigma_total_);
  const auto it = std::upper_bound(piece_begin_.begin(), piece_begin_.end(), sigma);
  const std::size_t k =
      static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, it - piece_begin_.begin() - 1));
  const Piece& pc = pieces_[k];
  PieceState st;
  evaluate(pc, std::clamp(sigma - pc.s0, 0.0, pc.len), st, false);
  position = st.p;
  rotation = st.R;
  if (tangent != nullptr) {
    const double n = st.p1.norm();
    *tangent = n > 1e-12 ? Eigen::Vector3d(st.p1 / n) : Eigen::Vector3d::Zero();
  }
}

void Path::sample(double t, Pose& pose, TaskVelocity* velocity) const noexcept {
  if (velocity != nullptr) *velocity = TaskVelocity{};
  if (pieces_.empty() || t <= 0.0) {
    pose = start_;
    return;
  }
  if (t >= duration_) {
    pose = end_;
    return;
  }
  double sigma = 0.0, rate = 0.0;
  const auto it = std::upper_bound(times_.begin(), times_.end(), t);
  const std::size_t i =
      static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, it - times_.begin() - 1));
  const int m = entry_motion_[i];
  if (m < 0) {
    sigma = hold_sigma_[i];
  } else {
    const PathMotion& mo = motions_[static_cast<std::size_t>(m)];
    const DoubleSProfile::Sample s = mo.profile.sample(t - times_[i]);
    sigma = std::min(mo.sigma_begin + s.s, mo.sigma_end);
    rate = s.ds;
  }
  const auto pit = std::upper_bound(piece_begin_.begin(), piece_begin_.end(), sigma);
  const std::size_t k =
      static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, pit - piece_begin_.begin() - 1));
  const Piece& pc = pieces_[k];
  PieceState st;
  evaluate(pc, std::clamp(sigma - pc.s0, 0.0, pc.len), st, velocity != nullptr);
  pose.position = st.p;
  pose.rpy = rpy_near(st.R, pc.rpy0);
  if (velocity != nullptr) {
    velocity->linear = st.p1 * rate;
    velocity->angular = st.omega * rate;
  }
}

}  // namespace cdpr
