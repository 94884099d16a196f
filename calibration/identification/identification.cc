// The identification problem (Ceres) and its report. All autodiff cost functors live in this
// translation unit (compiles slowly; keep them together).
#include "cdpr/calibration/identification.hpp"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <set>
#include <span>
#include <sstream>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/identifiability.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "identification_costs.hpp"
#include "identification_internal.hpp"

namespace cdpr {

double slack_threshold(const IdentificationOptions& options, const SensorNoise& noise) {
  return std::max(options.slack_tension_threshold,
                  options.slack_tension_sigmas * noise.sigma_force);
}

AnchorMask paper_anchor_mask() {
  AnchorMask mask = AnchorMask::Constant(3, 8, false);
  for (int c = 1; c <= 6; ++c) {  // x2..x7, y2..y7 (0-based 1..6)
    mask(0, c) = true;
    mask(1, c) = true;
  }
  for (int c = 4; c <= 7; ++c) mask(2, c) = true;  // z5..z8
  return mask;
}

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

using ident_detail::CableConstants;
using ident_detail::elongation_at;
using ident_detail::EquilibriumCost;
using ident_detail::pose_from_block;
using ident_detail::true_tension;

// Two unit vectors orthogonal to unit d (a tangent basis of the sphere at d).
void tangent_basis(const Eigen::Vector3d& d, Eigen::Vector3d& e1, Eigen::Vector3d& e2) {
  const Eigen::Vector3d helper =
      std::abs(d.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  e1 = d.cross(helper).normalized();
  e2 = d.cross(e1).normalized();
}

// Unstretched length U = L_k - dL at pose; false when the geometry is degenerate. With
// `compliance` non-null also d(dL)/dF there (m/N; 0 without a tension reading).
template <typename T>
bool unstretched_length(const CableConstants& k, const T* a, const T* b, const T* pose,
                        double tension_reading, const T& e, const T& g, const T& c, T& U,
                        Vec3<T>* unit = nullptr, Vec3<T>* arm = nullptr, T* force = nullptr,
                        T* compliance = nullptr) {
  Vec3<T> r;
  Mat3<T> R;
  pose_from_block(pose, r, R);
  const Vec3<T> rb = R * Vec3<T>(b[0], b[1], b[2]);
  const Vec3<T> P = r + rb;
  const CableGeometry<T> geom =
      cable_geometry<T>(Vec3<T>(a[0], a[1], a[2]), k.pulley_frame, T(k.pulley_radius), P);
  if (!geom.valid) return false;
  U = geom.length;
  if (compliance) *compliance = T(0);
  if (!std::isnan(tension_reading)) {
    U -= elongation_at<T>(k, geom.length, tension_reading, e, g, c, force, compliance);
  } else if (force) {
    *force = T(0);
  }
  if (unit) *unit = geom.unit;
  if (arm) *arm = rb;
  return true;
}

// Cable length residual. Blocks: a(3), b(3), pose(6), o(1), s(1), e(1), g(1), c(1).
// Its sigma combines the encoder noise and the force noise through the cable compliance at the
// CURRENT geometry and tension, sqrt(sigma_length^2 + (d(dL)/dF sigma_force)^2), so that, like the
// equilibrium residual, the objective does not depend on where the solver started.
struct LengthCost {
  const CableConstants* k = nullptr;  // Built::constants (shared: 100,000 poses, 8 cables each)
  double reading = 0.0;
  double tension = kNaN;
  double sigma_length = 1.0;
  double sigma_force = 0.0;       // 0: the force noise is not propagated
  double extra_compliance = 0.0;  // PoseMeasurement::extra_compliance, m/N
  template <typename T>
  bool operator()(const T* a, const T* b, const T* pose, const T* o, const T* s, const T* e,
                  const T* g, const T* c, T* residual) const {
    T U;
    T compliance;
    if (!unstretched_length<T>(*k, a, b, pose, tension, e[0], g[0], c[0], U, nullptr, nullptr,
                               nullptr, &compliance)) {
      return false;
    }
    const T force_part = (compliance + T(extra_compliance)) * T(sigma_force);
    const T sigma = sqrt(T(sigma_length * sigma_length) + force_part * force_part);
    residual[0] = (U - ((T(1) + s[0]) * T(reading) + o[0])) / sigma;
    return true;
  }
};

// Laser residual. Blocks: pose(6), origin(3), direction angles(2), normal angles(2), c(1).
struct LaserCost {
  Eigen::Vector3d d0, de1, de2;  // platform frame
  Eigen::Vector3d n0, ne1, ne2;  // world
  double reading = 0.0;
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* pose, const T* origin, const T* dir, const T* normal, const T* c,
                  T* residual) const {
    Vec3<T> r;
    Mat3<T> R;
    pose_from_block(pose, r, R);
    Vec3<T> d = d0.cast<T>() + de1.cast<T>() * dir[0] + de2.cast<T>() * dir[1];
    d = d / sqrt(d.squaredNorm());
    Vec3<T> n = n0.cast<T>() + ne1.cast<T>() * normal[0] + ne2.cast<T>() * normal[1];
    n = n / sqrt(n.squaredNorm());
    const Vec3<T> p = r + R * Vec3<T>(origin[0], origin[1], origin[2]);
    const Vec3<T> dw = R * d;
    const T den = n.dot(dw);
    if (!(abs(den) > T(1e-9))) return false;
    const T t = (c[0] - n.dot(p)) / den;
    residual[0] = (t - T(reading)) / T(sigma);
    return true;
  }
};

struct ReferenceCost {
  Eigen::Matrix<double, 6, 1> reference;
  Eigen::Matrix<double, 6, 1> inv_sigma;
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    for (int q = 0; q < 6; ++q) residual[q] = (pose[q] - T(reference(q))) * T(inv_sigma(q));
    return true;
  }
};

// Angle difference wrapped to (-pi, pi]; the derivative is exactly 1 (atan2(sin, cos)).
template <typename T>
T wrap_angle(const T& x) {
  using std::atan2;
  using std::cos;
  using std::sin;
  return atan2(sin(x), cos(x));
}

// Swivel-angle residual (issue 18). Blocks: a(3), b(3), pose(6), zero(1).
//   r = wrap(direction (gamma - zero) - reading) / sigma,  gamma = atan2(v_y, v_x),
//   v = Rp^T (r + R b - a)   (the swivel angle of kinematics.hpp, pulley frame Rp of the model)
struct SwivelCost {
  Eigen::Matrix3d pulley_frame = Eigen::Matrix3d::Identity();
  int direction = 1;
  double reading = 0.0;
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* a, const T* b, const T* pose, const T* zero, T* residual) const {
    Vec3<T> r;
    Mat3<T> R;
    pose_from_block(pose, r, R);
    const Vec3<T> P = r + R * Vec3<T>(b[0], b[1], b[2]);
    const Vec3<T> v = pulley_frame.transpose().cast<T>() * (P - Vec3<T>(a[0], a[1], a[2]));
    // On the swivel axis the angle is undefined.
    if (!(v(0) * v(0) + v(1) * v(1) > T(1e-18))) return false;
    const T gamma = atan2(v(1), v(0));
    residual[0] =
        wrap_angle<T>(T(static_cast<double>(direction)) * (gamma - zero[0]) - T(reading)) /
        T(sigma);
    return true;
  }
};

// Orientation of the inclinometer / IMU frame: R(pose) R_m0 rotation_from_rpy(d0, d1, 0).
template <typename T>
Mat3<T> sensor_rotation(const T* pose, const Eigen::Matrix3d& mount0, const T* d) {
  return rotation_from_rpy<T>(pose[3], pose[4], pose[5]) * mount0.cast<T>() *
         rotation_from_rpy<T>(d[0], d[1], T(0));
}

// Inclinometer residuals (issue 18), 2 per pose. Blocks: pose(6), mounting correction(2).
struct InclinometerCost {
  Eigen::Matrix3d mount0 = Eigen::Matrix3d::Identity();
  Eigen::Vector2d reading = Eigen::Vector2d::Zero();
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* pose, const T* mount, T* residual) const {
    using std::sqrt;
    const Mat3<T> Rs = sensor_rotation<T>(pose, mount0, mount);
    const T c = sqrt(Rs(2, 1) * Rs(2, 1) + Rs(2, 2) * Rs(2, 2));
    if (!(c > T(1e-9))) return false;  // sensor x axis vertical: roll undefined
    const T roll = atan2(Rs(2, 1), Rs(2, 2));
    const T pitch = atan2(-Rs(2, 0), c);
    residual[0] = wrap_angle<T>(roll - T(reading(0))) / T(sigma);
    residual[1] = wrap_angle<T>(pitch - T(reading(1))) / T(sigma);
    return true;
  }
};

// IMU heading residual (issue 18). Blocks: pose(6), mounting correction(2), yaw zero(1).
struct ImuYawCost {
  Eigen::Matrix3d mount0 = Eigen::Matrix3d::Identity();
  double reading = 0.0;
  double sigma = 1.0;
  template <typename T>
  bool operator()(const T* pose, const T* mount, const T* yaw_zero, T* residual) const {
    const Mat3<T> Rs = sensor_rotation<T>(pose, mount0, mount);
    if (!(Rs(0, 0) * Rs(0, 0) + Rs(1, 0) * Rs(1, 0) > T(1e-18))) return false;
    const T yaw = atan2(Rs(1, 0), Rs(0, 0));
    residual[0] = wrap_angle<T>(yaw - yaw_zero[0] - T(reading)) / T(sigma);
    return true;
  }
};

enum class Channel { kLength, kLaser, kWrench, kReference, kSwivel, kInclination, kImuYaw };

