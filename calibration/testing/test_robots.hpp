// Test robots shared by the calibration tests and benchmarks (header-only, namespace
// cdpr::testing). Numbers are SI; config/mini.yaml copies the MINI values below.
//
// MINI (Jin et al. 2018, Table 1, column "3D Tool Solidworks Data", mm -> m). The table's row of
// cable 7 repeats a +x corner; it belongs at (-0.5315, +0.345, 0.4415), used here.
//
//   cable   frame anchor a_i (m)              platform anchor b_i (m, platform frame)
//     1     ( 0.5000, -0.378, -0.4415)        ( 0.060, -0.075, -0.030)   bottom corners
//     2     (-0.5000, -0.378, -0.4415)        (-0.060, -0.075, -0.030)
//     3     (-0.5000,  0.378, -0.4415)        (-0.060,  0.075, -0.030)
//     4     ( 0.5000,  0.378, -0.4415)        ( 0.060,  0.075, -0.030)
//     5     ( 0.5315, -0.345,  0.4415)        ( 0.060, -0.075,  0.030)   top corners
//     6     (-0.5315, -0.345,  0.4415)        (-0.060, -0.075,  0.030)
//     7     (-0.5315,  0.345,  0.4415)        (-0.060,  0.075,  0.030)
//     8     ( 0.5315,  0.345,  0.4415)        ( 0.060,  0.075,  0.030)
//
// Platform: an assumed 0.12 x 0.15 x 0.06 m box (x, y, z; the paper gives no platform anchors);
// each cable goes to the platform corner on the same side as its frame anchor (not crossed),
// bottom cables to the bottom corners, top cables to the top corners. Among the boxes tried this
// keeps the structure matrix well conditioned: condition number (moment rows divided by the
// anchor radius 0.101 m) 4.2 at home and below 9 over the whole test workspace; a
// 0.12 x 0.10 x 0.10 box, for comparison, reaches ~700 with pulleys (a near-singular layout).
// Mass 2.0 kg, centre of mass at the platform origin, home pose = the origin, no rotation (the
// paper's reference platform).
//
// Pulleys (assumed): radius 0.025 m, swivel axis vertical. The cable reaches D along the swivel
// axis from the winch, travelling towards the platform's height: top pulleys ez = (0, 0, -1)
// (cable comes down into the pulley), bottom pulleys ez = (0, 0, +1) (cable comes up). ex is the
// horizontal direction from a_i towards the frame's vertical centre line (swivel angle ~0 at
// home), ey = ez x ex.
//
// Winch (assumed): drum diameter 0.04 m, pitch 0.002 m, gear ratio 10, 65536 counts per motor
// revolution, direction +1, length_offset 0. Cable (assumed, 1.5 mm Dyneema-like): EA 2.0e4 N,
// 0.0015 kg/m, Hooke, routing_length 0.5 m, tensions 5..200 N. Force sensors: gain 2 (paper),
// offset 0.
//
// LARGE: IPAnema-3-like dimensions, all values ASSUMED (the published IPAnema 3 anchors are not
// used): frame 16 m x 12 m x 5 m, bottom anchors (+-8.0, +-6.0, -2.3), top anchors
// (+-7.8, +-5.7, 2.5) in the same corner order as MINI; platform box 0.8 x 1.0 x 0.5 m (chosen
// like MINI's: condition number ~20 at home, below ~100 over the test workspace), 40 kg;
// pulley radius 0.1 m; drum 0.2 m, pitch 0.008 m, gear ratio 20; cable EA 3.0e5 N, 0.02 kg/m,
// routing_length 3 m, tensions 50..6000 N.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <numbers>
#include <random>
#include <string>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/robot_model.hpp"

