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
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/model_check.hpp"

namespace cdpr::config {
namespace {

// ---------------------------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------------------------

// Parse errors travel to parse_robot_config as this exception; nothing escapes the API.
struct ConfigError {
  Status status;
};

enum class Sign { kAny, kPositive, kNonNegative, kNonZero };

// What a value looks like, for "got ..." in messages.
std::string describe(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Scalar:
      return n.Scalar().empty() ? std::string("an empty value") : n.Scalar();
    case YAML::NodeType::Sequence:
      return "a list of " + std::to_string(n.size());
    case YAML::NodeType::Map:
      return "a map";
    case YAML::NodeType::Null:
      return "nothing";
    case YAML::NodeType::Undefined:
      return "nothing";
  }
  return "?";
}

std::string join(std::initializer_list<const char*> keys) {
  std::string s;
  for (const char* k : keys) {
    if (!s.empty()) s += ", ";
    s += k;
  }
  return s;
}

// yaml-cpp: a const lookup of a missing key gives an invalid node on which only IsDefined() may
// be called; every access below checks IsDefined() first.

// A value found for a field: the node, and the path where it was written (a cable entry or
// `defaults`).
struct Found {
  YAML::Node node;
  std::string path;
  explicit operator bool() const { return node.IsDefined() && !node.IsNull(); }
};

class Parser {
 public:
  explicit Parser(std::string_view file) : file_(file) {}

  RobotModel parse(const YAML::Node& root);

  // Prefixes "file:line: " to a check_model message, finding the line from its field name.
  Status locate(Status status) const {
    const std::string_view msg = status.message();
    const std::size_t colon = msg.find(": ");
    std::string field(msg.substr(0, colon == std::string_view::npos ? 0 : colon));
    while (!field.empty()) {
      const auto it = marks_.find(field);
      if (it != marks_.end()) return status.prepend(where(it->second));
      const std::size_t cut = field.find_last_of(".[");
      if (cut == std::string::npos) break;
      field.resize(cut);
    }
    return status.prepend(file_ + ": ");
  }

 private:
  std::string where(const YAML::Mark& mark) const {
    if (mark.is_null()) return file_ + ": ";
    return file_ + ":" + std::to_string(mark.line + 1) + ": ";
  }

  [[noreturn]] void fail(const YAML::Mark& mark, const std::string& path,
                         const std::string& what) const {
    const std::string text = where(mark) + path + ": " + what;
    throw ConfigError{Status(ErrorCode::kInvalidArgument, text)};
  }

  void remember(const std::string& path, const YAML::Node& node) {
    if (node.IsDefined()) marks_.emplace(path, node.Mark());
  }
  // The line of `key:` itself (a block list or map starts on the next lines).
  void remember_key(const YAML::Node& map, const char* key, const std::string& path) {
    for (auto it = map.begin(); it != map.end(); ++it) {
      if (it->first.Scalar() == key) marks_.emplace(path, it->first.Mark());
    }
  }

  void expect_map(const YAML::Node& n, const std::string& path, const char* what) const {
    if (!n.IsMap()) fail(n.Mark(), path, std::string("expected ") + what + ", got " + describe(n));
  }

  // Refuses unknown and repeated keys (typos must not silently fall back to defaults).
  void check_keys(const YAML::Node& map, const std::string& path,
                  std::initializer_list<const char*> known) const {
    std::set<std::string> seen;
    for (auto it = map.begin(); it != map.end(); ++it) {
      const std::string key = it->first.Scalar();
      bool ok = false;
      for (const char* k : known) ok = ok || key == k;
      const std::string field = path.empty() ? key : path + "." + key;
      if (!ok) {
        fail(it->first.Mark(), path.empty() ? std::string("(top level)") : path,
             "unknown field '" + key + "' (known fields: " + join(known) + ")");
      }
      if (!seen.insert(key).second) fail(it->first.Mark(), field, "field given twice");
    }
  }

