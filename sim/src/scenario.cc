#include "cdpr/sim/scenario.hpp"

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <random>
#include <sstream>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/config/robot_config.hpp"

namespace cdpr::sim {
namespace {

// Reads typed fields and reports "<file>:<line>: <field>: <reason>".
class Reader {
 public:
  explicit Reader(std::string file) : file_(std::move(file)) {}

  int line(const YAML::Node& n) const { return n.Mark().line >= 0 ? n.Mark().line + 1 : 0; }

  Status error(const YAML::Node& at, const std::string& field, const std::string& reason) const {
    const int l = line(at);
    if (l > 0) {
      return Status::Error(ErrorCode::kInvalidArgument, "%s:%d: %s: %s", file_.c_str(), l,
                           field.c_str(), reason.c_str());
    }
    return Status::Error(ErrorCode::kInvalidArgument, "%s: %s: %s", file_.c_str(), field.c_str(),
                         reason.c_str());
  }

  // Refuses keys not in `allowed` (a misspelt field must not pass unnoticed).
  Status only(const YAML::Node& map, const std::string& field,
              std::initializer_list<const char*> allowed) const {
    if (!map.IsMap()) return error(map, field, "expected a mapping");
    for (const auto& kv : map) {
      const std::string key = kv.first.Scalar();
      bool ok = false;
      for (const char* a : allowed) ok = ok || key == a;
      if (!ok) {
        std::string list;
        for (const char* a : allowed) {
          if (!list.empty()) list += ", ";
          list += a;
        }
        return error(kv.first, join(field, key), "unknown field (expected one of: " + list + ")");
      }
    }
    return Status::Ok();
  }

  static std::string join(const std::string& parent, const std::string& key) {
    return parent.empty() ? key : parent + "." + key;
  }

  Result<double> number(const YAML::Node& n, const std::string& field) const {
    if (!n.IsScalar()) return error(n, field, "expected a number");
    const std::string& s = n.Scalar();
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(s.c_str(), &end);
    if (s.empty() || end == s.c_str() || *end != '\0' || errno == ERANGE || !std::isfinite(v)) {
      return error(n, field, "expected a finite number, got '" + s + "'");
    }
    return v;
  }

  Result<double> positive(const YAML::Node& n, const std::string& field, const char* unit) const {
    Result<double> v = number(n, field);
    if (!v.ok()) return v;
    if (!(*v > 0.0)) {
      return error(n, field,
                   std::string("expected a positive number (") + unit + "), got " + n.Scalar());
    }
    return v;
  }

  Result<double> non_negative(const YAML::Node& n, const std::string& field,
                              const char* unit) const {
    Result<double> v = number(n, field);
    if (!v.ok()) return v;
    if (*v < 0.0) {
      return error(n, field,
                   std::string("expected a number >= 0 (") + unit + "), got " + n.Scalar());
    }
    return v;
  }

  // Integer in decimal or 0x hex, within [lo, hi].
  Result<std::uint64_t> integer(const YAML::Node& n, const std::string& field, std::uint64_t lo,
                                std::uint64_t hi) const {
    if (!n.IsScalar()) return error(n, field, "expected an integer");
    const std::string& s = n.Scalar();
    char* end = nullptr;
    errno = 0;
    const unsigned long long v = std::strtoull(s.c_str(), &end, 0);
    if (s.empty() || s[0] == '-' || end == s.c_str() || *end != '\0' || errno == ERANGE || v < lo ||
        v > hi) {
      std::ostringstream os;
      os << "expected an integer in [" << lo << ", " << hi << "] (decimal or 0x hex), got '" << s
         << "'";
      return error(n, field, os.str());
    }
    return static_cast<std::uint64_t>(v);
  }

  Result<bool> boolean(const YAML::Node& n, const std::string& field) const {
    if (n.IsScalar()) {
      const std::string& s = n.Scalar();
      if (s == "true" || s == "on" || s == "yes") return true;
      if (s == "false" || s == "off" || s == "no") return false;
    }
    return error(n, field, "expected true or false");
  }

