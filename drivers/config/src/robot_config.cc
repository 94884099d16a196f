#include "cdpr/config/robot_config.hpp"

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/model_check.hpp"
#include "cdpr/config/yaml_reader.hpp"
#include "cdpr/io/atomic_file.hpp"

namespace cdpr::config {
namespace {

// ---------------------------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------------------------

// Parse errors travel to parse_robot_config as this exception; nothing escapes the API.
struct ConfigError {
  Status status;
};

// The value of a field, or a ConfigError with the reader's message.
template <typename T>
T take(Result<T> r) {
  if (!r.ok()) throw ConfigError{r.status()};
  return std::move(r).value();
}
void take(const Status& s) {
  if (!s.ok()) throw ConfigError{s};
}

Eigen::Vector3d to_vector(const std::array<double, 3>& v) {
  return {v[0], v[1], v[2]};
}

class Parser {
 public:
  RobotModel parse(const YamlField& root);

  // Prefixes "file:line: " to a check_model message, finding the line from its field name.
  Status locate(Status status, const std::string& file) const {
    const std::string_view msg = status.message();
    const std::size_t colon = msg.find(": ");
    std::string field(msg.substr(0, colon == std::string_view::npos ? 0 : colon));
    while (!field.empty()) {
      const auto it = lines_.find(field);
      if (it != lines_.end()) return status.prepend(file + ":" + std::to_string(it->second) + ": ");
      const std::size_t cut = field.find_last_of(".[");
      if (cut == std::string::npos) break;
      field.resize(cut);
    }
    return status.prepend(file + ": ");
  }

 private:
  // Where each field was written, for the messages of check_model (first mention wins).
  void remember(const std::string& path, const YamlField& f) {
    if (f.node().IsDefined() && f.line() > 0) lines_.emplace(path, f.line());
  }

  double number(const YamlField& f, Sign sign, const char* unit) {
    remember(f.path(), f);
    return take(f.number(sign, unit));
  }
  Eigen::Vector3d vec3(const YamlField& f, const char* unit) {
    remember(f.path(), f);
    return to_vector(take(f.vector3(unit)));
  }
  YamlField required(const YamlField& map, const char* key, const char* meaning) {
    return take(map.required(key, meaning));
  }

  // Cable fields: the cable entry first, then `defaults:` (absent when neither has it).
  YamlField lookup(const YamlField& cable, const char* key) const {
    const YamlField own = cable[key];
    if (own.present()) return own;
    const YamlField d = (*defaults_)[key];
    return d.present() ? d : own;
  }
  // Key of a nested group (pulley, winch, force_sensor): the cable's group first, then the
  // defaults' group.
  YamlField lookup(const YamlField& cable, const char* group, const char* key) const {
    const YamlField own = cable[group][key];
    if (own.present()) return own;
    const YamlField d = (*defaults_)[group][key];
    return d.present() ? d : own;
  }

  // "cables[0].f_max: missing (maximum tension in N); give it here or in defaults", at the
  // cable entry's line.
  [[noreturn]] void missing(const YamlField& cable, const std::string& field,
                            const char* meaning) const {
    throw ConfigError{
        cable.error_at(cable.path() + "." + field,
                       std::string("missing (") + meaning + "); give it here or in defaults")};
  }

  double cable_number(const YamlField& cable, const char* key, Sign sign, const char* unit,
                      const char* meaning, const double* fallback) {
    const YamlField f = lookup(cable, key);
    if (!f.present()) {
      if (fallback != nullptr) return *fallback;
      missing(cable, key, meaning);
    }
    remember(cable.path() + "." + key, f);
    return number(f, sign, unit);
  }

  double group_number(const YamlField& cable, const char* group, const char* key, Sign sign,
                      const char* unit, const char* meaning, const double* fallback) {
    const YamlField f = lookup(cable, group, key);
    if (!f.present()) {
      if (fallback != nullptr) return *fallback;
      missing(cable, std::string(group) + "." + key, meaning);
    }
    remember(cable.path() + "." + group + "." + key, f);
    return number(f, sign, unit);
  }