namespace cdpr::testing {

// Pulley frame for an anchor: vertical swivel axis (ez = +z when `cable_goes_up`), ex horizontal
// towards the frame's vertical centre line, ey = ez x ex.
inline Eigen::Matrix3d vertical_swivel_frame(const Eigen::Vector3d& anchor, bool cable_goes_up) {
  const Eigen::Vector3d ez(0.0, 0.0, cable_goes_up ? 1.0 : -1.0);
  Eigen::Vector3d ex(-anchor.x(), -anchor.y(), 0.0);
  if (ex.norm() < 1e-12) ex = Eigen::Vector3d::UnitX();
  ex.normalize();
  Eigen::Matrix3d frame;
  frame.col(0) = ex;
  frame.col(1) = ez.cross(ex);
  frame.col(2) = ez;
  return frame;
}

// Eight-cable layout shared by both robots: cables 1-4 bottom (+x-y, -x-y, -x+y, +x+y), 5-8 top.
struct BoxRobotSpec {
  std::string name;
  Eigen::Vector2d bottom_xy;      // |x|, |y| of the bottom frame anchors, m
  double bottom_z = 0.0;          // m
  Eigen::Vector2d top_xy;         // |x|, |y| of the top frame anchors, m
  double top_z = 0.0;             // m
  Eigen::Vector3d platform_half;  // half sizes of the platform box, m
  double mass = 1.0;              // kg
  double pulley_radius = 0.0;     // m
  WinchModel winch;
  CableModel cable;
};

inline RobotModel make_box_robot(const BoxRobotSpec& spec, bool with_pulleys) {
  static constexpr double kSx[4] = {1.0, -1.0, -1.0, 1.0};
  static constexpr double kSy[4] = {-1.0, -1.0, 1.0, 1.0};
  RobotModel model;
  model.name = spec.name;
  model.frame_anchors.resize(3, 8);
  model.platform_anchors.resize(3, 8);
  for (int i = 0; i < 8; ++i) {
    const int c = i % 4;
    const bool top = i >= 4;
    const Eigen::Vector2d& xy = top ? spec.top_xy : spec.bottom_xy;
    model.frame_anchors.col(i) << kSx[c] * xy.x(), kSy[c] * xy.y(),
        top ? spec.top_z : spec.bottom_z;
    model.platform_anchors.col(i) << kSx[c] * spec.platform_half.x(),
        kSy[c] * spec.platform_half.y(), top ? spec.platform_half.z() : -spec.platform_half.z();
    PulleyModel pulley;
    pulley.radius = with_pulleys ? spec.pulley_radius : 0.0;
    pulley.frame = vertical_swivel_frame(model.frame_anchors.col(i), /*cable_goes_up=*/!top);
    model.pulleys.push_back(pulley);
    model.winches.push_back(spec.winch);
    model.cables.push_back(spec.cable);
    ForceSensorModel sensor;
    sensor.gain = 2.0;
    model.force_sensors.push_back(sensor);
  }
  model.platform.mass = spec.mass;
  model.home = Pose{};
  return model;
}

inline BoxRobotSpec mini_spec() {
  BoxRobotSpec s;
  s.name = "MINI";
  s.bottom_xy = {0.5, 0.378};
  s.bottom_z = -0.4415;
  s.top_xy = {0.5315, 0.345};
  s.top_z = 0.4415;
  s.platform_half = {0.06, 0.075, 0.03};
  s.mass = 2.0;
  s.pulley_radius = 0.025;
  s.winch.drum_diameter = 0.04;
  s.winch.drum_pitch = 0.002;
  s.winch.gear_ratio = 10.0;
  s.winch.counts_per_rev = 65536.0;
  s.cable.ea = 2.0e4;
  s.cable.mass_per_length = 0.0015;
  s.cable.routing_length = 0.5;
  s.cable.elongation = ElongationKind::kHooke;
  s.cable.f_min = 5.0;
  s.cable.f_max = 200.0;
  return s;
}

inline BoxRobotSpec large_spec() {
  BoxRobotSpec s;
  s.name = "LARGE (IPAnema-3-like, assumed)";
  s.bottom_xy = {8.0, 6.0};
  s.bottom_z = -2.3;
  s.top_xy = {7.8, 5.7};
  s.top_z = 2.5;
  s.platform_half = {0.4, 0.5, 0.25};
  s.mass = 40.0;
  s.pulley_radius = 0.1;
  s.winch.drum_diameter = 0.2;
  s.winch.drum_pitch = 0.008;
  s.winch.gear_ratio = 20.0;
  s.winch.counts_per_rev = 65536.0;
  s.cable.ea = 3.0e5;
  s.cable.mass_per_length = 0.02;
  s.cable.routing_length = 3.0;
  s.cable.elongation = ElongationKind::kHooke;
  s.cable.f_min = 50.0;
  s.cable.f_max = 6000.0;
  return s;
}

inline RobotModel mini_robot(bool with_pulleys = true) {
  return make_box_robot(mini_spec(), with_pulleys);
}
inline RobotModel large_robot(bool with_pulleys = true) {
  return make_box_robot(large_spec(), with_pulleys);
}

// CRANE4 (issue 18): a 4-cable suspended laboratory crane, every value ASSUMED (a typical lab
// crane, no published robot); config/crane4.yaml copies it. Frame 2.0 x 2.3 x 1.8 m (x, y, z),
// world origin on the floor at the frame's centre, z up; the four frame anchors are the swivel
// pulleys at the top corners (+-1.0, +-1.15, 1.8) in the order (+x-y, -x-y, -x+y, +x+y); the
// cable comes down into each pulley (axis -z, reference towards the centre line). Platform: 13 kg,
// cables attached at the corners of its 0.3 x 0.3 m top face (z = 0), centre of mass 0.35 m below
// it (a tool or load hanging under the attachment plate). Stability needs the centre of mass
// below the point where the cable lines converge (about 0.18 m under the plate at home): with the
// mass at 0.1 m the platform would balance upside-down-like and tilt far off centre. Home (0, 0,
// 0.8) m level: an equilibrium by symmetry, every cable at about 53 N. Pulley radius 0.03 m; drum
// 0.05 m, pitch 0.002 m, gear ratio 10; cable EA 4.0e4 N (2 mm Dyneema-like), 0.002 kg/m, 1.0 m
// routing, Hooke, tensions 5..300 N; force sensors gain 1.
inline RobotModel crane_robot(bool with_pulleys = true) {
  static constexpr double kSx[4] = {1.0, -1.0, -1.0, 1.0};
  static constexpr double kSy[4] = {-1.0, -1.0, 1.0, 1.0};
  RobotModel model;
  model.name = "CRANE4";
  model.suspended = true;
  model.frame_anchors.resize(3, 4);
  model.platform_anchors.resize(3, 4);
  for (int i = 0; i < 4; ++i) {
    model.frame_anchors.col(i) << kSx[i] * 1.0, kSy[i] * 1.15, 1.8;
    model.platform_anchors.col(i) << kSx[i] * 0.15, kSy[i] * 0.15, 0.0;
    PulleyModel pulley;
    pulley.radius = with_pulleys ? 0.03 : 0.0;
    pulley.frame = vertical_swivel_frame(model.frame_anchors.col(i), /*cable_goes_up=*/false);
    model.pulleys.push_back(pulley);
    WinchModel w;
    w.drum_diameter = 0.05;
    w.drum_pitch = 0.002;
    w.gear_ratio = 10.0;
    model.winches.push_back(w);
    CableModel c;
    c.ea = 4.0e4;
    c.mass_per_length = 0.002;
    c.routing_length = 1.0;
    c.elongation = ElongationKind::kHooke;
    c.f_min = 5.0;
    c.f_max = 300.0;
    model.cables.push_back(c);
    model.force_sensors.push_back(ForceSensorModel{});
  }
  model.platform.mass = 13.0;
  model.platform.center_of_mass = Eigen::Vector3d(0.0, 0.0, -0.35);
  model.platform.inertia = Eigen::Vector3d(0.15, 0.15, 0.2).asDiagonal();
  model.home = Pose{Eigen::Vector3d(0.0, 0.0, 0.8), Eigen::Vector3d::Zero()};
  return model;
}

// Poses uniformly drawn in a box of translations and roll/pitch/yaw within +-max_angle.
struct WorkspaceBox {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();       // m
  Eigen::Vector3d half_extent = Eigen::Vector3d::Zero();  // m
  double max_angle = 15.0 * std::numbers::pi / 180.0;     // rad
};

// MINI: the ISO 9283 measurement cube of the paper (312 mm, centred at the origin).
inline WorkspaceBox mini_workspace() {
  return {Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.156),
          15.0 * std::numbers::pi / 180.0};
}
// LARGE: an assumed 10 m x 7 m x 2.4 m box around the centre.
inline WorkspaceBox large_workspace() {
  return {Eigen::Vector3d::Zero(), Eigen::Vector3d(5.0, 3.5, 1.2), 15.0 * std::numbers::pi / 180.0};
}

template <typename Rng>
Pose random_pose(const WorkspaceBox& box, Rng& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Pose p;
  for (int k = 0; k < 3; ++k) {
    p.position(k) = box.center(k) + box.half_extent(k) * u(rng);
    p.rpy(k) = box.max_angle * u(rng);
  }
  return p;
}

}  // namespace cdpr::testing