  Result<std::string> text(const YAML::Node& n, const std::string& field) const {
    if (!n.IsScalar() || n.Scalar().empty()) return error(n, field, "expected a text");
    return n.Scalar();
  }

  Result<Eigen::Vector3d> vector3(const YAML::Node& n, const std::string& field,
                                  const char* unit) const {
    if (!n.IsSequence() || n.size() != 3) {
      return error(n, field, std::string("expected a list of 3 numbers (") + unit + ")");
    }
    Eigen::Vector3d v;
    for (std::size_t k = 0; k < 3; ++k) {
      Result<double> x = number(n[k], field + "[" + std::to_string(k) + "]");
      if (!x.ok()) return x.status();
      v(static_cast<int>(k)) = *x;
    }
    return v;
  }

  // A scalar or a list of numbers; `sign`: 0 any, 1 positive, 2 non-negative.
  Result<PerCable> per_cable(const YAML::Node& n, const std::string& field, int sign,
                             const char* unit) const {
    PerCable p;
    p.line = line(n);
    auto check = [&](const YAML::Node& x, const std::string& f) -> Result<double> {
      if (sign == 1) return positive(x, f, unit);
      if (sign == 2) return non_negative(x, f, unit);
      return number(x, f);
    };
    if (n.IsScalar()) {
      Result<double> v = check(n, field);
      if (!v.ok()) return v.status();
      p.values.push_back(*v);
      return p;
    }
    if (!n.IsSequence() || n.size() == 0) {
      return error(
          n, field,
          std::string("expected a number or a non-empty list of numbers, one per cable (") + unit +
              ")");
    }
    for (std::size_t k = 0; k < n.size(); ++k) {
      Result<double> v = check(n[k], field + "[" + std::to_string(k) + "]");
      if (!v.ok()) return v.status();
      p.values.push_back(*v);
    }
    return p;
  }

  const std::string& file() const { return file_; }

