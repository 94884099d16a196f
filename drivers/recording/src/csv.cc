#include "csv.hpp"

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdarg>
#include <cstring>
#include <ctime>
#include <fstream>
#include <sstream>
#include <system_error>

#include "cdpr/io/atomic_file.hpp"

namespace cdpr::recording {

// ---------------------------------------------------------------------------------------------
// Metadata and helpers
// ---------------------------------------------------------------------------------------------

void Metadata::set(std::string k, std::string value) {
  for (auto& [ek, ev] : entries_) {
    if (ek == k) {
      ev = std::move(value);
      return;
    }
  }
  entries_.emplace_back(std::move(k), std::move(value));
}

void Metadata::set_number(std::string k, double value) {
  set(std::move(k), format_number(value));
}

bool Metadata::has(std::string_view k) const {
  return std::any_of(entries_.begin(), entries_.end(), [&](const auto& e) { return e.first == k; });
}

std::string Metadata::get(std::string_view k) const {
  for (const auto& [ek, ev] : entries_) {
    if (ek == k) return ev;
  }
  return {};
}

Result<double> Metadata::number(std::string_view k) const {
  if (!has(k)) {
    return Status::error(ErrorCode::kNotFound, "metadata '%.*s' is absent",
                         static_cast<int>(k.size()), k.data());
  }
  const std::string v = get(k);
  double d = 0.0;
  const char* end = v.data() + v.size();
  const auto [ptr, ec] = std::from_chars(v.data(), end, d);
  if (ec != std::errc() || ptr != end || !std::isfinite(d)) {
    return Status::error(ErrorCode::kParseError, "metadata '%.*s': '%s' is not a number",
                         static_cast<int>(k.size()), k.data(), v.c_str());
  }
  return d;
}

std::uint64_t fnv1a64(std::string_view bytes) {
  std::uint64_t h = 0xcbf29ce484222325ULL;
  for (const char c : bytes) {
    h ^= static_cast<unsigned char>(c);
    h *= 0x100000001b3ULL;
  }
  return h;
}

Result<std::string> file_hash(const std::string& path) {
  CDPR_ASSIGN_OR_RETURN(const std::string text, detail::read_file(path));
  char buf[32];
  std::snprintf(buf, sizeof buf, "fnv1a64:%016llx", static_cast<unsigned long long>(fnv1a64(text)));
  return std::string(buf);
}

std::string format_number(double value) {
  if (std::isnan(value)) return {};
  char buf[64];
  const auto [ptr, ec] = std::to_chars(buf, buf + sizeof buf, value);
  if (ec != std::errc()) return "?";
  return std::string(buf, ptr);
}

std::string utc_timestamp() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

namespace detail {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
    s.remove_suffix(1);
  return s;
}

bool is_key(std::string_view k) {
  if (k.empty()) return false;
  return std::all_of(k.begin(), k.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '-' || c == '.';
  });
}

std::vector<std::string_view> split_cells(std::string_view line) {
  std::vector<std::string_view> cells;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = line.find(',', start);
    if (comma == std::string_view::npos) {
      cells.push_back(trim(line.substr(start)));
      break;
    }
    cells.push_back(trim(line.substr(start, comma - start)));
    start = comma + 1;
  }
  return cells;
}

// Cuts a cell to a printable length for messages.
std::string shown(std::string_view cell) {
  if (cell.size() <= 24) return std::string(cell);
  return std::string(cell.substr(0, 21)) + "...";
}

}  // namespace

int CsvTable::column(std::string_view column_name) const {
  for (std::size_t i = 0; i < header.size(); ++i) {
    if (header[i] == column_name) return static_cast<int>(i);
  }
  return -1;
}

Result<std::string> read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::error(errno == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIoError,
                         "cannot open '%s': %s", path.c_str(), std::strerror(errno));
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) {
    return Status::error(ErrorCode::kIoError, "cannot read '%s'", path.c_str());
  }
  return ss.str();
}

Status write_file(const std::string& path, const std::string& text) {
  return io::write_file_atomically(path, text);
}

