#include "cdpr/recording/recording.hpp"

#include <array>
#include <charconv>
#include <cmath>
#include <map>

#include "csv.hpp"

namespace cdpr::recording {

namespace {

using detail::CsvRow;
using detail::CsvTable;

constexpr std::array<const char*, 6> kCmd = {"cmd_x",    "cmd_y",     "cmd_z",
                                             "cmd_roll", "cmd_pitch", "cmd_yaw"};
constexpr std::array<const char*, 6> kRef = {"ref_x",    "ref_y",     "ref_z",
                                             "ref_roll", "ref_pitch", "ref_yaw"};
constexpr std::array<const char*, 6> kStart = {"start_x",    "start_y",     "start_z",
                                               "start_roll", "start_pitch", "start_yaw"};
constexpr const char* kRecordingFormat = "cdpr-recording 1";
constexpr const char* kCableFormat = "cdpr-cable-experiment 1";
constexpr const char* kForceFormat = "cdpr-force-experiment 1";
constexpr const char* kPoseListFormat = "cdpr-poses 1";

// "length_12" -> 12 for prefix "length_"; 0 when the name is not of that form.
int indexed(std::string_view column, std::string_view prefix) {
  if (column.size() <= prefix.size() || column.substr(0, prefix.size()) != prefix) return 0;
  const std::string_view digits = column.substr(prefix.size());
  if (digits.front() == '0') return 0;
  int v = 0;
  const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), v);
  if (ec != std::errc() || ptr != digits.data() + digits.size() || v <= 0) return 0;
  return v;
}

Status check_format(const CsvTable& t, const char* expected) {
  if (!t.metadata.has(key::kFormat)) return Status::success();
  const std::string f = t.metadata.get(key::kFormat);
  const std::string_view want(expected);
  const std::string_view family = want.substr(0, want.find(' '));
  if (f.compare(0, family.size(), family) != 0 ||
      (f.size() > family.size() && f[family.size()] != ' ')) {
    return Status::error(ErrorCode::kParseError, "%s: format '%s' is not '%s'", t.name.c_str(),
                         f.c_str(), expected);
  }
  if (f != want) {
    return Status::error(ErrorCode::kParseError,
                         "%s: format '%s' is not supported (this build reads '%s')", t.name.c_str(),
                         f.c_str(), expected);
  }
  return Status::success();
}

Status header_error(const CsvTable& t, const char* fmt, const char* what) {
  char reason[160];
  std::snprintf(reason, sizeof reason, fmt, what);
  return Status::error(ErrorCode::kParseError, "%s:%d: %s", t.name.c_str(), t.header_line, reason);
}

// Column layout of a recording, resolved from its header.
struct Layout {
  int pose = -1, time = -1;
  std::array<int, 6> cmd{-1, -1, -1, -1, -1, -1};
  std::array<int, 6> ref{-1, -1, -1, -1, -1, -1};
  std::array<int, 6> start{-1, -1, -1, -1, -1, -1};
  std::vector<int> lengths, tensions, lasers, swivels, planned;
  int temperature = -1;
  int incl_roll = -1, incl_pitch = -1, imu_yaw = -1;
  int scatter_length = -1, scatter_force = -1, supported = -1;
};

// Six columns that come together (ref_*, start_*): all six or none.
Status all_or_none(const CsvTable& t, const std::array<int, 6>& cols,
                   const std::array<const char*, 6>& names, const char* what) {
  int given = 0;
  for (const int c : cols) given += c >= 0 ? 1 : 0;
  if (given == 0 || given == 6) return Status::success();
  for (std::size_t a = 0; a < 6; ++a) {
    if (cols[a] < 0) return header_error(t, what, names[a]);
  }
  return Status::success();
}