struct RowInfo {
  Channel channel;
  int index;  // cable, laser or wrench component
};

struct LaserBlocks {
  std::array<double, 3> origin{};
  std::array<double, 2> direction{};
  std::array<double, 2> normal{};
  double c = 0.0;
  Eigen::Vector3d d0, de1, de2, n0, ne1, ne2;
};

// The Ceres problem with its parameter storage and layout.
struct Built {
  ceres::Problem problem;
  int m = 0;
  std::vector<std::array<double, 3>> a, b;
  std::vector<double> o, s, e, g, c;
  std::vector<LaserBlocks> lasers;
  std::vector<double> swivel_zero;     // zero_i, rad (issue 18)
  bool swivel_zero_free = false;       // some zero_i is estimated
  std::array<double, 2> incl_mount{};  // mounting correction (roll, pitch), rad
  Eigen::Matrix3d incl_mount0 = Eigen::Matrix3d::Identity();
  bool incl_mount_free = false;
  double imu_yaw_zero = 0.0;  // rad
  bool imu_yaw_zero_free = false;
  double mass = 1.0;            // platform mass, kg
  std::array<double, 3> com{};  // platform centre of mass, platform frame, m
  bool mass_free = false, com_free = false;
  std::vector<std::array<double, 6>> poses;
  std::vector<bool> pose_free;
  std::vector<CableConstants> constants;

  std::vector<double*> geometry_blocks;  // free geometry blocks, column order
  std::vector<int> geometry_sizes;       // tangent size of each
  std::vector<ParameterId> ids;
  std::vector<std::string> names, units;  // names: parameter_name(ids[q])
  std::vector<double*> value_ptr;         // ambient value of each geometry column
  std::vector<double> lower, upper;  // physical range of each geometry column (ParameterBounds)
  Eigen::Matrix3Xi anchor_columns;
  int num_geometry = 0;

  std::vector<std::vector<ceres::ResidualBlockId>> blocks_per_pose;
  std::vector<std::vector<RowInfo>> rows_per_pose;
  // The equilibrium functor of each pose (owned by its cost function; nullptr when none).
  std::vector<const EquilibriumCost*> equilibrium;
  std::vector<std::vector<double*>> equilibrium_blocks;  // its parameter blocks
  std::vector<std::string> notes;                        // warnings found while building
  int num_residuals = 0;
  bool shared_stiffness = false;
  bool home_tilt_free = false;  // suspended gauge: home roll and pitch are geometry columns
  // Suspended gauge held at a commanded pose (IdentificationOptions::home_at_commanded): the
  // calibrated home hangs at the config's home position and heading, not at the held pose.
  std::optional<Pose> hang_home_at;
};

// A geometry block of `size` coordinates; `half_range` bounds each free coordinate to its
// starting value +- half_range (infinity: unbounded), or, with `absolute`, to [lo, hi] given in
// `absolute` (lo, hi pairs per coordinate).
struct BlockRange {
  double half_range = std::numeric_limits<double>::infinity();
  bool absolute = false;
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
};

void add_geometry_block(Built& B, double* ptr, int size, const std::vector<bool>& estimated,
                        const std::vector<ParameterId>& ids, const std::string& unit, bool any_free,
                        const BlockRange& range) {
  B.problem.AddParameterBlock(ptr, size);
  std::vector<int> fixed;
  for (int q = 0; q < size; ++q) {
    if (!any_free || !estimated[static_cast<std::size_t>(q)]) fixed.push_back(q);
  }
  if (static_cast<int>(fixed.size()) == size) {
    B.problem.SetParameterBlockConstant(ptr);
    return;
  }
  if (!fixed.empty()) B.problem.SetManifold(ptr, new ceres::SubsetManifold(size, fixed));
  B.geometry_blocks.push_back(ptr);
  B.geometry_sizes.push_back(size - static_cast<int>(fixed.size()));
  for (int q = 0; q < size; ++q) {
    if (std::find(fixed.begin(), fixed.end(), q) != fixed.end()) continue;
    B.ids.push_back(ids[static_cast<std::size_t>(q)]);
    B.names.push_back(parameter_name(ids[static_cast<std::size_t>(q)]));
    B.units.push_back(unit);
    B.value_ptr.push_back(ptr + q);
    const double lo = range.absolute ? range.lo : ptr[q] - range.half_range;
    const double hi = range.absolute ? range.hi : ptr[q] + range.half_range;
    B.lower.push_back(lo);
    B.upper.push_back(hi);
    if (std::isfinite(lo)) B.problem.SetParameterLowerBound(ptr, q, lo);
    if (std::isfinite(hi)) B.problem.SetParameterUpperBound(ptr, q, hi);
  }
}

// The platform mass and centre of mass blocks: free when estimated and some pose has every
// tension measured (the equilibrium rows that see the weight).
void add_platform_weight_blocks(Built& B, const RobotModel& robot, const MeasurementSet& set,
                                const IdentificationOptions& opt) {
  bool weighed = false;
  for (const PoseMeasurement& pm : set.poses) {
    weighed = weighed || (pm.tensions.size() == robot.num_cables() && pm.tensions.allFinite());
  }
  weighed = weighed && opt.use_equilibrium;
  const ParameterBounds& bounds = opt.bounds;
  B.mass = robot.platform.mass;
  B.mass_free = opt.estimate_platform_mass && weighed;
  BlockRange mr;
  mr.absolute = true;
  mr.lo = bounds.mass_factor_min * robot.platform.mass;
  mr.hi = bounds.mass_factor_max * robot.platform.mass;
  add_geometry_block(B, &B.mass, 1, {true}, {ParameterId{ParameterKind::kPlatformMass, -1, -1}},
                     "kg", B.mass_free, mr);
  for (int q = 0; q < 3; ++q) B.com[static_cast<std::size_t>(q)] = robot.platform.center_of_mass(q);
  B.com_free = opt.estimate_platform_com && weighed;
  const BlockRange cr{robot.platform_radius()};
  using K = ParameterKind;
  add_geometry_block(B, B.com.data(), 3, {true, true, true},
                     {{K::kPlatformCom, -1, 0}, {K::kPlatformCom, -1, 1}, {K::kPlatformCom, -1, 2}},
                     "m", B.com_free, cr);
}

Status check_mask(const AnchorMask& mask, int m, const char* what) {
  if (mask.size() != 0 && mask.cols() != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "identification options: %s mask has %d columns, the robot has %d cables",
                         what, static_cast<int>(mask.cols()), m);
  }
  return Status::success();
}

