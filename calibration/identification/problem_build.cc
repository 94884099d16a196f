// The identification problem built from a model and a recording: the autodiff cost functors of
// the per-pose residuals, the parameter blocks with their bounds, and the residual blocks pose by
// pose (compiles slowly: every autodiff functor lives in this translation unit).
#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "identification_problem.hpp"

namespace cdpr::ident_detail {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Two unit vectors orthogonal to unit d (a tangent basis of the sphere at d).
void tangent_basis(const Eigen::Vector3d& d, Eigen::Vector3d& e1, Eigen::Vector3d& e2) {
  const Eigen::Vector3d helper =
      std::abs(d.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  e1 = d.cross(helper).normalized();
  e2 = d.cross(e1).normalized();
}

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

// The model and options as the problem needs them: every per-cable vector with m entries, the
// masks with m columns, one pose guess per measured pose, a home pose among them.
Status check_inputs(const CalibratedModel& model, const MeasurementSet& set,
                    const std::vector<Pose>& poses, const IdentificationOptions& opt,
                    bool fix_home) {
  const RobotModel& robot = model.robot;
  const int m = robot.num_cables();
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
  if (fix_home && (opt.home_pose_index < 0 || opt.home_pose_index >= n)) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "identification: home_pose_index %d is not one of the %d poses",
                         opt.home_pose_index, n);
  }
  if (n == 0) return Status(ErrorCode::kInvalidArgument, "identification: no poses measured");
  return Status::success();
}

// The per-cable storage (anchors, reading model, sensor corrections) at the model's values and
// each cable's constants.
void init_cables(Built& B, const CalibratedModel& model, const IdentificationOptions& opt) {
  const RobotModel& robot = model.robot;
  const int m = robot.num_cables();
  B.m = m;
  B.a.resize(static_cast<std::size_t>(m));
  B.b.resize(static_cast<std::size_t>(m));
  B.o.assign(static_cast<std::size_t>(m), 0.0);
  B.s.assign(static_cast<std::size_t>(m), 0.0);
  B.e.assign(static_cast<std::size_t>(m), 0.0);
  B.g.assign(static_cast<std::size_t>(m), 0.0);
  B.c.assign(static_cast<std::size_t>(m), 0.0);
  B.anchor_columns = Eigen::Matrix3Xi::Constant(3, m, -1);
  const bool ea_estimated = opt.estimate_stiffness != StiffnessEstimate::kFixed;
  B.shared_stiffness = opt.estimate_stiffness == StiffnessEstimate::kShared;
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    for (int q = 0; q < 3; ++q) {
      B.a[ui][static_cast<std::size_t>(q)] = robot.frame_anchors(q, i);
      B.b[ui][static_cast<std::size_t>(q)] = robot.platform_anchors(q, i);
    }
    B.o[ui] = model.readings.length_offsets(i);
    B.s[ui] = model.readings.length_scales(i);
    CableConstants k;
    k.pulley_frame = robot.pulleys[ui].frame;
    k.pulley_radius = robot.pulleys[ui].radius;
    k.cable = robot.cables[ui];
    k.sensor_gain = robot.force_sensors[ui].gain;
    k.sensor_offset = robot.force_sensors[ui].offset;
    k.estimated_stiffness = ea_estimated;
    B.constants.push_back(k);
  }
}

