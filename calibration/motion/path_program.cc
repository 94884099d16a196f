#include "cdpr/calibration/path_program.hpp"

#include <array>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <optional>

namespace cdpr {

namespace {

constexpr double kMaxMagnitude = 1e6;

// The words of one line, by letter (index letter - 'A'); empty when absent.
struct Words {
  std::array<std::optional<double>, 26> value{};
  std::vector<int> g;  // G numbers in line order
};

class Parser {
 public:
  Parser(std::string_view name, const Pose& start) : name_(name), pose_(start) {}

  Status fail(std::string_view word, const char* fmt, auto... args) const {
    char reason[200];
    if constexpr (sizeof...(args) == 0) {
      std::snprintf(reason, sizeof reason, "%s", fmt);
    } else {
      std::snprintf(reason, sizeof reason, fmt, args...);
    }
    return Status::error(ErrorCode::kParseError, "%.*s:%d: %.*s: %s",
                         static_cast<int>(name_.size()), name_.data(), line_,
                         static_cast<int>(word.size()), word.data(), reason);
  }

  Status parse_line(std::string_view text, int line, std::vector<PathSegment>& out) {
    line_ = line;
    Words w;
    if (Status s = split(text, w); !s.ok()) return s;
    std::optional<int> motion;
    for (const int g : w.g) {
      switch (g) {
        case 0:
        case 1:
        case 2:
        case 3:
        case 4:
        case 5:
          if (motion) return fail("G", "two motion words (G%d and G%d) on one line", *motion, g);
          motion = g;
          break;
        case 17:
        case 18:
        case 19:
          plane_ = g;
          break;
        case 90:
          break;
        case 20:
          return fail("G20", "inches are not supported: coordinates are metres");
        case 21:
          return fail("G21", "millimetres are not supported: coordinates are metres");
        case 91:
          return fail("G91", "relative coordinates are not supported (absolute only, G90)");
        default:
          return fail("G", "G%d is not supported", g);
      }
    }
    if (w.value['R' - 'A']) {
      return fail("R", "radius arcs are not supported: give the centre with I J K");
    }
    if (w.value['F' - 'A']) {
      const double f = *w.value['F' - 'A'];
      if (!(f > 0.0)) return fail("F", "the feed must be > 0 m/s (got %g)", f);
      feed_ = f;
    }
    if (motion == 4) return dwell(w, out);
    if (w.value['P' - 'A']) return fail("P", "P (dwell seconds) belongs to G4");
    const bool has_axis = any_of(w, "XYZABC");
    const bool has_centre = any_of(w, "IJK");
    if (!motion) {
      if (!has_axis && !has_centre) return Status::success();  // modal words or nothing
      if (!mode_) return fail("X", "coordinates without a motion word (G0, G1, G2, G3, G5)");
      motion = mode_;
    }
    mode_ = motion;
    if (has_centre && *motion != 2 && *motion != 3) {
      return fail("I", "I J K (arc centre) belong to G2 and G3");
    }
    return move(*motion, w, out);
  }

 private:
  static bool any_of(const Words& w, const char* letters) {
    for (const char* c = letters; *c != '\0'; ++c) {
      if (w.value[static_cast<std::size_t>(*c - 'A')]) return true;
    }
    return false;
  }

  // Words of a line without its comments.
  Status split(std::string_view text, Words& w) {
    std::size_t i = 0;
    while (i < text.size()) {
      const char c = text[i];
      if (c == ';') break;
      if (c == ' ' || c == '\t' || c == '\r') {
        ++i;
        continue;
      }
      if (c == '(') {
        const std::size_t close = text.find(')', i);
        if (close == std::string_view::npos) return fail("(", "comment without ')'");
        i = close + 1;
        continue;
      }
      if (!std::isalpha(static_cast<unsigned char>(c))) {
        return fail(text.substr(i, 1), "expected a word (a letter and a number)");
      }
      const char letter = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
      std::size_t j = i + 1;
      while (j < text.size() && text[j] != ' ' && text[j] != '\t' && text[j] != ';' &&
             text[j] != '(' && text[j] != '\r' &&
             !std::isalpha(static_cast<unsigned char>(text[j]))) {
        ++j;
      }
      // An exponent ('e') belongs to the number.
      while (j + 1 < text.size() && (text[j] == 'e' || text[j] == 'E') &&
             (std::isdigit(static_cast<unsigned char>(text[j + 1])) || text[j + 1] == '-' ||
              text[j + 1] == '+')) {
        j += 2;
        while (j < text.size() && std::isdigit(static_cast<unsigned char>(text[j]))) ++j;
      }
      const std::string_view word = text.substr(i, j - i);
      const std::string_view number = word.substr(1);
      if (std::strchr("GXYZABCIJKFPNR", letter) == nullptr) {
        return fail(word, "unknown word");
      }
      double v = 0.0;
      const char* first = number.data();
      const char* last = number.data() + number.size();
      if (first != last && *first == '+') ++first;
      const auto r = std::from_chars(first, last, v);
      if (number.empty() || r.ec != std::errc() || r.ptr != last || !std::isfinite(v)) {
        return fail(word, "expected a finite number after %c", letter);
      }
      if (std::abs(v) > kMaxMagnitude) return fail(word, "beyond %g", kMaxMagnitude);
      if (letter == 'G') {
        if (v != std::floor(v) || v < 0.0) return fail(word, "expected a G number");
        w.g.push_back(static_cast<int>(v));
      } else if (letter != 'N') {
        auto& slot = w.value[static_cast<std::size_t>(letter - 'A')];
        if (slot) return fail(word, "%c given twice on one line", letter);
        slot = v;
      }
      i = j;
    }
    return Status::success();
  }