  double number(const YAML::Node& n, const std::string& path, Sign sign, const char* unit) {
    remember(path, n);
    const char* expectation = "a number";
    switch (sign) {
      case Sign::kAny:
        break;
      case Sign::kPositive:
        expectation = "a positive number";
        break;
      case Sign::kNonNegative:
        expectation = "a non-negative number";
        break;
      case Sign::kNonZero:
        expectation = "a non-zero number";
        break;
    }
    const std::string unit_text = unit[0] != '\0' ? std::string(" (") + unit + ")" : "";
    double v = 0.0;
    if (!n.IsScalar() || !YAML::convert<double>::decode(n, v)) {
      fail(n.Mark(), path,
           std::string("expected ") + expectation + unit_text + ", got " + describe(n));
    }
    if (!std::isfinite(v)) {
      fail(n.Mark(), path,
           std::string("expected a finite number") + unit_text + ", got " + describe(n));
    }
    const bool ok = sign == Sign::kAny || (sign == Sign::kPositive && v > 0.0) ||
                    (sign == Sign::kNonNegative && v >= 0.0) ||
                    (sign == Sign::kNonZero && v != 0.0);
    if (!ok) {
      fail(n.Mark(), path,
           std::string("expected ") + expectation + unit_text + ", got " + describe(n));
    }
    return v;
  }

  int integer(const YAML::Node& n, const std::string& path, const char* expectation) {
    remember(path, n);
    int v = 0;
    if (!n.IsScalar() || !YAML::convert<int>::decode(n, v)) {
      fail(n.Mark(), path, std::string("expected ") + expectation + ", got " + describe(n));
    }
    return v;
  }

  Eigen::Vector3d vec3(const YAML::Node& n, const std::string& path, const char* unit) {
    remember(path, n);
    if (!n.IsSequence() || n.size() != 3) {
      fail(n.Mark(), path,
           std::string("expected a list of 3 numbers (") + unit + "), got " + describe(n));
    }
    Eigen::Vector3d v;
    for (int k = 0; k < 3; ++k) {
      v(k) = number(n[static_cast<std::size_t>(k)], path + "[" + std::to_string(k) + "]",
                    Sign::kAny, unit);
    }
    return v;
  }

  // A required key of a map.
  YAML::Node required(const YAML::Node& map, const std::string& path, const char* key,
                      const char* meaning) const {
    const YAML::Node n = map[key];
    if (!n.IsDefined() || n.IsNull()) {
      fail(map.Mark(), path, std::string("missing field '") + key + "' (" + meaning + ")");
    }
    return n;
  }

  // Cable fields: the cable entry first, then `defaults:`.
  Found lookup(const YAML::Node& cable, int i, const char* key) const {
    const YAML::Node own = cable[key];
    if (own.IsDefined() && !own.IsNull()) return {own, cable_path(i) + "." + key};
    if (defaults_.IsDefined()) {
      const YAML::Node d = defaults_[key];
      if (d.IsDefined() && !d.IsNull()) return {d, std::string("defaults.") + key};
    }
    return {YAML::Node(YAML::NodeType::Undefined), ""};
  }
  // Key of a nested group (pulley, winch, force_sensor): the cable's group first, then the
  // defaults' group.
  Found lookup(const YAML::Node& cable, int i, const char* group, const char* key) const {
    const YAML::Node g = cable[group];
    if (g.IsDefined() && g.IsMap()) {
      const YAML::Node own = g[key];
      if (own.IsDefined() && !own.IsNull()) {
        return {own, cable_path(i) + "." + group + "." + key};
      }
    }
    if (defaults_.IsDefined()) {
      const YAML::Node dg = defaults_[group];
      if (dg.IsDefined() && dg.IsMap()) {
        const YAML::Node d = dg[key];
        if (d.IsDefined() && !d.IsNull()) {
          return {d, std::string("defaults.") + group + "." + key};
        }
      }
    }
    return {YAML::Node(YAML::NodeType::Undefined), ""};
  }