// The frame and platform anchor blocks (the frame anchors' columns noted in anchor_columns).
void add_anchor_blocks(Built& B, const IdentificationOptions& opt) {
  const int m = B.m;
  const ParameterBounds& bounds = opt.bounds;
  for (int i = 0; i < m; ++i) {
    std::vector<bool> est(3);
    std::vector<ParameterId> nm(3);
    for (int q = 0; q < 3; ++q) {
      est[static_cast<std::size_t>(q)] =
          opt.frame_anchor_mask.size() == 0 ? true : opt.frame_anchor_mask(q, i);
      nm[static_cast<std::size_t>(q)] = {ParameterKind::kFrameAnchor, i, q};
    }
    const int before = static_cast<int>(B.names.size());
    add_geometry_block(B, B.a[static_cast<std::size_t>(i)].data(), 3, est, nm, "m",
                       opt.estimate_frame_anchors, {bounds.frame_anchor_m});
    int col = before;
    for (int q = 0; q < 3; ++q) {
      if (col < static_cast<int>(B.names.size()) &&
          B.value_ptr[static_cast<std::size_t>(col)] ==
              B.a[static_cast<std::size_t>(i)].data() + q) {
        B.anchor_columns(q, i) = col++;
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
    add_geometry_block(B, B.b[static_cast<std::size_t>(i)].data(), 3, est, nm, "m",
                       opt.estimate_platform_anchors, {bounds.platform_anchor_m});
  }
}

// The per-cable scalar blocks: length offsets and scales, stiffness, force gains and offsets.
void add_cable_scalar_blocks(Built& B, const RobotModel& robot, const IdentificationOptions& opt) {
  const int m = B.m;
  const ParameterBounds& bounds = opt.bounds;
  const bool ea_estimated = opt.estimate_stiffness != StiffnessEstimate::kFixed;
  auto scalar_blocks = [&](std::vector<double>& v, ParameterKind kind, const char* unit, bool on,
                           int count, const auto& range_of) {
    for (int i = 0; i < m; ++i) {
      const bool free_i = on && i < count;
      add_geometry_block(B, &v[static_cast<std::size_t>(i)], 1, {true},
                         {ParameterId{kind, count == 1 ? -1 : i, -1}}, unit, free_i, range_of(i));
    }
  };
  auto relative = [](double half) { return [half](int) { return BlockRange{half}; }; };
  scalar_blocks(B.o, ParameterKind::kLengthOffset, "m", opt.estimate_length_offsets, m,
                relative(bounds.length_offset_m));
  scalar_blocks(B.s, ParameterKind::kLengthScale, "-", opt.estimate_length_scales, m,
                relative(bounds.length_scale));
  // EA = EA_model (1 + e) within [ea_factor_min, ea_factor_max] x EA_model.
  scalar_blocks(B.e, ParameterKind::kStiffness, "-", ea_estimated,
                opt.estimate_stiffness == StiffnessEstimate::kShared ? 1 : m, [&](int) {
                  BlockRange r;
                  r.absolute = true;
                  r.lo = bounds.ea_factor_min - 1.0;
                  r.hi = bounds.ea_factor_max - 1.0;
                  return r;
                });
  scalar_blocks(B.g, ParameterKind::kForceGain, "-", opt.estimate_force_gains, m,
                relative(bounds.force_gain));
  // The offset is in raw units (gain x N): a fraction of the cable's largest tension, read.
  scalar_blocks(B.c, ParameterKind::kForceOffset, "N", opt.estimate_force_offsets, m, [&](int i) {
    const auto ui = static_cast<std::size_t>(i);
    return BlockRange{bounds.force_offset_fraction * robot.cables[ui].f_max *
                      std::abs(robot.force_sensors[ui].gain)};
  });
}

// Each laser's origin, beam direction and target plane (the plane fixed by the laser-plane gauge).
void add_laser_blocks(Built& B, const RobotModel& robot, const IdentificationOptions& opt,
                      bool fix_plane) {
  const int nl = static_cast<int>(robot.lasers.size());
  const ParameterBounds& bounds = opt.bounds;
  B.lasers.resize(static_cast<std::size_t>(nl));
  for (int l = 0; l < nl; ++l) {
    LaserBlocks& L = B.lasers[static_cast<std::size_t>(l)];
    const LaserModel& lm = robot.lasers[static_cast<std::size_t>(l)];
    for (int q = 0; q < 3; ++q) L.origin[static_cast<std::size_t>(q)] = lm.origin(q);
    L.d0 = lm.direction.normalized();
    tangent_basis(L.d0, L.de1, L.de2);
    L.n0 = lm.plane_normal.normalized();
    tangent_basis(L.n0, L.ne1, L.ne2);
    L.c = L.n0.dot(lm.plane_point);
    using K = ParameterKind;
    add_geometry_block(B, L.origin.data(), 3, {true, true, true},
                       {{K::kLaserOrigin, l, 0}, {K::kLaserOrigin, l, 1}, {K::kLaserOrigin, l, 2}},
                       "m", opt.estimate_laser_origin, {bounds.laser_origin_m});
    add_geometry_block(B, L.direction.data(), 2, {true, true},
                       {{K::kLaserDirection, l, 0}, {K::kLaserDirection, l, 1}}, "rad",
                       opt.estimate_laser_direction, {bounds.laser_direction_rad});
    add_geometry_block(B, L.normal.data(), 2, {true, true},
                       {{K::kLaserPlaneNormal, l, 0}, {K::kLaserPlaneNormal, l, 1}}, "rad",
                       opt.estimate_laser_plane && !fix_plane, {bounds.plane_normal_rad});
    add_geometry_block(B, &L.c, 1, {true}, {{K::kLaserPlaneOffset, l, -1}}, "m",
                       opt.estimate_laser_plane && !fix_plane, {bounds.plane_offset_m});
  }
}

// The swivel zeros, the inclinometer mounting and the IMU yaw zero: free only when estimated and
// measured somewhere.
void add_orientation_sensor_blocks(Built& B, const RobotModel& robot, const MeasurementSet& set,
                                   const IdentificationOptions& opt) {
  const int m = B.m;
  const ParameterBounds& bounds = opt.bounds;
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
  B.swivel_zero.assign(static_cast<std::size_t>(m), 0.0);
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    B.swivel_zero[ui] = robot.swivel_encoder(i).zero;
    const bool free_i = opt.estimate_swivel_zeros && opt.use_swivel && swivel_seen[ui];
    B.swivel_zero_free = B.swivel_zero_free || free_i;
    add_geometry_block(B, &B.swivel_zero[ui], 1, {true},
                       {ParameterId{ParameterKind::kSwivelZero, i, -1}}, "rad", free_i,
                       {bounds.swivel_zero_rad});
  }
  B.incl_mount0 = rotation_from_rpy<double>(robot.inclinometer.mounting_rpy);
  B.incl_mount_free = opt.estimate_inclinometer_mounting &&
                      ((opt.use_inclinometer && incl_seen) || (opt.use_imu_yaw && yaw_seen));
  add_geometry_block(B, B.incl_mount.data(), 2, {true, true},
                     {ParameterId{ParameterKind::kInclinometerMount, -1, 0},
                      ParameterId{ParameterKind::kInclinometerMount, -1, 1}},
                     "rad", B.incl_mount_free, {bounds.inclinometer_mount_rad});
  B.imu_yaw_zero = robot.inclinometer.yaw_zero;
  B.imu_yaw_zero_free = opt.estimate_imu_yaw_zero && opt.use_imu_yaw && yaw_seen;
  add_geometry_block(B, &B.imu_yaw_zero, 1, {true},
                     {ParameterId{ParameterKind::kImuYawZero, -1, -1}}, "rad", B.imu_yaw_zero_free,
                     {bounds.imu_yaw_zero_rad});
}

// The pose blocks at their guesses, the home pose held (by the gauge) at its reference, commanded
// or configured pose; a suspended robot with fewer than 6 cables estimates the home's tilt.
void add_pose_blocks(Built& B, const RobotModel& robot, const MeasurementSet& set,
                     const std::vector<Pose>& poses, const IdentificationOptions& opt,
                     bool fix_home) {
  const int m = B.m;
  const int n = set.num_poses();
  const bool suspended_gauge = fix_home && robot.suspended && m < 6 && opt.use_equilibrium;
  B.poses.resize(static_cast<std::size_t>(n));
  B.pose_free.assign(static_cast<std::size_t>(n), true);
  for (int j = 0; j < n; ++j) {
    Pose p = poses[static_cast<std::size_t>(j)];
    if (fix_home && j == opt.home_pose_index) {
      const PoseMeasurement& pm = set.poses[static_cast<std::size_t>(j)];
      p = pm.reference ? *pm.reference : opt.home_at_commanded ? pm.commanded : robot.home;
      B.pose_free[static_cast<std::size_t>(j)] = false;
    }
    const auto v = p.vector();
    for (int q = 0; q < 6; ++q)
      B.poses[static_cast<std::size_t>(j)][static_cast<std::size_t>(q)] = v(q);
    B.problem.AddParameterBlock(B.poses[static_cast<std::size_t>(j)].data(), 6);
    if (!B.pose_free[static_cast<std::size_t>(j)] && !suspended_gauge) {
      B.problem.SetParameterBlockConstant(B.poses[static_cast<std::size_t>(j)].data());
    }
  }
  if (suspended_gauge) {
    // Suspended robot with m < 6 cables: gravity fixes the world frame's tilt (the equilibrium
    // residuals), so the home pose holds only its position and heading; its roll and pitch are
    // estimated with the geometry (two more columns, "home.roll", "home.pitch").
    add_geometry_block(B, B.poses[static_cast<std::size_t>(opt.home_pose_index)].data(), 6,
                       {false, false, false, true, true, false},
                       {ParameterId{ParameterKind::kHomePose, -1, 0},
                        {ParameterKind::kHomePose, -1, 1},
                        {ParameterKind::kHomePose, -1, 2},
                        {ParameterKind::kHomePose, -1, 3},
                        {ParameterKind::kHomePose, -1, 4},
                        {ParameterKind::kHomePose, -1, 5}},
                       "rad", true, {opt.bounds.home_tilt_rad});
    B.home_tilt_free = true;
    if (opt.home_at_commanded) B.hang_home_at = robot.home;
    B.num_geometry = static_cast<int>(B.names.size());
  }
}

// A new loss of the options' kind for one residual block (Ceres owns it; nullptr: least squares).
ceres::LossFunction* make_loss(const IdentificationOptions& opt) {
  switch (opt.loss) {
    case RobustLoss::kHuber:
      return new ceres::HuberLoss(opt.loss_scale);
    case RobustLoss::kCauchy:
      return new ceres::CauchyLoss(opt.loss_scale);
    case RobustLoss::kNone:
      return nullptr;
  }
  return nullptr;
}

// What one pose's residual rows are built from.
struct PoseRows {
  const RobotModel& robot;
  const IdentificationOptions& opt;
  const SensorNoise noise;  // the set's, widened by the pose's scatter (noise_at)
  const PoseMeasurement& pm;
  std::size_t j;
  double* pose;
  bool have_tensions;
};

// The residual block `id` of the pose, with its `rows` rows of `channel` from `index` on.
void add_row(Built& B, const PoseRows& P, ceres::ResidualBlockId id, Channel channel, int index,
             int rows = 1) {
  B.blocks_per_pose[P.j].push_back(id);
  for (int q = 0; q < rows; ++q) B.rows_per_pose[P.j].push_back({channel, index + q});
}

// The pose's cable length rows: a slack cable (tension reading below the threshold) sags, its
// length says nothing exact about the geometry, so it is left out (its zero tension still enters
// the equilibrium).
void add_length_rows(Built& B, const PoseRows& P, double slack, bool& missing_tension_warned) {
  const int m = B.m;
  const PoseMeasurement& pm = P.pm;
  for (int i = 0; i < m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    if (std::isnan(pm.cable_lengths(i))) continue;
    if (P.have_tensions && !std::isnan(pm.tensions(i)) && pm.tensions(i) < slack) continue;
    auto* f = new LengthCost;
    f->k = &B.constants[ui];
    f->reading = pm.cable_lengths(i);
    f->tension = P.have_tensions ? pm.tensions(i) : kNaN;
    if (std::isnan(f->tension) && !missing_tension_warned &&
        P.robot.cables[ui].elongation != ElongationKind::kRigid) {
      B.notes.push_back("some tensions are missing: their cables are taken as unstretched");
      missing_tension_warned = true;
    }
    // Force noise propagated through the elongation (at the current geometry, LengthCost).
    f->sigma_length = P.noise.sigma_length;
    f->sigma_force = std::isnan(f->tension) ? 0.0 : P.noise.sigma_force;
    f->extra_compliance = pm.extra_compliance.size() == m ? pm.extra_compliance(i) : 0.0;
    double* e_ptr = P.opt.estimate_stiffness == StiffnessEstimate::kShared ? &B.e[0] : &B.e[ui];
    auto id = B.problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<LengthCost, 1, 3, 3, 6, 1, 1, 1, 1, 1>(f), make_loss(P.opt),
        B.a[ui].data(), B.b[ui].data(), P.pose, &B.o[ui], &B.s[ui], e_ptr, &B.g[ui], &B.c[ui]);
    add_row(B, P, id, Channel::kLength, i);
  }
}

