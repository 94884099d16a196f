// The constant description of a cable robot (Pinocchio-style "Model"): geometry, winches, cables,
// pulleys, sensors. Algorithms take a const RobotModel& plus a scratch workspace of their own.
//
// Conventions (stated once, used everywhere; docs/config.md repeats them):
// - SI units: m, rad, N, s, kg.
// - World frame K0: z up, gravity g = (0, 0, -9.81) m/s^2.
// - Platform pose: position r (world, m) of the platform frame origin, orientation from
//   roll-pitch-yaw (rad) as R = Rz(yaw) * Ry(pitch) * Rx(roll).
// - Cable i runs from frame anchor a_i (world) to platform anchor b_i (platform frame).
//   Cable vector l_i = a_i - r - R b_i, length l_i = ||l_i||, unit vector u_i = l_i / l_i (points
//   from the platform towards the frame). Cable force on the platform = f_i * u_i with f_i >= 0.
// - Swivel pulley: a_i is the fixed point D_i on the swivel axis where the cable enters the
//   pulley. The pulley frame (rotation `frame`, world columns ex, ey, ez) has ez along the swivel
//   axis, pointing the way the incoming cable travels (from the winch into the pulley), and ex the
//   reference direction of the swivel angle gamma. The pulley centre is at distance `radius` from
//   the axis. With radius == 0 the pulley is a point anchor.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <string>
#include <vector>

namespace cdpr {

// A platform pose: position and roll-pitch-yaw.
struct Pose {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // m, world
  Eigen::Vector3d rpy = Eigen::Vector3d::Zero();       // rad: roll, pitch, yaw