// Builds the problem with values from `model` and pose guesses `poses`.
Result<std::unique_ptr<Built>> build(const CalibratedModel& model, const MeasurementSet& set,
                                     const std::vector<Pose>& poses,
                                     const IdentificationOptions& opt) {
  const RobotModel& robot = model.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  const int n = set.num_poses();
  CDPR_RETURN_IF_ERROR(validate(set, robot));
  if (m < 1) return Status(ErrorCode::kInvalidArgument, "identification: the robot has no cables");
  if (static_cast<int>(robot.pulleys.size()) != m || static_cast<int>(robot.cables.size()) != m ||
      static_cast<int>(robot.force_sensors.size()) != m || robot.platform_anchors.cols() != m ||
      static_cast<int>(robot.winches.size()) != m) {
    return Status(ErrorCode::kInvalidArgument,
                  "identification: the robot model's per-cable vectors do not all have m entries");
  }
  if (model.readings.length_offsets.size() != m || model.readings.length_scales.size() != m) {
    return Status(ErrorCode::kInvalidArgument,
                  "identification: the reading model needs one offset and one scale per cable");
  }
  CDPR_RETURN_IF_ERROR(check_mask(opt.frame_anchor_mask, m, "frame anchor"));
  CDPR_RETURN_IF_ERROR(check_mask(opt.platform_anchor_mask, m, "platform anchor"));
  if (static_cast<int>(poses.size()) != n) {
    return Status(ErrorCode::kInternal, "identification: pose guesses do not match the set");
  }
  const bool fix_home = opt.gauge == Gauge::kHomePose || opt.gauge == Gauge::kHomePoseAndLaserPlane;
  const bool fix_plane =
      opt.gauge == Gauge::kLaserPlane || opt.gauge == Gauge::kHomePoseAndLaserPlane;
  if (fix_home && (opt.home_pose_index < 0 || opt.home_pose_index >= n)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "identification: home_pose_index %d is not one of the %d poses",
                         opt.home_pose_index, n);
  }
  if (n == 0) return Status(ErrorCode::kInvalidArgument, "identification: no poses measured");

  auto B = std::make_unique<Built>();
  B->m = m;
  B->a.resize(static_cast<std::size_t>(m));
  B->b.resize(static_cast<std::size_t>(m));
  B->o.assign(static_cast<std::size_t>(m), 0.0);
  B->s.assign(static_cast<std::size_t>(m), 0.0);
  B->e.assign(static_cast<std::size_t>(m), 0.0);
  B->g.assign(static_cast<std::size_t>(m), 0.0);
  B->c.assign(static_cast<std::size_t>(m), 0.0);
  B->anchor_columns = Eigen::Matrix3Xi::Constant(3, m, -1);
  const bool ea_estimated = opt.estimate_stiffness != StiffnessEstimate::kFixed;
  B->shared_stiffness = opt.estimate_stiffness == StiffnessEstimate::kShared;
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    for (int q = 0; q < 3; ++q) {
      B->a[ui][static_cast<std::size_t>(q)] = robot.frame_anchors(q, i);
      B->b[ui][static_cast<std::size_t>(q)] = robot.platform_anchors(q, i);
    }
    B->o[ui] = model.readings.length_offsets(i);
    B->s[ui] = model.readings.length_scales(i);
    CableConstants k;
    k.pulley_frame = robot.pulleys[ui].frame;
    k.pulley_radius = robot.pulleys[ui].radius;
    k.cable = robot.cables[ui];
    k.sensor_gain = robot.force_sensors[ui].gain;
    k.sensor_offset = robot.force_sensors[ui].offset;
    k.estimated_stiffness = ea_estimated;
    B->constants.push_back(k);
  }
  // Geometry blocks in a fixed order: a, b, o, s, e, g, c, lasers, each free coordinate bounded
  // to its physical range (ParameterBounds).
  const ParameterBounds& bounds = opt.bounds;
  for (int i = 0; i < m; ++i) {
    std::vector<bool> est(3);
    std::vector<ParameterId> nm(3);
    for (int q = 0; q < 3; ++q) {
      est[static_cast<std::size_t>(q)] =
          opt.frame_anchor_mask.size() == 0 ? true : opt.frame_anchor_mask(q, i);
      nm[static_cast<std::size_t>(q)] = {ParameterKind::kFrameAnchor, i, q};
    }
    const int before = static_cast<int>(B->names.size());
    add_geometry_block(*B, B->a[static_cast<std::size_t>(i)].data(), 3, est, nm, "m",
                       opt.estimate_frame_anchors, {bounds.frame_anchor_m});
    int col = before;
    for (int q = 0; q < 3; ++q) {
      if (col < static_cast<int>(B->names.size()) &&
          B->value_ptr[static_cast<std::size_t>(col)] ==
              B->a[static_cast<std::size_t>(i)].data() + q) {
        B->anchor_columns(q, i) = col++;
      }
    }
  }
  for (int i = 0; i < m; ++i) {
    std::vector<bool> est(3);
    std::vector<ParameterId> nm(3);
    for (int q = 0; q < 3; ++q) {
      est[static_cast<std::size_t>(q)] =
          opt.platform_anchor_mask.size() == 0 ? true : opt.platform_anchor_mask(q, i);
      nm[static_cast<std::size_t>(q)] = {ParameterKind::kPlatformAnchor, i, q};
    }
    add_geometry_block(*B, B->b[static_cast<std::size_t>(i)].data(), 3, est, nm, "m",
                       opt.estimate_platform_anchors, {bounds.platform_anchor_m});
  }
  auto scalar_blocks = [&](std::vector<double>& v, ParameterKind kind, const char* unit, bool on,
                           int count, const auto& range_of) {
    for (int i = 0; i < m; ++i) {
      const bool free_i = on && i < count;
      add_geometry_block(*B, &v[static_cast<std::size_t>(i)], 1, {true},
                         {ParameterId{kind, count == 1 ? -1 : i, -1}}, unit, free_i, range_of(i));
    }
  };
  auto relative = [](double half) { return [half](int) { return BlockRange{half}; }; };
  scalar_blocks(B->o, ParameterKind::kLengthOffset, "m", opt.estimate_length_offsets, m,
                relative(bounds.length_offset_m));
  scalar_blocks(B->s, ParameterKind::kLengthScale, "-", opt.estimate_length_scales, m,
                relative(bounds.length_scale));
  // EA = EA_model (1 + e) within [ea_factor_min, ea_factor_max] x EA_model.
  scalar_blocks(B->e, ParameterKind::kStiffness, "-", ea_estimated,
                opt.estimate_stiffness == StiffnessEstimate::kShared ? 1 : m, [&](int) {
                  BlockRange r;
                  r.absolute = true;
                  r.lo = bounds.ea_factor_min - 1.0;
                  r.hi = bounds.ea_factor_max - 1.0;
                  return r;
                });
  scalar_blocks(B->g, ParameterKind::kForceGain, "-", opt.estimate_force_gains, m,
                relative(bounds.force_gain));
  // The offset is in raw units (gain x N): a fraction of the cable's largest tension, read.
  scalar_blocks(B->c, ParameterKind::kForceOffset, "N", opt.estimate_force_offsets, m, [&](int i) {
    const auto ui = static_cast<std::size_t>(i);
    return BlockRange{bounds.force_offset_fraction * robot.cables[ui].f_max *
                      std::abs(robot.force_sensors[ui].gain)};
  });
  B->lasers.resize(static_cast<std::size_t>(nl));
  for (int l = 0; l < nl; ++l) {
    LaserBlocks& L = B->lasers[static_cast<std::size_t>(l)];
    const LaserModel& lm = robot.lasers[static_cast<std::size_t>(l)];
    for (int q = 0; q < 3; ++q) L.origin[static_cast<std::size_t>(q)] = lm.origin(q);
    L.d0 = lm.direction.normalized();
    tangent_basis(L.d0, L.de1, L.de2);
    L.n0 = lm.plane_normal.normalized();
    tangent_basis(L.n0, L.ne1, L.ne2);
    L.c = L.n0.dot(lm.plane_point);
    using K = ParameterKind;
    add_geometry_block(*B, L.origin.data(), 3, {true, true, true},
                       {{K::kLaserOrigin, l, 0}, {K::kLaserOrigin, l, 1}, {K::kLaserOrigin, l, 2}},
                       "m", opt.estimate_laser_origin, {bounds.laser_origin_m});
    add_geometry_block(*B, L.direction.data(), 2, {true, true},
                       {{K::kLaserDirection, l, 0}, {K::kLaserDirection, l, 1}}, "rad",
                       opt.estimate_laser_direction, {bounds.laser_direction_rad});
    add_geometry_block(*B, L.normal.data(), 2, {true, true},
                       {{K::kLaserPlaneNormal, l, 0}, {K::kLaserPlaneNormal, l, 1}}, "rad",
                       opt.estimate_laser_plane && !fix_plane, {bounds.plane_normal_rad});
    add_geometry_block(*B, &L.c, 1, {true}, {{K::kLaserPlaneOffset, l, -1}}, "m",
                       opt.estimate_laser_plane && !fix_plane, {bounds.plane_offset_m});
  }
  // Issue 18 channels: free only when estimated and measured somewhere.
  {
    std::vector<bool> swivel_seen(static_cast<std::size_t>(m), false);
    bool incl_seen = false, yaw_seen = false;
    for (const PoseMeasurement& pm : set.poses) {
      if (pm.swivel_angles.size() == m) {
        for (int i = 0; i < m; ++i) {
          if (!std::isnan(pm.swivel_angles(i))) swivel_seen[static_cast<std::size_t>(i)] = true;
        }
      }
      if (!std::isnan(pm.inclination(0))) incl_seen = true;
      if (!std::isnan(pm.imu_yaw)) yaw_seen = true;
    }
    B->swivel_zero.assign(static_cast<std::size_t>(m), 0.0);
    for (int i = 0; i < m; ++i) {
      const auto ui = static_cast<std::size_t>(i);
      B->swivel_zero[ui] = robot.swivel_encoder(i).zero;
      const bool free_i = opt.estimate_swivel_zeros && opt.use_swivel && swivel_seen[ui];
      B->swivel_zero_free = B->swivel_zero_free || free_i;
      add_geometry_block(*B, &B->swivel_zero[ui], 1, {true},
                         {ParameterId{ParameterKind::kSwivelZero, i, -1}}, "rad", free_i,
                         {bounds.swivel_zero_rad});
    }
    B->incl_mount0 = rotation_from_rpy<double>(robot.inclinometer.mounting_rpy);
    B->incl_mount_free = opt.estimate_inclinometer_mounting &&
                         ((opt.use_inclinometer && incl_seen) || (opt.use_imu_yaw && yaw_seen));
    add_geometry_block(*B, B->incl_mount.data(), 2, {true, true},
                       {ParameterId{ParameterKind::kInclinometerMount, -1, 0},
                        ParameterId{ParameterKind::kInclinometerMount, -1, 1}},
                       "rad", B->incl_mount_free, {bounds.inclinometer_mount_rad});
    B->imu_yaw_zero = robot.inclinometer.yaw_zero;
    B->imu_yaw_zero_free = opt.estimate_imu_yaw_zero && opt.use_imu_yaw && yaw_seen;
    add_geometry_block(*B, &B->imu_yaw_zero, 1, {true},
                       {ParameterId{ParameterKind::kImuYawZero, -1, -1}}, "rad",
                       B->imu_yaw_zero_free, {bounds.imu_yaw_zero_rad});
  }
  add_platform_weight_blocks(*B, robot, set, opt);
  B->num_geometry = static_cast<int>(B->names.size());

  // Poses.
  const bool suspended_gauge = fix_home && robot.suspended && m < 6 && opt.use_equilibrium;
  B->poses.resize(static_cast<std::size_t>(n));
  B->pose_free.assign(static_cast<std::size_t>(n), true);
  for (int j = 0; j < n; ++j) {
    Pose p = poses[static_cast<std::size_t>(j)];
    if (fix_home && j == opt.home_pose_index) {
      const PoseMeasurement& pm = set.poses[static_cast<std::size_t>(j)];
      p = pm.reference ? *pm.reference : opt.home_at_commanded ? pm.commanded : robot.home;
      B->pose_free[static_cast<std::size_t>(j)] = false;
    }
    const auto v = p.vector();
    for (int q = 0; q < 6; ++q)
      B->poses[static_cast<std::size_t>(j)][static_cast<std::size_t>(q)] = v(q);
    B->problem.AddParameterBlock(B->poses[static_cast<std::size_t>(j)].data(), 6);
    if (!B->pose_free[static_cast<std::size_t>(j)] && !suspended_gauge) {
      B->problem.SetParameterBlockConstant(B->poses[static_cast<std::size_t>(j)].data());
    }
  }
  if (suspended_gauge) {
    // Suspended robot with m < 6 cables: gravity fixes the world frame's tilt (the equilibrium
    // residuals), so the home pose holds only its position and heading; its roll and pitch are
    // estimated with the geometry (two more columns, "home.roll", "home.pitch").
    add_geometry_block(*B, B->poses[static_cast<std::size_t>(opt.home_pose_index)].data(), 6,
                       {false, false, false, true, true, false},
                       {ParameterId{ParameterKind::kHomePose, -1, 0},
                        {ParameterKind::kHomePose, -1, 1},
                        {ParameterKind::kHomePose, -1, 2},
                        {ParameterKind::kHomePose, -1, 3},
                        {ParameterKind::kHomePose, -1, 4},
                        {ParameterKind::kHomePose, -1, 5}},
                       "rad", true, {bounds.home_tilt_rad});
    B->home_tilt_free = true;
    if (opt.home_at_commanded) B->hang_home_at = robot.home;
    B->num_geometry = static_cast<int>(B->names.size());
  }

  // Residuals, pose by pose.
  B->blocks_per_pose.resize(static_cast<std::size_t>(n));
  B->rows_per_pose.resize(static_cast<std::size_t>(n));
  B->equilibrium.assign(static_cast<std::size_t>(n), nullptr);
  B->equilibrium_blocks.assign(static_cast<std::size_t>(n), {});
  auto make_loss = [&]() -> ceres::LossFunction* {
    switch (opt.loss) {
      case RobustLoss::kHuber:
        return new ceres::HuberLoss(opt.loss_scale);
      case RobustLoss::kCauchy:
        return new ceres::CauchyLoss(opt.loss_scale);
      case RobustLoss::kNone:
        return nullptr;
    }
    return nullptr;
  };
  const SensorNoise& noise = set.noise;
  const double slack = slack_threshold(opt, noise);
  bool missing_tension_warned = false;
  KinematicsData kin(robot);
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    double* pose = B->poses[uj].data();
    const bool have_tensions = pm.tensions.size() == m;
    const SensorNoise pose_noise = noise_at(noise, pm);
    inverse_kinematics(robot,
                       Pose::from_vector(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(pose)), kin);
    if (opt.use_lengths) {
      for (int i = 0; i < m; ++i) {
        const auto ui = static_cast<std::size_t>(i);
        if (std::isnan(pm.cable_lengths(i))) continue;
        // A slack cable (tension reading below the threshold) sags: its length says nothing
        // exact about the geometry, so it is left out (its zero tension still enters the
        // equilibrium).
        if (have_tensions && !std::isnan(pm.tensions(i)) && pm.tensions(i) < slack) {
          continue;
        }
        auto* f = new LengthCost;
        f->k = &B->constants[ui];
        f->reading = pm.cable_lengths(i);
        f->tension = have_tensions ? pm.tensions(i) : kNaN;
        if (std::isnan(f->tension) && !missing_tension_warned &&
            robot.cables[ui].elongation != ElongationKind::kRigid) {
          B->notes.push_back("some tensions are missing: their cables are taken as unstretched");
          missing_tension_warned = true;
        }
        // Force noise propagated through the elongation (at the current geometry, LengthCost).
        f->sigma_length = pose_noise.sigma_length;
        f->sigma_force = std::isnan(f->tension) ? 0.0 : pose_noise.sigma_force;
        f->extra_compliance = pm.extra_compliance.size() == m ? pm.extra_compliance(i) : 0.0;
        double* e_ptr = opt.estimate_stiffness == StiffnessEstimate::kShared ? &B->e[0] : &B->e[ui];
        auto id = B->problem.AddResidualBlock(
            new ceres::AutoDiffCostFunction<LengthCost, 1, 3, 3, 6, 1, 1, 1, 1, 1>(f), make_loss(),
            B->a[ui].data(), B->b[ui].data(), pose, &B->o[ui], &B->s[ui], e_ptr, &B->g[ui],
            &B->c[ui]);
        B->blocks_per_pose[uj].push_back(id);
        B->rows_per_pose[uj].push_back({Channel::kLength, i});
      }
    }
    if (opt.use_laser) {
      for (int l = 0; l < std::min<int>(nl, static_cast<int>(pm.laser_distances.size())); ++l) {
        if (std::isnan(pm.laser_distances(l))) continue;
        LaserBlocks& L = B->lasers[static_cast<std::size_t>(l)];
        auto* f = new LaserCost;
        f->d0 = L.d0;
        f->de1 = L.de1;
        f->de2 = L.de2;
        f->n0 = L.n0;
        f->ne1 = L.ne1;
        f->ne2 = L.ne2;
        f->reading = pm.laser_distances(l);
        f->sigma = noise.sigma_laser;
        auto id = B->problem.AddResidualBlock(
            new ceres::AutoDiffCostFunction<LaserCost, 1, 6, 3, 2, 2, 1>(f), make_loss(), pose,
            L.origin.data(), L.direction.data(), L.normal.data(), &L.c);
        B->blocks_per_pose[uj].push_back(id);
        B->rows_per_pose[uj].push_back({Channel::kLaser, l});
      }
    }
    // A supported platform (it rested on something): the cables did not carry its whole weight.
    if (opt.use_equilibrium && have_tensions && pm.tensions.allFinite() && !pm.supported) {
      auto* f = new EquilibriumCost;
      f->k = B->constants;
      f->tensions = pm.tensions;
      f->gravity = robot.gravity;
      f->external = pm.external_wrench;
      f->sigma_force = pose_noise.sigma_force;
      f->sigma_length = pose_noise.sigma_length;
      f->shared_stiffness = opt.estimate_stiffness == StiffnessEstimate::kShared;
      if (robot.suspended && m < 6) {
        const Eigen::JacobiSVD<Eigen::MatrixXd> svd(Eigen::MatrixXd(kin.structure_matrix),
                                                    Eigen::ComputeFullU);
        // The 6 - m unit wrench axes with the largest share in the complement (distinct).
        const Eigen::MatrixXd N0 = svd.matrixU().rightCols(6 - m);
        const Eigen::VectorXd share = N0.rowwise().squaredNorm();
        std::vector<int> order(6);
        for (int q = 0; q < 6; ++q) order[static_cast<std::size_t>(q)] = q;
        std::stable_sort(order.begin(), order.end(),
                         [&](int x, int y) { return share(x) > share(y); });
        f->null_basis = Eigen::MatrixXd::Zero(6, 6 - m);
        for (int q = 0; q < 6 - m; ++q) f->null_basis(order[static_cast<std::size_t>(q)], q) = 1.0;
        f->sigma_null = opt.suspended_equilibrium_sigma;
      }
      if (pm.extra_compliance.size() == m) {
        f->extra_compliance.assign(pm.extra_compliance.data(), pm.extra_compliance.data() + m);
      }
      if (opt.use_lengths) {
        // The cables that have a length row at this pose (the same test as above).
        f->readings.assign(static_cast<std::size_t>(m), kNaN);
        for (const RowInfo& ri : B->rows_per_pose[uj]) {
          if (ri.channel == Channel::kLength) {
            f->readings[static_cast<std::size_t>(ri.index)] = pm.cable_lengths(ri.index);
          }
        }
      }
      B->equilibrium[uj] = f;
      std::vector<double*> blocks;
      std::vector<int> sizes;
      const auto add_block = [&](double* ptr, int size) {
        blocks.push_back(ptr);
        sizes.push_back(size);
      };
      add_block(pose, 6);
      for (int i = 0; i < m; ++i) {
        add_block(B->a[static_cast<std::size_t>(i)].data(), 3);
      }
      for (int i = 0; i < m; ++i) {
        add_block(B->b[static_cast<std::size_t>(i)].data(), 3);
      }
      for (int i = 0; i < m; ++i) {
        add_block(&B->g[static_cast<std::size_t>(i)], 1);
      }
      for (int i = 0; i < m; ++i) {
        add_block(&B->c[static_cast<std::size_t>(i)], 1);
      }
      for (int i = 0; i < m; ++i) {
        add_block(&B->o[static_cast<std::size_t>(i)], 1);
      }
      for (int i = 0; i < m; ++i) {
        add_block(&B->s[static_cast<std::size_t>(i)], 1);
      }
      for (int i = 0; i < (f->shared_stiffness ? 1 : m); ++i) {
        add_block(&B->e[static_cast<std::size_t>(i)], 1);
      }
      f->mass_block = static_cast<int>(blocks.size());
      add_block(&B->mass, 1);
      add_block(B->com.data(), 3);
      auto* cost = ident_detail::equilibrium_cost_function(f, sizes);
      B->equilibrium_blocks[uj] = blocks;
      auto id = B->problem.AddResidualBlock(cost, make_loss(), blocks);
      B->blocks_per_pose[uj].push_back(id);
      for (int q = 0; q < 6; ++q) B->rows_per_pose[uj].push_back({Channel::kWrench, q});
    }
    if (opt.use_reference && pm.reference && B->pose_free[uj]) {
      auto* f = new ReferenceCost;
      f->reference = pm.reference->vector();
      f->inv_sigma << Eigen::Vector3d::Constant(1.0 / noise.sigma_reference_position),
          Eigen::Vector3d::Constant(1.0 / noise.sigma_reference_angle);
      auto id = B->problem.AddResidualBlock(new ceres::AutoDiffCostFunction<ReferenceCost, 6, 6>(f),
                                            make_loss(), pose);
      B->blocks_per_pose[uj].push_back(id);
      for (int q = 0; q < 6; ++q) B->rows_per_pose[uj].push_back({Channel::kReference, q});
    }
    if (opt.use_swivel && pm.swivel_angles.size() == m) {
      for (int i = 0; i < m; ++i) {
        const auto ui = static_cast<std::size_t>(i);
        if (std::isnan(pm.swivel_angles(i))) continue;
        auto* f = new SwivelCost;
        f->pulley_frame = robot.pulleys[ui].frame;
        f->direction = robot.swivel_encoder(i).direction;
        f->reading = pm.swivel_angles(i);
        f->sigma = noise.sigma_swivel;
        auto id = B->problem.AddResidualBlock(
            new ceres::AutoDiffCostFunction<SwivelCost, 1, 3, 3, 6, 1>(f), make_loss(),
            B->a[ui].data(), B->b[ui].data(), pose, &B->swivel_zero[ui]);
        B->blocks_per_pose[uj].push_back(id);
        B->rows_per_pose[uj].push_back({Channel::kSwivel, i});
      }
    }
    if (opt.use_inclinometer && !std::isnan(pm.inclination(0)) && !std::isnan(pm.inclination(1))) {
      auto* f = new InclinometerCost;
      f->mount0 = B->incl_mount0;
      f->reading = pm.inclination;
      f->sigma = noise.sigma_inclination;
      auto id =
          B->problem.AddResidualBlock(new ceres::AutoDiffCostFunction<InclinometerCost, 2, 6, 2>(f),
                                      make_loss(), pose, B->incl_mount.data());
      B->blocks_per_pose[uj].push_back(id);
      B->rows_per_pose[uj].push_back({Channel::kInclination, 0});
      B->rows_per_pose[uj].push_back({Channel::kInclination, 1});
    }
    if (opt.use_imu_yaw && !std::isnan(pm.imu_yaw)) {
      auto* f = new ImuYawCost;
      f->mount0 = B->incl_mount0;
      f->reading = pm.imu_yaw;
      f->sigma = noise.sigma_imu_yaw;
      auto id =
          B->problem.AddResidualBlock(new ceres::AutoDiffCostFunction<ImuYawCost, 1, 6, 2, 1>(f),
                                      make_loss(), pose, B->incl_mount.data(), &B->imu_yaw_zero);
      B->blocks_per_pose[uj].push_back(id);
      B->rows_per_pose[uj].push_back({Channel::kImuYaw, 0});
    }
    B->num_residuals += static_cast<int>(B->rows_per_pose[uj].size());
  }
  return B;
}