  void check_cable_keys(const YamlField& entry, bool is_defaults) const;
  void parse_cable(const YamlField& cable, int i, RobotModel& model);
  PulleyModel parse_pulley(const YamlField& cable);
  ElongationKind parse_elongation(const YamlField& cable, PolynomialSurface& poly);
  Eigen::Vector3d unit_or_given(const YamlField& f);
  PlatformModel parse_platform(const YamlField& p);
  Pose parse_home(const YamlField& h);
  LaserModel parse_laser(const YamlField& l);

  std::optional<YamlField> defaults_;  // root["defaults"], present or not
  std::map<std::string, int> lines_;
};

void Parser::check_cable_keys(const YamlField& entry, bool is_defaults) const {
  if (is_defaults) {
    take(entry.check_keys({"pulley", "winch", "ea", "mass_per_length", "routing_length",
                           "elongation", "f_min", "f_max", "force_sensor", "swivel_encoder"}));
  } else {
    take(entry.check_keys({"frame_anchor", "platform_anchor", "pulley", "winch", "ea",
                           "mass_per_length", "routing_length", "elongation", "f_min", "f_max",
                           "force_sensor", "swivel_encoder"}));
  }
  if (const YamlField enc = entry["swivel_encoder"]; enc.present()) {
    take(enc.expect_map("a map with zero and direction"));
    take(enc.check_keys({"zero", "direction"}));
  }
  if (const YamlField pulley = entry["pulley"]; pulley.is_map()) {
    take(pulley.check_keys({"radius", "axis", "reference"}));
  }
  if (const YamlField winch = entry["winch"]; winch.present()) {
    take(winch.expect_map("a map of winch fields"));
    take(winch.check_keys({"drum_diameter", "drum_pitch", "gear_ratio", "counts_per_rev",
                           "direction", "length_offset"}));
  }
  if (const YamlField sensor = entry["force_sensor"]; sensor.present()) {
    take(sensor.expect_map("a map with gain and offset"));
    take(sensor.check_keys({"gain", "offset"}));
  }
}

// Normalises a direction, keeping vectors that are already unit (to the last bits) unchanged,
// so that a saved model reads back exactly.
Eigen::Vector3d Parser::unit_or_given(const YamlField& f) {
  const Eigen::Vector3d v = vec3(f, "direction");
  const double norm = v.norm();
  if (!(norm > 0.0)) take(f.error("expected a non-zero direction, got [0, 0, 0]"));
  return std::abs(norm - 1.0) <= 1e-14 ? v : Eigen::Vector3d(v / norm);
}

PulleyModel Parser::parse_pulley(const YamlField& cable) {
  PulleyModel p;
  const std::string path = cable.path() + ".pulley";
  const YamlField own = cable["pulley"];
  remember(path, own.node().IsDefined() ? own : cable);
  // `pulley: none` on a cable overrides any default: a point anchor.
  const auto is_none = [](const YamlField& f) {
    return f.is_scalar() && (f.scalar() == "none" || f.scalar() == "point");
  };
  const char* expected = "expected a map {radius, axis, reference} or 'none', got ";
  if (is_none(own)) return p;
  if (own.present() && !own.is_map()) take(own.error(expected + own.describe()));
  const YamlField dflt = (*defaults_)["pulley"];
  if (!own.present() && is_none(dflt)) return p;
  if (dflt.present() && !dflt.is_map() && !is_none(dflt)) {
    take(dflt.error(expected + dflt.describe()));
  }
  const double zero = 0.0;
  p.radius = group_number(cable, "pulley", "radius", Sign::kNonNegative, "m",
                          "pulley radius in m, 0 for a point anchor", &zero);
  const YamlField axis = lookup(cable, "pulley", "axis");
  const YamlField reference = lookup(cable, "pulley", "reference");
  if (!axis.present() || !reference.present()) {
    if (p.radius > 0.0) {
      missing(cable, !axis.present() ? "pulley.axis" : "pulley.reference",
              !axis.present()
                  ? "unit vector of the swivel axis in the world, the way the cable runs into "
                    "the pulley"
                  : "direction in the world from which the swivel angle is measured");
    }
    return p;  // point anchor without a frame: identity
  }
  remember(path + ".axis", axis);
  remember(path + ".reference", reference);
  const Eigen::Vector3d ez = unit_or_given(axis);
  const Eigen::Vector3d r = vec3(reference, "direction");
  const double along = r.dot(ez);
  Eigen::Vector3d ex = r - along * ez;
  if (!(ex.norm() > 1e-9 * r.norm())) {
    take(reference.error("expected a direction not parallel to the pulley axis"));
  }
  // A reference that is already unit and perpendicular to round-off (what save_robot_config
  // writes) is kept bit for bit: projecting it again would move it by an ulp at every load.
  if (std::abs(along) <= 1e-14 && std::abs(r.norm() - 1.0) <= 1e-14) {
    ex = r;
  } else if (std::abs(along) > 1e-14 || std::abs(ex.norm() - 1.0) > 1e-14) {
    ex.normalize();
  }
  p.frame.col(0) = ex;
  p.frame.col(1) = ez.cross(ex);
  p.frame.col(2) = ez;
  return p;
}

ElongationKind Parser::parse_elongation(const YamlField& cable, PolynomialSurface& poly) {
  const YamlField f = lookup(cable, "elongation");
  if (!f.present()) return ElongationKind::kHooke;
  remember(cable.path() + ".elongation", f);
  const char* expected = "expected 'rigid', 'hooke' or {model: polynomial, order, coefficients}";
  if (f.is_map()) {
    take(f.check_keys({"model", "order", "coefficients", "length_center", "length_scale",
                       "tension_center", "tension_scale"}));
  }
  const YamlField model = f.is_map() ? required(f, "model", "rigid, hooke or polynomial") : f;
  if (!model.is_scalar()) take(model.error_at(f.path(), expected));
  const std::string kind = model.scalar();
  if (kind == "rigid") return ElongationKind::kRigid;
  if (kind == "hooke") return ElongationKind::kHooke;
  if (kind != "polynomial") take(model.error_at(f.path(), std::string(expected) + ", got " + kind));
  if (!f.is_map()) take(f.error("a polynomial needs order and coefficients"));
  const YamlField order = required(f, "order", "total degree of the polynomial");
  remember(order.path(), order);
  poly.order = static_cast<int>(take(order.integer(0, 8)));
  const YamlField coeffs = required(
      f, "coefficients", "c_ij of dL = sum c_ij L^i F^j in graded order, in m / (m^i N^j)");
  const std::size_t n = static_cast<std::size_t>((poly.order + 1) * (poly.order + 2) / 2);
  if (!coeffs.is_list() || coeffs.size() != n) {
    take(coeffs.error("order " + std::to_string(poly.order) + " needs a list of " +
                      std::to_string(n) + " numbers, got " + coeffs.describe()));
  }
  poly.coefficients.resize(n);
  for (std::size_t k = 0; k < n; ++k) poly.coefficients[k] = number(coeffs[k], Sign::kAny, "");
  const auto optional = [&](const char* key, Sign sign, const char* unit, double fallback) {
    const YamlField value = f[key];
    return value.present() ? number(value, sign, unit) : fallback;
  };
  poly.length_center = optional("length_center", Sign::kAny, "m", 0.0);
  poly.length_scale = optional("length_scale", Sign::kPositive, "m", 1.0);
  poly.tension_center = optional("tension_center", Sign::kAny, "N", 0.0);
  poly.tension_scale = optional("tension_scale", Sign::kPositive, "N", 1.0);
  return ElongationKind::kPolynomial;
}

void Parser::parse_cable(const YamlField& cable, int i, RobotModel& model) {
  remember(cable.path(), cable);
  take(cable.expect_map("a map of cable fields"));
  check_cable_keys(cable, false);

  model.frame_anchors.col(i) =
      vec3(required(cable, "frame_anchor", "a_i, the frame-side anchor in the world, m"), "m");
  model.platform_anchors.col(i) =
      vec3(required(cable, "platform_anchor", "b_i, the anchor on the platform, platform frame, m"),
           "m");

  const auto k = static_cast<std::size_t>(i);
  model.pulleys[k] = parse_pulley(cable);

  const double zero = 0.0;
  WinchModel& w = model.winches[k];
  w.drum_diameter = group_number(cable, "winch", "drum_diameter", Sign::kPositive, "m",
                                 "drum diameter in m", nullptr);
  w.drum_pitch = group_number(cable, "winch", "drum_pitch", Sign::kNonNegative, "m",
                              "groove pitch in m per drum revolution", nullptr);
  w.gear_ratio =
      group_number(cable, "winch", "gear_ratio", Sign::kPositive, "motor rev per drum rev",
                   "motor revolutions per drum revolution", nullptr);
  w.counts_per_rev = group_number(cable, "winch", "counts_per_rev", Sign::kPositive, "counts",
                                  "encoder counts per motor revolution", nullptr);
  w.length_offset = group_number(cable, "winch", "length_offset", Sign::kAny, "m",
                                 "cable length command at encoder count 0", &zero);
  if (const YamlField dir = lookup(cable, "winch", "direction"); dir.present()) {
    remember(cable.path() + ".winch.direction", dir);
    const double d = take(dir.number(Sign::kAny, ""));
    if (d != 1.0 && d != -1.0) take(dir.error("expected 1 or -1, got " + dir.describe()));
    w.direction = static_cast<int>(d);
  }

  CableModel& c = model.cables[k];
  c.ea = cable_number(cable, "ea", Sign::kPositive, "N", "axial stiffness E*A in N", nullptr);
  c.mass_per_length = cable_number(cable, "mass_per_length", Sign::kNonNegative, "kg/m",
                                   "cable mass per metre", &zero);
  c.routing_length = cable_number(cable, "routing_length", Sign::kNonNegative, "m",
                                  "cable from the drum to the frame anchor", &zero);
  c.elongation = parse_elongation(cable, c.polynomial);
  c.f_min = cable_number(cable, "f_min", Sign::kNonNegative, "N", "minimum tension in N", nullptr);
  c.f_max = cable_number(cable, "f_max", Sign::kPositive, "N", "maximum tension in N", nullptr);

  ForceSensorModel& s = model.force_sensors[k];
  const double one = 1.0;
  s.gain = group_number(cable, "force_sensor", "gain", Sign::kNonZero, "raw units per N",
                        "raw = gain * tension + offset", &one);
  s.offset = group_number(cable, "force_sensor", "offset", Sign::kAny, "raw units",
                          "raw = gain * tension + offset", &zero);

  SwivelEncoderModel& enc = model.swivel_encoders[k];
  enc.zero = group_number(cable, "swivel_encoder", "zero", Sign::kAny, "rad",
                          "swivel angle at which the encoder reads 0", &zero);
  if (const YamlField dir = lookup(cable, "swivel_encoder", "direction"); dir.present()) {
    remember(cable.path() + ".swivel_encoder.direction", dir);
    const double d = take(dir.number(Sign::kAny, ""));
    if (d != 1.0 && d != -1.0) take(dir.error("expected 1 or -1, got " + dir.describe()));
    enc.direction = static_cast<int>(d);
  }
}

PlatformModel Parser::parse_platform(const YamlField& p) {
  PlatformModel out;
  remember("platform", p);
  take(p.expect_map("a map with mass, center_of_mass, inertia"));
  take(p.check_keys({"mass", "center_of_mass", "inertia"}));
  out.mass = number(required(p, "mass", "platform mass in kg"), Sign::kPositive, "kg");
  if (const YamlField com = p["center_of_mass"]; com.present()) out.center_of_mass = vec3(com, "m");
  if (const YamlField inertia = p["inertia"]; inertia.present()) {
    remember(inertia.path(), inertia);
    if (!inertia.is_list() || inertia.size() != 3) {
      take(inertia.error(
          "expected [Ixx, Iyy, Izz] or a 3x3 list of lists (kg m^2, about the centre of mass), "
          "got " +
          inertia.describe()));
    }
    if (inertia[std::size_t{0}].is_list()) {
      for (std::size_t r = 0; r < 3; ++r) {
        out.inertia.row(static_cast<int>(r)) = vec3(inertia[r], "kg m^2").transpose();
      }
    } else {
      out.inertia = vec3(inertia, "kg m^2").asDiagonal();
    }
  }
  return out;
}

Pose Parser::parse_home(const YamlField& h) {
  Pose pose;
  remember("home", h);
  take(h.expect_map("a map with position and rpy"));
  take(h.check_keys({"position", "rpy"}));
  if (const YamlField position = h["position"]; position.present()) {
    pose.position = vec3(position, "m");
  }
  if (const YamlField rpy = h["rpy"]; rpy.present()) pose.rpy = vec3(rpy, "rad");
  return pose;
}

LaserModel Parser::parse_laser(const YamlField& l) {
  LaserModel laser;
  remember(l.path(), l);
  take(l.expect_map("a map with origin, direction, plane_point, plane_normal, range"));
  take(l.check_keys({"origin", "direction", "plane_point", "plane_normal", "range"}));
  if (const YamlField origin = l["origin"]; origin.present()) laser.origin = vec3(origin, "m");
  laser.direction =
      vec3(required(l, "direction", "unit beam direction, platform frame"), "unit vector");
  laser.plane_point = vec3(required(l, "plane_point", "a point of the target plane, world"), "m");
  laser.plane_normal =
      vec3(required(l, "plane_normal", "unit normal of the target plane, world"), "unit vector");
  const YamlField range = required(l, "range", "[min, max] measuring range in m");
  remember(range.path(), range);
  if (!range.is_list() || range.size() != 2) {
    take(range.error("expected [min, max] (m), got " + range.describe()));
  }
  laser.range_min = number(range[std::size_t{0}], Sign::kNonNegative, "m");
  laser.range_max = number(range[std::size_t{1}], Sign::kPositive, "m");
  return laser;
}

RobotModel Parser::parse(const YamlField& root) {
  take(root.expect_map("a map of fields"));
  take(root.check_keys({"name", "gravity", "suspended", "defaults", "cables", "platform", "home",
                        "lasers", "inclinometer"}));
  // Whole-section messages of check_model point at the section's key line.
  for (const char* key : {"name", "gravity", "suspended", "defaults", "cables", "platform", "home",
                          "lasers", "inclinometer"}) {
    if (const int line = root.key_line(key); line > 0) lines_.emplace(key, line);
  }
  for (const char* alias : {"pulleys", "winches", "force_sensors", "platform_anchors"}) {
    if (const int line = root.key_line("cables"); line > 0) lines_.emplace(alias, line);
  }
  defaults_.emplace(root["defaults"]);
  RobotModel model;
  const YamlField name = required(root, "name", "the robot's name");
  remember("name", name);
  model.name = take(name.text());
  if (const YamlField gravity = root["gravity"]; gravity.present()) {
    model.gravity = number(gravity, Sign::kNonNegative, "m/s^2");
  }
  if (const YamlField suspended = root["suspended"]; suspended.present()) {
    remember("suspended", suspended);
    model.suspended = take(suspended.boolean());
  }
  if (defaults_->present()) {
    take(defaults_->expect_map("a map with the keys of a cable entry"));
    check_cable_keys(*defaults_, true);
  }

  const YamlField cables = required(root, "cables", "one entry per cable, see docs/config.md");
  if (!cables.is_list() || cables.size() == 0) {
    take(cables.error("expected a list of cable entries, got " + cables.describe()));
  }
  const int m = static_cast<int>(cables.size());
  model.frame_anchors.resize(3, m);
  model.platform_anchors.resize(3, m);
  model.pulleys.resize(static_cast<std::size_t>(m));
  model.winches.resize(static_cast<std::size_t>(m));
  model.cables.resize(static_cast<std::size_t>(m));
  model.force_sensors.resize(static_cast<std::size_t>(m));
  model.swivel_encoders.resize(static_cast<std::size_t>(m));
  for (int i = 0; i < m; ++i) parse_cable(cables[static_cast<std::size_t>(i)], i, model);

  model.platform = parse_platform(required(root, "platform", "mass, centre of mass"));
  if (const YamlField home = root["home"]; home.present()) model.home = parse_home(home);
  if (const YamlField lasers = root["lasers"]; lasers.present()) {
    remember("lasers", lasers);
    take(lasers.expect_list("a list of laser entries"));
    for (std::size_t j = 0; j < lasers.size(); ++j) model.lasers.push_back(parse_laser(lasers[j]));
  }
  if (const YamlField incl = root["inclinometer"]; incl.present()) {
    remember("inclinometer", incl);
    take(incl.expect_map("a map with mounting_rpy and yaw_zero"));
    take(incl.check_keys({"mounting_rpy", "yaw_zero"}));
    if (const YamlField rpy = incl["mounting_rpy"]; rpy.present()) {
      model.inclinometer.mounting_rpy = vec3(rpy, "rad");
    }
    if (const YamlField yz = incl["yaw_zero"]; yz.present()) {
      model.inclinometer.yaw_zero = number(yz, Sign::kAny, "rad");
    }
  }
  return model;
}

// ---------------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------------

// Shortest decimal form that reads back to the same double (at most 17 significant digits).
std::string num(double v) {
  if (v == 0.0) v = 0.0;  // -0 would be written "-0", which the reader takes for the integer 0
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, r.ptr);
}

std::string vec(const Eigen::Vector3d& v) {
  return "[" + num(v.x()) + ", " + num(v.y()) + ", " + num(v.z()) + "]";
}

std::string quoted(const std::string& s) {
  std::string out = "\"";
  for (const char ch : s) {
    if (ch == '"' || ch == '\\') {
      out += '\\';
      out += ch;
    } else if (static_cast<unsigned char>(ch) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\x%02x", static_cast<unsigned>(ch));
      out += buf;
    } else {
      out += ch;
    }
  }
  return out + "\"";
}

bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof(double)) == 0;
}
bool same_bits(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return same_bits(a.x(), b.x()) && same_bits(a.y(), b.y()) && same_bits(a.z(), b.z());
}