void add_laser_rows(Built& B, const PoseRows& P) {
  const int nl = static_cast<int>(B.lasers.size());
  for (int l = 0; l < std::min<int>(nl, static_cast<int>(P.pm.laser_distances.size())); ++l) {
    if (std::isnan(P.pm.laser_distances(l))) continue;
    LaserBlocks& L = B.lasers[static_cast<std::size_t>(l)];
    auto* f = new LaserCost;
    f->d0 = L.d0;
    f->de1 = L.de1;
    f->de2 = L.de2;
    f->n0 = L.n0;
    f->ne1 = L.ne1;
    f->ne2 = L.ne2;
    f->reading = P.pm.laser_distances(l);
    f->sigma = P.noise.sigma_laser;
    auto id = B.problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<LaserCost, 1, 6, 3, 2, 2, 1>(f), make_loss(P.opt), P.pose,
        L.origin.data(), L.direction.data(), L.normal.data(), &L.c);
    add_row(B, P, id, Channel::kLaser, l);
  }
}

// A suspended robot with m < 6 cables: the 6 - m unit wrench axes with the largest share in the
// complement of the structure matrix (distinct), the directions its equilibrium leaves free.
Eigen::MatrixXd suspended_null_basis(const KinematicsData& kin, int m) {
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(Eigen::MatrixXd(kin.structure_matrix),
                                              Eigen::ComputeFullU);
  const Eigen::MatrixXd N0 = svd.matrixU().rightCols(6 - m);
  const Eigen::VectorXd share = N0.rowwise().squaredNorm();
  std::vector<int> order(6);
  for (int q = 0; q < 6; ++q) order[static_cast<std::size_t>(q)] = q;
  std::stable_sort(order.begin(), order.end(), [&](int x, int y) { return share(x) > share(y); });
  Eigen::MatrixXd basis = Eigen::MatrixXd::Zero(6, 6 - m);
  for (int q = 0; q < 6 - m; ++q) basis(order[static_cast<std::size_t>(q)], q) = 1.0;
  return basis;
}