// Jacobian pieces per pose and the Schur complement onto the geometry columns.
struct Information {
  std::vector<Eigen::MatrixXd> per_pose;             // P x P (only when asked for: n P^2 doubles)
  Eigen::MatrixXd total;                             // P x P
  std::vector<Eigen::Matrix<double, 6, 6>> hpp_inv;  // per free pose
  std::vector<Eigen::MatrixXd> hpg;                  // 6 x P per free pose
  std::vector<double> residuals;                     // in row order, as evaluated
  std::vector<Eigen::MatrixXd> jg, jp;               // raw blocks (only when kept)
};

// `with_per_pose`: keep each pose's Schur-reduced P x P information (pose design needs them; the
// identification does not, and on 100,000 poses they are a gigabyte).
Result<Information> information(Built& B, bool apply_loss, bool keep = false,
                                bool with_per_pose = false) {
  const int P = B.num_geometry;
  const int n = static_cast<int>(B.poses.size());
  Information info;
  if (with_per_pose) info.per_pose.assign(static_cast<std::size_t>(n), Eigen::MatrixXd::Zero(P, P));
  info.total = Eigen::MatrixXd::Zero(P, P);
  info.hpp_inv.assign(static_cast<std::size_t>(n), Eigen::Matrix<double, 6, 6>::Zero());
  info.hpg.assign(static_cast<std::size_t>(n), Eigen::MatrixXd::Zero(6, P));
  std::size_t total_rows = 0;
  for (const auto& rows : B.rows_per_pose) total_rows += rows.size();
  info.residuals.reserve(total_rows);
  // The Jacobian is evaluated a chunk of poses at a time: the whole one as a CRS matrix is about
  // 4 kB per MINI pose (400 MB for 100,000 poses). Each pose's rows and columns, and so every sum
  // below, are the same as in one evaluation.
  constexpr int kChunk = 1024;
  ceres::Problem::EvaluateOptions eo;
  eo.apply_loss_function = apply_loss;
  std::vector<double> chunk_residuals;
  for (int j0 = 0; j0 < n; j0 += kChunk) {
    const int j1 = std::min(n, j0 + kChunk);
    eo.parameter_blocks = B.geometry_blocks;
    eo.residual_blocks.clear();
    std::vector<int> pose_col(static_cast<std::size_t>(j1 - j0), -1);
    int col = P;
    for (int j = j0; j < j1; ++j) {
      const auto uj = static_cast<std::size_t>(j);
      eo.residual_blocks.insert(eo.residual_blocks.end(), B.blocks_per_pose[uj].begin(),
                                B.blocks_per_pose[uj].end());
      if (!B.pose_free[uj]) continue;
      eo.parameter_blocks.push_back(B.poses[uj].data());
      pose_col[static_cast<std::size_t>(j - j0)] = col;
      col += 6;
    }
    if (eo.residual_blocks.empty()) continue;
    ceres::CRSMatrix J;
    double cost = 0.0;
    chunk_residuals.clear();
    if (!B.problem.Evaluate(eo, &cost, &chunk_residuals, nullptr, &J)) {
      return Status(
          ErrorCode::kNumericalFailure,
          "identification: the model cannot be evaluated (a cable is degenerate at a pose)");
    }
    if (J.num_cols != col) {
      return Status::error(ErrorCode::kInternal,
                           "identification: Jacobian has %d columns, expected %d", J.num_cols, col);
    }
    info.residuals.insert(info.residuals.end(), chunk_residuals.begin(), chunk_residuals.end());
    int row = 0;
    for (int j = j0; j < j1; ++j) {
      const int rows = static_cast<int>(B.rows_per_pose[static_cast<std::size_t>(j)].size());
      Eigen::MatrixXd Jg = Eigen::MatrixXd::Zero(rows, P);
      Eigen::MatrixXd Jp = Eigen::MatrixXd::Zero(rows, 6);
      const int pc = pose_col[static_cast<std::size_t>(j - j0)];
      for (int r = 0; r < rows; ++r) {
        const int R = row + r;
        for (int idx = J.rows[static_cast<std::size_t>(R)];
             idx < J.rows[static_cast<std::size_t>(R) + 1]; ++idx) {
          const int cidx = J.cols[static_cast<std::size_t>(idx)];
          const double v = J.values[static_cast<std::size_t>(idx)];
          if (cidx < P) {
            Jg(r, cidx) = v;
          } else if (pc >= 0 && cidx >= pc && cidx < pc + 6) {
            Jp(r, cidx - pc) = v;
          }
        }
      }
      row += rows;
      Eigen::MatrixXd S = Jg.transpose() * Jg;
      if (keep) {
        info.jg.push_back(Jg);
        info.jp.push_back(Jp);
      }
      if (pc >= 0) {
        const Eigen::Matrix<double, 6, 6> Hpp = Jp.transpose() * Jp;
        const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(Hpp);
        Eigen::Matrix<double, 6, 1> inv = Eigen::Matrix<double, 6, 1>::Zero();
        const double lmax = es.eigenvalues().maxCoeff();
        for (int q = 0; q < 6; ++q) {
          if (es.eigenvalues()(q) > 1e-12 * lmax && lmax > 0) inv(q) = 1.0 / es.eigenvalues()(q);
        }
        const Eigen::Matrix<double, 6, 6> Hinv =
            es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
        const Eigen::MatrixXd Hpg = Jp.transpose() * Jg;
        S -= Hpg.transpose() * Hinv * Hpg;
        info.hpp_inv[static_cast<std::size_t>(j)] = Hinv;
        info.hpg[static_cast<std::size_t>(j)] = Hpg;
      }
      S = 0.5 * (S + S.transpose());
      info.total += S;
      if (with_per_pose) info.per_pose[static_cast<std::size_t>(j)] = std::move(S);
    }
  }
  return info;
}