 private:
  std::string file_;
};

std::string resolve_path(std::string_view base_dir, const std::string& p) {
  if (p.empty() || std::filesystem::path(p).is_absolute()) return p;
  return (std::filesystem::path(base_dir) / p).lexically_normal().string();
}

Status parse_truth(const Reader& rd, const YAML::Node& n, std::string_view base_dir,
                   TruthSource& t) {
  CDPR_RETURN_IF_ERROR(rd.only(n, "truth", {"config", "perturb"}));
  if (n["config"]) {
    std::string p;
    CDPR_ASSIGN_OR_RETURN(p, rd.text(n["config"], "truth.config"));
    t.config_path = resolve_path(base_dir, p);
  }
  if (const YAML::Node q = n["perturb"]) {
    CDPR_RETURN_IF_ERROR(
        rd.only(q, "truth.perturb", {"frame_anchor_std", "platform_anchor_std", "seed"}));
    if (q["frame_anchor_std"]) {
      CDPR_ASSIGN_OR_RETURN(
          t.frame_anchor_std,
          rd.per_cable(q["frame_anchor_std"], "truth.perturb.frame_anchor_std", 2, "m"));
    }
    if (q["platform_anchor_std"]) {
      CDPR_ASSIGN_OR_RETURN(
          t.platform_anchor_std,
          rd.per_cable(q["platform_anchor_std"], "truth.perturb.platform_anchor_std", 2, "m"));
    }
    if (q["seed"]) {
      CDPR_ASSIGN_OR_RETURN(t.perturb_seed,
                            rd.integer(q["seed"], "truth.perturb.seed", 0, ~std::uint64_t{0}));
    }
  }
  return Status::Ok();
}

Status parse_noise(const Reader& rd, const YAML::Node& n, SensorNoiseLevels& s) {
  CDPR_RETURN_IF_ERROR(rd.only(n, "noise", {"encoder_counts", "force_raw", "laser"}));
  if (n["encoder_counts"]) {
    CDPR_ASSIGN_OR_RETURN(s.encoder_counts,
                          rd.non_negative(n["encoder_counts"], "noise.encoder_counts", "counts"));
  }
  if (n["force_raw"]) {
    CDPR_ASSIGN_OR_RETURN(s.force_raw,
                          rd.non_negative(n["force_raw"], "noise.force_raw", "raw units"));
  }
  if (n["laser"]) {
    CDPR_ASSIGN_OR_RETURN(s.laser, rd.non_negative(n["laser"], "noise.laser", "m"));
  }
  return Status::Ok();
}

Status parse_polynomial(const Reader& rd, const YAML::Node& n, PolynomialSurface& p) {
  const std::string f = "effects.polynomial";
  CDPR_RETURN_IF_ERROR(rd.only(n, f,
                               {"order", "coefficients", "length_center", "length_scale",
                                "tension_center", "tension_scale"}));
  if (!n["order"]) return rd.error(n, f + ".order", "missing");
  if (!n["coefficients"]) return rd.error(n, f + ".coefficients", "missing");
  std::uint64_t order = 0;
  CDPR_ASSIGN_OR_RETURN(order, rd.integer(n["order"], f + ".order", 0, kMaxPolynomialOrder));
  p.order = static_cast<int>(order);
  PerCable c;
  CDPR_ASSIGN_OR_RETURN(c, rd.per_cable(n["coefficients"], f + ".coefficients", 0, "m"));
  p.coefficients = c.values;
  if (static_cast<int>(p.coefficients.size()) != polynomial_surface_size(p.order)) {
    return rd.error(n["coefficients"], f + ".coefficients",
                    "order " + std::to_string(p.order) + " needs " +
                        std::to_string(polynomial_surface_size(p.order)) +
                        " coefficients (graded order), got " +
                        std::to_string(p.coefficients.size()));
  }
  if (n["length_center"]) {
    CDPR_ASSIGN_OR_RETURN(p.length_center, rd.number(n["length_center"], f + ".length_center"));
  }
  if (n["length_scale"]) {
    CDPR_ASSIGN_OR_RETURN(p.length_scale, rd.positive(n["length_scale"], f + ".length_scale", "m"));
  }
  if (n["tension_center"]) {
    CDPR_ASSIGN_OR_RETURN(p.tension_center, rd.number(n["tension_center"], f + ".tension_center"));
  }
  if (n["tension_scale"]) {
    CDPR_ASSIGN_OR_RETURN(p.tension_scale,
                          rd.positive(n["tension_scale"], f + ".tension_scale", "N"));
  }
  const Status v = validate_polynomial_surface(p);
  if (!v.ok()) return rd.error(n, f, std::string(v.message()));
  return Status::Ok();
}

Status parse_effects(const Reader& rd, const YAML::Node& n, HiddenEffects& e) {
  CDPR_RETURN_IF_ERROR(
      rd.only(n, "effects",
              {"cable_law", "stiff_ea", "hooke", "polynomial", "creep", "sag", "pulley_radius",
               "transmission_scale", "encoder_zero_offset", "force_sensor", "laser", "thermal"}));
  if (n["cable_law"]) {
    std::string law;
    CDPR_ASSIGN_OR_RETURN(law, rd.text(n["cable_law"], "effects.cable_law"));
    if (law == "config") {
      e.base_law = BaseCableLaw::kConfig;
    } else if (law == "stiff") {
      e.base_law = BaseCableLaw::kStiff;
    } else {
      return rd.error(n["cable_law"], "effects.cable_law",
                      "expected 'config' or 'stiff', got '" + law + "'");
    }
  }
  if (n["stiff_ea"]) {
    CDPR_ASSIGN_OR_RETURN(e.stiff_ea, rd.positive(n["stiff_ea"], "effects.stiff_ea", "N"));
  }
  if (const YAML::Node h = n["hooke"]) {
    CDPR_RETURN_IF_ERROR(rd.only(h, "effects.hooke", {"ea"}));
    if (!h["ea"]) return rd.error(h, "effects.hooke.ea", "missing (N)");
    CDPR_ASSIGN_OR_RETURN(e.hooke_ea, rd.per_cable(h["ea"], "effects.hooke.ea", 1, "N"));
  }
  if (const YAML::Node p = n["polynomial"]) {
    if (e.hooke_ea.given()) {
      return rd.error(p, "effects.polynomial", "give either effects.hooke or effects.polynomial");
    }
    PolynomialSurface s;
    CDPR_RETURN_IF_ERROR(parse_polynomial(rd, p, s));
    e.polynomial = s;
  }
  if (const YAML::Node c = n["creep"]) {
    CDPR_RETURN_IF_ERROR(rd.only(c, "effects.creep", {"coefficient", "tau"}));
    CreepEffect creep;
    if (!c["coefficient"]) return rd.error(c, "effects.creep.coefficient", "missing (1/N)");
    CDPR_ASSIGN_OR_RETURN(creep.coefficient,
                          rd.non_negative(c["coefficient"], "effects.creep.coefficient", "1/N"));
    if (!c["tau"]) return rd.error(c, "effects.creep.tau", "missing (s)");
    CDPR_ASSIGN_OR_RETURN(creep.tau_s, rd.positive(c["tau"], "effects.creep.tau", "s"));
    e.creep = creep;
  }
  if (n["sag"]) {
    CDPR_ASSIGN_OR_RETURN(e.sag, rd.boolean(n["sag"], "effects.sag"));
  }
  if (e.sag && e.polynomial) {
    return rd.error(n["sag"], "effects.sag",
                    "sag is modelled for Hooke cables only (not with effects.polynomial)");
  }
  if (n["pulley_radius"]) {
    CDPR_ASSIGN_OR_RETURN(e.pulley_radius,
                          rd.per_cable(n["pulley_radius"], "effects.pulley_radius", 2, "m"));
  }
  if (n["transmission_scale"]) {
    CDPR_ASSIGN_OR_RETURN(e.transmission_scale, rd.per_cable(n["transmission_scale"],
                                                             "effects.transmission_scale", 0, "1"));
    for (double s : e.transmission_scale.values) {
      if (!(s > -0.5 && s < 0.5)) {
        return rd.error(n["transmission_scale"], "effects.transmission_scale",
                        "expected relative scale errors in (-0.5, 0.5)");
      }
    }
  }
  if (n["encoder_zero_offset"]) {
    CDPR_ASSIGN_OR_RETURN(
        e.encoder_zero_offset,
        rd.per_cable(n["encoder_zero_offset"], "effects.encoder_zero_offset", 0, "m"));
  }
  if (const YAML::Node f = n["force_sensor"]) {
    CDPR_RETURN_IF_ERROR(rd.only(f, "effects.force_sensor", {"gain_error", "offset_error"}));
    if (f["gain_error"]) {
      CDPR_ASSIGN_OR_RETURN(
          e.force_gain_error,
          rd.per_cable(f["gain_error"], "effects.force_sensor.gain_error", 0, "1"));
      for (double g : e.force_gain_error.values) {
        if (!(g > -0.9)) {
          return rd.error(f["gain_error"], "effects.force_sensor.gain_error",
                          "expected relative gain errors > -0.9");
        }
      }
    }
    if (f["offset_error"]) {
      CDPR_ASSIGN_OR_RETURN(
          e.force_offset_error,
          rd.per_cable(f["offset_error"], "effects.force_sensor.offset_error", 0, "raw units"));
    }
  }
  if (const YAML::Node l = n["laser"]) {
    CDPR_RETURN_IF_ERROR(
        rd.only(l, "effects.laser", {"mount_offset", "mount_tilt", "plane_tilt", "plane_offset"}));
    if (l["mount_offset"]) {
      CDPR_ASSIGN_OR_RETURN(e.laser_mount_offset,
                            rd.vector3(l["mount_offset"], "effects.laser.mount_offset", "m"));
    }
    if (l["mount_tilt"]) {
      CDPR_ASSIGN_OR_RETURN(e.laser_mount_tilt,
                            rd.vector3(l["mount_tilt"], "effects.laser.mount_tilt", "rad"));
    }
    if (l["plane_tilt"]) {
      CDPR_ASSIGN_OR_RETURN(e.plane_tilt,
                            rd.vector3(l["plane_tilt"], "effects.laser.plane_tilt", "rad"));
    }
    if (l["plane_offset"]) {
      CDPR_ASSIGN_OR_RETURN(e.plane_offset,
                            rd.number(l["plane_offset"], "effects.laser.plane_offset"));
    }
  }
  if (const YAML::Node t = n["thermal"]) {
    CDPR_RETURN_IF_ERROR(rd.only(t, "effects.thermal", {"alpha", "rate", "max_delta"}));
    ThermalEffect th;
    if (!t["alpha"]) return rd.error(t, "effects.thermal.alpha", "missing (1/K)");
    CDPR_ASSIGN_OR_RETURN(th.alpha, rd.number(t["alpha"], "effects.thermal.alpha"));
    if (!t["rate"]) return rd.error(t, "effects.thermal.rate", "missing (K/s)");
    CDPR_ASSIGN_OR_RETURN(th.rate_k_per_s, rd.number(t["rate"], "effects.thermal.rate"));
    if (t["max_delta"]) {
      CDPR_ASSIGN_OR_RETURN(th.max_delta_k,
                            rd.non_negative(t["max_delta"], "effects.thermal.max_delta", "K"));
    }
    e.thermal = th;
  }
  return Status::Ok();
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

Status parse_fault(const Reader& rd, const YAML::Node& n, const std::string& f, Fault& out) {
  CDPR_RETURN_IF_ERROR(rd.only(
      n, f, {"type", "at", "duration", "cable", "emcy", "object", "subindex", "code", "limit"}));
  out.line = rd.line(n);
  if (!n["type"]) return rd.error(n, f + ".type", "missing");
  std::string type;
  CDPR_ASSIGN_OR_RETURN(type, rd.text(n["type"], f + ".type"));
  bool found = false;
  std::string names;
  for (const FaultName& fn : kFaultNames) {
    if (type == fn.name) {
      out.kind = fn.kind;
      found = true;
    }
    names += names.empty() ? "" : ", ";
    names += fn.name;
  }
  if (!found) return rd.error(n["type"], f + ".type", "'" + type + "' is not one of " + names);
  if (!n["at"]) return rd.error(n, f + ".at", "missing (s)");
  CDPR_ASSIGN_OR_RETURN(out.at_s, rd.non_negative(n["at"], f + ".at", "s"));
  if (n["duration"]) {
    CDPR_ASSIGN_OR_RETURN(out.duration_s, rd.positive(n["duration"], f + ".duration", "s"));
  }

  const bool needs_cable =
      out.kind == FaultKind::kDriveFault || out.kind == FaultKind::kDriveSilent ||
      out.kind == FaultKind::kSdoAbort || out.kind == FaultKind::kCableOverload;
  if (needs_cable) {
    if (!n["cable"]) return rd.error(n, f + ".cable", "missing (cable number, 1..m)");
    std::uint64_t c = 0;
    CDPR_ASSIGN_OR_RETURN(c, rd.integer(n["cable"], f + ".cable", 1, 1024));
    out.cable = static_cast<int>(c) - 1;
  } else if (n["cable"]) {
    return rd.error(n["cable"], f + ".cable", "not used by a " + type + " fault");
  }
  const bool uses_emcy =
      out.kind == FaultKind::kDriveFault || out.kind == FaultKind::kCableOverload;
  if (uses_emcy) {
    out.emcy_code = 0x2310;  // continuous over-current (CiA 402 drives' usual overload code)
    if (n["emcy"]) {
      std::uint64_t c = 0;
      CDPR_ASSIGN_OR_RETURN(c, rd.integer(n["emcy"], f + ".emcy", 0, 0xFFFF));
      out.emcy_code = static_cast<std::uint16_t>(c);
    }
  } else if (n["emcy"]) {
    return rd.error(n["emcy"], f + ".emcy", "not used by a " + type + " fault");
  }
  if (out.kind == FaultKind::kSdoAbort) {
    if (!n["object"]) return rd.error(n, f + ".object", "missing (object index, e.g. 0x6064)");
    std::uint64_t v = 0;
    CDPR_ASSIGN_OR_RETURN(v, rd.integer(n["object"], f + ".object", 0, 0xFFFF));
    out.object = static_cast<std::uint16_t>(v);
    if (n["subindex"]) {
      CDPR_ASSIGN_OR_RETURN(v, rd.integer(n["subindex"], f + ".subindex", 0, 0xFF));
      out.subindex = static_cast<std::uint8_t>(v);
    }
    out.abort_code = 0x06020000;  // object does not exist
    if (n["code"]) {
      CDPR_ASSIGN_OR_RETURN(v, rd.integer(n["code"], f + ".code", 0, 0xFFFFFFFF));
      out.abort_code = static_cast<std::uint32_t>(v);
    }
  } else {
    for (const char* k : {"object", "subindex", "code"}) {
      if (n[k]) return rd.error(n[k], f + "." + k, "only used by sdo_abort faults");
    }
  }
  if (out.kind == FaultKind::kCableOverload) {
    if (!n["limit"]) return rd.error(n, f + ".limit", "missing (tension limit, N)");
    CDPR_ASSIGN_OR_RETURN(out.tension_limit, rd.positive(n["limit"], f + ".limit", "N"));
  } else if (n["limit"]) {
    return rd.error(n["limit"], f + ".limit", "only used by cable_overload faults");
  }
  return Status::Ok();
}

Status parse_laser_serving(const Reader& rd, const YAML::Node& n, std::string_view base_dir,
                           LaserServing& l) {
  CDPR_RETURN_IF_ERROR(rd.only(n, "laser", {"register_map", "slave_id", "baud", "parity"}));
  if (n["register_map"]) {
    std::string p;
    CDPR_ASSIGN_OR_RETURN(p, rd.text(n["register_map"], "laser.register_map"));
    l.register_map_path = resolve_path(base_dir, p);
  }
  std::uint64_t v = 0;
  if (n["slave_id"]) {
    CDPR_ASSIGN_OR_RETURN(v, rd.integer(n["slave_id"], "laser.slave_id", 1, 247));
    l.slave_id = static_cast<int>(v);
  }
  if (n["baud"]) {
    CDPR_ASSIGN_OR_RETURN(v, rd.integer(n["baud"], "laser.baud", 1200, 4000000));
    l.baud = static_cast<int>(v);
  }
  if (n["parity"]) {
    std::string p;
    CDPR_ASSIGN_OR_RETURN(p, rd.text(n["parity"], "laser.parity"));
    if (p == "none") {
      l.parity = 'N';
    } else if (p == "even") {
      l.parity = 'E';
    } else if (p == "odd") {
      l.parity = 'O';
    } else {
      return rd.error(n["parity"], "laser.parity", "expected none, even or odd, got '" + p + "'");
    }
  }
  return Status::Ok();
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
  const Reader rd{std::string(name)};
  YAML::Node root;
  try {
    root = YAML::Load(std::string(text));
  } catch (const YAML::Exception& e) {
    return Status::Error(ErrorCode::kParseError, "%s:%d: YAML syntax: %s", rd.file().c_str(),
                         e.mark.line + 1, e.msg.c_str());
  }
  Scenario s;
  s.file = std::string(name);
  if (!root || root.IsNull()) {
    return Status::Error(ErrorCode::kInvalidArgument, "%s: empty scenario", rd.file().c_str());
  }
  CDPR_RETURN_IF_ERROR(rd.only(root, "", {"name", "truth", "noise", "effects", "faults", "laser"}));
  if (root["name"]) {
    CDPR_ASSIGN_OR_RETURN(s.name, rd.text(root["name"], "name"));
  }
  if (root["truth"]) CDPR_RETURN_IF_ERROR(parse_truth(rd, root["truth"], base_dir, s.truth));
  if (root["noise"]) CDPR_RETURN_IF_ERROR(parse_noise(rd, root["noise"], s.noise));
  if (root["effects"]) CDPR_RETURN_IF_ERROR(parse_effects(rd, root["effects"], s.effects));
  if (const YAML::Node f = root["faults"]) {
    if (!f.IsSequence()) return rd.error(f, "faults", "expected a list of faults");
    for (std::size_t k = 0; k < f.size(); ++k) {
      Fault fault;
      CDPR_RETURN_IF_ERROR(parse_fault(rd, f[k], "faults[" + std::to_string(k) + "]", fault));
      s.faults.push_back(fault);
    }
  }
  if (root["laser"])
    CDPR_RETURN_IF_ERROR(parse_laser_serving(rd, root["laser"], base_dir, s.laser));
  return s;
}

Result<Scenario> load_scenario(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    return Status::Error(std::filesystem::exists(path) ? ErrorCode::kIoError : ErrorCode::kNotFound,
                         "%s: cannot open the scenario file", path.c_str());
  }
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string dir = std::filesystem::path(path).parent_path().string();
  return parse_scenario(ss.str(), path, dir.empty() ? "." : dir);
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
               {&e.force_offset_error, "effects.force_sensor.offset_error"}};
  for (const auto& l : lists) {
    if (!l.p->fits(m)) {
      return Status::Error(ErrorCode::kInvalidArgument,
                           "%s:%d: %s: %d values for a robot with %d cables (give 1 or %d)",
                           s.file.c_str(), l.p->line, l.field, static_cast<int>(l.p->values.size()),
                           m, m);
    }
  }
  for (std::size_t k = 0; k < s.faults.size(); ++k) {
    const Fault& f = s.faults[k];
    if (f.cable >= m) {
      return Status::Error(ErrorCode::kInvalidArgument,
                           "%s:%d: faults[%d].cable: cable %d does not exist (the robot has %d)",
                           s.file.c_str(), f.line, static_cast<int>(k), f.cable + 1, m);
    }
  }
  return Status::Ok();
}

Result<RobotModel> resolve_truth(const Scenario& s, const RobotModel& nominal) {
  RobotModel truth = nominal;
  if (!s.truth.config_path.empty()) {
    Result<RobotModel> t = config::load_robot_config(s.truth.config_path);
    if (!t.ok()) {
      Status st = t.status();
      return Status::Error(st.code(), "%s: truth.config: %.*s", s.file.c_str(),
                           static_cast<int>(st.message().size()), st.message().data());
    }
    truth = std::move(*t);
    if (truth.num_cables() != nominal.num_cables()) {
      return Status::Error(ErrorCode::kInvalidArgument,
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
      return Status::Error(ErrorCode::kInvalidArgument,
                           "%s: effects.sag: cable %d of the true robot is not a Hooke cable (sag "
                           "is modelled for Hooke cables only)",
                           s.file.c_str(), i + 1);
    }
    if (e.sag && !(c.mass_per_length > 0.0)) {
      return Status::Error(ErrorCode::kInvalidArgument,
                           "%s: effects.sag: cable %d has no mass_per_length in the true robot "
                           "description (nothing to sag)",
                           s.file.c_str(), i + 1);
    }
  }
  return truth;
}

}  // namespace cdpr::sim
