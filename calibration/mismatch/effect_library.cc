#include "cdpr/calibration/effect_library.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "cdpr/calibration/mismatch.hpp"
#include "text_format.hpp"

namespace cdpr {
namespace {

using mismatch_detail::format;

// ---- Words for the fitted coefficients (q of k: per cable when k > 1).

std::string cable_of(int q, int k) {
  return k > 1 ? std::to_string(q + 1) : std::string();
}
std::string of_cable(int q, int k) {
  return k > 1 ? " of cable " + cable_of(q, k) : std::string();
}

EffectParameter describe_hooke(int q, int k, double v, double s) {
  // The columns are the compliance 1 / EA.
  EffectParameter e;
  e.name = k > 1 ? "EA_" + cable_of(q, k) : "EA";
  e.unit = "N";
  e.value = 1.0 / v;
  e.std_dev = s / (v * v);
  const int dg = digits_for(e.std_dev / 1e3);
  e.text = "cable elasticity" + of_cable(q, k) +
           format(": EA = %.*f +- %.*f kN", dg, e.value / 1e3, dg, e.std_dev / 1e3);
  return e;
}

EffectParameter describe_compliance(int q, int k, double v, double s) {
  EffectParameter e{k > 1 ? "c_" + cable_of(q, k) : "c", "m/N", v, s, {}};
  const int dg = digits_for(1e6 * s);
  e.text = (k > 1 ? "winch/sensor compliance of winch " + cable_of(q, k)
                  : std::string("winch/sensor compliance")) +
           ": " + format("%.*f +- %.*f um/N", dg, 1e6 * v, dg, 1e6 * s);
  return e;
}

EffectParameter describe_encoder_offset(int q, int k, double v, double s) {
  EffectParameter e{"o_" + cable_of(q, k), "m", v, s, {}};
  const int dg = digits_for(1e3 * s);
  e.text = "encoder zero offset" + of_cable(q, k) + ": " + signed_number(1e3 * v, dg) +
           format(" +- %.*f mm", dg, 1e3 * s);
  return e;
}

EffectParameter describe_encoder_drift(int q, int k, double v, double s) {
  EffectParameter e{"drift_" + cable_of(q, k), "m/s", v, s, {}};
  const int dg = digits_for(6e7 * s);
  e.text = "encoder drift" + of_cable(q, k) + ": " + signed_number(6e7 * v, dg) +
           format(" +- %.*f um/min", dg, 6e7 * s);
  return e;
}

EffectParameter describe_transmission_drift(int, int, double v, double s) {
  EffectParameter e{"transmission_drift", "1/s", v, s, {}};
  const int dg = digits_for(6e7 * s);
  e.text =
      "transmission drift: " + signed_number(6e7 * v, dg) + format(" +- %.*f ppm/min", dg, 6e7 * s);
  return e;
}

EffectParameter describe_creep(int, int, double v, double s) {
  // dL = v F L ln(1 + t / 10 s): v is the compliance added per e-fold of time.
  EffectParameter e{"creep", "1/N", v, s, {}};
  e.text = format(
      "cable creep: compliance +%.3g +- %.2g 1/N per e-fold of time (dL = c F L ln(1 + t / 10 "
      "s))",
      v, s);
  return e;
}

EffectParameter describe_nonlinear_elasticity(int q, int, double v, double s) {
  // dL = (a F + k2 F^2) L added to the model's elongation.
  EffectParameter e{q == 0 ? "a" : "k2", q == 0 ? "1/N" : "1/N^2", v, s, {}};
  e.text =
      q == 0
          ? format("nonlinear cable elongation (a F + k2 F^2) L: linear part a = %.3g +- %.2g 1/N",
                   v, s)
          : format("nonlinear cable elongation (a F + k2 F^2) L: k2 = %.3g +- %.2g 1/N^2", v, s);
  return e;
}

EffectParameter describe_hysteresis(int q, int k, double v, double s) {
  // Length rows ~d: the true length is longer by v when last paid out, shorter when reeled in.
  EffectParameter e{"h_" + cable_of(q, k), "m", v, s, {}};
  const int dg = digits_for(1e3 * s);
  e.text = "cable hysteresis" + of_cable(q, k) + ": " + signed_number(1e3 * v, dg) +
           format(
               " +- %.*f mm (the length after paying out minus the reading; the opposite "
               "after reeling in)",
               dg, 1e3 * s);
  return e;
}

EffectParameter describe_pulley_friction(int q, int k, double v, double s) {
  // The tension reading is off by v when last paid out and by -v when reeled in.
  EffectParameter e{"f_" + cable_of(q, k), "N", v, s, {}};
  const int dg = digits_for(s);
  e.text = "pulley friction" + of_cable(q, k) + ": tension reading " + signed_number(v, dg) +
           format(" +- %.*f N after paying out, the opposite after reeling in", dg, s);
  return e;
}

EffectParameter describe_drum_scale(int q, int k, double v, double s) {
  // Jacobian columns: the parameter change is -v.
  EffectParameter e{k > 1 ? "s_" + cable_of(q, k) : "s", "-", -v, s, {}};
  const int dg = digits_for(100 * s);
  e.text = (k > 1 ? "drum scale error of winch " + cable_of(q, k)
                  : std::string("drum scale error of every winch")) +
           ": " + signed_number(-100 * v, dg) + format(" +- %.*f %%", dg, 100 * s);
  return e;
}

EffectParameter describe_sag(int, int, double v, double s) {
  EffectParameter e{"mass_per_length", "kg/m", v, s, {}};
  const int dg = digits_for(1e3 * s);
  e.text =
      format("cable sag: mass per length %.*f +- %.*f g/m (catenary)", dg, 1e3 * v, dg, 1e3 * s);
  return e;
}

// ---- Writing an effect into the calibrated model.

bool rigid_cables(const CalibratedModel& model) {
  return std::all_of(model.robot.cables.begin(), model.robot.cables.end(),
                     [](const CableModel& c) { return c.elongation == ElongationKind::kRigid; });
}

bool write_encoder_offsets(const Eigen::VectorXd& theta, CalibratedModel& model) {
  if (theta.size() != model.robot.num_cables()) return false;
  model.readings.length_offsets += theta;
  return true;
}

bool write_shared_drum_scale(const Eigen::VectorXd& theta, CalibratedModel& model) {
  if (theta.size() != 1) return false;
  for (int i = 0; i < model.robot.num_cables(); ++i) {
    model.readings.length_scales(i) -= theta(0);
    model.robot.winches[static_cast<std::size_t>(i)].drum_diameter *= 1.0 - theta(0);
    model.robot.winches[static_cast<std::size_t>(i)].drum_pitch *= 1.0 - theta(0);
  }
  return true;
}

bool write_mass_per_length(const Eigen::VectorXd& theta, CalibratedModel& model) {
  if (theta.size() != 1 || !(theta(0) > 0)) return false;
  for (auto& c : model.robot.cables) c.mass_per_length = theta(0);
  return true;
}

// EA = 1 / theta (shared or per cable), only into a config whose cables were rigid.
bool write_hooke(const Eigen::VectorXd& theta, CalibratedModel& model) {
  if (!rigid_cables(model) || !(theta.array() > 0).all()) return false;
  for (int i = 0; i < model.robot.num_cables(); ++i) {
    auto& c = model.robot.cables[static_cast<std::size_t>(i)];
    c.ea = 1.0 / theta(theta.size() == 1 ? 0 : i);
    c.elongation = ElongationKind::kHooke;
  }
  return true;
}

// dL = c F as a first-order polynomial surface in the plain variables.
bool write_compliance(const Eigen::VectorXd& theta, CalibratedModel& model) {
  if (!rigid_cables(model)) return false;
  for (int i = 0; i < model.robot.num_cables(); ++i) {
    auto& c = model.robot.cables[static_cast<std::size_t>(i)];
    c.elongation = ElongationKind::kPolynomial;
    c.polynomial = PolynomialSurface{};
    c.polynomial.order = 1;
    c.polynomial.coefficients = {0.0, 0.0, theta(theta.size() == 1 ? 0 : i)};
  }
  return true;
}

// dL = (a F + k2 F^2) L: the L F and L F^2 terms of a third-order surface (coefficients by total
// degree d, then by the power of F: L^(d-j) F^j is at d (d + 1) / 2 + j).
bool write_nonlinear_elasticity(const Eigen::VectorXd& theta, CalibratedModel& model) {
  if (!rigid_cables(model) || theta.size() != 2) return false;
  for (auto& c : model.robot.cables) {
    c.elongation = ElongationKind::kPolynomial;
    c.polynomial = PolynomialSurface{};
    c.polynomial.order = 3;
    c.polynomial.coefficients.assign(10, 0.0);
    c.polynomial.coefficients[4] = theta(0);  // L F   (d = 2, j = 1)
    c.polynomial.coefficients[8] = theta(1);  // L F^2 (d = 3, j = 2)
  }
  return true;
}

// ---- The identification switches.

void estimate_shared_stiffness(IdentificationOptions& o) {
  o.estimate_stiffness = StiffnessEstimate::kShared;
}
void estimate_stiffness_per_cable(IdentificationOptions& o) {
  o.estimate_stiffness = StiffnessEstimate::kPerCable;
}
void estimate_length_scales(IdentificationOptions& o) {
  o.estimate_length_scales = true;
}
void estimate_platform_anchors(IdentificationOptions& o) {
  o.estimate_platform_anchors = true;
  o.platform_anchor_mask = AnchorMask();
}
void estimate_force_gains(IdentificationOptions& o) {
  o.estimate_force_gains = true;
}
void estimate_force_offsets(IdentificationOptions& o) {
  o.estimate_force_offsets = true;
}
void estimate_platform_weight(IdentificationOptions& o) {
  o.estimate_platform_mass = true;
  o.estimate_platform_com = true;
}
// Applied after estimate_platform_weight: a wrong mass alone should not pay for three
// centre-of-mass coordinates (the lower BIC is kept).
void platform_mass_only(IdentificationOptions& o) {
  o.estimate_platform_com = false;
}
void estimate_laser_mounting(IdentificationOptions& o) {
  o.estimate_laser_origin = true;
  o.estimate_laser_direction = true;
}
// Applied after estimate_laser_mounting. The origin's component along the target plane's normal
// trades against the plane offset (both estimated): the beam direction alone is then the
// identifiable mounting error (identify() refuses the full set). When both can be fitted the
// lower BIC is kept: a tilted beam without an offset origin should not pay for three origin
// coordinates.
void laser_direction_only(IdentificationOptions& o) {
  o.estimate_laser_origin = false;
}
void estimate_laser_direction(IdentificationOptions& o) {
  o.estimate_laser_direction = true;
}
void estimate_laser_plane(IdentificationOptions& o) {
  o.estimate_laser_plane = true;
}

const ExplainingVariable kTensionTimesLength{"tension x loaded length", "N m"};
const ExplainingVariable kTension{"tension", "N"};
const ExplainingVariable kLoadedLength{"loaded length", "m"};
const ExplainingVariable kTime{"time", "s"};
const ExplainingVariable kLastMove{"direction of the last move", ""};
const ExplainingVariable kPoseIndex{"pose index", ""};

using C = EffectColumns;
using R = EffectRefit;

std::vector<EffectDescriptor> make_library() {
  std::vector<EffectDescriptor> lib;
  // Regressors on the length rows.
  lib.push_back({"hooke_shared", "cable elasticity (Hooke, ~F*L), one EA for all cables",
                 "elasticity", "elasticity", C::kLengthRows, R::kIdentification,
                 estimate_shared_stiffness, nullptr, "ParameterBounds::ea_factor_min/max",
                 describe_hooke, write_hooke, kTensionTimesLength});
  lib.push_back({"hooke_per_cable", "cable elasticity (Hooke, ~F*L), EA per cable", "elasticity",
                 "elasticity", C::kLengthRows, R::kIdentification, estimate_stiffness_per_cable,
                 nullptr, "ParameterBounds::ea_factor_min/max", describe_hooke, write_hooke,
                 kTensionTimesLength});
  lib.push_back({"compliance_shared", "winch/sensor compliance (~F), the same for all winches",
                 "compliance", "compliance", C::kLengthRows, R::kGaussNewton, nullptr, nullptr,
                 "none (linear)", describe_compliance, write_compliance, kTension});
  lib.push_back({"compliance_per_cable", "winch/sensor compliance (~F), per winch", "compliance",
                 "compliance", C::kLengthRows, R::kGaussNewton, nullptr, nullptr, "none (linear)",
                 describe_compliance, write_compliance, kTension});
  lib.push_back({"encoder_offset_per_cable", "encoder zero offset (~1), per cable",
                 "encoder offset", "encoder offset", C::kLengthRows, R::kGaussNewton, nullptr,
                 nullptr, "none (linear)", describe_encoder_offset, write_encoder_offsets,
                 kPoseIndex});
  lib.push_back({"encoder_drift_per_cable", "encoder drift over time (~t), per cable",
                 "encoder drift", "encoder drift", C::kLengthRows, R::kGaussNewton, nullptr,
                 nullptr, "none (linear)", describe_encoder_drift, nullptr, kTime});
  lib.push_back({"creep_shared",
                 "cable creep (~F*L*ln(1 + t/10 s): compliance growing with time under load)",
                 "creep", "creep", C::kLengthRows, R::kGaussNewton, nullptr, nullptr,
                 "none (linear)", describe_creep, nullptr, kTime});
  lib.push_back({"transmission_drift_shared",
                 "transmission drift over time (~t*L, e.g. drum heating), all cables",
                 "transmission drift", "transmission drift", C::kLengthRows, R::kGaussNewton,
                 nullptr, nullptr, "none (linear)", describe_transmission_drift, nullptr, kTime});
  lib.push_back({"sag_shared",
                 "cable sag (catenary: the arc is longer than the chord, ~Lh^2 L / F^2, and the "
                 "platform carries part of each cable's weight)",
                 "sag", "sag", C::kCatenary, R::kCatenary, nullptr, nullptr, "mass per length >= 0",
                 describe_sag, write_mass_per_length, kPoseIndex});
  lib.push_back({"nonlinear_elasticity_shared",
                 "nonlinear cable elasticity ((a F + k2 F^2) L, a polynomial elongation)",
                 "nonlinear elasticity", "elasticity", C::kLengthRows, R::kGaussNewton, nullptr,
                 nullptr, "none (linear)", describe_nonlinear_elasticity,
                 write_nonlinear_elasticity, kTensionTimesLength});
  // Parameters the standard identification does not estimate.
  lib.push_back({"drum_scale_per_cable", "drum/transmission scale error (~L), per cable",
                 "drum scale", "drum scale", C::kUnestimatedParameters, R::kIdentification,
                 estimate_length_scales, nullptr, "ParameterBounds::length_scale",
                 describe_drum_scale, nullptr, kLoadedLength});
  lib.back().parameters = {ParameterKind::kLengthScale};
  lib.push_back({"platform_anchors", "platform anchor positions (b_i)", "platform anchors",
                 "platform anchors", C::kUnestimatedParameters, R::kIdentification,
                 estimate_platform_anchors, nullptr, "ParameterBounds::platform_anchor_m", nullptr,
                 nullptr, kPoseIndex});
  lib.back().parameters = {ParameterKind::kPlatformAnchor};
  lib.push_back(
      {"force_gain_per_cable", "force sensor gain error (~F in the equilibrium), per cable",
       "force sensor gain", "force sensor gain", C::kUnestimatedParameters, R::kIdentification,
       estimate_force_gains, nullptr, "ParameterBounds::force_gain", nullptr, nullptr, kTension});
  lib.back().parameters = {ParameterKind::kForceGain};
  lib.push_back({"force_offset_per_cable", "force sensor offset (~1 in the equilibrium), per cable",
                 "force sensor offset", "force sensor offset", C::kUnestimatedParameters,
                 R::kIdentification, estimate_force_offsets, nullptr,
                 "ParameterBounds::force_offset_fraction", nullptr, nullptr, kTension});
  lib.back().parameters = {ParameterKind::kForceOffset};
  // The platform's weight: one force and moment pattern shared by every cable at every pose. The
  // per-cable force sensor gains explain a misfit of the equilibrium cable by cable (their common
  // mode is a wrong mass): its rival, in its selection group, never beside it.
  lib.push_back({"platform_weight",
                 "platform mass and centre of mass (the weight's force and moment in the "
                 "equilibrium, the same at every pose)",
                 "platform weight", "force sensor gain", C::kUnestimatedParameters,
                 R::kIdentification, estimate_platform_weight, platform_mass_only,
                 "ParameterBounds::mass_factor_min/max, centre of mass within the platform radius",
                 nullptr, nullptr, kPoseIndex});
  lib.back().parameters = {ParameterKind::kPlatformMass, ParameterKind::kPlatformCom};
  lib.back().per_cable_rival = "force_gain_per_cable";
  lib.push_back({"laser_mounting", "laser mounting (origin and beam direction on the platform)",
                 "laser mounting", "laser mounting", C::kUnestimatedParameters, R::kIdentification,
                 estimate_laser_mounting, laser_direction_only,
                 "ParameterBounds::laser_origin_m, laser_direction_rad", nullptr, nullptr,
                 kPoseIndex});
  lib.back().parameters = {ParameterKind::kLaserOrigin, ParameterKind::kLaserDirection};
  // The beam direction alone (a tilted mount, the common mounting error): the screen tests it on
  // its 2 directions instead of the mounting's 4, so a small tilt passes its gate more often.
  lib.push_back({"laser_direction", "laser beam direction (a tilted mount)", "laser mounting",
                 "laser mounting", C::kUnestimatedParameters, R::kIdentification,
                 estimate_laser_direction, nullptr, "ParameterBounds::laser_direction_rad", nullptr,
                 nullptr, kPoseIndex});
  lib.back().parameters = {ParameterKind::kLaserDirection};
  lib.push_back({"laser_plane", "laser target plane (offset and tilt)", "laser plane",
                 "laser plane", C::kUnestimatedParameters, R::kIdentification, estimate_laser_plane,
                 nullptr, "ParameterBounds::plane_normal_rad, plane_offset_m", nullptr, nullptr,
                 kPoseIndex});
  lib.back().parameters = {ParameterKind::kLaserPlaneNormal, ParameterKind::kLaserPlaneOffset};
  lib.push_back({"drum_scale_shared", "drum/transmission scale error (~L), all drums alike",
                 "drum scale", "drum scale", C::kSumOfPerCable, R::kGaussNewton, nullptr, nullptr,
                 "none (linear)", describe_drum_scale, write_shared_drum_scale, kLoadedLength});
  // Direction-dependent effects.
  lib.push_back({"hysteresis_per_cable",
                 "cable hysteresis (a length error +-h depending on whether the cable was last "
                 "paid out or reeled in), per cable",
                 "cable hysteresis", "cable hysteresis", C::kLastMoveDirection, R::kGaussNewton,
                 nullptr, nullptr, "none (linear)", describe_hysteresis, nullptr, kLastMove});
  lib.push_back({"pulley_friction_per_cable",
                 "pulley friction (a tension-reading error +-f depending on whether the cable was "
                 "last paid out or reeled in), per cable",
                 "pulley friction", "pulley friction", C::kLastMoveDirection, R::kGaussNewton,
                 nullptr, nullptr, "none (linear)", describe_pulley_friction, nullptr, kLastMove});
  return lib;
}

}  // namespace

const std::vector<EffectDescriptor>& effect_library() {
  static const std::vector<EffectDescriptor> lib = make_library();
  return lib;
}

const EffectDescriptor* find_effect(std::string_view id) {
  for (const EffectDescriptor& e : effect_library()) {
    if (e.id == id) return &e;
  }
  return nullptr;
}

EffectParameter describe_coefficient(std::string_view id, int q, int k, double value,
                                     double std_dev) {
  const EffectDescriptor* e = find_effect(id);
  if (e != nullptr && e->describe != nullptr) return e->describe(q, k, value, std_dev);
  EffectParameter p;
  p.name = std::string(id) + "_" + std::to_string(q + 1);
  p.value = value;
  p.std_dev = std_dev;
  p.text =
      format("%s coefficient %d: %.4g +- %.2g", std::string(id).c_str(), q + 1, value, std_dev);
  return p;
}

bool write_effect(std::string_view id, const Eigen::VectorXd& theta, CalibratedModel& model) {
  const EffectDescriptor* e = find_effect(id);
  return e != nullptr && e->write != nullptr && e->write(theta, model);
}

std::string selection_group(const std::string& family) {
  for (const EffectDescriptor& e : effect_library()) {
    if (e.family == family) return std::string(e.group);
  }
  return family;
}

ExplainingVariable explaining_variable(const std::string& family) {
  for (const EffectDescriptor& e : effect_library()) {
    if (e.family == family) return e.plotted_against;
  }
  return kPoseIndex;
}

int digits_for(double std_dev) {
  if (!(std_dev > 0) || !std::isfinite(std_dev)) return 3;
  return std::clamp(1 - static_cast<int>(std::floor(std::log10(std_dev))), 0, 6);
}

std::string signed_number(double v, int digits) {
  return format("%+.*f", digits, v);
}

}  // namespace cdpr