Status resolve_layout(const CsvTable& t, Layout* layout) {
  std::map<int, int> lengths, tensions, lasers, swivels, planned;  // index -> column
  for (std::size_t c = 0; c < t.header.size(); ++c) {
    const std::string& h = t.header[c];
    const int col = static_cast<int>(c);
    bool known = true;
    if (h == "pose") {
      layout->pose = col;
    } else if (h == "time_s") {
      layout->time = col;
    } else if (h == "temperature_c") {
      layout->temperature = col;
    } else if (int i = indexed(h, "length_"); i > 0) {
      lengths[i] = col;
    } else if (int j = indexed(h, "tension_"); j > 0) {
      tensions[j] = col;
    } else if (int k = indexed(h, "laser_"); k > 0) {
      lasers[k] = col;
    } else if (int w = indexed(h, "swivel_"); w > 0) {
      swivels[w] = col;
    } else if (h == "incl_roll") {
      layout->incl_roll = col;
    } else if (h == "incl_pitch") {
      layout->incl_pitch = col;
    } else if (h == "imu_yaw") {
      layout->imu_yaw = col;
    } else if (int q = indexed(h, "planned_tension_"); q > 0) {
      planned[q] = col;
    } else if (h == "scatter_length_m") {
      layout->scatter_length = col;
    } else if (h == "scatter_force_n") {
      layout->scatter_force = col;
    } else if (h == "supported") {
      layout->supported = col;
    } else {
      known = false;
      for (std::size_t a = 0; a < 6; ++a) {
        if (h == kCmd[a]) layout->cmd[a] = col, known = true;
        if (h == kRef[a]) layout->ref[a] = col, known = true;
        if (h == kStart[a]) layout->start[a] = col, known = true;
      }
    }
    if (!known) {
      return Status::error(ErrorCode::kParseError, "%s:%d: column %zu (%s): unknown column",
                           t.name.c_str(), t.header_line, c + 1, h.c_str());
    }
  }
  if (layout->pose < 0) return header_error(t, "missing required column '%s'", "pose");
  if (layout->time < 0) return header_error(t, "missing required column '%s'", "time_s");
  for (std::size_t a = 0; a < 6; ++a) {
    if (layout->cmd[a] < 0) return header_error(t, "missing required column '%s'", kCmd[a]);
  }
  auto contiguous = [&](const std::map<int, int>& cols, const char* prefix, std::vector<int>* out) {
    const int n = cols.empty() ? 0 : cols.rbegin()->first;
    for (int i = 1; i <= n; ++i) {
      const auto it = cols.find(i);
      if (it == cols.end()) {
        char name[48];
        std::snprintf(name, sizeof name, "%s%d", prefix, i);
        return header_error(t, "missing required column '%s'", name);
      }
      out->push_back(it->second);
    }
    return Status::success();
  };
  CDPR_RETURN_IF_ERROR(contiguous(lengths, "length_", &layout->lengths));
  CDPR_RETURN_IF_ERROR(contiguous(tensions, "tension_", &layout->tensions));
  CDPR_RETURN_IF_ERROR(contiguous(lasers, "laser_", &layout->lasers));
  if (layout->lengths.empty()) return header_error(t, "missing required column '%s'", "length_1");
  if (layout->tensions.size() != layout->lengths.size()) {
    return Status::error(ErrorCode::kParseError,
                         "%s:%d: %zu length_ columns but %zu tension_ columns (one of each per "
                         "cable)",
                         t.name.c_str(), t.header_line, layout->lengths.size(),
                         layout->tensions.size());
  }
  CDPR_RETURN_IF_ERROR(contiguous(swivels, "swivel_", &layout->swivels));
  if (!layout->swivels.empty() && layout->swivels.size() != layout->lengths.size()) {
    return Status::error(
        ErrorCode::kParseError, "%s:%d: %zu swivel_ columns but %zu cables (one per cable or none)",
        t.name.c_str(), t.header_line, layout->swivels.size(), layout->lengths.size());
  }
  if ((layout->incl_roll < 0) != (layout->incl_pitch < 0)) {
    return header_error(t, "missing column '%s' (incl_roll and incl_pitch come together)",
                        layout->incl_roll < 0 ? "incl_roll" : "incl_pitch");
  }
  CDPR_RETURN_IF_ERROR(contiguous(planned, "planned_tension_", &layout->planned));
  if (!layout->planned.empty() && layout->planned.size() != layout->lengths.size()) {
    return Status::error(ErrorCode::kParseError,
                         "%s:%d: %zu planned_tension_ columns but %zu cables (one per cable or "
                         "none)",
                         t.name.c_str(), t.header_line, layout->planned.size(),
                         layout->lengths.size());
  }
  CDPR_RETURN_IF_ERROR(
      all_or_none(t, layout->ref, kRef, "missing column '%s' (ref_ columns are all six or none)"));
  return all_or_none(t, layout->start, kStart,
                     "missing column '%s' (start_ columns are all six or none)");
}

