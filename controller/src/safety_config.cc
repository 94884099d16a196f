#include "cdpr/controller/safety_config.hpp"

#include <array>
#include <cmath>
#include <limits>

#include "cdpr/config/yaml_reader.hpp"

namespace cdpr::controller {
namespace {

using config::Sign;
using config::YamlField;

// The kinds of e-stop source: adding one is one row.
constexpr std::array<EStopSourceKind, 2> kEStopKinds{{
    {"drive_input", 0x60FD, 0, true,
     "a bit of a drive's digital inputs 0x60FD (its e-stop or STO status; bits 16..31 are the "
     "manufacturer's)"},
    {"pdo_bit", 0, 0, false,
     "a bit of any object an I/O node's TPDO maps (`index`, `sub` required)"},
}};

std::string where(const YamlField& f) {
  const int l = f.line();
  return f.file() + (l > 0 ? ":" + std::to_string(l) : std::string()) + ": " + f.path();
}

Status read_source(const YamlField& e, EStopSource& s) {
  CDPR_RETURN_IF_ERROR(
      e.expect_map("an e-stop source, e.g. {kind: drive_input, node: 1, bit: 16}"));
  CDPR_RETURN_IF_ERROR(e.check_keys({"kind", "node", "index", "sub", "bit", "stale_s"}));
  CDPR_ASSIGN_OR_RETURN(YamlField kind, e.required("kind", "the kind of source"));
  std::string name;
  CDPR_ASSIGN_OR_RETURN(name, kind.text());
  s.kind = -1;
  std::string names;
  for (std::size_t k = 0; k < kEStopKinds.size(); ++k) {
    if (name == kEStopKinds[k].name) s.kind = static_cast<int>(k);
    names += (names.empty() ? "" : ", ") + std::string(kEStopKinds[k].name);
  }
  if (s.kind < 0) return kind.error("'" + name + "' is not one of " + names);
  const EStopSourceKind& k = kEStopKinds[static_cast<std::size_t>(s.kind)];
  CDPR_ASSIGN_OR_RETURN(YamlField node, e.required("node", "the CANopen node it is read from"));
  CDPR_ASSIGN_OR_RETURN(const std::int64_t id, node.integer(1, 127));
  s.node = static_cast<int>(id);
  s.index = k.index;
  s.sub = k.sub;
  if (k.index == 0) {
    CDPR_ASSIGN_OR_RETURN(YamlField index, e.required("index", "the object's index"));
    CDPR_ASSIGN_OR_RETURN(const std::int64_t i, index.integer(0x1000, 0xFFFF));
    s.index = static_cast<std::uint16_t>(i);
    CDPR_RETURN_IF_ERROR(e.optional("sub", s.sub, 0, 255));
  } else if (e["index"].present() || e["sub"].present()) {
    return e.error(std::string("a ") + k.name + " source reads its own object: no index or sub");
  }
  CDPR_ASSIGN_OR_RETURN(YamlField bit, e.required("bit", "the bit that reads 1 while closed"));
  CDPR_ASSIGN_OR_RETURN(const std::int64_t b, bit.integer(0, 31));
  s.bit = static_cast<int>(b);
  double stale = s.stale_s;
  if (e["stale_s"].present()) {
    CDPR_ASSIGN_OR_RETURN(stale, e["stale_s"].number_in(0.001, 10.0, "s"));
  }
  s.stale_s = stale;
  s.where = where(e);
  return Status::success();
}

Status read_brakes(const YamlField& n, BrakeSettings& b) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.expect_map("the holding brakes, e.g. {control: output, bit: 0}"));
  CDPR_RETURN_IF_ERROR(
      n.check_keys({"control", "index", "sub", "bit", "release_delay_s", "apply_delay_s"}));
  int control = 0;
  CDPR_RETURN_IF_ERROR(n.optional_choice("control", control, {"none", "drive", "output"}));
  b.control = static_cast<BrakeControl>(control);
  CDPR_RETURN_IF_ERROR(n.optional("index", b.index, 0x1000, 0xFFFF));
  CDPR_RETURN_IF_ERROR(n.optional("sub", b.sub, 0, 255));
  CDPR_RETURN_IF_ERROR(n.optional("bit", b.bit, 0, 31));
  for (const auto& [key, out] : {std::pair{"release_delay_s", &b.release_delay_s},
                                 std::pair{"apply_delay_s", &b.apply_delay_s}}) {
    if (n[key].present()) {
      CDPR_ASSIGN_OR_RETURN(*out, n[key].number_in(0.0, 10.0, "s"));
    }
  }
  b.where = where(n);
  return Status::success();
}

