#include "cdpr/sim/scenario.hpp"

#include <cmath>
#include <filesystem>
#include <iterator>
#include <limits>
#include <random>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/config/yaml_reader.hpp"

namespace cdpr::sim {
namespace {

using config::Sign;
using config::YamlDocument;
using config::YamlField;

// A number or a list of numbers, one per cable.
Result<PerCable> per_cable(const YamlField& f, Sign sign, const char* unit) {
  PerCable p;
  p.line = f.line();
  CDPR_ASSIGN_OR_RETURN(p.values, f.numbers(sign, unit, /*scalar_allowed=*/true));
  if (p.values.empty()) {
    return f.error(
        std::string("expected a number or a non-empty list of numbers, one per cable (") + unit +
        ")");
  }
  return p;
}

// An optional per-cable list: `out` keeps its value when the key is absent.
Status optional_per_cable(const YamlField& map, const char* key, Sign sign, const char* unit,
                          PerCable& out) {
  const YamlField f = map[key];
  if (!f.present()) return Status::success();
  CDPR_ASSIGN_OR_RETURN(out, per_cable(f, sign, unit));
  return Status::success();
}

Status optional_vector(const YamlField& map, const char* key, const char* unit,
                       Eigen::Vector3d& out) {
  const YamlField f = map[key];
  if (!f.present()) return Status::success();
  CDPR_ASSIGN_OR_RETURN(const auto v, f.vector3(unit));
  out = Eigen::Vector3d(v[0], v[1], v[2]);
  return Status::success();
}

std::string resolve_path(std::string_view base_dir, const std::string& p) {
  if (p.empty() || std::filesystem::path(p).is_absolute()) return p;
  return (std::filesystem::path(base_dir) / p).lexically_normal().string();
}

Status parse_truth(const YamlField& n, std::string_view base_dir, TruthSource& t) {
  CDPR_RETURN_IF_ERROR(n.check_keys({"config", "perturb"}));
  std::string config;
  CDPR_RETURN_IF_ERROR(n.optional("config", config));
  if (!config.empty()) t.config_path = resolve_path(base_dir, config);
  if (const YamlField q = n["perturb"]; q.present()) {
    CDPR_RETURN_IF_ERROR(q.check_keys({"frame_anchor_std", "platform_anchor_std", "seed"}));
    CDPR_RETURN_IF_ERROR(
        optional_per_cable(q, "frame_anchor_std", Sign::kNonNegative, "m", t.frame_anchor_std));
    CDPR_RETURN_IF_ERROR(optional_per_cable(q, "platform_anchor_std", Sign::kNonNegative, "m",
                                            t.platform_anchor_std));
    CDPR_RETURN_IF_ERROR(
        q.optional("seed", t.perturb_seed, 0, std::numeric_limits<std::int64_t>::max()));
  }
  return Status::success();
}

Status parse_noise(const YamlField& n, SensorNoiseLevels& s) {
  CDPR_RETURN_IF_ERROR(n.check_keys({"encoder_counts", "force_raw", "laser"}));
  CDPR_RETURN_IF_ERROR(
      n.optional("encoder_counts", s.encoder_counts, Sign::kNonNegative, "counts"));
  CDPR_RETURN_IF_ERROR(n.optional("force_raw", s.force_raw, Sign::kNonNegative, "raw units"));
  CDPR_RETURN_IF_ERROR(n.optional("laser", s.laser, Sign::kNonNegative, "m"));
  return Status::success();
}

Status parse_polynomial(const YamlField& n, PolynomialSurface& p) {
  CDPR_RETURN_IF_ERROR(n.check_keys({"order", "coefficients", "length_center", "length_scale",
                                     "tension_center", "tension_scale"}));
  CDPR_ASSIGN_OR_RETURN(const YamlField order, n.required("order"));
  CDPR_ASSIGN_OR_RETURN(const YamlField coefficients, n.required("coefficients"));
  CDPR_ASSIGN_OR_RETURN(const std::int64_t order_value, order.integer(0, kMaxPolynomialOrder));
  p.order = static_cast<int>(order_value);
  CDPR_ASSIGN_OR_RETURN(const PerCable c, per_cable(coefficients, Sign::kAny, "m"));
  p.coefficients = c.values;
  if (static_cast<int>(p.coefficients.size()) != polynomial_surface_size(p.order)) {
    return coefficients.error("order " + std::to_string(p.order) + " needs " +
                              std::to_string(polynomial_surface_size(p.order)) +
                              " coefficients (graded order), got " +
                              std::to_string(p.coefficients.size()));
  }
  CDPR_RETURN_IF_ERROR(n.optional("length_center", p.length_center));
  CDPR_RETURN_IF_ERROR(n.optional("length_scale", p.length_scale, Sign::kPositive, "m"));
  CDPR_RETURN_IF_ERROR(n.optional("tension_center", p.tension_center));
  CDPR_RETURN_IF_ERROR(n.optional("tension_scale", p.tension_scale, Sign::kPositive, "N"));
  const Status v = validate_polynomial_surface(p);
  if (!v.ok()) return n.error(v.message());
  return Status::success();
}

Status parse_effects(const YamlField& n, HiddenEffects& e) {
  CDPR_RETURN_IF_ERROR(
      n.check_keys({"cable_law", "stiff_ea", "hooke", "polynomial", "creep", "sag", "pulley_radius",
                    "transmission_scale", "encoder_zero_offset", "force_sensor", "laser", "thermal",
                    "cable_hysteresis", "pulley_friction"}));
  int law = e.base_law == BaseCableLaw::kStiff ? 1 : 0;
  CDPR_RETURN_IF_ERROR(n.optional_choice("cable_law", law, {"config", "stiff"}));
  e.base_law = law == 1 ? BaseCableLaw::kStiff : BaseCableLaw::kConfig;
  CDPR_RETURN_IF_ERROR(n.optional("stiff_ea", e.stiff_ea, Sign::kPositive, "N"));
  if (const YamlField h = n["hooke"]; h.present()) {
    CDPR_RETURN_IF_ERROR(h.check_keys({"ea"}));
    CDPR_ASSIGN_OR_RETURN(const YamlField ea, h.required("ea", "N"));
    CDPR_ASSIGN_OR_RETURN(e.hooke_ea, per_cable(ea, Sign::kPositive, "N"));
  }
  if (const YamlField p = n["polynomial"]; p.present()) {
    if (e.hooke_ea.given()) return p.error("give either effects.hooke or effects.polynomial");
    PolynomialSurface s;
    CDPR_RETURN_IF_ERROR(parse_polynomial(p, s));
    e.polynomial = s;
  }
  if (const YamlField c = n["creep"]; c.present()) {
    CDPR_RETURN_IF_ERROR(c.check_keys({"coefficient", "tau"}));
    CreepEffect creep;
    CDPR_ASSIGN_OR_RETURN(const YamlField coefficient, c.required("coefficient", "1/N"));
    CDPR_ASSIGN_OR_RETURN(creep.coefficient, coefficient.number(Sign::kNonNegative, "1/N"));
    CDPR_ASSIGN_OR_RETURN(const YamlField tau, c.required("tau", "s"));
    CDPR_ASSIGN_OR_RETURN(creep.tau_s, tau.number(Sign::kPositive, "s"));
    e.creep = creep;
  }
  CDPR_RETURN_IF_ERROR(n.optional("sag", e.sag));
  if (e.sag && e.polynomial) {
    return n["sag"].error("sag is modelled for Hooke cables only (not with effects.polynomial)");
  }
  CDPR_RETURN_IF_ERROR(
      optional_per_cable(n, "pulley_radius", Sign::kNonNegative, "m", e.pulley_radius));
  CDPR_RETURN_IF_ERROR(
      optional_per_cable(n, "transmission_scale", Sign::kAny, "1", e.transmission_scale));
  for (double s : e.transmission_scale.values) {
    if (!(s > -0.5 && s < 0.5)) {
      return n["transmission_scale"].error("expected relative scale errors in (-0.5, 0.5)");
    }
  }
  CDPR_RETURN_IF_ERROR(
      optional_per_cable(n, "encoder_zero_offset", Sign::kAny, "m", e.encoder_zero_offset));
  CDPR_RETURN_IF_ERROR(
      optional_per_cable(n, "cable_hysteresis", Sign::kNonNegative, "m", e.cable_hysteresis));
  CDPR_RETURN_IF_ERROR(
      optional_per_cable(n, "pulley_friction", Sign::kNonNegative, "N", e.pulley_friction));
  if (const YamlField f = n["force_sensor"]; f.present()) {
    CDPR_RETURN_IF_ERROR(f.check_keys({"gain_error", "offset_error"}));
    CDPR_RETURN_IF_ERROR(optional_per_cable(f, "gain_error", Sign::kAny, "1", e.force_gain_error));
    for (double g : e.force_gain_error.values) {
      if (!(g > -0.9)) return f["gain_error"].error("expected relative gain errors > -0.9");
    }
    CDPR_RETURN_IF_ERROR(
        optional_per_cable(f, "offset_error", Sign::kAny, "raw units", e.force_offset_error));
  }
  if (const YamlField l = n["laser"]; l.present()) {
    CDPR_RETURN_IF_ERROR(
        l.check_keys({"mount_offset", "mount_tilt", "plane_tilt", "plane_offset"}));
    CDPR_RETURN_IF_ERROR(optional_vector(l, "mount_offset", "m", e.laser_mount_offset));
    CDPR_RETURN_IF_ERROR(optional_vector(l, "mount_tilt", "rad", e.laser_mount_tilt));
    CDPR_RETURN_IF_ERROR(optional_vector(l, "plane_tilt", "rad", e.plane_tilt));
    CDPR_RETURN_IF_ERROR(l.optional("plane_offset", e.plane_offset));
  }
  if (const YamlField t = n["thermal"]; t.present()) {
    CDPR_RETURN_IF_ERROR(t.check_keys({"alpha", "rate", "max_delta"}));
    ThermalEffect th;
    CDPR_ASSIGN_OR_RETURN(const YamlField alpha, t.required("alpha", "1/K"));
    CDPR_ASSIGN_OR_RETURN(th.alpha, alpha.number(Sign::kAny, "1/K"));
    CDPR_ASSIGN_OR_RETURN(const YamlField rate, t.required("rate", "K/s"));
    CDPR_ASSIGN_OR_RETURN(th.rate_k_per_s, rate.number(Sign::kAny, "K/s"));
    CDPR_RETURN_IF_ERROR(t.optional("max_delta", th.max_delta_k, Sign::kNonNegative, "K"));
    e.thermal = th;
  }
  return Status::success();
}

struct FaultName {
  const char* name;
  FaultKind kind;
};
constexpr FaultName kFaultNames[] = {
    {"drive_fault", FaultKind::kDriveFault},
    {"drive_silent", FaultKind::kDriveSilent},
    {"sdo_abort", FaultKind::kSdoAbort},
    {"bus_off", FaultKind::kBusOff},
    {"laser_timeout", FaultKind::kLaserTimeout},
    {"laser_garbage", FaultKind::kLaserGarbage},
    {"laser_out_of_range", FaultKind::kLaserOutOfRange},
    {"cable_overload", FaultKind::kCableOverload},
};

Status parse_fault(const YamlField& n, Fault& out) {
  CDPR_RETURN_IF_ERROR(n.check_keys(
      {"type", "at", "duration", "cable", "emcy", "object", "subindex", "code", "limit"}));
  out.line = n.line();
  CDPR_ASSIGN_OR_RETURN(const YamlField type_field, n.required("type"));
  CDPR_ASSIGN_OR_RETURN(
      const int kind,
      type_field.choice({"drive_fault", "drive_silent", "sdo_abort", "bus_off", "laser_timeout",
                         "laser_garbage", "laser_out_of_range", "cable_overload"}));
  static_assert(std::size(kFaultNames) == 8, "the choices above list kFaultNames in order");
  out.kind = kFaultNames[kind].kind;
  const std::string type = kFaultNames[kind].name;
  CDPR_ASSIGN_OR_RETURN(const YamlField at, n.required("at", "s"));
  CDPR_ASSIGN_OR_RETURN(out.at_s, at.number(Sign::kNonNegative, "s"));
  CDPR_RETURN_IF_ERROR(n.optional("duration", out.duration_s, Sign::kPositive, "s"));

  const bool needs_cable =
      out.kind == FaultKind::kDriveFault || out.kind == FaultKind::kDriveSilent ||
      out.kind == FaultKind::kSdoAbort || out.kind == FaultKind::kCableOverload;
  if (needs_cable) {
    CDPR_ASSIGN_OR_RETURN(const YamlField cable, n.required("cable", "cable number, 1..m"));
    CDPR_ASSIGN_OR_RETURN(const std::int64_t c, cable.integer(1, 1024));
    out.cable = static_cast<int>(c) - 1;
  } else if (n["cable"].present()) {
    return n["cable"].error("not used by a " + type + " fault");
  }
  const bool uses_emcy =
      out.kind == FaultKind::kDriveFault || out.kind == FaultKind::kCableOverload;
  if (uses_emcy) {
    out.emcy_code = 0x2310;  // continuous over-current (CiA 402 drives' usual overload code)
    CDPR_RETURN_IF_ERROR(n.optional("emcy", out.emcy_code, 0, 0xFFFF));
  } else if (n["emcy"].present()) {
    return n["emcy"].error("not used by a " + type + " fault");
  }
  if (out.kind == FaultKind::kSdoAbort) {
    CDPR_ASSIGN_OR_RETURN(const YamlField object,
                          n.required("object", "object index, e.g. 0x6064"));
    CDPR_ASSIGN_OR_RETURN(const std::int64_t index, object.integer(0, 0xFFFF));
    out.object = static_cast<std::uint16_t>(index);
    CDPR_RETURN_IF_ERROR(n.optional("subindex", out.subindex, 0, 0xFF));
    out.abort_code = 0x06020000;  // object does not exist
    CDPR_RETURN_IF_ERROR(n.optional("code", out.abort_code, 0, 0xFFFFFFFF));
  } else {
    for (const char* k : {"object", "subindex", "code"}) {
      if (n[k].present()) return n[k].error("only used by sdo_abort faults");
    }
  }
  if (out.kind == FaultKind::kCableOverload) {
    CDPR_ASSIGN_OR_RETURN(const YamlField limit, n.required("limit", "tension limit, N"));
    CDPR_ASSIGN_OR_RETURN(out.tension_limit, limit.number(Sign::kPositive, "N"));
  } else if (n["limit"].present()) {
    return n["limit"].error("only used by cable_overload faults");
  }
  return Status::success();
}

Status parse_laser_serving(const YamlField& n, std::string_view base_dir, LaserServing& l) {
  CDPR_RETURN_IF_ERROR(n.check_keys({"register_map", "slave_id", "baud", "parity"}));
  std::string map;
  CDPR_RETURN_IF_ERROR(n.optional("register_map", map));
  if (!map.empty()) l.register_map_path = resolve_path(base_dir, map);
  CDPR_RETURN_IF_ERROR(n.optional("slave_id", l.slave_id, 1, 247));
  CDPR_RETURN_IF_ERROR(n.optional("baud", l.baud, 1200, 4000000));
  int parity = l.parity == 'N' ? 0 : (l.parity == 'O' ? 2 : 1);
  CDPR_RETURN_IF_ERROR(n.optional_choice("parity", parity, {"none", "even", "odd"}));
  l.parity = parity == 0 ? 'N' : (parity == 2 ? 'O' : 'E');
  return Status::success();
}

Result<Scenario> parse_document(const YamlDocument& doc, std::string_view base_dir) {
  Scenario s;
  s.file = doc.file();
  const YamlField root = doc.root();
  if (!root.present()) {
    return Status::error(ErrorCode::kInvalidArgument, "%s: empty scenario", s.file.c_str());
  }
  CDPR_RETURN_IF_ERROR(
      root.check_keys({"name", "truth", "noise", "effects", "drifts", "faults", "laser"}));
  CDPR_RETURN_IF_ERROR(root.optional("name", s.name));
  if (const YamlField f = root["truth"]; f.present()) {
    CDPR_RETURN_IF_ERROR(parse_truth(f, base_dir, s.truth));
  }
  if (const YamlField f = root["noise"]; f.present()) CDPR_RETURN_IF_ERROR(parse_noise(f, s.noise));
  if (const YamlField f = root["effects"]; f.present()) {
    CDPR_RETURN_IF_ERROR(parse_effects(f, s.effects));
  }
  if (const YamlField f = root["drifts"]; f.present()) {
    CDPR_RETURN_IF_ERROR(f.expect_list("a list of drifts"));
    for (std::size_t k = 0; k < f.size(); ++k) {
      Drift drift;
      CDPR_RETURN_IF_ERROR(parse_drift(f[k], drift));
      s.drifts.push_back(drift);
    }
  }
  if (const YamlField f = root["faults"]; f.present()) {
    CDPR_RETURN_IF_ERROR(f.expect_list("a list of faults"));
    for (std::size_t k = 0; k < f.size(); ++k) {
      Fault fault;
      CDPR_RETURN_IF_ERROR(parse_fault(f[k], fault));
      s.faults.push_back(fault);
    }
  }
  if (const YamlField f = root["laser"]; f.present()) {
    CDPR_RETURN_IF_ERROR(parse_laser_serving(f, base_dir, s.laser));
  }
  return s;
}

}  // namespace

std::string_view to_string(FaultKind k) {
  for (const FaultName& fn : kFaultNames) {
    if (fn.kind == k) return fn.name;
  }
  return "unknown";
}

const Fault* Scenario::laser_fault_at(double t) const {
  for (const Fault& f : faults) {
    const bool is_laser = f.kind == FaultKind::kLaserTimeout ||
                          f.kind == FaultKind::kLaserGarbage ||
                          f.kind == FaultKind::kLaserOutOfRange;
    if (is_laser && f.active_at(t)) return &f;
  }
  return nullptr;
}

Result<Scenario> parse_scenario(std::string_view text, std::string_view name,
                                std::string_view base_dir) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::parse(text, name));
  return parse_document(doc, base_dir);
}