Status check_size(const char* what, Eigen::Index got, int want, std::int64_t pose) {
  if (got != want) {
    return Status::error(ErrorCode::kInvalidArgument, "pose %lld: %ld %s values, expected %d",
                         static_cast<long long>(pose), static_cast<long>(got), what, want);
  }
  return Status::success();
}

Status append(std::string* out, double v, const char* what, std::int64_t pose) {
  if (std::isinf(v)) {
    return Status::error(ErrorCode::kInvalidArgument, "pose %lld: %s is infinite",
                         static_cast<long long>(pose), what);
  }
  *out += ',';
  *out += format_number(v);
  return Status::success();
}

// "writing <path>: <message>"; a long path is shortened in its middle, the reason is kept.
Status with_path(const Status& s, const std::string& path) {
  Status out = s;
  out.prepend("writing " + path + ": ");
  return out;
}

// A six-column pose cell group (ref_*, start_*): NaN when the file has none of them.
Status parse_pose_cells(const CsvTable& t, const CsvRow& row, const std::array<int, 6>& cols,
                        Pose* out) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  out->position.setConstant(nan);
  out->rpy.setConstant(nan);
  if (cols[0] < 0) return Status::success();
  for (int a = 0; a < 6; ++a) {
    double v = 0.0;
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, cols[static_cast<std::size_t>(a)], true, &v));
    (a < 3 ? out->position : out->rpy)(a % 3) = v;
  }
  return Status::success();
}

// The optional columns of what a campaign knows besides the readings: planned tensions, the
// pose's scatter, the supported flag, the start pose.
Status parse_campaign_cells(const CsvTable& t, const CsvRow& row, const Layout& layout,
                            RecordedPose* p) {
  if (!layout.planned.empty()) {
    p->planned_tensions.resize(static_cast<Eigen::Index>(layout.planned.size()));
    for (std::size_t i = 0; i < layout.planned.size(); ++i) {
      CDPR_RETURN_IF_ERROR(detail::parse_double(
          t, row, layout.planned[i], true, &p->planned_tensions(static_cast<Eigen::Index>(i))));
    }
  }
  for (const auto& [col, out] : {std::pair{layout.scatter_length, &p->scatter_length_m},
                                 std::pair{layout.scatter_force, &p->scatter_force_n}}) {
    if (col < 0) continue;
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, col, true, out));
    if (*out < 0.0) {
      return detail::cell_error(t, row, col, "a scatter is a standard deviation, >= 0 (got %g)",
                                *out);
    }
  }
  if (layout.supported >= 0) {
    double v = 0.0;
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, layout.supported, true, &v));
    if (!std::isnan(v) && v != 0.0 && v != 1.0) {
      return detail::cell_error(t, row, layout.supported,
                                "expected 1 (the platform rested on something) or 0, got %g", v);
    }
    p->supported = v == 1.0;
  }
  return parse_pose_cells(t, row, layout.start, &p->start);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Recording
// ---------------------------------------------------------------------------------------------