  Status dwell(const Words& w, std::vector<PathSegment>& out) {
    if (!w.value['P' - 'A']) return fail("G4", "a dwell needs P (seconds)");
    if (any_of(w, "XYZABCIJK")) return fail("G4", "a dwell takes no coordinates");
    const double p = *w.value['P' - 'A'];
    if (p < 0.0) return fail("P", "the dwell must be >= 0 s (got %g)", p);
    PathSegment s;
    s.kind = PathSegment::Kind::kDwell;
    s.dwell = p;
    s.target = pose_;
    s.line = line_;
    return push(s, out);
  }

  Status move(int motion, const Words& w, std::vector<PathSegment>& out) {
    const Eigen::Vector3d start = pose_.position;
    static constexpr char kAxes[6] = {'X', 'Y', 'Z', 'A', 'B', 'C'};
    for (int k = 0; k < 6; ++k) {
      const auto& v = w.value[static_cast<std::size_t>(kAxes[k] - 'A')];
      if (!v) continue;
      if (k < 3) {
        pose_.position(k) = *v;
      } else {
        pose_.rpy(k - 3) = *v;
      }
    }
    PathSegment s;
    s.target = pose_;
    s.line = line_;
    s.feed = motion == 0 ? std::numeric_limits<double>::quiet_NaN() : feed_;
    if (motion == 0 || motion == 1) {
      s.kind = PathSegment::Kind::kLine;
    } else if (motion == 5) {
      s.kind = PathSegment::Kind::kSpline;
    } else {
      if (!any_of(w, "IJK")) return fail("G" + std::to_string(motion), "an arc needs I J K");
      s.kind = PathSegment::Kind::kArc;
      const Eigen::Vector3d offset(w.value['I' - 'A'].value_or(0.0),
                                   w.value['J' - 'A'].value_or(0.0),
                                   w.value['K' - 'A'].value_or(0.0));
      s.center = start + offset;
      const Eigen::Vector3d normal = plane_ == 17   ? Eigen::Vector3d::UnitZ()
                                     : plane_ == 18 ? Eigen::Vector3d::UnitY()
                                                    : Eigen::Vector3d::UnitX();
      s.axis = motion == 3 ? normal : Eigen::Vector3d(-normal);
    }
    return push(s, out);
  }

  Status push(const PathSegment& s, std::vector<PathSegment>& out) {
    if (out.size() >= kMaxPathSegments) {
      return fail("G", "more than %zu instructions", kMaxPathSegments);
    }
    out.push_back(s);
    return Status::success();
  }

  std::string_view name_;
  Pose pose_;
  int line_ = 0;
  int plane_ = 17;
  std::optional<int> mode_;
  double feed_ = std::numeric_limits<double>::quiet_NaN();
};

}  // namespace

Result<std::vector<PathSegment>> parse_path_program(std::string_view text, std::string_view name,
                                                    const Pose& start) {
  if (text.size() > kMaxPathFileBytes) {
    return Status::error(ErrorCode::kParseError, "%.*s: larger than %zu bytes",
                         static_cast<int>(name.size()), name.data(), kMaxPathFileBytes);
  }
  if (!start.position.allFinite() || !start.rpy.allFinite()) {
    return Status(ErrorCode::kInvalidArgument, "path program: the start pose is not finite");
  }
  Parser parser(name, start);
  std::vector<PathSegment> out;
  int line = 0;
  std::size_t pos = 0;
  while (pos < text.size()) {
    ++line;
    std::size_t end = text.find('\n', pos);
    if (end == std::string_view::npos) end = text.size();
    const std::string_view l = text.substr(pos, end - pos);
    pos = end + 1;
    if (l.size() > kMaxPathLineBytes) {
      return Status::error(ErrorCode::kParseError, "%.*s:%d: the line is longer than %zu bytes",
                           static_cast<int>(name.size()), name.data(), line, kMaxPathLineBytes);
    }
    if (Status s = parser.parse_line(l, line, out); !s.ok()) return s;
  }
  return out;
}

}  // namespace cdpr
