#include "render.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "cdpr/controller/control_protocol.hpp"

namespace cdpr::ctl {

namespace {

using json = nlohmann::json;

bool is_scalar(const json& v) {
  return v.is_primitive();  // null, string, boolean, number
}

bool all_scalars(const json& arr) {
  return std::all_of(arr.begin(), arr.end(), [](const json& v) { return is_scalar(v); });
}

bool flat_objects(const json& arr) {
  return !arr.empty() && std::all_of(arr.begin(), arr.end(), [](const json& v) {
    return v.is_object() && std::all_of(v.begin(), v.end(), [](const json& f) {
             return is_scalar(f) || (f.is_array() && all_scalars(f) && f.size() <= 8);
           });
  });
}

std::string inline_value(const json& v) {
  if (is_scalar(v)) return render_scalar(v);
  if (v.is_array() && all_scalars(v)) {
    std::string s = "[";
    for (std::size_t i = 0; i < v.size(); ++i) {
      if (i > 0) s += ", ";
      s += render_scalar(v[i]);
    }
    return s + "]";
  }
  return control::dump_safely(v);
}

void render_table(const json& rows, const std::string& pad, std::string& out) {
  std::vector<std::string> cols;
  for (const auto& row : rows) {
    for (const auto& [k, v] : row.items()) {
      if (std::find(cols.begin(), cols.end(), k) == cols.end()) cols.push_back(k);
    }
  }
  std::vector<std::vector<std::string>> cells;
  std::vector<std::size_t> width(cols.size());
  for (std::size_t c = 0; c < cols.size(); ++c) width[c] = cols[c].size();
  for (const auto& row : rows) {
    std::vector<std::string> line;
    for (std::size_t c = 0; c < cols.size(); ++c) {
      const auto it = row.find(cols[c]);
      line.push_back(it == row.end() ? "" : inline_value(*it));
      width[c] = std::max(width[c], line.back().size());
    }
    cells.push_back(std::move(line));
  }
  auto emit = [&](const std::vector<std::string>& line) {
    std::string s = pad;
    for (std::size_t c = 0; c < line.size(); ++c) {
      s += line[c];
      if (c + 1 < line.size()) s += std::string(width[c] - line[c].size() + 2, ' ');
    }
    while (!s.empty() && s.back() == ' ') s.pop_back();
    out += s + "\n";
  };
  emit(cols);
  for (const auto& line : cells) emit(line);
}

void render_into(const json& v, int indent, std::string& out) {
  const std::string pad(static_cast<std::size_t>(indent), ' ');
  if (v.is_object()) {
    for (const auto& [k, item] : v.items()) {
      if (is_scalar(item) || (item.is_array() && all_scalars(item)) ||
          (item.is_object() && item.empty()) || (item.is_array() && item.empty())) {
        out += pad + k + ": " + (item.is_object() ? "-" : inline_value(item)) + "\n";
      } else if (item.is_array() && flat_objects(item)) {
        out += pad + k + ":\n";
        render_table(item, pad + "  ", out);
      } else {
        out += pad + k + ":\n";
        render_into(item, indent + 2, out);
      }
    }
  } else if (v.is_array()) {
    for (const auto& item : v) {
      if (is_scalar(item) || (item.is_array() && all_scalars(item))) {
        out += pad + "- " + inline_value(item) + "\n";
      } else {
        out += pad + "-\n";
        render_into(item, indent + 2, out);
      }
    }
  } else {
    out += pad + render_scalar(v) + "\n";
  }
}

std::string num(double v, const char* fmt) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

// "T 12.3..85.0 N" from an array of tensions; "" when there are none.
std::string tension_range(const json& tensions) {
  if (!tensions.is_array() || tensions.empty()) return "";
  double lo = INFINITY, hi = -INFINITY;
  for (const auto& t : tensions) {
    if (!t.is_number()) continue;
    lo = std::min(lo, t.get<double>());
    hi = std::max(hi, t.get<double>());
  }
  if (!(lo <= hi)) return "";
  return "T " + num(lo, "%.1f") + ".." + num(hi, "%.1f") + " N";
}

std::string laser_text(const json& laser) {
  if (!laser.is_number()) return "";
  return "laser " + num(laser.get<double>(), "%.5f") + " m";
}

std::string str_field(const json& data, const char* key, const char* fallback = "") {
  const auto it = data.find(key);
  if (it == data.end() || it->is_null()) return fallback;
  return render_scalar(*it);
}

}  // namespace

std::string render_scalar(const json& v) {
  if (v.is_string()) return v.get<std::string>();
  if (v.is_null()) return "-";
  if (v.is_boolean()) return v.get<bool>() ? "yes" : "no";
  if (v.is_number_integer()) return std::to_string(v.get<std::int64_t>());
  if (v.is_number_unsigned()) return std::to_string(v.get<std::uint64_t>());
  if (v.is_number_float()) return num(v.get<double>(), "%.6g");
  return control::dump_safely(v);
}

std::string render_result(const json& result) {
  std::string out;
  render_into(result, 0, out);
  return out;
}

std::string format_duration(const json& seconds) {
  if (!seconds.is_number()) return "-";
  const double s = seconds.get<double>();
  if (!(s >= 0) || !std::isfinite(s)) return "-";
  const auto total = static_cast<long long>(std::llround(s));
  const long long h = total / 3600, m = (total / 60) % 60, sec = total % 60;
  char buf[48];
  if (h > 0) {
    std::snprintf(buf, sizeof buf, "%lld:%02lld:%02lld", h, m, sec);
  } else {
    std::snprintf(buf, sizeof buf, "%lld:%02lld", m, sec);
  }
  return buf;
}

std::string progress_bar(const json& p, int width) {
  const std::string phase = str_field(p, "phase", "?");
  std::string pose_text;
  const json pose = p.value("pose", json()), poses = p.value("poses", json());
  if (pose.is_number() && poses.is_number() && poses.get<double>() > 0) {
    pose_text = "pose " + render_scalar(pose) + "/" + render_scalar(poses);
    const double frac = std::clamp(pose.get<double>() / poses.get<double>(), 0.0, 1.0);
    constexpr int kBar = 20;
    const int filled = static_cast<int>(std::lround(frac * kBar));
    pose_text += " [" + std::string(static_cast<std::size_t>(filled), '#') +
                 std::string(static_cast<std::size_t>(kBar - filled), '-') + "]";
  }
  std::string line = phase;
  for (const std::string& part :
       {pose_text, format_duration(p.value("elapsed_s", json())) + " elapsed",
        format_duration(p.value("remaining_s", json())) + " left",
        tension_range(p.value("tensions", json())), laser_text(p.value("laser_m", json()))}) {
    if (!part.empty()) line += "  " + part;
  }
  if (width > 4 && line.size() > static_cast<std::size_t>(width - 1)) {
    line.resize(static_cast<std::size_t>(width - 1));
  }
  return line;
}

std::string event_line(const control::ControlEvent& ev) {
  const json& d = ev.data;
  if (ev.type == "state") {
    std::string s = "state: " + str_field(d, "state", "?");
    const std::string reason = str_field(d, "reason");
    return reason.empty() ? s : s + " (" + reason + ")";
  }
  if (ev.type == "progress") {
    std::string s = "progress: " + str_field(d, "phase", "?");
    if (d.contains("pose") && d.contains("poses")) {
      s += " pose " + str_field(d, "pose") + "/" + str_field(d, "poses");
    }
    s += ", elapsed " + format_duration(d.value("elapsed_s", json()));
    s += ", remaining " + format_duration(d.value("remaining_s", json()));
    if (const std::string t = tension_range(d.value("tensions", json())); !t.empty()) {
      s += ", " + t;
    }
    if (const std::string l = laser_text(d.value("laser_m", json())); !l.empty()) s += ", " + l;
    return s;
  }
  if (ev.type == "fault") {
    std::string s = "FAULT: " + str_field(d, "fault", "?");
    if (const std::string node = str_field(d, "node"); !node.empty() && node != "-") {
      s += " (node " + node + ")";
    }
    const std::string m = str_field(d, "message");
    return m.empty() ? s : s + ": " + m;
  }
  if (ev.type == "calibration") {
    std::string s = "calibration " +
                    str_field(d, "calibration", str_field(d, "version", "?").c_str()) + ": " +
                    str_field(d, "outcome", "?");
    if (const auto g = d.find("gates_passed"); g != d.end() && g->is_boolean()) {
      s += g->get<bool>() ? " (gates passed)" : " (gates failed)";
    }
    const std::string m = str_field(d, "message");
    return m.empty() ? s : s + ": " + m;
  }
  if (ev.type == "log") return "[" + str_field(d, "level", "info") + "] " + str_field(d, "message");
  if (ev.type == "dropped") {
    return "(" + str_field(d, "count", "?") + " events dropped: this client read too slowly)";
  }
  return ev.type + ": " + control::dump_safely(d);
}

}  // namespace cdpr::ctl