Result<Recording> parse_recording(std::string_view text, std::string_view name) {
  CDPR_ASSIGN_OR_RETURN(const CsvTable t, detail::parse_table(text, name));
  CDPR_RETURN_IF_ERROR(check_format(t, kRecordingFormat));
  Layout layout;
  CDPR_RETURN_IF_ERROR(resolve_layout(t, &layout));

  Recording rec;
  rec.metadata = t.metadata;
  rec.num_cables = static_cast<int>(layout.lengths.size());
  rec.num_lasers = static_cast<int>(layout.lasers.size());
  rec.has_swivel = !layout.swivels.empty();
  rec.has_inclinometer = layout.incl_roll >= 0;
  rec.has_imu_yaw = layout.imu_yaw >= 0;
  rec.has_reference = layout.ref[0] >= 0;
  rec.has_temperature = layout.temperature >= 0;
  rec.has_planned_tensions = !layout.planned.empty();
  rec.has_scatter_length = layout.scatter_length >= 0;
  rec.has_scatter_force = layout.scatter_force >= 0;
  rec.has_supported = layout.supported >= 0;
  rec.has_start = layout.start[0] >= 0;
  rec.header = t.header;
  rec.poses.reserve(t.rows.size());
  int previous_line = 0;
  for (const CsvRow& row : t.rows) {
    RecordedPose p;
    CDPR_RETURN_IF_ERROR(detail::parse_int(t, row, layout.pose, &p.index));
    if (!rec.poses.empty() && p.index <= rec.poses.back().index) {
      return detail::cell_error(t, row, layout.pose,
                                "pose index %lld does not increase (line %d has %lld)",
                                static_cast<long long>(p.index), previous_line,
                                static_cast<long long>(rec.poses.back().index));
    }
    previous_line = row.line;
    p.line = row.line;
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, layout.time, false, &p.time_s));
    for (int a = 0; a < 6; ++a) {
      double v = 0.0;
      CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, layout.cmd[a], false, &v));
      (a < 3 ? p.commanded.position : p.commanded.rpy)(a % 3) = v;
    }
    auto fill = [&](const std::vector<int>& cols, Eigen::VectorXd* out) {
      out->resize(static_cast<Eigen::Index>(cols.size()));
      for (std::size_t i = 0; i < cols.size(); ++i) {
        if (Status s =
                detail::parse_double(t, row, cols[i], true, &(*out)(static_cast<Eigen::Index>(i)));
            !s.ok()) {
          return s;
        }
      }
      return Status::success();
    };
    CDPR_RETURN_IF_ERROR(fill(layout.lengths, &p.lengths));
    CDPR_RETURN_IF_ERROR(fill(layout.tensions, &p.tensions));
    CDPR_RETURN_IF_ERROR(fill(layout.lasers, &p.lasers));
    if (rec.has_swivel) CDPR_RETURN_IF_ERROR(fill(layout.swivels, &p.swivels));
    if (rec.has_inclinometer) {
      CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, layout.incl_roll, true, &p.inclination(0)));
      CDPR_RETURN_IF_ERROR(
          detail::parse_double(t, row, layout.incl_pitch, true, &p.inclination(1)));
      if (std::isnan(p.inclination(0)) != std::isnan(p.inclination(1))) {
        return detail::cell_error(
            t, row, std::isnan(p.inclination(0)) ? layout.incl_roll : layout.incl_pitch,
            "empty cell, but incl_roll and incl_pitch are measured together");
      }
    }
    if (rec.has_imu_yaw) {
      CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, layout.imu_yaw, true, &p.imu_yaw));
    }
    CDPR_RETURN_IF_ERROR(parse_pose_cells(t, row, layout.ref, &p.reference));
    if (rec.has_temperature) {
      CDPR_RETURN_IF_ERROR(
          detail::parse_double(t, row, layout.temperature, true, &p.temperature_c));
    }
    CDPR_RETURN_IF_ERROR(parse_campaign_cells(t, row, layout, &p));
    rec.poses.push_back(std::move(p));
  }
  return rec;
}

Result<Recording> read_recording(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const std::string text, detail::read_file(path));
  return parse_recording(text, path);
}

namespace {

Status check_columns(const Recording& rec) {
  if (rec.num_cables < 1 || rec.num_lasers < 0) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "a recording needs at least one cable (has %d cables and %d lasers)",
                         rec.num_cables, rec.num_lasers);
  }
  return Status::success();
}

}  // namespace