Result<Scenario> load_scenario(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::load(path, "scenario"));
  const std::string dir = std::filesystem::path(path).parent_path().string();
  return parse_document(doc, dir.empty() ? "." : dir);
}

Status check_against(const Scenario& s, int m) {
  const HiddenEffects& e = s.effects;
  const struct {
    const PerCable* p;
    const char* field;
  } lists[] = {{&s.truth.frame_anchor_std, "truth.perturb.frame_anchor_std"},
               {&s.truth.platform_anchor_std, "truth.perturb.platform_anchor_std"},
               {&e.hooke_ea, "effects.hooke.ea"},
               {&e.pulley_radius, "effects.pulley_radius"},
               {&e.transmission_scale, "effects.transmission_scale"},
               {&e.encoder_zero_offset, "effects.encoder_zero_offset"},
               {&e.force_gain_error, "effects.force_sensor.gain_error"},
               {&e.force_offset_error, "effects.force_sensor.offset_error"},
               {&e.cable_hysteresis, "effects.cable_hysteresis"},
               {&e.pulley_friction, "effects.pulley_friction"}};
  for (const auto& l : lists) {
    if (!l.p->fits(m)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s:%d: %s: %d values for a robot with %d cables (give 1 or %d)",
                           s.file.c_str(), l.p->line, l.field, static_cast<int>(l.p->values.size()),
                           m, m);
    }
  }
  for (std::size_t k = 0; k < s.drifts.size(); ++k) {
    const Drift& d = s.drifts[k];
    if (d.cable >= m) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s:%d: drifts[%d].cable: cable %d does not exist (the robot has %d)",
                           s.file.c_str(), d.line, static_cast<int>(k), d.cable + 1, m);
    }
  }
  for (std::size_t k = 0; k < s.faults.size(); ++k) {
    const Fault& f = s.faults[k];
    if (f.cable >= m) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s:%d: faults[%d].cable: cable %d does not exist (the robot has %d)",
                           s.file.c_str(), f.line, static_cast<int>(k), f.cable + 1, m);
    }
  }
  return Status::success();
}