// Moves the per-pose information out of `info`.
GeometryInformation to_public(const Built& B, Information& info, const CalibratedModel& model) {
  GeometryInformation gi;
  gi.ids = B.ids;
  gi.names = B.names;
  gi.units = B.units;
  gi.values.resize(B.num_geometry);
  for (int q = 0; q < B.num_geometry; ++q) gi.values(q) = *B.value_ptr[static_cast<std::size_t>(q)];
  gi.per_pose = std::move(info.per_pose);
  gi.information = info.total;
  gi.anchor_columns = B.anchor_columns;
  KinematicsData kin(model.robot);
  inverse_kinematics(model.robot, model.robot.home, kin);
  gi.home_cable_directions = kin.unit_vectors;
  gi.frame_anchors = model.robot.frame_anchors;
  for (int i = 0; i < B.m; ++i) {
    for (int q = 0; q < 3; ++q)
      gi.frame_anchors(q, i) = B.a[static_cast<std::size_t>(i)][static_cast<std::size_t>(q)];
  }
  gi.num_residuals = B.num_residuals;
  for (const auto& rows : B.rows_per_pose) {
    for (const RowInfo& ri : rows) {
      switch (ri.channel) {
        case Channel::kLength:
          ++gi.channel_rows.length;
          break;
        case Channel::kLaser:
          ++gi.channel_rows.laser;
          break;
        case Channel::kWrench:
          ++gi.channel_rows.wrench;
          break;
        case Channel::kReference:
          ++gi.channel_rows.reference;
          break;
        case Channel::kSwivel:
          ++gi.channel_rows.swivel;
          break;
        case Channel::kInclination:
          ++gi.channel_rows.inclination;
          break;
        case Channel::kImuYaw:
          ++gi.channel_rows.imu_yaw;
          break;
      }
    }
  }
  for (bool f : B.pose_free) gi.home_pose_fixed = gi.home_pose_fixed || !f;
  gi.home_tilt_free = B.home_tilt_free;
  int free_poses = 0;
  for (bool f : B.pose_free) free_poses += f ? 1 : 0;
  gi.num_pose_parameters = 6 * free_poses;
  return gi;
}