Result<std::string> format_recording_header(const Recording& rec) {
  CDPR_RETURN_IF_ERROR(check_columns(rec));
  std::string out;
  CDPR_RETURN_IF_ERROR(detail::format_metadata(rec.metadata, kRecordingFormat, &out));
  out += "pose,time_s";
  for (const char* c : kCmd) out += std::string(",") + c;
  for (int i = 1; i <= rec.num_cables; ++i) out += ",length_" + std::to_string(i);
  for (int i = 1; i <= rec.num_cables; ++i) out += ",tension_" + std::to_string(i);
  for (int i = 1; i <= rec.num_lasers; ++i) out += ",laser_" + std::to_string(i);
  if (rec.has_swivel) {
    for (int i = 1; i <= rec.num_cables; ++i) out += ",swivel_" + std::to_string(i);
  }
  if (rec.has_inclinometer) out += ",incl_roll,incl_pitch";
  if (rec.has_imu_yaw) out += ",imu_yaw";
  if (rec.has_reference) {
    for (const char* c : kRef) out += std::string(",") + c;
  }
  if (rec.has_temperature) out += ",temperature_c";
  if (rec.has_planned_tensions) {
    for (int i = 1; i <= rec.num_cables; ++i) out += ",planned_tension_" + std::to_string(i);
  }
  if (rec.has_scatter_length) out += ",scatter_length_m";
  if (rec.has_scatter_force) out += ",scatter_force_n";
  if (rec.has_supported) out += ",supported";
  if (rec.has_start) {
    for (const char* c : kStart) out += std::string(",") + c;
  }
  out += '\n';
  return out;
}

namespace {

Status append_campaign_cells(const Recording& rec, const RecordedPose& p, std::string* out) {
  if (rec.has_planned_tensions) {
    CDPR_RETURN_IF_ERROR(
        check_size("planned tension", p.planned_tensions.size(), rec.num_cables, p.index));
    for (Eigen::Index i = 0; i < p.planned_tensions.size(); ++i) {
      CDPR_RETURN_IF_ERROR(append(out, p.planned_tensions(i), "a planned tension", p.index));
    }
  }
  if (rec.has_scatter_length) {
    CDPR_RETURN_IF_ERROR(append(out, p.scatter_length_m, "the length scatter", p.index));
  }
  if (rec.has_scatter_force) {
    CDPR_RETURN_IF_ERROR(append(out, p.scatter_force_n, "the force scatter", p.index));
  }
  if (rec.has_supported) *out += p.supported ? ",1" : ",0";
  if (rec.has_start) {
    const auto start = p.start.vector();
    for (int a = 0; a < 6; ++a) {
      CDPR_RETURN_IF_ERROR(append(out, start(a), "the start pose", p.index));
    }
  }
  return Status::success();
}

}  // namespace

Result<std::string> format_recording_row(const Recording& rec, const RecordedPose& p) {
  CDPR_RETURN_IF_ERROR(check_columns(rec));
  CDPR_RETURN_IF_ERROR(check_size("length", p.lengths.size(), rec.num_cables, p.index));
  CDPR_RETURN_IF_ERROR(check_size("tension", p.tensions.size(), rec.num_cables, p.index));
  CDPR_RETURN_IF_ERROR(check_size("laser", p.lasers.size(), rec.num_lasers, p.index));
  if (rec.has_swivel) {
    CDPR_RETURN_IF_ERROR(check_size("swivel", p.swivels.size(), rec.num_cables, p.index));
  }
  if (!std::isfinite(p.time_s) || !p.commanded.vector().allFinite()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "pose %lld: time and commanded pose must be finite",
                         static_cast<long long>(p.index));
  }
  std::string out = std::to_string(p.index);
  out += ',' + format_number(p.time_s);
  const auto cmd = p.commanded.vector();
  for (int a = 0; a < 6; ++a) out += ',' + format_number(cmd(a));
  for (Eigen::Index i = 0; i < p.lengths.size(); ++i) {
    CDPR_RETURN_IF_ERROR(append(&out, p.lengths(i), "a length", p.index));
  }
  for (Eigen::Index i = 0; i < p.tensions.size(); ++i) {
    CDPR_RETURN_IF_ERROR(append(&out, p.tensions(i), "a tension", p.index));
  }
  for (Eigen::Index i = 0; i < p.lasers.size(); ++i) {
    CDPR_RETURN_IF_ERROR(append(&out, p.lasers(i), "a laser distance", p.index));
  }
  if (rec.has_swivel) {
    for (Eigen::Index i = 0; i < p.swivels.size(); ++i) {
      CDPR_RETURN_IF_ERROR(append(&out, p.swivels(i), "a swivel angle", p.index));
    }
  }
  if (rec.has_inclinometer) {
    CDPR_RETURN_IF_ERROR(append(&out, p.inclination(0), "the inclinometer roll", p.index));
    CDPR_RETURN_IF_ERROR(append(&out, p.inclination(1), "the inclinometer pitch", p.index));
  }
  if (rec.has_imu_yaw) {
    CDPR_RETURN_IF_ERROR(append(&out, p.imu_yaw, "the IMU yaw", p.index));
  }
  if (rec.has_reference) {
    const auto ref = p.reference.vector();
    for (int a = 0; a < 6; ++a) {
      CDPR_RETURN_IF_ERROR(append(&out, ref(a), "the reference pose", p.index));
    }
  }
  if (rec.has_temperature) {
    CDPR_RETURN_IF_ERROR(append(&out, p.temperature_c, "the temperature", p.index));
  }
  CDPR_RETURN_IF_ERROR(append_campaign_cells(rec, p, &out));
  out += '\n';
  return out;
}

