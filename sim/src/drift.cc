#include "cdpr/sim/drift.hpp"

#include <string>

#include "cdpr/config/yaml_reader.hpp"

namespace cdpr::sim {
namespace {

using config::Sign;
using config::YamlField;

Status parse_pulley_move(const YamlField& n, Drift& d) {
  CDPR_ASSIGN_OR_RETURN(const YamlField by, n.required("by", "m"));
  CDPR_ASSIGN_OR_RETURN(const auto v, by.vector3("m"));
  d.by = Eigen::Vector3d(v[0], v[1], v[2]);
  return Status::success();
}

Status parse_force_sensor(const YamlField& n, Drift& d) {
  CDPR_RETURN_IF_ERROR(n.optional("gain", d.gain, Sign::kAny, "1"));
  if (!(d.gain > -0.9)) return n["gain"].error("expected a relative gain change > -0.9");
  CDPR_RETURN_IF_ERROR(n.optional("offset", d.offset, Sign::kAny, "raw units"));
  if (!n["gain"].present() && !n["offset"].present()) {
    return n.error("a force_sensor drift needs gain, offset or both");
  }
  return Status::success();
}

Status parse_encoder_slip(const YamlField& n, Drift& d) {
  CDPR_ASSIGN_OR_RETURN(const YamlField counts, n.required("counts", "counts"));
  CDPR_ASSIGN_OR_RETURN(d.counts, counts.number(Sign::kAny, "counts"));
  return Status::success();
}

struct DriftEntry {
  const char* name;
  DriftKind kind;
  std::initializer_list<const char*> fields;  // besides type, cable, at, duration
  Status (*parse)(const YamlField&, Drift&);
};
const DriftEntry kDriftKinds[] = {
    {"pulley_move", DriftKind::kPulleyMove, {"by"}, parse_pulley_move},
    {"force_sensor", DriftKind::kForceSensor, {"gain", "offset"}, parse_force_sensor},
    {"encoder_slip", DriftKind::kEncoderSlip, {"counts"}, parse_encoder_slip},
};

}  // namespace

std::string_view to_string(DriftKind k) {
  for (const DriftEntry& e : kDriftKinds) {
    if (e.kind == k) return e.name;
  }
  return "unknown";
}

Status parse_drift(const YamlField& n, Drift& out) {
  out.line = n.line();
  CDPR_ASSIGN_OR_RETURN(const YamlField type, n.required("type"));
  std::string name;
  CDPR_RETURN_IF_ERROR(n.optional("type", name));
  const DriftEntry* entry = nullptr;
  std::string known;
  for (const DriftEntry& e : kDriftKinds) {
    if (name == e.name) entry = &e;
    known += known.empty() ? e.name : std::string(", ") + e.name;
  }
  if (entry == nullptr) return type.error("unknown drift '" + name + "' (one of: " + known + ")");
  CDPR_RETURN_IF_ERROR(
      n.check_keys({"type", "cable", "at", "duration", "by", "gain", "offset", "counts"}));
  for (const DriftEntry& other : kDriftKinds) {
    for (const char* f : other.fields) {
      bool own = false;
      for (const char* g : entry->fields) own = own || std::string_view(f) == g;
      if (!own && n[f].present()) return n[f].error("not used by a " + name + " drift");
    }
  }
  out.kind = entry->kind;
  CDPR_ASSIGN_OR_RETURN(const YamlField cable, n.required("cable", "cable number, 1..m"));
  CDPR_ASSIGN_OR_RETURN(const std::int64_t c, cable.integer(1, 1024));
  out.cable = static_cast<int>(c) - 1;
  CDPR_RETURN_IF_ERROR(n.optional("at", out.at_s, Sign::kNonNegative, "s"));
  CDPR_RETURN_IF_ERROR(n.optional("duration", out.duration_s, Sign::kNonNegative, "s"));
  return entry->parse(n, out);
}

}  // namespace cdpr::sim