CalibratedModel extract(const Built& B, const CalibratedModel& initial) {
  CalibratedModel out = initial;
  const int m = B.m;
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    for (int q = 0; q < 3; ++q) {
      out.robot.frame_anchors(q, i) = B.a[ui][static_cast<std::size_t>(q)];
      out.robot.platform_anchors(q, i) = B.b[ui][static_cast<std::size_t>(q)];
    }
    out.readings.length_offsets(i) = B.o[ui];
    out.readings.length_scales(i) = B.s[ui];
    WinchModel& w = out.robot.winches[ui];
    const double k = 1.0 + B.s[ui] - initial.readings.length_scales(i);
    w.length_offset = k * w.length_offset + (B.o[ui] - initial.readings.length_offsets(i));
    w.drum_diameter *= k;
    w.drum_pitch *= k;
    out.robot.force_sensors[ui].gain = initial.robot.force_sensors[ui].gain * (1.0 + B.g[ui]);
    out.robot.force_sensors[ui].offset = initial.robot.force_sensors[ui].offset + B.c[ui];
  }
  // Stiffness: only when it was estimated (a shared value lives in e[0]).
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    const bool shared_used = B.constants[ui].estimated_stiffness;
    if (!shared_used) continue;
    const double e = B.shared_stiffness ? B.e[0] : B.e[ui];
    out.robot.cables[ui].ea = initial.robot.cables[ui].ea * (1.0 + e);
    out.robot.cables[ui].elongation = ElongationKind::kHooke;
  }
  if (B.swivel_zero_free) {
    out.robot.swivel_encoders.resize(static_cast<std::size_t>(m));
    for (int i = 0; i < m; ++i) {
      const auto ui = static_cast<std::size_t>(i);
      out.robot.swivel_encoders[ui].direction = initial.robot.swivel_encoder(i).direction;
      out.robot.swivel_encoders[ui].zero = B.swivel_zero[ui];
    }
  }
  if (B.incl_mount_free) {
    out.robot.inclinometer.mounting_rpy = rpy_from_rotation(
        B.incl_mount0 * rotation_from_rpy<double>(B.incl_mount[0], B.incl_mount[1], 0.0));
  }
  if (B.imu_yaw_zero_free) out.robot.inclinometer.yaw_zero = B.imu_yaw_zero;
  out.robot.platform.mass = B.mass;
  out.robot.platform.center_of_mass = Eigen::Vector3d(B.com[0], B.com[1], B.com[2]);
  if (B.home_tilt_free) {
    // A suspended robot's home is where the calibrated model hangs at the home position and
    // heading (the estimated tilt, made an exact equilibrium so that the model check accepts it).
    for (std::size_t j = 0; j < B.poses.size(); ++j) {
      if (B.pose_free[j]) continue;
      const Pose estimated =
          Pose::from_vector(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(B.poses[j].data()));
      const Pose target = B.hang_home_at ? *B.hang_home_at : estimated;
      const Result<SuspendedState> hang = suspended_equilibrium_pose(out.robot, target);
      out.robot.home = hang.ok() ? hang->pose : target;
    }
  }
  for (std::size_t l = 0; l < B.lasers.size(); ++l) {
    const LaserBlocks& L = B.lasers[l];
    LaserModel& lm = out.robot.lasers[l];
    lm.origin = Eigen::Vector3d(L.origin[0], L.origin[1], L.origin[2]);
    lm.direction = (L.d0 + L.de1 * L.direction[0] + L.de2 * L.direction[1]).normalized();
    lm.plane_normal = (L.n0 + L.ne1 * L.normal[0] + L.ne2 * L.normal[1]).normalized();
    lm.plane_point = L.c * lm.plane_normal;
  }
  return out;
}

std::vector<Pose> initial_poses(const MeasurementSet& set) {
  std::vector<Pose> p;
  p.reserve(set.poses.size());
  for (const PoseMeasurement& pm : set.poses) p.push_back(start_of(pm));
  return p;
}

// Pseudo-inverse of a symmetric PSD matrix after column normalisation; `null` receives the
// normalised null-space basis.
Eigen::MatrixXd pseudo_inverse_normalized(const Eigen::MatrixXd& S, double rel_tol, int* rank,
                                          double* condition, Eigen::MatrixXd* null_basis) {
  const int P = static_cast<int>(S.rows());
  if (P == 0) {  // nothing estimated (a fixed model: only the poses are fitted)
    if (rank) *rank = 0;
    if (condition) *condition = 0.0;
    if (null_basis) *null_basis = Eigen::MatrixXd();
    return Eigen::MatrixXd();
  }
  Eigen::VectorXd d(P);
  for (int q = 0; q < P; ++q) d(q) = S(q, q) > 0 ? std::sqrt(S(q, q)) : 1.0;
  const Eigen::MatrixXd N = d.cwiseInverse().asDiagonal() * S * d.cwiseInverse().asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(N);
  const Eigen::VectorXd lam = es.eigenvalues().cwiseMax(0.0);
  const double lmax = lam.size() ? lam.maxCoeff() : 0.0;
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(P);
  int r = 0;
  double smin = lmax;
  std::vector<int> null_idx;
  for (int q = 0; q < P; ++q) {
    // Singular values are sqrt(lambda): compare sigma ratios with rel_tol.
    if (lmax > 0 && std::sqrt(lam(q) / lmax) > rel_tol) {
      inv(q) = 1.0 / lam(q);
      ++r;
      smin = std::min(smin, lam(q));
    } else {
      null_idx.push_back(q);
    }
  }
  if (rank) *rank = r;
  if (condition) {
    *condition =
        (r == P && smin > 0) ? std::sqrt(lmax / smin) : std::numeric_limits<double>::infinity();
  }
  if (null_basis) {
    null_basis->resize(P, static_cast<int>(null_idx.size()));
    for (std::size_t k = 0; k < null_idx.size(); ++k) {
      null_basis->col(static_cast<int>(k)) = es.eigenvectors().col(null_idx[k]);
    }
  }
  const Eigen::MatrixXd Ninv = es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
  return d.cwiseInverse().asDiagonal() * Ninv * d.cwiseInverse().asDiagonal();
}

}  // namespace

namespace {

// geometry_information, with or without the per-pose matrices.
Result<GeometryInformation> geometry_information_impl(const CalibratedModel& model,
                                                      const MeasurementSet& set,
                                                      const std::vector<Pose>& poses,
                                                      const IdentificationOptions& options,
                                                      bool keep_jacobians, bool with_per_pose) {
  auto built = build(model, set, poses, options);
  if (!built) return built.status();
  auto info = information(**built, false, keep_jacobians, with_per_pose);
  if (!info) return info.status();
  GeometryInformation gi = to_public(**built, *info, model);
  gi.jacobian_geometry = std::move(info->jg);
  gi.jacobian_pose = std::move(info->jp);
  return gi;
}

}  // namespace

Result<GeometryInformation> geometry_information(const CalibratedModel& model,
                                                 const MeasurementSet& set,
                                                 const std::vector<Pose>& poses,
                                                 const IdentificationOptions& options,
                                                 bool keep_jacobians) {
  return geometry_information_impl(model, set, poses, options, keep_jacobians, true);
}

Result<GeometryInformation> ident_detail::total_geometry_information(
    const CalibratedModel& model, const MeasurementSet& set, const std::vector<Pose>& poses,
    const IdentificationOptions& options) {
  return geometry_information_impl(model, set, poses, options, false, false);
}

Result<std::vector<Eigen::VectorXd>> evaluate_residuals(const CalibratedModel& model,
                                                        const MeasurementSet& set,
                                                        const std::vector<Pose>& poses,
                                                        const IdentificationOptions& options) {
  auto built = build(model, set, poses, options);
  if (!built) return built.status();
  Built& B = **built;
  std::vector<ceres::ResidualBlockId> blocks;
  for (const auto& v : B.blocks_per_pose) blocks.insert(blocks.end(), v.begin(), v.end());
  std::vector<Eigen::VectorXd> out;
  std::vector<double> r;
  if (!blocks.empty()) {
    ceres::Problem::EvaluateOptions eo;
    eo.apply_loss_function = false;
    eo.residual_blocks = blocks;
    double cost = 0.0;
    if (!B.problem.Evaluate(eo, &cost, &r, nullptr, nullptr)) {
      return Status(ErrorCode::kNumericalFailure,
                    "evaluate_residuals: the model cannot be evaluated at these poses");
    }
  }
  std::size_t row = 0;
  for (const auto& rows : B.rows_per_pose) {
    Eigen::VectorXd v(static_cast<Eigen::Index>(rows.size()));
    for (Eigen::Index q = 0; q < v.size(); ++q) v(q) = r[row++];
    out.push_back(std::move(v));
  }
  return out;
}