  Eigen::Matrix<double, 6, 1> vector() const {
    Eigen::Matrix<double, 6, 1> v;
    v << position, rpy;
    return v;
  }
  static Pose from_vector(const Eigen::Matrix<double, 6, 1>& v) {
    return Pose{v.head<3>(), v.tail<3>()};
  }
};

struct PulleyModel {
  double radius = 0.0;                                  // m; 0 = point anchor (no pulley)
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();  // columns ex, ey, ez in world
  bool enabled() const { return radius > 0.0; }
};

// Winch transmission, paper Eq. 1: L = sqrt((pi d)^2 + p^2) * turns_of_drum.
struct WinchModel {
  double drum_diameter = 0.05;    // m
  double drum_pitch = 0.0;        // m per drum revolution (groove pitch)
  double gear_ratio = 1.0;        // motor revolutions per drum revolution
  double counts_per_rev = 65536;  // encoder counts per motor revolution
  int direction = 1;              // +1: positive counts pay cable out (length grows); -1 reversed
  // Added for winch.hpp (encoder zero): the cable length command (unstretched length from the
  // frame anchor D to the platform anchor, see ik_compensation.hpp) at encoder count 0, m.
  // Identified by the calibration (it trades against the frame anchor along the cable).
  double length_offset = 0.0;
};

enum class ElongationKind { kRigid, kHooke, kPolynomial };

// Polynomial surface dL = sum_{i+j<=order} c_ij * L^i * F^j, coefficients in graded order
// (i + j = 0, then 1, ...; within a degree, increasing j). L in m, F in N, dL in m.
//
// Added for elongation.hpp (well-conditioned fits): the polynomial is evaluated in the scaled
// variables s = (L - length_center) / length_scale and t = (F - tension_center) / tension_scale,
// i.e. dL = sum c_ij s^i t^j. The defaults (0, 1, 0, 1) give the plain form above. L is the loaded
// cable length between drum and platform (routing_length + kinematic length), F the tension.
struct PolynomialSurface {
  int order = 0;
  std::vector<double> coefficients;  // (order + 1) (order + 2) / 2 entries, graded order
  double length_center = 0.0;        // m
  double length_scale = 1.0;         // m, > 0
  double tension_center = 0.0;       // N
  double tension_scale = 1.0;        // N, > 0
};

struct CableModel {
  double ea = 1.0e5;             // axial stiffness E*A, N
  double mass_per_length = 0.0;  // kg/m
  // m, cable between the winch drum and the frame anchor (through the routing pulleys). It is
  // stretched by the tension too. Added for the config loader (drivers/config); 0 = unknown.
  double routing_length = 0.0;
  ElongationKind elongation = ElongationKind::kHooke;
  PolynomialSurface polynomial;  // used when elongation == kPolynomial
  double f_min = 5.0;            // N, minimum allowed tension
  double f_max = 500.0;          // N, maximum allowed tension
};

// Force sensor: raw = gain * tension + offset (the paper's rig: gain 2).
struct ForceSensorModel {
  double gain = 1.0;
  double offset = 0.0;  // N (in raw units)
};

struct PlatformModel {
  double mass = 1.0;                                             // kg
  Eigen::Vector3d center_of_mass = Eigen::Vector3d::Zero();      // platform frame, m
  Eigen::Matrix3d inertia = Eigen::Matrix3d::Identity() * 0.01;  // kg m^2 about the CoM (optional)
};

// A 1-D laser distance sensor on the platform, aimed at a plane fixed in the world.
struct LaserModel {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();         // platform frame, m
  Eigen::Vector3d direction = -Eigen::Vector3d::UnitZ();    // platform frame, unit
  Eigen::Vector3d plane_point = Eigen::Vector3d::Zero();    // world, m
  Eigen::Vector3d plane_normal = Eigen::Vector3d::UnitZ();  // world, unit
  double range_min = 0.0;                                   // m
  double range_max = 10.0;                                  // m
};

// Encoder on the swivel axis of pulley i (issue 18). With gamma the swivel angle of
// kinematics.hpp (angle of the platform anchor about the pulley axis ez, from the pulley's
// reference direction ex) it reads
//   swivel_i = wrap(direction * (gamma - zero))          (rad, wrapped to (-pi, pi])
// `zero` is the geometric swivel angle at which the encoder reads 0; it is what the
// identification estimates ("swivel-zeros").
struct SwivelEncoderModel {
  double zero = 0.0;  // rad
  int direction = 1;  // +1: the reading grows with gamma (about +ez); -1 reversed
};

// Inclinometer (optionally an IMU with a heading) on the platform (issue 18). Its sensor frame
// has the orientation R_s = R(pose) * R_m in the world, R_m = rotation_from_rpy(mounting_rpy)
// (the sensor frame in the platform frame). It reads the roll and pitch of R_s (gravity's
// direction in the sensor frame, R_s = Rz(yaw) Ry(pitch) Rx(roll)):
//   incl_roll = atan2(R_s(2,1), R_s(2,2)),  incl_pitch = atan2(-R_s(2,0), hypot(R_s(2,1),
//   R_s(2,2)))
// and, for an IMU with a heading, imu_yaw = wrap(atan2(R_s(1,0), R_s(0,0)) - yaw_zero).
struct InclinometerModel {
  Eigen::Vector3d mounting_rpy = Eigen::Vector3d::Zero();  // rad, sensor frame in platform frame
  double yaw_zero = 0.0;  // rad, heading of the IMU's reference in the world (imu_yaw only)
};

struct RobotModel {
  std::string name;
  Eigen::Matrix3Xd frame_anchors;               // a_i, 3 x m, world
  Eigen::Matrix3Xd platform_anchors;            // b_i, 3 x m, platform frame
  std::vector<PulleyModel> pulleys;             // m entries
  std::vector<WinchModel> winches;              // m entries
  std::vector<CableModel> cables;               // m entries
  std::vector<ForceSensorModel> force_sensors;  // m entries
  PlatformModel platform;
  Pose home;
  std::vector<LaserModel> lasers;
  double gravity = 9.81;  // m/s^2, along -z of the world
  // Swivel-angle encoders (issue 18): m entries, or empty = every cable zero 0, direction +1.
  std::vector<SwivelEncoderModel> swivel_encoders;
  InclinometerModel inclinometer;  // used only by recordings with incl_/imu_ columns
  // Suspended robot (issue 18): the platform hangs from the cables and gravity keeps them taut.
  // With fewer than six cables (under-actuated, e.g. a 4-cable crane) the cable lengths fix only
  // m of the six pose coordinates; the other 6 - m follow from the static equilibrium
  // (suspended_statics.hpp). model_check then asks for equilibrium at home instead of rank 6.
  bool suspended = false;

  // The swivel encoder of cable i (the default one when swivel_encoders is empty).
  SwivelEncoderModel swivel_encoder(int i) const {
    return swivel_encoders.empty() ? SwivelEncoderModel{}
                                   : swivel_encoders[static_cast<std::size_t>(i)];
  }

  int num_cables() const { return static_cast<int>(frame_anchors.cols()); }

  // The platform's characteristic length rho (m): the largest |b_i|, or 1 for a point platform
  // (every |b_i| under 1 um). It turns moments into forces and rotations into lengths wherever
  // force and moment rows, or position and angle errors, are weighed together.
  double platform_radius() const {
    double rho = 0.0;
    for (int i = 0; i < num_cables(); ++i) rho = std::max(rho, platform_anchors.col(i).norm());
    return rho > 1e-6 ? rho : 1.0;
  }
};

}  // namespace cdpr