Result<CsvTable> parse_table(std::string_view text, std::string_view name) {
  CsvTable t;
  t.name = std::string(name);
  const char* fname = t.name.c_str();
  std::vector<int> metadata_lines;
  int line_no = 0;
  std::size_t pos = 0;
  // A UTF-8 byte order mark (spreadsheet exports write one) is not part of the first line.
  if (text.substr(0, 3) == "\xEF\xBB\xBF") pos = 3;
  while (pos < text.size()) {
    std::size_t nl = text.find('\n', pos);
    if (nl == std::string_view::npos) nl = text.size();
    const std::string_view raw = text.substr(pos, nl - pos);
    pos = nl + 1;
    ++line_no;
    const std::string_view line = trim(raw);
    if (line.empty()) continue;
    if (line.front() == '#') {
      if (t.header_line != 0) continue;  // a comment between rows: ignored
      const std::string_view body = trim(line.substr(1));
      const std::size_t colon = body.find(':');
      if (colon == std::string_view::npos) continue;  // a plain comment
      const std::string_view k = trim(body.substr(0, colon));
      if (!is_key(k)) continue;
      const std::string_view v = trim(body.substr(colon + 1));
      for (std::size_t i = 0; i < t.metadata.entries().size(); ++i) {
        if (t.metadata.entries()[i].first == k) {
          return Status::error(ErrorCode::kParseError,
                               "%s:%d: metadata key '%.*s' appears twice (first on line %d)", fname,
                               line_no, static_cast<int>(k.size()), k.data(), metadata_lines[i]);
        }
      }
      t.metadata.set(std::string(k), std::string(v));
      metadata_lines.push_back(line_no);
      if (k == key::kUnits) t.units_line = line_no;
      continue;
    }
    if (t.header_line == 0) {
      t.header_line = line_no;
      const auto names = split_cells(line);
      for (std::size_t c = 0; c < names.size(); ++c) {
        if (names[c].empty()) {
          return Status::error(ErrorCode::kParseError, "%s:%d: column %zu: empty column name",
                               fname, line_no, c + 1);
        }
        for (std::size_t d = 0; d < c; ++d) {
          if (t.header[d] == names[c]) {
            return Status::error(ErrorCode::kParseError,
                                 "%s:%d: column %zu (%.*s): duplicates column %zu", fname, line_no,
                                 c + 1, static_cast<int>(names[c].size()), names[c].data(), d + 1);
          }
        }
        t.header.emplace_back(names[c]);
      }
      continue;
    }
    CsvRow row;
    row.line = line_no;
    row.cells = split_cells(line);
    const std::size_t n = row.cells.size(), m = t.header.size();
    if (n < m) {
      return Status::error(ErrorCode::kParseError,
                           "%s:%d: column %zu (%s): missing cell (row has %zu cells, header on "
                           "line %d has %zu columns)",
                           fname, line_no, n + 1, t.header[n].c_str(), n, t.header_line, m);
    }
    if (n > m) {
      return Status::error(ErrorCode::kParseError,
                           "%s:%d: column %zu: extra cell '%s' (row has %zu cells, header on line "
                           "%d has %zu columns)",
                           fname, line_no, m + 1, shown(row.cells[m]).c_str(), n, t.header_line, m);
    }
    t.rows.push_back(std::move(row));
  }
  if (t.header_line == 0) {
    return Status::error(ErrorCode::kParseError, "%s: no header row", fname);
  }
  if (!t.metadata.has(key::kUnits)) {
    return Status::error(ErrorCode::kParseError,
                         "%s: no '# units: SI' line before the header (values must be SI: m, rad, "
                         "N, s, kg)",
                         fname);
  }
  if (t.metadata.get(key::kUnits) != kUnitsSI) {
    return Status::error(
        ErrorCode::kParseError,
        "%s:%d: units '%s' are not supported; values must be SI (m, rad, N, s, kg)", fname,
        t.units_line, shown(t.metadata.get(key::kUnits)).c_str());
  }
  if (t.rows.empty()) {
    return Status::error(ErrorCode::kParseError, "%s:%d: no data rows after the header", fname,
                         t.header_line);
  }
  return t;
}