Result<std::string> format_recording(const Recording& rec) {
  CDPR_RETURN_IF_ERROR(check_columns(rec));
  if (rec.poses.empty()) {
    return Status(ErrorCode::kInvalidArgument, "a recording needs at least one pose");
  }
  CDPR_ASSIGN_OR_RETURN(std::string out, format_recording_header(rec));
  for (std::size_t n = 0; n < rec.poses.size(); ++n) {
    const RecordedPose& p = rec.poses[n];
    if (n > 0 && p.index <= rec.poses[n - 1].index) {
      return Status::error(ErrorCode::kInvalidArgument, "pose index %lld does not increase",
                           static_cast<long long>(p.index));
    }
    CDPR_ASSIGN_OR_RETURN(const std::string row, format_recording_row(rec, p));
    out += row;
  }
  return out;
}

Status write_recording(const Recording& recording, const std::string& path) {
  auto text = format_recording(recording);
  if (!text.ok()) return with_path(text.status(), path);
  return detail::write_file(path, *text);
}

Status check_against_model(const Recording& recording, const RobotModel& model) {
  const int m = model.num_cables();
  const int k = static_cast<int>(model.lasers.size());
  const std::string robot =
      model.name.empty() ? std::string("the config") : "config '" + model.name + "'";
  if (recording.num_cables != m) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "cable count mismatch: the recording has %d cables (length_1..length_%d) "
                         "but %s has %d",
                         recording.num_cables, recording.num_cables, robot.c_str(), m);
  }
  if (recording.num_lasers != 0 && recording.num_lasers != k) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "laser count mismatch: the recording has %d laser columns but %s has %d "
                         "lasers",
                         recording.num_lasers, robot.c_str(), k);
  }
  if (recording.has_swivel) {
    for (int i = 0; i < m; ++i) {
      if (!model.pulleys[static_cast<std::size_t>(i)].enabled()) {
        return Status::error(ErrorCode::kFailedPrecondition,
                             "swivel_%d: cable %d has no swivel pulley in %s (pulley.radius 0), so "
                             "its swivel angle is undefined",
                             i + 1, i + 1, robot.c_str());
      }
    }
  }
  return Status::success();
}

// ---------------------------------------------------------------------------------------------
// Cable experiment
// ---------------------------------------------------------------------------------------------