// The pose's equilibrium row (6 residuals) with its parameter blocks in EquilibriumCost's order.
void add_equilibrium_row(Built& B, const PoseRows& P, const KinematicsData& kin) {
  const int m = B.m;
  const PoseMeasurement& pm = P.pm;
  auto* f = new EquilibriumCost;
  f->k = B.constants;
  f->tensions = pm.tensions;
  f->gravity = P.robot.gravity;
  f->external = pm.external_wrench;
  f->sigma_force = P.noise.sigma_force;
  f->sigma_length = P.noise.sigma_length;
  f->shared_stiffness = P.opt.estimate_stiffness == StiffnessEstimate::kShared;
  if (P.robot.suspended && m < 6) {
    f->null_basis = suspended_null_basis(kin, m);
    f->sigma_null = P.opt.suspended_equilibrium_sigma;
  }
  if (pm.extra_compliance.size() == m) {
    f->extra_compliance.assign(pm.extra_compliance.data(), pm.extra_compliance.data() + m);
  }
  if (P.opt.use_lengths) {
    // The cables that have a length row at this pose (the same test as add_length_rows).
    f->readings.assign(static_cast<std::size_t>(m), kNaN);
    for (const RowInfo& ri : B.rows_per_pose[P.j]) {
      if (ri.channel == Channel::kLength) {
        f->readings[static_cast<std::size_t>(ri.index)] = pm.cable_lengths(ri.index);
      }
    }
  }
  B.equilibrium[P.j] = f;
  std::vector<double*> blocks;
  std::vector<int> sizes;
  const auto add_block = [&](double* ptr, int size) {
    blocks.push_back(ptr);
    sizes.push_back(size);
  };
  add_block(P.pose, 6);
  for (int i = 0; i < m; ++i) add_block(B.a[static_cast<std::size_t>(i)].data(), 3);
  for (int i = 0; i < m; ++i) add_block(B.b[static_cast<std::size_t>(i)].data(), 3);
  for (std::vector<double>* v : {&B.g, &B.c, &B.o, &B.s}) {
    for (int i = 0; i < m; ++i) add_block(&(*v)[static_cast<std::size_t>(i)], 1);
  }
  for (int i = 0; i < (f->shared_stiffness ? 1 : m); ++i) {
    add_block(&B.e[static_cast<std::size_t>(i)], 1);
  }
  f->mass_block = static_cast<int>(blocks.size());
  add_block(&B.mass, 1);
  add_block(B.com.data(), 3);
  auto* cost = equilibrium_cost_function(f, sizes);
  B.equilibrium_blocks[P.j] = blocks;
  auto id = B.problem.AddResidualBlock(cost, make_loss(P.opt), blocks);
  add_row(B, P, id, Channel::kWrench, 0, 6);
}