  [[noreturn]] void missing(const YAML::Node& cable, int i, const std::string& field,
                            const char* meaning) const {
    fail(cable.Mark(), cable_path(i),
         "missing field '" + field + "' (" + meaning + "); give it here or in defaults");
  }

  double cable_number(const YAML::Node& cable, int i, const char* key, Sign sign, const char* unit,
                      const char* meaning, const double* fallback) {
    const Found f = lookup(cable, i, key);
    if (!f) {
      if (fallback != nullptr) return *fallback;
      missing(cable, i, key, meaning);
    }
    remember(cable_path(i) + "." + key, f.node);
    return number(f.node, f.path, sign, unit);
  }

  double group_number(const YAML::Node& cable, int i, const char* group, const char* key, Sign sign,
                      const char* unit, const char* meaning, const double* fallback) {
    const Found f = lookup(cable, i, group, key);
    if (!f) {
      if (fallback != nullptr) return *fallback;
      missing(cable, i, std::string(group) + "." + key, meaning);
    }
    remember(cable_path(i) + "." + group + "." + key, f.node);
    return number(f.node, f.path, sign, unit);
  }

  static std::string cable_path(int i) { return "cables[" + std::to_string(i) + "]"; }

  void parse_defaults(const YAML::Node& d);
  void check_cable_keys(const YAML::Node& entry, const std::string& path, bool is_defaults) const;
  void parse_cable(const YAML::Node& cable, int i, RobotModel& model);
  PulleyModel parse_pulley(const YAML::Node& cable, int i);
  ElongationKind parse_elongation(const YAML::Node& cable, int i, PolynomialSurface& poly);
  Eigen::Vector3d unit_or_given(const YAML::Node& n, const std::string& path);
  PlatformModel parse_platform(const YAML::Node& p);
  Pose parse_home(const YAML::Node& h);
  LaserModel parse_laser(const YAML::Node& l, const std::string& path);