namespace {

// Resolves required columns by name; no other column is allowed.
template <std::size_t N>
Status resolve_fixed(const CsvTable& t, const std::array<const char*, N>& names,
                     std::array<int, N>* cols) {
  for (std::size_t c = 0; c < t.header.size(); ++c) {
    bool known = false;
    for (std::size_t a = 0; a < N; ++a) {
      if (t.header[c] == names[a]) (*cols)[a] = static_cast<int>(c), known = true;
    }
    if (!known) {
      return Status::error(ErrorCode::kParseError, "%s:%d: column %zu (%s): unknown column",
                           t.name.c_str(), t.header_line, c + 1, t.header[c].c_str());
    }
  }
  for (std::size_t a = 0; a < N; ++a) {
    if ((*cols)[a] < 0) return header_error(t, "missing required column '%s'", names[a]);
  }
  return Status::success();
}

constexpr std::array<const char*, 3> kCableColumns = {"length_m", "tension_n", "elongation_m"};
constexpr std::array<const char*, 3> kForceColumns = {"channel", "mass_kg", "raw"};

}  // namespace

Result<CableExperiment> parse_cable_experiment(std::string_view text, std::string_view name) {
  CDPR_ASSIGN_OR_RETURN(const CsvTable t, detail::parse_table(text, name));
  CDPR_RETURN_IF_ERROR(check_format(t, kCableFormat));
  std::array<int, 3> cols{-1, -1, -1};
  CDPR_RETURN_IF_ERROR(resolve_fixed(t, kCableColumns, &cols));
  CableExperiment e;
  e.metadata = t.metadata;
  for (const CsvRow& row : t.rows) {
    CableSample c;
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, cols[0], false, &c.length_m));
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, cols[1], false, &c.tension_n));
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, cols[2], false, &c.elongation_m));
    if (c.length_m <= 0.0) return detail::cell_error(t, row, cols[0], "a length must be > 0 m");
    if (c.tension_n < 0.0) return detail::cell_error(t, row, cols[1], "a tension must be >= 0 N");
    e.samples.push_back(c);
  }
  return e;
}

Result<CableExperiment> read_cable_experiment(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const std::string text, detail::read_file(path));
  return parse_cable_experiment(text, path);
}

Result<std::string> format_cable_experiment(const CableExperiment& e) {
  std::string out;
  CDPR_RETURN_IF_ERROR(detail::format_metadata(e.metadata, kCableFormat, &out));
  out += "length_m,tension_n,elongation_m\n";
  for (const CableSample& c : e.samples) {
    if (!std::isfinite(c.length_m) || !std::isfinite(c.tension_n) ||
        !std::isfinite(c.elongation_m)) {
      return Status(ErrorCode::kInvalidArgument, "cable experiment: every value must be finite");
    }
    out += format_number(c.length_m) + ',' + format_number(c.tension_n) + ',' +
           format_number(c.elongation_m) + '\n';
  }
  return out;
}

Status write_cable_experiment(const CableExperiment& e, const std::string& path) {
  auto text = format_cable_experiment(e);
  if (!text.ok()) return with_path(text.status(), path);
  return detail::write_file(path, *text);
}

// ---------------------------------------------------------------------------------------------
// Force-sensor experiment
// ---------------------------------------------------------------------------------------------

Result<ForceSensorExperiment> parse_force_experiment(std::string_view text, std::string_view name) {
  CDPR_ASSIGN_OR_RETURN(const CsvTable t, detail::parse_table(text, name));
  CDPR_RETURN_IF_ERROR(check_format(t, kForceFormat));
  std::array<int, 3> cols{-1, -1, -1};
  CDPR_RETURN_IF_ERROR(resolve_fixed(t, kForceColumns, &cols));
  ForceSensorExperiment e;
  e.metadata = t.metadata;
  for (const CsvRow& row : t.rows) {
    ForceSample f;
    std::int64_t channel = 0;
    CDPR_RETURN_IF_ERROR(detail::parse_int(t, row, cols[0], &channel));
    if (channel < 1 || channel > 1000) {
      return detail::cell_error(t, row, cols[0], "channel %lld is not in 1..1000",
                                static_cast<long long>(channel));
    }
    f.channel = static_cast<int>(channel);
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, cols[1], false, &f.mass_kg));
    CDPR_RETURN_IF_ERROR(detail::parse_double(t, row, cols[2], false, &f.raw));
    if (f.mass_kg < 0.0) return detail::cell_error(t, row, cols[1], "a mass must be >= 0 kg");
    e.samples.push_back(f);
  }
  return e;
}