void add_reference_row(Built& B, const PoseRows& P) {
  auto* f = new ReferenceCost;
  f->reference = P.pm.reference->vector();
  f->inv_sigma << Eigen::Vector3d::Constant(1.0 / P.noise.sigma_reference_position),
      Eigen::Vector3d::Constant(1.0 / P.noise.sigma_reference_angle);
  auto id = B.problem.AddResidualBlock(new ceres::AutoDiffCostFunction<ReferenceCost, 6, 6>(f),
                                       make_loss(P.opt), P.pose);
  add_row(B, P, id, Channel::kReference, 0, 6);
}

void add_swivel_rows(Built& B, const PoseRows& P) {
  for (int i = 0; i < B.m; ++i) {
    const auto ui = static_cast<std::size_t>(i);
    if (std::isnan(P.pm.swivel_angles(i))) continue;
    auto* f = new SwivelCost;
    f->pulley_frame = P.robot.pulleys[ui].frame;
    f->direction = P.robot.swivel_encoder(i).direction;
    f->reading = P.pm.swivel_angles(i);
    f->sigma = P.noise.sigma_swivel;
    auto id = B.problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<SwivelCost, 1, 3, 3, 6, 1>(f), make_loss(P.opt),
        B.a[ui].data(), B.b[ui].data(), P.pose, &B.swivel_zero[ui]);
    add_row(B, P, id, Channel::kSwivel, i);
  }
}