std::string elongation_text(const CableModel& c) {
  switch (c.elongation) {
    case ElongationKind::kRigid:
      return "rigid";
    case ElongationKind::kHooke:
      return "hooke";
    case ElongationKind::kPolynomial: {
      std::string s =
          "{model: polynomial, order: " + std::to_string(c.polynomial.order) + ", coefficients: [";
      for (std::size_t k = 0; k < c.polynomial.coefficients.size(); ++k) {
        if (k > 0) s += ", ";
        s += num(c.polynomial.coefficients[k]);
      }
      s += "]";
      const PolynomialSurface& p = c.polynomial;
      s += ", length_center: " + num(p.length_center) + ", length_scale: " + num(p.length_scale);
      s +=
          ", tension_center: " + num(p.tension_center) + ", tension_scale: " + num(p.tension_scale);
      return s + "}";
    }
  }
  return "hooke";
}

// "{a: 1, b: 2}" from the fields that are present.
std::string flow_map(const std::vector<std::pair<std::string, std::string>>& fields) {
  std::string s = "{";
  for (std::size_t k = 0; k < fields.size(); ++k) {
    if (k > 0) s += ", ";
    s += fields[k].first + ": " + fields[k].second;
  }
  return s + "}";
}

Result<RobotModel> parse_document(const YamlDocument& doc, Parser& parser) {
  RobotModel model;
  try {
    model = parser.parse(doc.root());
  } catch (const ConfigError& e) {
    return e.status;
  }
  const Status check = check_model(model);
  if (!check.ok()) return parser.locate(check, doc.file());
  return model;
}