Result<ForceSensorExperiment> read_force_experiment(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const std::string text, detail::read_file(path));
  return parse_force_experiment(text, path);
}

Result<std::string> format_force_experiment(const ForceSensorExperiment& e) {
  std::string out;
  CDPR_RETURN_IF_ERROR(detail::format_metadata(e.metadata, kForceFormat, &out));
  out += "channel,mass_kg,raw\n";
  for (const ForceSample& f : e.samples) {
    if (f.channel < 1 || !std::isfinite(f.mass_kg) || !std::isfinite(f.raw)) {
      return Status(ErrorCode::kInvalidArgument,
                    "force experiment: channels start at 1 and values must be finite");
    }
    out += std::to_string(f.channel) + ',' + format_number(f.mass_kg) + ',' + format_number(f.raw) +
           '\n';
  }
  return out;
}

Status write_force_experiment(const ForceSensorExperiment& e, const std::string& path) {
  auto text = format_force_experiment(e);
  if (!text.ok()) return with_path(text.status(), path);
  return detail::write_file(path, *text);
}

// ---------------------------------------------------------------------------------------------
// Pose list
// ---------------------------------------------------------------------------------------------

namespace {
constexpr std::array<const char*, 7> kPoseColumns = {"pose", "x", "y", "z", "roll", "pitch", "yaw"};
}  // namespace

Result<PoseList> parse_pose_list(std::string_view text, std::string_view name) {
  CDPR_ASSIGN_OR_RETURN(const CsvTable t, detail::parse_table(text, name));
  CDPR_RETURN_IF_ERROR(check_format(t, kPoseListFormat));
  std::array<int, 7> cols{-1, -1, -1, -1, -1, -1, -1};
  CDPR_RETURN_IF_ERROR(resolve_fixed(t, kPoseColumns, &cols));
  PoseList list;
  list.metadata = t.metadata;
  std::int64_t previous = 0;
  int previous_line = 0;
  for (const CsvRow& row : t.rows) {
    std::int64_t index = 0;
    CDPR_RETURN_IF_ERROR(detail::parse_int(t, row, cols[0], &index));
    if (previous_line != 0 && index <= previous) {
      return detail::cell_error(
          t, row, cols[0], "pose index %lld does not increase (line %d has %lld)",
          static_cast<long long>(index), previous_line, static_cast<long long>(previous));
    }
    previous = index;
    previous_line = row.line;
    Pose p;
    for (int a = 0; a < 6; ++a) {
      double v = 0.0;
      CDPR_RETURN_IF_ERROR(
          detail::parse_double(t, row, cols[static_cast<std::size_t>(a) + 1], false, &v));
      (a < 3 ? p.position : p.rpy)(a % 3) = v;
    }
    list.poses.push_back(p);
    list.lines.push_back(row.line);
  }
  return list;
}

Result<PoseList> read_pose_list(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const std::string text, detail::read_file(path));
  return parse_pose_list(text, path);
}

Result<std::string> format_pose_list(const PoseList& list) {
  if (list.poses.empty()) return Status(ErrorCode::kInvalidArgument, "a pose list needs a pose");
  std::string out;
  CDPR_RETURN_IF_ERROR(detail::format_metadata(list.metadata, kPoseListFormat, &out));
  out += "pose,x,y,z,roll,pitch,yaw\n";
  for (std::size_t j = 0; j < list.poses.size(); ++j) {
    const auto v = list.poses[j].vector();
    if (!v.allFinite()) {
      return Status::error(ErrorCode::kInvalidArgument, "pose %zu is not finite", j);
    }
    out += std::to_string(j);
    for (int a = 0; a < 6; ++a) out += ',' + format_number(v(a));
    out += '\n';
  }
  return out;
}

Status write_pose_list(const PoseList& list, const std::string& path) {
  auto text = format_pose_list(list);
  if (!text.ok()) return with_path(text.status(), path);
  return detail::write_file(path, *text);
}

}  // namespace cdpr::recording