Result<IdentificationReport> identify(const CalibratedModel& initial, const MeasurementSet& set,
                                      const IdentificationOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  auto built = build(initial, set, initial_poses(set), options);
  if (!built) return built.status();
  Built& B = **built;
  // P == 0 is a fixed model: only the free poses are fitted (a model checked on a recording,
  // pose_refit.hpp).
  const int P = B.num_geometry;
  // The initial values, before the solver moves them (the problem is built once).
  std::vector<double> initial_values(static_cast<std::size_t>(P));
  for (int q = 0; q < P; ++q) {
    initial_values[static_cast<std::size_t>(q)] = *B.value_ptr[static_cast<std::size_t>(q)];
  }
  int free_pose_params = 0;
  for (bool f : B.pose_free) free_pose_params += f ? 6 : 0;
  const int num_params = P + free_pose_params;
  if (B.num_residuals <= num_params) {
    return Status::error(
        ErrorCode::kFailedPrecondition,
        "identification: too few poses: %d poses give %d residuals for %d unknowns "
        "(%d parameters + %d pose coordinates); measure more poses",
        set.num_poses(), B.num_residuals, num_params, P, free_pose_params);
  }
  // Identifiability at the initial guess (nothing to check for a fixed model).
  if (P > 0) {
    auto info0 = information(B, false);
    if (!info0) return info0.status();
    IdentifiabilityOptions io;
    io.rank_tolerance = options.rank_tolerance;
    const IdentifiabilityReport ir = analyze_identifiability(to_public(B, *info0, initial), io);
    if (options.refuse_unidentifiable) {
      CDPR_RETURN_IF_ERROR(require_identifiable(ir));
    }
  }

  ceres::Solver::Options so;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.gradient_tolerance = options.gradient_tolerance;
  so.parameter_tolerance = options.parameter_tolerance;
  so.num_threads = options.num_threads;
  so.logging_type = ceres::SILENT;
  // Solver iterations as progress (IdentificationOptions::progress).
  struct IterationProgress final : ceres::IterationCallback {
    const IdentificationOptions* o = nullptr;
    ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
      o->progress("solver iteration", s.iteration, o->max_iterations);
      return ceres::SOLVER_CONTINUE;
    }
  } iteration_progress;
  iteration_progress.o = &options;
  if (options.progress) so.callbacks.push_back(&iteration_progress);
  if (free_pose_params > 0 && P > 0) {
    so.linear_solver_type = ceres::DENSE_SCHUR;
    // Poses are eliminated first (group 0). Every other block gets a group of its own, in the
    // order the problem was built: within one group Ceres orders blocks by their address, which
    // would make the last bits of the result depend on where the heap put the parameter vectors.
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    std::vector<double*> all;
    B.problem.GetParameterBlocks(&all);
    std::set<const double*> pose_blocks;
    for (const auto& pose : B.poses) pose_blocks.insert(pose.data());
    int group = 1;
    for (double* p : all) ordering->AddElementToGroup(p, pose_blocks.count(p) ? 0 : group++);
    so.linear_solver_ordering = ordering;
  } else {
    so.linear_solver_type = ceres::DENSE_QR;
  }
  ceres::Solver::Summary summary;
  const auto ts = std::chrono::steady_clock::now();
  ceres::Solve(so, &B.problem, &summary);
  const auto te = std::chrono::steady_clock::now();

  IdentificationReport rep;
  rep.solve_time_s = std::chrono::duration<double>(te - ts).count();
  rep.initial_cost = summary.initial_cost;
  rep.final_cost = summary.final_cost;
  rep.iterations = static_cast<int>(summary.iterations.size()) - 1;
  rep.converged = summary.termination_type == ceres::CONVERGENCE;
  rep.termination = summary.message;
  rep.num_residuals = B.num_residuals;
  rep.num_parameters = num_params;
  rep.dof = B.num_residuals - num_params;
  if (summary.termination_type == ceres::FAILURE) {
    return Status::error(ErrorCode::kNumericalFailure, "identification: Ceres failed: %s",
                         summary.message.c_str());
  }
  rep.estimate = extract(B, initial);
  for (const auto& p : B.poses) {
    rep.poses.push_back(Pose::from_vector(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(p.data())));
  }

  // Residuals without loss: chi2 and per pose / channel.
  auto info_noloss = information(B, false);
  if (!info_noloss) return info_noloss.status();
  const RobotModel& robot = initial.robot;
  const int m = robot.num_cables();
  const int nl = static_cast<int>(robot.lasers.size());
  const SensorNoise& noise = set.noise;
  KinematicsData kin(robot);
  double sl = 0, sla = 0, sw = 0, ssw = 0, sinc = 0, syaw = 0;
  int nlen = 0, nlas = 0, nw = 0, nsw = 0, ninc = 0, nyaw = 0;
  std::size_t row = 0;
  for (std::size_t j = 0; j < B.poses.size(); ++j) {
    PoseResiduals pr;
    pr.length_m = Eigen::VectorXd::Constant(m, kNaN);
    pr.length_normalized = Eigen::VectorXd::Constant(m, kNaN);
    pr.laser_m = Eigen::VectorXd::Constant(nl, kNaN);
    pr.laser_normalized = Eigen::VectorXd::Constant(nl, kNaN);
    pr.swivel_rad = Eigen::VectorXd::Constant(m, kNaN);
    pr.swivel_normalized = Eigen::VectorXd::Constant(m, kNaN);
    for (const RowInfo& ri : B.rows_per_pose[j]) {
      const double r = info_noloss->residuals[row++];
      rep.chi2 += r * r;
      switch (ri.channel) {
        case Channel::kLength: {
          pr.length_normalized(ri.index) = r;  // SI value computed below
          break;
        }
        case Channel::kLaser:
          pr.laser_normalized(ri.index) = r;
          pr.laser_m(ri.index) = r * noise.sigma_laser;
          rep.log_det_covariance += 2.0 * std::log(noise.sigma_laser);
          sla += pr.laser_m(ri.index) * pr.laser_m(ri.index);
          ++nlas;
          break;
        case Channel::kWrench:
          pr.wrench_normalized(ri.index) = r;
          break;
        case Channel::kReference:
          pr.reference_normalized(ri.index) = r;
          break;
        case Channel::kSwivel:
          pr.swivel_normalized(ri.index) = r;
          pr.swivel_rad(ri.index) = r * noise.sigma_swivel;
          rep.log_det_covariance += 2.0 * std::log(noise.sigma_swivel);
          ssw += pr.swivel_rad(ri.index) * pr.swivel_rad(ri.index);
          ++nsw;
          break;
        case Channel::kInclination:
          pr.inclination_normalized(ri.index) = r;
          pr.inclination_rad(ri.index) = r * noise.sigma_inclination;
          rep.log_det_covariance += 2.0 * std::log(noise.sigma_inclination);
          sinc += pr.inclination_rad(ri.index) * pr.inclination_rad(ri.index);
          ++ninc;
          break;
        case Channel::kImuYaw:
          pr.imu_yaw_normalized = r;
          pr.imu_yaw_rad = r * noise.sigma_imu_yaw;
          rep.log_det_covariance += 2.0 * std::log(noise.sigma_imu_yaw);
          syaw += pr.imu_yaw_rad * pr.imu_yaw_rad;
          ++nyaw;
          break;
      }
    }
    // SI values of the length residuals: recompute U - reading model directly.
    inverse_kinematics(rep.estimate.robot, rep.poses[j], kin);
    const PoseMeasurement& pm = set.poses[j];
    for (int i = 0; i < m; ++i) {
      if (std::isnan(pr.length_normalized(i))) continue;
      const auto ui = static_cast<std::size_t>(i);
      double U = kin.lengths(i);
      const double tr = pm.tensions.size() == m ? pm.tensions(i) : kNaN;
      if (!std::isnan(tr)) {
        CableConstants k = B.constants[ui];
        const double F = true_tension(k, tr, B.g[ui], B.c[ui]);
        const double loaded = ident_detail::loaded_length<double>(k.cable, kin.lengths(i));
        if (k.estimated_stiffness) {
          const double ea =
              k.cable.ea *
              (1.0 + (options.estimate_stiffness == StiffnessEstimate::kShared ? B.e[0] : B.e[ui]));
          U -= F * loaded / (ea + F);
        } else {
          U -= cable_elongation<double>(k.cable, loaded, F);
        }
      }
      // The row's variance as LengthCost has it: encoder noise plus the force noise through the
      // compliance d(dL)/dF at the estimate (elongation_at, as in LengthCost).
      double compliance = 0.0;
      if (!std::isnan(tr)) {
        const double e =
            options.estimate_stiffness == StiffnessEstimate::kShared ? B.e[0] : B.e[ui];
        elongation_at<double>(B.constants[ui], kin.lengths(i), tr, e, B.g[ui], B.c[ui], nullptr,
                              &compliance);
        if (pm.extra_compliance.size() == m) compliance += pm.extra_compliance(i);
      }
      const SensorNoise pose_noise = noise_at(noise, pm);
      rep.log_det_covariance +=
          std::log(pose_noise.sigma_length * pose_noise.sigma_length +
                   compliance * compliance * pose_noise.sigma_force * pose_noise.sigma_force);
      pr.length_m(i) = U - ((1.0 + B.s[ui]) * pm.cable_lengths(i) + B.o[ui]);
      sl += pr.length_m(i) * pr.length_m(i);
      ++nlen;
    }
    if (!std::isnan(pr.wrench_normalized(0)) && B.equilibrium[j] != nullptr) {
      Eigen::Matrix<double, 6, 1> w;
      Eigen::Matrix<double, 6, 6> cov;
      if (B.equilibrium[j]->wrench<double>(B.equilibrium_blocks[j].data(), w, cov)) {
        pr.wrench_si = w;
        const double ridge = 1e-12 * cov.trace();
        for (int q = 0; q < 6; ++q) cov(q, q) += ridge;
        const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(cov);
        if (llt.info() == Eigen::Success) {
          rep.log_det_covariance +=
              2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
        }
      }
      sw += pr.wrench_si.head<3>().squaredNorm();
      nw += 3;
    }
    rep.residuals.push_back(std::move(pr));
  }
  rep.rms_length_m = nlen ? std::sqrt(sl / nlen) : 0.0;
  rep.rms_laser_m = nlas ? std::sqrt(sla / nlas) : 0.0;
  rep.rms_wrench_n = nw ? std::sqrt(sw / nw) : 0.0;
  rep.rms_swivel_rad = nsw ? std::sqrt(ssw / nsw) : 0.0;
  rep.rms_inclination_rad = ninc ? std::sqrt(sinc / ninc) : 0.0;
  rep.rms_imu_yaw_rad = nyaw ? std::sqrt(syaw / nyaw) : 0.0;

  // Covariance of the geometry (Schur complement, pseudo-inverse with null-space handling) and of
  // the poses.
  rep.parameters.resize(static_cast<std::size_t>(P));
  {
    for (int q = 0; q < P; ++q) {
      ParameterEstimate& pe = rep.parameters[static_cast<std::size_t>(q)];
      pe.id = B.ids[static_cast<std::size_t>(q)];
      pe.name = B.names[static_cast<std::size_t>(q)];
      pe.unit = B.units[static_cast<std::size_t>(q)];
      pe.value = *B.value_ptr[static_cast<std::size_t>(q)];
      pe.initial = initial_values[static_cast<std::size_t>(q)];
      pe.std_dev = std::numeric_limits<double>::infinity();
      pe.lower = B.lower[static_cast<std::size_t>(q)];
      pe.upper = B.upper[static_cast<std::size_t>(q)];
      const double tol = 1e-7 * (pe.upper - pe.lower);
      pe.at_bound = pe.value <= pe.lower + tol || pe.value >= pe.upper - tol;
    }
  }
  rep.pose_std.assign(B.poses.size(), Eigen::Matrix<double, 6, 1>::Zero());
  auto info_loss =
      options.loss == RobustLoss::kNone ? std::move(info_noloss) : information(B, true);
  if (!info_loss) return info_loss.status();
  {
    Eigen::MatrixXd null_basis;
    double cond = 0.0;
    const Eigen::MatrixXd cov = pseudo_inverse_normalized(info_loss->total, options.rank_tolerance,
                                                          &rep.rank, &cond, &null_basis);
    rep.condition_number = cond;
    if (options.compute_covariance) {
      rep.covariance = cov;
      for (int q = 0; q < P; ++q) {
        const double in_null = null_basis.cols() ? null_basis.row(q).squaredNorm() : 0.0;
        rep.parameters[static_cast<std::size_t>(q)].std_dev =
            in_null > 1e-2 ? std::numeric_limits<double>::infinity()
                           : std::sqrt(std::max(0.0, cov(q, q)));
      }
      for (std::size_t j = 0; j < B.poses.size(); ++j) {
        if (!B.pose_free[j]) continue;
        const Eigen::Matrix<double, 6, 6>& Hinv = info_loss->hpp_inv[j];
        const Eigen::MatrixXd X = Hinv * info_loss->hpg[j];
        const Eigen::Matrix<double, 6, 6> cp = Hinv + X * cov * X.transpose();
        rep.pose_std[j] = cp.diagonal().cwiseMax(0.0).cwiseSqrt();
      }
    }
  }

  // Warnings.
  char buf[512];
  for (const std::string& n : B.notes) rep.warnings.push_back(n);
  if (!rep.converged) {
    rep.warnings.push_back("the solver did not converge: " + summary.message);
  }
  for (const ParameterEstimate& pe : rep.parameters) {
    if (!pe.at_bound) continue;
    std::snprintf(buf, sizeof(buf),
                  "%s = %.6g %s ended on the %s bound of its physical range [%.6g, %.6g]: the data "
                  "push it outside what the robot can be (a missing effect or a bad recording)",
                  pe.name.c_str(), pe.value, pe.unit.c_str(),
                  pe.value <= 0.5 * (pe.lower + pe.upper) ? "lower" : "upper", pe.lower, pe.upper);
    rep.warnings.emplace_back(buf);
  }
  if (rep.dof > 0) {
    const double z = (rep.chi2 - rep.dof) / std::sqrt(2.0 * rep.dof);
    if (std::abs(z) > options.chi2_warning_sigmas) {
      std::snprintf(buf, sizeof(buf),
                    "chi-square %.1f is far from its %d degrees of freedom (%.1f sigma): the noise "
                    "figures or the model are wrong%s",
                    rep.chi2, rep.dof, z, z > 0 ? " (unmodelled effect or optimistic sigmas)" : "");
      rep.warnings.emplace_back(buf);
    }
  }
  if (rep.rank < P) {
    std::snprintf(buf, sizeof(buf), "rank deficient: rank %d of %d parameters", rep.rank, P);
    rep.warnings.emplace_back(buf);
  }
  if (rep.condition_number > options.condition_warning) {
    std::snprintf(buf, sizeof(buf), "condition number %.3g > %.3g: weakly identifiable parameters",
                  rep.condition_number, options.condition_warning);
    rep.warnings.emplace_back(buf);
  }
  const Eigen::Matrix3Xd& anchors = robot.frame_anchors;
  const double frame_size =
      anchors.cols() ? (anchors.rowwise().maxCoeff() - anchors.rowwise().minCoeff()).norm() : 0.0;
  const double huge = std::max(options.huge_std_anchor, options.huge_std_fraction * frame_size);
  for (const ParameterEstimate& pe : rep.parameters) {
    if (options.compute_covariance && pe.unit == "m" && pe.std_dev > huge) {
      std::snprintf(buf, sizeof(buf),
                    "%s has a huge standard deviation (%.3g m, above %.3g m: %.3g %% of the "
                    "%.3g m frame)",
                    pe.name.c_str(), pe.std_dev, huge, 100.0 * options.huge_std_fraction,
                    frame_size);
      rep.warnings.emplace_back(buf);
    }
  }
  rep.total_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