void add_inclinometer_row(Built& B, const PoseRows& P) {
  auto* f = new InclinometerCost;
  f->mount0 = B.incl_mount0;
  f->reading = P.pm.inclination;
  f->sigma = P.noise.sigma_inclination;
  auto id =
      B.problem.AddResidualBlock(new ceres::AutoDiffCostFunction<InclinometerCost, 2, 6, 2>(f),
                                 make_loss(P.opt), P.pose, B.incl_mount.data());
  add_row(B, P, id, Channel::kInclination, 0, 2);
}

void add_imu_yaw_row(Built& B, const PoseRows& P) {
  auto* f = new ImuYawCost;
  f->mount0 = B.incl_mount0;
  f->reading = P.pm.imu_yaw;
  f->sigma = P.noise.sigma_imu_yaw;
  auto id =
      B.problem.AddResidualBlock(new ceres::AutoDiffCostFunction<ImuYawCost, 1, 6, 2, 1>(f),
                                 make_loss(P.opt), P.pose, B.incl_mount.data(), &B.imu_yaw_zero);
  add_row(B, P, id, Channel::kImuYaw, 0);
}

// Every pose's residual rows, channel by channel in a fixed order.
void add_residual_rows(Built& B, const RobotModel& robot, const MeasurementSet& set,
                       const IdentificationOptions& opt) {
  const int m = B.m;
  const int n = set.num_poses();
  B.blocks_per_pose.resize(static_cast<std::size_t>(n));
  B.rows_per_pose.resize(static_cast<std::size_t>(n));
  B.equilibrium.assign(static_cast<std::size_t>(n), nullptr);
  B.equilibrium_blocks.assign(static_cast<std::size_t>(n), {});
  const double slack = slack_threshold(opt, set.noise);
  bool missing_tension_warned = false;
  KinematicsData kin(robot);
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const PoseMeasurement& pm = set.poses[uj];
    double* pose = B.poses[uj].data();
    const PoseRows P{robot, opt, noise_at(set.noise, pm), pm, uj, pose, pm.tensions.size() == m};
    inverse_kinematics(robot,
                       Pose::from_vector(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(pose)), kin);
    if (opt.use_lengths) add_length_rows(B, P, slack, missing_tension_warned);
    if (opt.use_laser) add_laser_rows(B, P);
    // A supported platform (it rested on something): the cables did not carry its whole weight.
    if (opt.use_equilibrium && P.have_tensions && pm.tensions.allFinite() && !pm.supported) {
      add_equilibrium_row(B, P, kin);
    }
    if (opt.use_reference && pm.reference && B.pose_free[uj]) add_reference_row(B, P);
    if (opt.use_swivel && pm.swivel_angles.size() == m) add_swivel_rows(B, P);
    if (opt.use_inclinometer && !std::isnan(pm.inclination(0)) && !std::isnan(pm.inclination(1))) {
      add_inclinometer_row(B, P);
    }
    if (opt.use_imu_yaw && !std::isnan(pm.imu_yaw)) add_imu_yaw_row(B, P);
    B.num_residuals += static_cast<int>(B.rows_per_pose[uj].size());
  }
}

}  // namespace

