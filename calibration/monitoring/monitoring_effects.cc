#include "monitoring_effects.hpp"

#include "cdpr/calibration/elongation.hpp"

namespace cdpr::monitoring {
namespace {

// Pulley moved by da: the true cable is longer by u_i . da, and its direction at the platform
// turns by (I - u u^T) da / L_free, so the measured tensions' wrench misses F_i times that.
void fill_frame_anchor(const SampleGeometry& g, int i, Monitor::Signature& s, int col) {
  const KinematicsData& k = *g.kinematics;
  const Eigen::Vector3d u = k.unit_vectors.col(i);
  const Eigen::Matrix3d turn =
      (Eigen::Matrix3d::Identity() - u * u.transpose()) / k.free_lengths(i);
  const Eigen::Vector3d arm = k.rotation * g.robot->platform_anchors.col(i);  // R b_i
  for (int c = 0; c < 3; ++c) {
    s(i, col + c) = u(c);
    const Eigen::Vector3d du = g.tensions[i] * turn.col(c);
    s.block<3, 1>(g.m, col + c) = -du;
    s.block<3, 1>(g.m + 3, col + c) = -arm.cross(du);
  }
}

// Force sensor offset d on cable i: the reading is F + d, the length row's elongation is
// computed at it (+ compliance d), the wrench gains the cable's column times d.
void fill_force_offset(const SampleGeometry& g, int i, Monitor::Signature& s, int col) {
  s(i, col) = g.compliance[i];
  s.block<6, 1>(g.m, col) = g.kinematics->structure_matrix.col(i);
}

// Encoder slip: the drum paid out s more than the encoder says: the length reading is short by s.
void fill_encoder_slip(const SampleGeometry&, int i, Monitor::Signature& s, int col) {
  s(i, col) = -1.0;
}

// Thermal growth kappa = alpha dT: the unstretched cable is longer by kappa (routing + l).
void fill_thermal(const SampleGeometry& g, int, Monitor::Signature& s, int col) {
  for (int i = 0; i < g.m; ++i) {
    s(i, col) = -(g.robot->cables[static_cast<std::size_t>(i)].routing_length + g.lengths[i]);
  }
}

// Creep compliance c: the cable stretches c F (routing + L_k) more than the model says.
void fill_creep(const SampleGeometry& g, int, Monitor::Signature& s, int col) {
  for (int i = 0; i < g.m; ++i) {
    s(i, col) = -g.tensions[i] * loaded_length(g.robot->cables[static_cast<std::size_t>(i)],
                                               g.kinematics->lengths(i));
  }
}

const EffectEntry kEffects[] = {
    {MonitorEffect::kFrameAnchor, "frame_anchor", "pulley moved (frame anchor %d)", true, 3, true,
     "frame anchor %d (x, y, z)", "mm", 1e3, fill_frame_anchor},
    {MonitorEffect::kForceOffset, "force_offset_per_cable", "force sensor drift on cable %d", true,
     1, false, "force sensor %d offset", "N", 1.0, fill_force_offset},
    {MonitorEffect::kEncoderSlip, "encoder_offset_per_cable", "encoder slip on cable %d", true, 1,
     true, "encoder zero of cable %d", "mm", 1e3, fill_encoder_slip},
    {MonitorEffect::kThermalGrowth, "thermal_growth", "cable length growth (thermal, ~ length)",
     false, 1, true, "every cable's length offset (or the thermal coefficient)", "mm/m", 1e3,
     fill_thermal},
    {MonitorEffect::kCreepGrowth, "creep_shared", "cable length growth (creep, ~ tension x length)",
     false, 1, true, "the cables' elasticity (EA) and length offsets", "1/N", 1.0, fill_creep},
};

}  // namespace

std::span<const EffectEntry> effect_table() {
  return kEffects;
}

int first_column(const EffectEntry& e, int cable, int m) {
  int col = 0;
  for (const EffectEntry& x : kEffects) {
    if (&x == &e) return col + (e.per_cable ? cable * e.columns : 0);
    col += x.per_cable ? x.columns * m : x.columns;
  }
  return -1;
}

int total_columns(int m) {
  int col = 0;
  for (const EffectEntry& x : kEffects) col += x.per_cable ? x.columns * m : x.columns;
  return col;
}

}  // namespace cdpr::monitoring