Status cell_error(const CsvTable& t, const CsvRow& row, int col, const char* reason_fmt, ...) {
  char reason[160];
  va_list args;
  va_start(args, reason_fmt);
  std::vsnprintf(reason, sizeof reason, reason_fmt, args);
  va_end(args);
  return Status::error(ErrorCode::kParseError, "%s:%d: column %d (%s): %s", t.name.c_str(),
                       row.line, col + 1, t.header[static_cast<std::size_t>(col)].c_str(), reason);
}

Status parse_double(const CsvTable& t, const CsvRow& row, int col, bool allow_empty, double* out) {
  std::string_view cell = row.cells[static_cast<std::size_t>(col)];
  if (cell.empty()) {
    if (allow_empty) {
      *out = std::numeric_limits<double>::quiet_NaN();
      return Status::success();
    }
    return cell_error(t, row, col, "empty cell, but this column is required");
  }
  std::string_view digits = cell;
  if (digits.size() > 1 && digits.front() == '+' && digits[1] != '-' && digits[1] != '+') {
    digits.remove_prefix(1);
  }
  double v = 0.0;
  const char* end = digits.data() + digits.size();
  const auto [ptr, ec] = std::from_chars(digits.data(), end, v);
  if (ec == std::errc::result_out_of_range) {
    return cell_error(t, row, col, "'%s' is out of the range of a double", shown(cell).c_str());
  }
  if (ec != std::errc() || ptr != end) {
    return cell_error(t, row, col, "'%s' is not a number", shown(cell).c_str());
  }
  if (std::isnan(v)) {
    return cell_error(t, row, col, "'%s' is not allowed (leave the cell empty when not measured)",
                      shown(cell).c_str());
  }
  if (std::isinf(v)) {
    return cell_error(t, row, col, "'%s' is not a finite number", shown(cell).c_str());
  }
  *out = v;
  return Status::success();
}

Status parse_int(const CsvTable& t, const CsvRow& row, int col, std::int64_t* out) {
  std::string_view cell = row.cells[static_cast<std::size_t>(col)];
  if (cell.empty()) return cell_error(t, row, col, "empty cell, but this column is required");
  std::int64_t v = 0;
  const char* end = cell.data() + cell.size();
  const auto [ptr, ec] = std::from_chars(cell.data(), end, v);
  if (ec != std::errc() || ptr != end) {
    return cell_error(t, row, col, "'%s' is not an integer", shown(cell).c_str());
  }
  *out = v;
  return Status::success();
}

Status format_metadata(const Metadata& metadata, std::string_view format, std::string* out) {
  if (metadata.has(key::kUnits) && metadata.get(key::kUnits) != kUnitsSI) {
    return Status::error(ErrorCode::kInvalidArgument, "metadata units '%s': only SI is written",
                         metadata.get(key::kUnits).c_str());
  }
  std::string fmt = metadata.has(key::kFormat) ? metadata.get(key::kFormat) : std::string(format);
  *out += "# format: " + fmt + "\n";
  *out += "# units: " + std::string(kUnitsSI) + "\n";
  for (const auto& [k, v] : metadata.entries()) {
    if (k == key::kFormat || k == key::kUnits) continue;
    if (!is_key(k)) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "metadata key '%s' must be letters, digits, '_', '-' or '.'", k.c_str());
    }
    if (v.find_first_of("\r\n") != std::string::npos) {
      return Status::error(ErrorCode::kInvalidArgument, "metadata '%s' holds a line break",
                           k.c_str());
    }
    if (trim(v) != v) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "metadata '%s' starts or ends with blanks (not kept by readers)",
                           k.c_str());
    }
    *out += "# " + k + ": " + v + "\n";
  }
  return Status::success();
}

}  // namespace detail
}  // namespace cdpr::recording