std::vector<std::string> IdentificationReport::parameters_at_bound() const {
  std::vector<std::string> v;
  for (const ParameterEstimate& pe : parameters)
    if (pe.at_bound) v.push_back(pe.name);
  return v;
}

std::string IdentificationReport::brief_report() const {
  char buf[320];
  std::snprintf(buf, sizeof(buf),
                "Identification: %s, %d iterations, cost %.6g -> %.6g, chi2 %.1f / dof %d, "
                "rank %d, cond %.3g, %.1f ms, %zu warnings",
                converged ? "CONVERGED" : "NOT CONVERGED", iterations, initial_cost, final_cost,
                chi2, dof, rank, condition_number, 1e3 * total_time_s, warnings.size());
  return buf;
}

std::string IdentificationReport::full_report() const {
  std::ostringstream os;
  char buf[320];
  os << "cdpr identification report\n";
  os << "--------------------------\n";
  std::snprintf(buf, sizeof(buf), "%-28s %12d\n%-28s %12d\n%-28s %12d\n", "Residuals",
                num_residuals, "Parameters (incl. poses)", num_parameters, "Degrees of freedom",
                dof);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12.6g\n%-28s %12.6g\n%-28s %12.6g\n", "Initial cost",
                initial_cost, "Final cost", final_cost, "Chi-square (no loss)", chi2);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12d\n%-28s %12.3f\n%-28s %12.3f\n", "Iterations",
                iterations, "Solve time (ms)", 1e3 * solve_time_s, "Total time (ms)",
                1e3 * total_time_s);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12d\n%-28s %12.4g\n", "Rank (geometry)", rank,
                "Condition number", condition_number);
  os << buf;
  std::snprintf(buf, sizeof(buf), "%-28s %12.4g\n%-28s %12.4g\n%-28s %12.4g\n",
                "RMS length residual (m)", rms_length_m, "RMS laser residual (m)", rms_laser_m,
                "RMS wrench residual (N)", rms_wrench_n);
  os << buf;
  if (rms_swivel_rad > 0 || rms_inclination_rad > 0 || rms_imu_yaw_rad > 0) {
    std::snprintf(buf, sizeof(buf), "%-28s %12.4g\n%-28s %12.4g\n%-28s %12.4g\n",
                  "RMS swivel residual (rad)", rms_swivel_rad, "RMS inclin. residual (rad)",
                  rms_inclination_rad, "RMS IMU yaw residual (rad)", rms_imu_yaw_rad);
    os << buf;
  }
  os << "\nParameters:\n";
  std::snprintf(buf, sizeof(buf), "  %-24s %14s %14s %14s %12s  %s\n", "name", "initial",
                "estimate", "change", "std dev", "unit");
  os << buf;
  for (const ParameterEstimate& p : parameters) {
    std::snprintf(buf, sizeof(buf), "  %-24s %14.7g %14.7g %14.4g %12.4g  %s\n", p.name.c_str(),
                  p.initial, p.value, p.value - p.initial, p.std_dev, p.unit.c_str());
    os << buf;
  }
  os << "\nTermination: " << (converged ? "CONVERGENCE" : "NO CONVERGENCE") << " (" << termination
     << ")\n";
  if (warnings.empty()) {
    os << "Solver: no warnings.\n";
  } else {
    os << "Solver warnings:\n";
    for (const std::string& w : warnings) os << "  - " << w << "\n";
  }
  return os.str();
}

}  // namespace cdpr