Result<RobotModel> resolve_truth(const Scenario& s, const RobotModel& nominal) {
  RobotModel truth = nominal;
  if (!s.truth.config_path.empty()) {
    Result<RobotModel> t = config::load_robot_config(s.truth.config_path);
    if (!t.ok()) {
      Status st = t.status();
      return Status::error(st.code(), "%s: truth.config: %.*s", s.file.c_str(),
                           static_cast<int>(st.message().size()), st.message().data());
    }
    truth = std::move(*t);
    if (truth.num_cables() != nominal.num_cables()) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: truth.config: the true robot has %d cables, the nominal %d",
                           s.file.c_str(), truth.num_cables(), nominal.num_cables());
    }
  }
  const int m = truth.num_cables();
  CDPR_RETURN_IF_ERROR(check_against(s, m));

  // Seeded perturbation: frame anchors first (cable by cable, x y z), then platform anchors.
  if (s.truth.frame_anchor_std.given() || s.truth.platform_anchor_std.given()) {
    std::mt19937_64 rng(s.truth.perturb_seed);
    std::normal_distribution<double> normal(0.0, 1.0);
    for (int i = 0; i < m; ++i) {
      const double sd = s.truth.frame_anchor_std.at(i);
      for (int k = 0; k < 3; ++k) truth.frame_anchors(k, i) += sd * normal(rng);
    }
    for (int i = 0; i < m; ++i) {
      const double sd = s.truth.platform_anchor_std.at(i);
      for (int k = 0; k < 3; ++k) truth.platform_anchors(k, i) += sd * normal(rng);
    }
  }

  const HiddenEffects& e = s.effects;
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    CableModel& c = truth.cables[k];
    if (e.pulley_radius.given()) truth.pulleys[k].radius = e.pulley_radius.at(i);
    if (e.hooke_ea.given()) {
      c.elongation = ElongationKind::kHooke;
      c.ea = e.hooke_ea.at(i);
    } else if (e.polynomial) {
      c.elongation = ElongationKind::kPolynomial;
      c.polynomial = *e.polynomial;
    } else if (e.base_law == BaseCableLaw::kStiff || c.elongation == ElongationKind::kRigid) {
      // Rigid cables have no elasto-static equilibrium: "no elasticity" is a very stiff Hooke law.
      c.elongation = ElongationKind::kHooke;
      c.ea = e.stiff_ea;
    }
    if (e.sag && c.elongation != ElongationKind::kHooke) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: effects.sag: cable %d of the true robot is not a Hooke cable (sag "
                           "is modelled for Hooke cables only)",
                           s.file.c_str(), i + 1);
    }
    if (e.sag && !(c.mass_per_length > 0.0)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: effects.sag: cable %d has no mass_per_length in the true robot "
                           "description (nothing to sag)",
                           s.file.c_str(), i + 1);
    }
  }
  return truth;
}

}  // namespace cdpr::sim