Status read_lengths(const YamlField& n, SafetySettings& s) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.expect_map("the cable length limits, e.g. {min: 0.05, max: 2.5}"));
  CDPR_RETURN_IF_ERROR(n.check_keys({"min", "max", "tolerance"}));
  if (n["min"].present()) {
    CDPR_ASSIGN_OR_RETURN(s.min_cable_length, n["min"].numbers(Sign::kNonNegative, "m", true));
  }
  if (n["max"].present()) {
    CDPR_ASSIGN_OR_RETURN(s.max_cable_length, n["max"].numbers(Sign::kPositive, "m", true));
  }
  if (n["tolerance"].present()) {
    CDPR_ASSIGN_OR_RETURN(s.cable_length_tolerance, n["tolerance"].number_in(0.0, 0.1, "m"));
  }
  s.cable_length_where = where(n);
  return Status::success();
}

Status read_workspace(const YamlField& n, SafetySettings& s) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.expect_map("the workspace box, e.g. {min: [x, y, z], max: [x, y, z]}"));
  CDPR_RETURN_IF_ERROR(n.check_keys({"min", "max"}));
  CDPR_ASSIGN_OR_RETURN(YamlField lo, n.required("min", "the box's lower corner (m)"));
  CDPR_ASSIGN_OR_RETURN(YamlField hi, n.required("max", "the box's upper corner (m)"));
  CDPR_ASSIGN_OR_RETURN(s.workspace_min, lo.vector3("m"));
  CDPR_ASSIGN_OR_RETURN(s.workspace_max, hi.vector3("m"));
  for (int j = 0; j < 3; ++j) {
    const auto a = static_cast<std::size_t>(j);
    if (!(s.workspace_min[a] < s.workspace_max[a])) {
      return hi.error(std::string("max must exceed min on every axis (") + "xyz"[j] + ")");
    }
  }
  s.workspace = true;
  return Status::success();
}

}  // namespace

std::span<const EStopSourceKind> estop_source_kinds() {
  return kEStopKinds;
}

Status read_safety_settings(const YamlField& n, SafetySettings& s) {
  if (!n.present()) return Status::success();
  CDPR_RETURN_IF_ERROR(n.expect_map("the safety chain: estop, brakes, cable_length, workspace"));
  CDPR_RETURN_IF_ERROR(n.check_keys({"estop", "brakes", "cable_length", "workspace"}));
  const YamlField estop = n["estop"];
  if (estop.present()) {
    CDPR_RETURN_IF_ERROR(estop.expect_list("a list of e-stop sources"));
    if (estop.size() > 32) return estop.error("at most 32 e-stop sources");
    for (std::size_t i = 0; i < estop.size(); ++i) {
      CDPR_RETURN_IF_ERROR(read_source(estop[i], s.estop.emplace_back()));
    }
  }
  CDPR_RETURN_IF_ERROR(read_brakes(n["brakes"], s.brakes));
  CDPR_RETURN_IF_ERROR(read_lengths(n["cable_length"], s));
  return read_workspace(n["workspace"], s);
}

double cable_length_limit(const SafetySettings& s, int cable, bool upper) {
  const std::vector<double>& v = upper ? s.max_cable_length : s.min_cable_length;
  if (v.empty()) return upper ? std::numeric_limits<double>::infinity() : 0.0;
  return v.size() == 1 ? v[0] : v[static_cast<std::size_t>(cable)];
}

Status check_safety_limits(const SafetySettings& s, int num_cables) {
  for (const std::vector<double>* v : {&s.min_cable_length, &s.max_cable_length}) {
    if (v->size() > 1 && static_cast<int>(v->size()) != num_cables) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: %zu cable lengths for a robot of %d cables (one each, or one for "
                           "all)",
                           s.cable_length_where.c_str(), v->size(), num_cables);
    }
  }
  for (int i = 0; i < num_cables; ++i) {
    if (!(cable_length_limit(s, i, false) < cable_length_limit(s, i, true))) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s: cable %d: min %g m is not below max %g m",
                           s.cable_length_where.c_str(), i + 1, cable_length_limit(s, i, false),
                           cable_length_limit(s, i, true));
    }
  }
  return Status::success();
}

}  // namespace cdpr::controller