Result<RobotModel> parse_document(const YamlDocument& doc) {
  Parser parser;
  return parse_document(doc, parser);
}

}  // namespace

Result<RobotModel> parse_robot_config(std::string_view text, std::string_view name_for_messages) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::parse(text, name_for_messages));
  return parse_document(doc);
}

Result<RobotModel> load_robot_config(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::load(path, "robot config"));
  return parse_document(doc);
}

Result<CheckedRobot> check_robot_config(const std::string& path, const ModelPlausibility& limits) {
  CDPR_ASSIGN_OR_RETURN(const YamlDocument doc, YamlDocument::load(path, "robot config"));
  Parser parser;
  CheckedRobot out;
  CDPR_ASSIGN_OR_RETURN(out.model, parse_document(doc, parser));
  for (Status& s : check_model_plausible(out.model, limits)) {
    out.findings.push_back(parser.locate(std::move(s), doc.file()));
  }
  return out;
}

Status write_robot_config(const std::string& path, const RobotModel& model,
                          std::string_view header) {
  return io::write_file_atomically(path, std::string(header) + save_robot_config(model));
}

std::string save_robot_config(const RobotModel& model) {
  const int m = model.num_cables();
  std::string out;
  out += "# Robot description written by cdpr (save_robot_config). SI units; see docs/config.md.\n";
  out += "name: " + quoted(model.name) + "\n";
  out += "gravity: " + num(model.gravity) + "\n";
  if (model.suspended) out += "suspended: true\n";
  if (m == 0) return out + "cables: []\n";

  // Cable 0 supplies the defaults; the entries list what differs from it.
  const PulleyModel& p0 = model.pulleys[0];
  const WinchModel& w0 = model.winches[0];
  const CableModel& c0 = model.cables[0];
  const ForceSensorModel& s0 = model.force_sensors[0];
  out += "defaults:\n";
  out += "  pulley: " +
         flow_map({{"radius", num(p0.radius)},
                   {"axis", vec(p0.frame.col(2))},
                   {"reference", vec(p0.frame.col(0))}}) +
         "\n";
  out += "  winch: " +
         flow_map({{"drum_diameter", num(w0.drum_diameter)},
                   {"drum_pitch", num(w0.drum_pitch)},
                   {"gear_ratio", num(w0.gear_ratio)},
                   {"counts_per_rev", num(w0.counts_per_rev)},
                   {"direction", std::to_string(w0.direction)},
                   {"length_offset", num(w0.length_offset)}}) +
         "\n";
  out += "  ea: " + num(c0.ea) + "\n";
  out += "  mass_per_length: " + num(c0.mass_per_length) + "\n";
  out += "  routing_length: " + num(c0.routing_length) + "\n";
  out += "  elongation: " + elongation_text(c0) + "\n";
  out += "  f_min: " + num(c0.f_min) + "\n";
  out += "  f_max: " + num(c0.f_max) + "\n";
  out += "  force_sensor: " + flow_map({{"gain", num(s0.gain)}, {"offset", num(s0.offset)}}) + "\n";

  out += "cables:\n";
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    out += "  - frame_anchor: " + vec(model.frame_anchors.col(i)) + "  # cable " +
           std::to_string(i + 1) + "\n";
    out += "    platform_anchor: " + vec(model.platform_anchors.col(i)) + "\n";
    const PulleyModel& p = model.pulleys[k];
    std::vector<std::pair<std::string, std::string>> pf;
    if (!same_bits(p.radius, p0.radius)) pf.emplace_back("radius", num(p.radius));
    if (!same_bits(p.frame.col(2), p0.frame.col(2)) ||
        !same_bits(p.frame.col(0), p0.frame.col(0))) {
      pf.emplace_back("axis", vec(p.frame.col(2)));
      pf.emplace_back("reference", vec(p.frame.col(0)));
    }
    if (!pf.empty()) out += "    pulley: " + flow_map(pf) + "\n";
    const WinchModel& w = model.winches[k];
    std::vector<std::pair<std::string, std::string>> wf;
    if (!same_bits(w.drum_diameter, w0.drum_diameter)) {
      wf.emplace_back("drum_diameter", num(w.drum_diameter));
    }
    if (!same_bits(w.drum_pitch, w0.drum_pitch)) wf.emplace_back("drum_pitch", num(w.drum_pitch));
    if (!same_bits(w.gear_ratio, w0.gear_ratio)) wf.emplace_back("gear_ratio", num(w.gear_ratio));
    if (!same_bits(w.counts_per_rev, w0.counts_per_rev)) {
      wf.emplace_back("counts_per_rev", num(w.counts_per_rev));
    }
    if (w.direction != w0.direction) wf.emplace_back("direction", std::to_string(w.direction));
    if (!same_bits(w.length_offset, w0.length_offset)) {
      wf.emplace_back("length_offset", num(w.length_offset));
    }
    if (!wf.empty()) out += "    winch: " + flow_map(wf) + "\n";
    const CableModel& c = model.cables[k];
    if (!same_bits(c.ea, c0.ea)) out += "    ea: " + num(c.ea) + "\n";
    if (!same_bits(c.mass_per_length, c0.mass_per_length)) {
      out += "    mass_per_length: " + num(c.mass_per_length) + "\n";
    }
    if (!same_bits(c.routing_length, c0.routing_length)) {
      out += "    routing_length: " + num(c.routing_length) + "\n";
    }
    if (elongation_text(c) != elongation_text(c0)) {
      out += "    elongation: " + elongation_text(c) + "\n";
    }
    if (!same_bits(c.f_min, c0.f_min)) out += "    f_min: " + num(c.f_min) + "\n";
    if (!same_bits(c.f_max, c0.f_max)) out += "    f_max: " + num(c.f_max) + "\n";
    const ForceSensorModel& s = model.force_sensors[k];
    std::vector<std::pair<std::string, std::string>> sf;
    if (!same_bits(s.gain, s0.gain)) sf.emplace_back("gain", num(s.gain));
    if (!same_bits(s.offset, s0.offset)) sf.emplace_back("offset", num(s.offset));
    if (!sf.empty()) out += "    force_sensor: " + flow_map(sf) + "\n";
    // Swivel encoders: written only when they differ from the default (zero 0, direction +1),
    // so configs without them save as before.
    const SwivelEncoderModel e = model.swivel_encoder(i);
    std::vector<std::pair<std::string, std::string>> ef;
    if (!same_bits(e.zero, 0.0)) ef.emplace_back("zero", num(e.zero));
    if (e.direction != 1) ef.emplace_back("direction", std::to_string(e.direction));
    if (!ef.empty()) out += "    swivel_encoder: " + flow_map(ef) + "\n";
  }

  const PlatformModel& pl = model.platform;
  out += "platform:\n";
  out += "  mass: " + num(pl.mass) + "\n";
  out += "  center_of_mass: " + vec(pl.center_of_mass) + "\n";
  out += "  inertia: [" + vec(pl.inertia.row(0).transpose()) + ", " +
         vec(pl.inertia.row(1).transpose()) + ", " + vec(pl.inertia.row(2).transpose()) + "]\n";
  out += "home:\n";
  out += "  position: " + vec(model.home.position) + "\n";
  out += "  rpy: " + vec(model.home.rpy) + "\n";
  const InclinometerModel& incl = model.inclinometer;
  if (!same_bits(incl.mounting_rpy, Eigen::Vector3d::Zero()) || !same_bits(incl.yaw_zero, 0.0)) {
    out += "inclinometer: " +
           flow_map({{"mounting_rpy", vec(incl.mounting_rpy)}, {"yaw_zero", num(incl.yaw_zero)}}) +
           "\n";
  }
  if (model.lasers.empty()) {
    out += "lasers: []\n";
  } else {
    out += "lasers:\n";
    for (const LaserModel& l : model.lasers) {
      out += "  - origin: " + vec(l.origin) + "\n";
      out += "    direction: " + vec(l.direction) + "\n";
      out += "    plane_point: " + vec(l.plane_point) + "\n";
      out += "    plane_normal: " + vec(l.plane_normal) + "\n";
      out += "    range: [" + num(l.range_min) + ", " + num(l.range_max) + "]\n";
    }
  }
  return out;
}

}  // namespace cdpr::config