  std::string file_;
  YAML::Node defaults_{YAML::NodeType::Undefined};
  std::map<std::string, YAML::Mark> marks_;
};

void Parser::check_cable_keys(const YAML::Node& entry, const std::string& path,
                              bool is_defaults) const {
  if (is_defaults) {
    check_keys(entry, path,
               {"pulley", "winch", "ea", "mass_per_length", "routing_length", "elongation", "f_min",
                "f_max", "force_sensor"});
  } else {
    check_keys(entry, path,
               {"frame_anchor", "platform_anchor", "pulley", "winch", "ea", "mass_per_length",
                "routing_length", "elongation", "f_min", "f_max", "force_sensor"});
  }
  const YAML::Node pulley = entry["pulley"];
  if (pulley.IsDefined() && pulley.IsMap())
    check_keys(pulley, path + ".pulley", {"radius", "axis", "reference"});
  const YAML::Node winch = entry["winch"];
  if (winch.IsDefined()) {
    expect_map(winch, path + ".winch", "a map of winch fields");
    check_keys(winch, path + ".winch",
               {"drum_diameter", "drum_pitch", "gear_ratio", "counts_per_rev", "direction",
                "length_offset"});
  }
  const YAML::Node sensor = entry["force_sensor"];
  if (sensor.IsDefined()) {
    expect_map(sensor, path + ".force_sensor", "a map with gain and offset");
    check_keys(sensor, path + ".force_sensor", {"gain", "offset"});
  }
}

void Parser::parse_defaults(const YAML::Node& d) {
  expect_map(d, "defaults", "a map with the keys of a cable entry");
  check_cable_keys(d, "defaults", true);
  defaults_.reset(d);
}

// Normalises a direction, keeping vectors that are already unit (to the last bits) unchanged,
// so that a saved model reads back exactly.
Eigen::Vector3d Parser::unit_or_given(const YAML::Node& n, const std::string& path) {
  const Eigen::Vector3d v = vec3(n, path, "direction");
  const double norm = v.norm();
  if (!(norm > 0.0)) fail(n.Mark(), path, "expected a non-zero direction, got [0, 0, 0]");
  return std::abs(norm - 1.0) <= 1e-14 ? v : Eigen::Vector3d(v / norm);
}

PulleyModel Parser::parse_pulley(const YAML::Node& cable, int i) {
  PulleyModel p;
  const std::string path = cable_path(i) + ".pulley";
  const YAML::Node own = cable["pulley"];
  remember(path, own.IsDefined() ? own : cable);
  // `pulley: none` on a cable overrides any default: a point anchor.
  const auto is_none = [](const YAML::Node& n) {
    return n.IsDefined() && n.IsScalar() && (n.Scalar() == "none" || n.Scalar() == "point");
  };
  if (is_none(own)) return p;
  if (own.IsDefined() && !own.IsNull() && !own.IsMap()) {
    fail(own.Mark(), path,
         "expected a map {radius, axis, reference} or 'none', got " + describe(own));
  }
  const YAML::Node dflt = defaults_.IsDefined() ? defaults_["pulley"] : YAML::Node();
  if (!own.IsDefined() && is_none(dflt)) return p;
  if (dflt.IsDefined() && !dflt.IsNull() && !dflt.IsMap() && !is_none(dflt)) {
    fail(dflt.Mark(), "defaults.pulley",
         "expected a map {radius, axis, reference} or 'none', got " + describe(dflt));
  }
  const double zero = 0.0;
  p.radius = group_number(cable, i, "pulley", "radius", Sign::kNonNegative, "m",
                          "pulley radius in m, 0 for a point anchor", &zero);
  const Found axis = lookup(cable, i, "pulley", "axis");
  const Found reference = lookup(cable, i, "pulley", "reference");
  if (!axis || !reference) {
    if (p.radius > 0.0) {
      missing(cable, i, !axis ? "pulley.axis" : "pulley.reference",
              !axis ? "unit vector of the swivel axis in the world, the way the cable runs into "
                      "the pulley"
                    : "direction in the world from which the swivel angle is measured");
    }
    return p;  // point anchor without a frame: identity
  }
  remember(path + ".axis", axis.node);
  remember(path + ".reference", reference.node);
  const Eigen::Vector3d ez = unit_or_given(axis.node, axis.path);
  const Eigen::Vector3d r = vec3(reference.node, reference.path, "direction");
  const double along = r.dot(ez);
  Eigen::Vector3d ex = r - along * ez;
  if (!(ex.norm() > 1e-9 * r.norm())) {
    fail(reference.node.Mark(), reference.path,
         "expected a direction not parallel to the pulley axis");
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

ElongationKind Parser::parse_elongation(const YAML::Node& cable, int i, PolynomialSurface& poly) {
  const Found f = lookup(cable, i, "elongation");
  if (!f) return ElongationKind::kHooke;
  remember(cable_path(i) + ".elongation", f.node);
  const char* expected = "expected 'rigid', 'hooke' or {model: polynomial, order, coefficients}";
  // (yaml-cpp nodes are references: never assign one node to another, bind once.)
  if (f.node.IsMap()) {
    check_keys(f.node, f.path,
               {"model", "order", "coefficients", "length_center", "length_scale", "tension_center",
                "tension_scale"});
  }
  const YAML::Node model_node =
      f.node.IsMap() ? required(f.node, f.path, "model", "rigid, hooke or polynomial") : f.node;
  if (!model_node.IsScalar()) fail(model_node.Mark(), f.path, expected);
  const std::string kind = model_node.Scalar();
  if (kind == "rigid") return ElongationKind::kRigid;
  if (kind == "hooke") return ElongationKind::kHooke;
  if (kind != "polynomial") {
    fail(model_node.Mark(), f.path, std::string(expected) + ", got " + kind);
  }
  if (!f.node.IsMap()) fail(f.node.Mark(), f.path, "a polynomial needs order and coefficients");
  const YAML::Node order = required(f.node, f.path, "order", "total degree of the polynomial");
  poly.order = integer(order, f.path + ".order", "a non-negative integer");
  if (poly.order < 0 || poly.order > 8) {
    fail(order.Mark(), f.path + ".order",
         "expected an integer from 0 to 8, got " + describe(order));
  }
  const YAML::Node coeffs =
      required(f.node, f.path, "coefficients",
               "c_ij of dL = sum c_ij L^i F^j in graded order, in m / (m^i N^j)");
  const std::size_t n = static_cast<std::size_t>((poly.order + 1) * (poly.order + 2) / 2);
  if (!coeffs.IsSequence() || coeffs.size() != n) {
    fail(coeffs.Mark(), f.path + ".coefficients",
         "order " + std::to_string(poly.order) + " needs a list of " + std::to_string(n) +
             " numbers, got " + describe(coeffs));
  }
  poly.coefficients.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    poly.coefficients[k] =
        number(coeffs[k], f.path + ".coefficients[" + std::to_string(k) + "]", Sign::kAny, "");
  }
  const auto optional = [&](const char* key, Sign sign, const char* unit, double fallback) {
    const YAML::Node value = f.node[key];
    return value.IsDefined() ? number(value, f.path + "." + key, sign, unit) : fallback;
  };
  poly.length_center = optional("length_center", Sign::kAny, "m", 0.0);
  poly.length_scale = optional("length_scale", Sign::kPositive, "m", 1.0);
  poly.tension_center = optional("tension_center", Sign::kAny, "N", 0.0);
  poly.tension_scale = optional("tension_scale", Sign::kPositive, "N", 1.0);
  return ElongationKind::kPolynomial;
}

void Parser::parse_cable(const YAML::Node& cable, int i, RobotModel& model) {
  const std::string path = cable_path(i);
  remember(path, cable);
  expect_map(cable, path, "a map of cable fields");
  check_cable_keys(cable, path, false);

  model.frame_anchors.col(i) =
      vec3(required(cable, path, "frame_anchor", "a_i, the frame-side anchor in the world, m"),
           path + ".frame_anchor", "m");
  model.platform_anchors.col(i) =
      vec3(required(cable, path, "platform_anchor",
                    "b_i, the anchor on the platform, platform frame, m"),
           path + ".platform_anchor", "m");

  const auto k = static_cast<std::size_t>(i);
  model.pulleys[k] = parse_pulley(cable, i);

  const double zero = 0.0;
  WinchModel& w = model.winches[k];
  w.drum_diameter = group_number(cable, i, "winch", "drum_diameter", Sign::kPositive, "m",
                                 "drum diameter in m", nullptr);
  w.drum_pitch = group_number(cable, i, "winch", "drum_pitch", Sign::kNonNegative, "m",
                              "groove pitch in m per drum revolution", nullptr);
  w.gear_ratio =
      group_number(cable, i, "winch", "gear_ratio", Sign::kPositive, "motor rev per drum rev",
                   "motor revolutions per drum revolution", nullptr);
  w.counts_per_rev = group_number(cable, i, "winch", "counts_per_rev", Sign::kPositive, "counts",
                                  "encoder counts per motor revolution", nullptr);
  w.length_offset = group_number(cable, i, "winch", "length_offset", Sign::kAny, "m",
                                 "cable length command at encoder count 0", &zero);
  const Found dir = lookup(cable, i, "winch", "direction");
  if (dir) {
    remember(path + ".winch.direction", dir.node);
    w.direction = integer(dir.node, dir.path, "1 or -1");
    if (w.direction != 1 && w.direction != -1) {
      fail(dir.node.Mark(), dir.path, "expected 1 or -1, got " + describe(dir.node));
    }
  }

  CableModel& c = model.cables[k];
  c.ea = cable_number(cable, i, "ea", Sign::kPositive, "N", "axial stiffness E*A in N", nullptr);
  c.mass_per_length = cable_number(cable, i, "mass_per_length", Sign::kNonNegative, "kg/m",
                                   "cable mass per metre", &zero);
  c.routing_length = cable_number(cable, i, "routing_length", Sign::kNonNegative, "m",
                                  "cable from the drum to the frame anchor", &zero);
  c.elongation = parse_elongation(cable, i, c.polynomial);
  c.f_min =
      cable_number(cable, i, "f_min", Sign::kNonNegative, "N", "minimum tension in N", nullptr);
  c.f_max = cable_number(cable, i, "f_max", Sign::kPositive, "N", "maximum tension in N", nullptr);

  ForceSensorModel& s = model.force_sensors[k];
  const double one = 1.0;
  s.gain = group_number(cable, i, "force_sensor", "gain", Sign::kNonZero, "raw units per N",
                        "raw = gain * tension + offset", &one);
  s.offset = group_number(cable, i, "force_sensor", "offset", Sign::kAny, "raw units",
                          "raw = gain * tension + offset", &zero);
}

PlatformModel Parser::parse_platform(const YAML::Node& p) {
  PlatformModel out;
  remember("platform", p);
  expect_map(p, "platform", "a map with mass, center_of_mass, inertia");
  check_keys(p, "platform", {"mass", "center_of_mass", "inertia"});
  out.mass = number(required(p, "platform", "mass", "platform mass in kg"), "platform.mass",
                    Sign::kPositive, "kg");
  const YAML::Node com = p["center_of_mass"];
  if (com.IsDefined()) out.center_of_mass = vec3(com, "platform.center_of_mass", "m");
  const YAML::Node inertia = p["inertia"];
  if (inertia.IsDefined()) {
    remember("platform.inertia", inertia);
    const char* expected =
        "expected [Ixx, Iyy, Izz] or a 3x3 list of lists (kg m^2, about the centre of mass)";
    if (!inertia.IsSequence() || inertia.size() != 3) {
      fail(inertia.Mark(), "platform.inertia",
           std::string(expected) + ", got " + describe(inertia));
    }
    if (inertia[0].IsSequence()) {
      for (std::size_t r = 0; r < 3; ++r) {
        out.inertia.row(static_cast<int>(r)) =
            vec3(inertia[r], "platform.inertia[" + std::to_string(r) + "]", "kg m^2").transpose();
      }
    } else {
      out.inertia = vec3(inertia, "platform.inertia", "kg m^2").asDiagonal();
    }
  }
  return out;
}

Pose Parser::parse_home(const YAML::Node& h) {
  Pose pose;
  remember("home", h);
  expect_map(h, "home", "a map with position and rpy");
  check_keys(h, "home", {"position", "rpy"});
  if (h["position"].IsDefined()) pose.position = vec3(h["position"], "home.position", "m");
  if (h["rpy"].IsDefined()) pose.rpy = vec3(h["rpy"], "home.rpy", "rad");
  return pose;
}

LaserModel Parser::parse_laser(const YAML::Node& l, const std::string& path) {
  LaserModel laser;
  remember(path, l);
  expect_map(l, path, "a map with origin, direction, plane_point, plane_normal, range");
  check_keys(l, path, {"origin", "direction", "plane_point", "plane_normal", "range"});
  if (l["origin"].IsDefined()) laser.origin = vec3(l["origin"], path + ".origin", "m");
  laser.direction = vec3(required(l, path, "direction", "unit beam direction, platform frame"),
                         path + ".direction", "unit vector");
  laser.plane_point = vec3(required(l, path, "plane_point", "a point of the target plane, world"),
                           path + ".plane_point", "m");
  laser.plane_normal =
      vec3(required(l, path, "plane_normal", "unit normal of the target plane, world"),
           path + ".plane_normal", "unit vector");
  const YAML::Node range = required(l, path, "range", "[min, max] measuring range in m");
  remember(path + ".range", range);
  if (!range.IsSequence() || range.size() != 2) {
    fail(range.Mark(), path + ".range", "expected [min, max] (m), got " + describe(range));
  }
  laser.range_min = number(range[0], path + ".range[0]", Sign::kNonNegative, "m");
  laser.range_max = number(range[1], path + ".range[1]", Sign::kPositive, "m");
  return laser;
}

RobotModel Parser::parse(const YAML::Node& root) {
  if (!root.IsMap())
    fail(root.Mark(), "(top level)", "expected a map of fields, got " + describe(root));
  check_keys(root, "", {"name", "gravity", "defaults", "cables", "platform", "home", "lasers"});
  // Whole-section messages of check_model point at the section's key line.
  for (const char* key : {"name", "gravity", "defaults", "cables", "platform", "home", "lasers"}) {
    remember_key(root, key, key);
  }
  for (const char* alias : {"pulleys", "winches", "force_sensors", "platform_anchors"}) {
    remember_key(root, "cables", alias);
  }
  RobotModel model;
  const YAML::Node name = required(root, "(top level)", "name", "the robot's name");
  remember("name", name);
  if (!name.IsScalar()) fail(name.Mark(), "name", "expected a string, got " + describe(name));
  model.name = name.Scalar();
  if (root["gravity"].IsDefined()) {
    model.gravity = number(root["gravity"], "gravity", Sign::kNonNegative, "m/s^2");
  }
  if (root["defaults"].IsDefined()) parse_defaults(root["defaults"]);

  const YAML::Node cables =
      required(root, "(top level)", "cables", "one entry per cable, see docs/config.md");

  if (!cables.IsSequence() || cables.size() == 0) {
    fail(cables.Mark(), "cables", "expected a list of cable entries, got " + describe(cables));
  }
  const int m = static_cast<int>(cables.size());
  model.frame_anchors.resize(3, m);
  model.platform_anchors.resize(3, m);
  model.pulleys.resize(static_cast<std::size_t>(m));
  model.winches.resize(static_cast<std::size_t>(m));
  model.cables.resize(static_cast<std::size_t>(m));
  model.force_sensors.resize(static_cast<std::size_t>(m));
  for (int i = 0; i < m; ++i) parse_cable(cables[static_cast<std::size_t>(i)], i, model);

  model.platform =
      parse_platform(required(root, "(top level)", "platform", "mass, centre of mass"));
  if (root["home"].IsDefined()) model.home = parse_home(root["home"]);
  const YAML::Node lasers = root["lasers"];
  if (lasers.IsDefined() && !lasers.IsNull()) {
    remember("lasers", lasers);
    if (!lasers.IsSequence()) {
      fail(lasers.Mark(), "lasers", "expected a list of laser entries, got " + describe(lasers));
    }
    for (std::size_t j = 0; j < lasers.size(); ++j) {
      model.lasers.push_back(parse_laser(lasers[j], "lasers[" + std::to_string(j) + "]"));
    }
  }
  return model;
}

// ---------------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------------

// Shortest decimal form that reads back to the same double (at most 17 significant digits).
std::string num(double v) {
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

}  // namespace

Result<RobotModel> parse_robot_config(std::string_view text, std::string_view name_for_messages) {
  Parser parser(name_for_messages);
  RobotModel model;
  try {
    const YAML::Node root = YAML::Load(std::string(text));
    model = parser.parse(root);
  } catch (const ConfigError& e) {
    return e.status;
  } catch (const YAML::Exception& e) {
    std::string where(name_for_messages);
    if (!e.mark.is_null()) {
      where += ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1);
    }
    return Status(ErrorCode::kParseError, where + ": YAML syntax error: " + e.msg);
  }
  const Status check = check_model(model);
  if (!check.ok()) return parser.locate(check);
  return model;
}

Result<RobotModel> load_robot_config(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    const int err = errno;
    return Status::Error(err == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIoError,
                         "cannot open robot config %s: %s", path.c_str(), std::strerror(err));
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) {
    return Status::Error(ErrorCode::kIoError, "cannot read robot config %s", path.c_str());
  }
  return parse_robot_config(text.str(), path);
}

std::string save_robot_config(const RobotModel& model) {
  const int m = model.num_cables();
  std::string out;
  out += "# Robot description written by cdpr (save_robot_config). SI units; see docs/config.md.\n";
  out += "name: " + quoted(model.name) + "\n";
  out += "gravity: " + num(model.gravity) + "\n";
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
