#include "cdpr/report/iso9283.hpp"

#include <cmath>

namespace cdpr::report {
namespace {

using json = nlohmann::json;

// The six figures, one table for writing and reading.
struct Field {
  const char* key;
  double Iso9283Figures::*value;
};
constexpr Field kFields[] = {
    {"ap_m", &Iso9283Figures::ap_m},           {"rp_m", &Iso9283Figures::rp_m},
    {"at_line_m", &Iso9283Figures::at_line_m}, {"at_circle_m", &Iso9283Figures::at_circle_m},
    {"rt_line_m", &Iso9283Figures::rt_line_m}, {"rt_circle_m", &Iso9283Figures::rt_circle_m},
};

json figures_json(const Iso9283Figures& f) {
  json j = json::object();
  for (const Field& field : kFields) j[field.key] = f.*field.value;
  return j;
}

Status error(std::string_view file, const std::string& what) {
  return Status(ErrorCode::kParseError, std::string(file) + ": " + what);
}

Status read_figures(const json& doc, const char* column, std::string_view file,
                    Iso9283Figures& out) {
  const auto it = doc.find(column);
  if (it == doc.end() || !it->is_object()) {
    return error(file, std::string(column) + ": missing (an object of the six figures)");
  }
  for (const Field& field : kFields) {
    const auto v = it->find(field.key);
    if (v == it->end() || !v->is_number() || !std::isfinite(v->get<double>()) ||
        v->get<double>() < 0.0) {
      return error(file,
                   std::string(column) + "." + field.key + ": expected a number of metres >= 0");
    }
    out.*field.value = v->get<double>();
  }
  return Status::success();
}

}  // namespace

json iso9283_json(const Iso9283Measured& m) {
  return {{"format", kIso9283Format},
          {"setup", m.setup},
          {"nominal", figures_json(m.nominal)},
          {"calibrated", figures_json(m.calibrated)}};
}

Result<Iso9283Measured> parse_iso9283(std::string_view text, std::string_view file) {
  const json doc = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded() || !doc.is_object()) {
    return error(file, "not a JSON object (iso9283_bench --out writes one)");
  }
  const auto format = doc.find("format");
  if (format == doc.end() || !format->is_string() || format->get<std::string>() != kIso9283Format) {
    return error(file, std::string("format: expected \"") + kIso9283Format + "\"");
  }
  Iso9283Measured m;
  const auto setup = doc.find("setup");
  if (setup != doc.end()) {
    if (!setup->is_string()) return error(file, "setup: expected a string");
    m.setup = setup->get<std::string>();
  }
  CDPR_RETURN_IF_ERROR(read_figures(doc, "nominal", file, m.nominal));
  CDPR_RETURN_IF_ERROR(read_figures(doc, "calibrated", file, m.calibrated));
  return m;
}

}  // namespace cdpr::report