Result<std::unique_ptr<Built>> build_problem(const CalibratedModel& model,
                                             const MeasurementSet& set,
                                             const std::vector<Pose>& poses,
                                             const IdentificationOptions& opt) {
  const bool fix_home = opt.gauge == Gauge::kHomePose || opt.gauge == Gauge::kHomePoseAndLaserPlane;
  const bool fix_plane =
      opt.gauge == Gauge::kLaserPlane || opt.gauge == Gauge::kHomePoseAndLaserPlane;
  CDPR_RETURN_IF_ERROR(check_inputs(model, set, poses, opt, fix_home));
  const RobotModel& robot = model.robot;
  auto B = std::make_unique<Built>();
  init_cables(*B, model, opt);
  // Geometry blocks in a fixed order: a, b, o, s, e, g, c, lasers, the orientation sensors, the
  // platform's weight, each free coordinate bounded to its physical range (ParameterBounds).
  add_anchor_blocks(*B, opt);
  add_cable_scalar_blocks(*B, robot, opt);
  add_laser_blocks(*B, robot, opt, fix_plane);
  add_orientation_sensor_blocks(*B, robot, set, opt);
  add_platform_weight_blocks(*B, robot, set, opt);
  B->num_geometry = static_cast<int>(B->names.size());
  add_pose_blocks(*B, robot, set, poses, opt, fix_home);
  add_residual_rows(*B, robot, set, opt);
  return B;
}

}  // namespace cdpr::ident_detail
