#include "svg.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <sstream>

#include "cdpr/report/format.hpp"

namespace cdpr::report::svg {
namespace {

struct Range {
  double lo = 0.0, hi = 1.0;
};

Range range_of(const std::vector<const std::vector<double>*>& values) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto* v : values) {
    for (double x : *v) {
      if (!std::isfinite(x)) continue;
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
  }
  if (!(lo <= hi)) return {0.0, 1.0};
  if (hi - lo < 1e-12 * std::max(1.0, std::abs(hi))) {
    const double pad = hi == 0.0 ? 0.5 : std::abs(hi) * 0.05;
    return {lo - pad, hi + pad};
  }
  const double pad = 0.04 * (hi - lo);
  return {lo - pad, hi + pad};
}

// Tick positions at 1, 2 or 5 times a power of ten, about five of them.
std::vector<double> ticks(const Range& r) {
  const double span = r.hi - r.lo;
  const double raw = span / 5.0;
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  double step = p;
  for (double f : {1.0, 2.0, 5.0, 10.0}) {
    step = f * p;
    if (span / step <= 6.0) break;
  }
  std::vector<double> t;
  for (double v = std::ceil(r.lo / step) * step; v <= r.hi + 1e-9 * step; v += step) {
    t.push_back(std::abs(v) < 1e-12 * step ? 0.0 : v);
  }
  return t;
}

struct Frame {
  double left = 64, right = 16, top = 46, bottom = 48;
  double width = 640, height = 340;
  Range x, y;
  double px(double v) const { return left + (v - x.lo) / (x.hi - x.lo) * (width - left - right); }
  double py(double v) const { return top + (y.hi - v) / (y.hi - y.lo) * (height - top - bottom); }
};

std::string coord(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.1f", v);
  return buf;
}

// Axes, grid, tick labels, axis titles and the plot title.
std::string axes(const Frame& f, const std::string& title, const std::string& xlabel,
                 const std::string& ylabel, bool x_ticks = true) {
  std::ostringstream s;
  // About 80 characters fit beside nothing else at this width; longer titles are shortened.
  const std::string shown_title = title.size() > 84 ? title.substr(0, 81) + "..." : title;
  s << "<text x=\"" << coord(f.left) << "\" y=\"18\" class=\"t\">" << html_escape(shown_title)
    << "</text>\n";
  for (double t : ticks(f.y)) {
    s << "<line x1=\"" << coord(f.left) << "\" x2=\"" << coord(f.width - f.right) << "\" y1=\""
      << coord(f.py(t)) << "\" y2=\"" << coord(f.py(t)) << "\" class=\"g\"/>"
      << "<text x=\"" << coord(f.left - 6) << "\" y=\"" << coord(f.py(t) + 4)
      << "\" text-anchor=\"end\">" << html_escape(fmt(t, 4)) << "</text>\n";
  }
  if (x_ticks) {
    for (double t : ticks(f.x)) {
      s << "<line x1=\"" << coord(f.px(t)) << "\" x2=\"" << coord(f.px(t)) << "\" y1=\""
        << coord(f.top) << "\" y2=\"" << coord(f.height - f.bottom) << "\" class=\"g\"/>"
        << "<text x=\"" << coord(f.px(t)) << "\" y=\"" << coord(f.height - f.bottom + 16)
        << "\" text-anchor=\"middle\">" << html_escape(fmt(t, 4)) << "</text>\n";
    }
  }
  s << "<rect x=\"" << coord(f.left) << "\" y=\"" << coord(f.top) << "\" width=\""
    << coord(f.width - f.left - f.right) << "\" height=\"" << coord(f.height - f.top - f.bottom)
    << "\" class=\"a\"/>\n";
  s << "<text x=\"" << coord((f.left + f.width - f.right) / 2) << "\" y=\"" << coord(f.height - 10)
    << "\" text-anchor=\"middle\">" << html_escape(xlabel) << "</text>\n";
  const double cy = (f.top + f.height - f.bottom) / 2;
  s << "<text x=\"14\" y=\"" << coord(cy) << "\" text-anchor=\"middle\" transform=\"rotate(-90 14 "
    << coord(cy) << ")\">" << html_escape(ylabel) << "</text>\n";
  return s.str();
}

std::string horizontal_line(const Frame& f, double y, const std::string& cls) {
  if (!(y >= f.y.lo && y <= f.y.hi)) return "";
  return "<line x1=\"" + coord(f.left) + "\" x2=\"" + coord(f.width - f.right) + "\" y1=\"" +
         coord(f.py(y)) + "\" y2=\"" + coord(f.py(y)) + "\" class=\"" + cls + "\"/>\n";
}

std::string legend(const Frame& f, const std::vector<std::pair<std::string, std::string>>& items) {
  std::ostringstream s;
  double x = f.width - f.right - 8;
  for (auto it = items.rbegin(); it != items.rend(); ++it) {
    const double w = 14.0 + 7.0 * static_cast<double>(it->first.size());
    x -= w;
    s << "<rect x=\"" << coord(x) << "\" y=\"26\" width=\"10\" height=\"10\" class=\"" << it->second
      << "\"/><text x=\"" << coord(x + 13) << "\" y=\"35\">" << html_escape(it->first)
      << "</text>\n";
  }
  return s.str();
}

// Each plot carries its style, so that it also reads correctly when saved on its own.
constexpr const char* kSvgStyle =
    "<style>text{font-family:sans-serif;font-size:11px;fill:#222}.t{font-size:13px;"
    "font-weight:bold}.g{stroke:#eee}.a{fill:none;stroke:#888}.z{stroke:#444}"
    ".d{stroke:#999;stroke-dasharray:4 3}.b{fill:#1f77b4;fill-opacity:.45;stroke:#1f77b4}"
    ".f{fill:#d62728;fill-opacity:.75;stroke:none}.o{fill:#fff;stroke:#222;stroke-width:1.5}"
    ".p{fill:#555;fill-opacity:.7}.e{fill:#ff7f0e;fill-opacity:.25;stroke:#ff7f0e}"
    ".w{stroke:#d62728;stroke-width:1.8}.bx{fill:none;stroke:#2ca02c;stroke-dasharray:6 3}"
    ".fr{fill:none;stroke:#bbb}.na{fill:#ddd}</style>\n";

// The root element: the plot's title as its accessible name, and its description as <desc>.
std::string svg_open(const Frame& f, const std::string& label, const std::string& description) {
  return "<svg xmlns=\"http://www.w3.org/2000/svg\" class=\"plot\" width=\"" + coord(f.width) +
         "\" height=\"" + coord(f.height) + "\" viewBox=\"0 0 " + coord(f.width) + " " +
         coord(f.height) + "\" role=\"img\" aria-label=\"" + html_escape(label) + "\">\n<title>" +
         html_escape(label) + "</title>\n<desc>" + html_escape(description) + "</desc>\n" +
         kSvgStyle + "<rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>\n";
}

// "before: 120 points, RMS 2.3; after: 120 points, RMS 0.98."
std::string series_description(const std::vector<double>& before,
                               const std::vector<double>& after) {
  int n = 0;
  std::string d = "before: ";
  const double rb = rms_finite(before, &n);
  d += std::to_string(n) + " points, RMS " + fmt(rb, 3);
  if (!after.empty()) {
    const double ra = rms_finite(after, &n);
    d += "; after: " + std::to_string(n) + " points, RMS " + fmt(ra, 3);
  }
  return d + ".";
}

}  // namespace

double rms_finite(const std::vector<double>& v, int* count) {
  double s = 0.0;
  int n = 0;
  for (double x : v) {
    if (!std::isfinite(x)) continue;
    s += x * x;
    ++n;
  }
  if (count != nullptr) *count = n;
  return n == 0 ? std::numeric_limits<double>::quiet_NaN() : std::sqrt(s / n);
}

std::string scatter(const Scatter& p) {
  Frame f;
  f.x = range_of({&p.x});
  f.y = range_of({&p.before, &p.after});
  f.y.lo = std::min(f.y.lo, p.y_floor);
  f.y.hi = std::max(f.y.hi, p.y_ceiling);
  std::ostringstream s;
  s << svg_open(f, p.title,
                p.description.empty() ? series_description(p.before, p.after) : p.description);
  s << axes(f, p.title, p.xlabel, p.ylabel);
  s << horizontal_line(f, 0.0, "z") << horizontal_line(f, 2.0, "d")
    << horizontal_line(f, -2.0, "d");
  auto points = [&](const std::vector<double>& y, const std::string& cls, double r) {
    for (std::size_t k = 0; k < p.x.size() && k < y.size(); ++k) {
      if (!std::isfinite(p.x[k]) || !std::isfinite(y[k])) continue;
      s << "<circle cx=\"" << coord(f.px(p.x[k])) << "\" cy=\"" << coord(f.py(y[k])) << "\" r=\""
        << r << "\" class=\"" << cls << "\"><title>cable "
        << (k < p.cable.size() ? p.cable[k] + 1 : 0) << ": " << html_escape(fmt(y[k], 3))
        << "</title></circle>\n";
    }
  };
  points(p.before, "b", 3.0);
  points(p.after, "f", 2.2);
  std::vector<std::pair<std::string, std::string>> items = {{"before", "b"}};
  if (!p.after.empty()) items.push_back({"after", "f"});
  s << legend(f, items) << "</svg>\n";
  return s.str();
}

std::string bars(const Bars& m) {
  Frame f;
  f.x = {0.0, static_cast<double>(m.before.size())};
  std::vector<double> tops = m.before;
  for (std::size_t i = 0; i < m.whiskers.size() && i < tops.size(); ++i) {
    if (std::isfinite(m.whiskers[i])) tops[i] += m.whiskers[i];
  }
  f.y = range_of({&tops, &m.after});
  f.y.lo = 0.0;
  f.y.hi = std::max(f.y.hi, m.y_ceiling);
  std::ostringstream s;
  std::string description = m.description;
  if (description.empty()) {
    for (std::size_t i = 0; i < m.before.size(); ++i) {
      description += (i == 0 ? "" : "; ") + m.xlabel + " " + std::to_string(i + 1) + ": " +
                     m.before_label + " " + fmt(m.before[i], 3);
      if (i < m.after.size()) description += ", " + m.after_label + " " + fmt(m.after[i], 3);
    }
  }
  s << svg_open(f, m.title, description) << axes(f, m.title, m.xlabel, m.ylabel, false);
  s << horizontal_line(f, m.reference, "d");
  const double slot = (f.width - f.left - f.right) / std::max<double>(1.0, f.x.hi);
  const bool two = !m.after.empty();
  const double w = slot * (two ? 0.36 : 0.6);
  for (std::size_t i = 0; i < m.before.size(); ++i) {
    const double x0 = f.left + slot * static_cast<double>(i) + slot * (two ? 0.12 : 0.2);
    auto bar = [&](double x, double v, const std::string& cls, const std::string& what) {
      if (!std::isfinite(v)) return;
      s << "<rect x=\"" << coord(x) << "\" y=\"" << coord(f.py(v)) << "\" width=\"" << coord(w)
        << "\" height=\"" << coord(f.py(0.0) - f.py(v)) << "\" class=\"" << cls
        << "\"><title>cable " << i + 1 << " " << what << ": " << html_escape(fmt(v, 3))
        << "</title></rect>\n";
    };
    bar(x0, m.before[i], "b", m.before_label);
    if (i < m.whiskers.size() && std::isfinite(m.whiskers[i]) && std::isfinite(m.before[i])) {
      const double cx = x0 + w / 2;
      const double lo = std::max(0.0, m.before[i] - m.whiskers[i]);
      const double hi = m.before[i] + m.whiskers[i];
      s << "<line x1=\"" << coord(cx) << "\" x2=\"" << coord(cx) << "\" y1=\"" << coord(f.py(lo))
        << "\" y2=\"" << coord(f.py(hi)) << "\" class=\"z\"><title>cable " << i + 1 << ": +-"
        << html_escape(fmt(m.whiskers[i], 3)) << "</title></line>\n";
    }
    if (two && i < m.after.size()) bar(x0 + w, m.after[i], "f", m.after_label);
    s << "<text x=\"" << coord(f.left + slot * (static_cast<double>(i) + 0.5)) << "\" y=\""
      << coord(f.height - f.bottom + 16) << "\" text-anchor=\"middle\">" << i + 1 << "</text>\n";
  }
  std::vector<std::pair<std::string, std::string>> items = {{m.before_label, "b"}};
  if (two) items.push_back({m.after_label, "f"});
  s << legend(f, items) << "</svg>\n";
  return s.str();
}

namespace {

// White to blue (negative) or red (positive) by |t| <= 1.
std::string diverging(double t) {
  t = std::clamp(t, -1.0, 1.0);
  const double a = std::abs(t);
  const double r0 = t < 0 ? 33 : 178, g0 = t < 0 ? 102 : 24, b0 = t < 0 ? 172 : 43;
  auto mix = [a](double c) { return static_cast<int>(std::lround(255.0 * (1.0 - a) + c * a)); };
  return "rgb(" + std::to_string(mix(r0)) + "," + std::to_string(mix(g0)) + "," +
         std::to_string(mix(b0)) + ")";
}

}  // namespace

std::string heatmap(const Heatmap& h) {
  const std::size_t rows = h.values.size();
  std::size_t cols = 0;
  for (const auto& r : h.values) cols = std::max(cols, r.size());
  Frame f;
  f.width = h.width;
  f.left = 70;
  f.right = 16;
  f.top = 46;
  f.bottom = 44;
  const double row_height = rows > 12 ? 14.0 : 22.0;
  f.height = h.height > 0 ? h.height : f.top + f.bottom + row_height * static_cast<double>(rows);
  const double cw = (f.width - f.left - f.right) / std::max<double>(1.0, static_cast<double>(cols));
  const double ch =
      (f.height - f.top - f.bottom) / std::max<double>(1.0, static_cast<double>(rows));
  // The text alternative: the largest |value| and where, and how many cells exceed 2.
  double worst = 0.0;
  std::size_t wr = 0, wc = 0;
  int above = 0, cells = 0;
  for (std::size_t r = 0; r < rows; ++r) {
    for (std::size_t c = 0; c < h.values[r].size(); ++c) {
      const double v = h.values[r][c];
      if (!std::isfinite(v)) continue;
      ++cells;
      if (std::abs(v) > 2.0) ++above;
      if (std::abs(v) > worst) {
        worst = std::abs(v);
        wr = r;
        wc = c;
      }
    }
  }
  std::string description = h.description;
  if (description.empty() && cells > 0) {
    description = std::to_string(rows) + " rows by " + std::to_string(cols) + " columns; " +
                  std::to_string(above) + " of " + std::to_string(cells) +
                  " cells beyond 2 in magnitude; the largest, " + fmt(h.values[wr][wc], 3) +
                  ", at " + (wr < h.row_labels.size() ? h.row_labels[wr] : "") + ", " + h.xlabel +
                  " " + (wc < h.column_labels.size() ? std::to_string(h.column_labels[wc]) : "") +
                  ".";
  }
  std::ostringstream s;
  s << svg_open(f, h.title, description);
  const std::string shown_title = h.title.size() > 100 ? h.title.substr(0, 97) + "..." : h.title;
  s << "<text x=\"" << coord(f.left) << "\" y=\"18\" class=\"t\">" << html_escape(shown_title)
    << "</text>\n";
  for (std::size_t r = 0; r < rows; ++r) {
    const double y = f.top + ch * static_cast<double>(r);
    s << "<text x=\"" << coord(f.left - 6) << "\" y=\"" << coord(y + ch / 2 + 4)
      << "\" text-anchor=\"end\">" << html_escape(r < h.row_labels.size() ? h.row_labels[r] : "")
      << "</text>\n";
    for (std::size_t c = 0; c < h.values[r].size(); ++c) {
      const double v = h.values[r][c];
      const std::string where =
          (r < h.row_labels.size() ? h.row_labels[r] : "") + ", " + h.xlabel + " " +
          (c < h.column_labels.size() ? std::to_string(h.column_labels[c]) : std::to_string(c));
      s << "<rect x=\"" << coord(f.left + cw * static_cast<double>(c)) << "\" y=\"" << coord(y)
        << "\" width=\"" << coord(cw + 0.3) << "\" height=\"" << coord(ch + 0.3) << "\"";
      if (std::isfinite(v)) {
        s << " fill=\"" << diverging(v / h.limit) << "\"><title>" << html_escape(where) << ": "
          << html_escape(fmt(v, 3)) << "</title></rect>\n";
      } else {
        s << " class=\"na\"><title>" << html_escape(where) << ": none</title></rect>\n";
      }
    }
  }
  s << "<rect x=\"" << coord(f.left) << "\" y=\"" << coord(f.top) << "\" width=\""
    << coord(f.width - f.left - f.right) << "\" height=\"" << coord(f.height - f.top - f.bottom)
    << "\" class=\"a\"/>\n";
  const std::size_t every = std::max<std::size_t>(1, (cols + 19) / 20);
  for (std::size_t c = 0; c < cols; c += every) {
    s << "<text x=\"" << coord(f.left + cw * (static_cast<double>(c) + 0.5)) << "\" y=\""
      << coord(f.height - f.bottom + 14) << "\" text-anchor=\"middle\">"
      << (c < h.column_labels.size() ? h.column_labels[c] : static_cast<int>(c)) << "</text>\n";
  }
  s << "<text x=\"" << coord((f.left + f.width - f.right) / 2) << "\" y=\"" << coord(f.height - 8)
    << "\" text-anchor=\"middle\">" << html_escape(h.xlabel) << "</text>\n";
  s << "<text x=\"14\" y=\"" << coord(f.top - 6) << "\">" << html_escape(h.ylabel) << "</text>\n";
  // Colour key: -limit .. +limit in nine steps.
  const double kx = f.width - f.right - 9 * 14 - 150;
  for (int k = 0; k < 9; ++k) {
    const double t = -1.0 + 0.25 * k;
    s << "<rect x=\"" << coord(kx + 14 * k) << "\" y=\"26\" width=\"14\" height=\"10\" fill=\""
      << diverging(t) << "\"/>";
  }
  s << "<text x=\"" << coord(kx - 4) << "\" y=\"35\" text-anchor=\"end\">"
    << html_escape(fmt(-h.limit, 3)) << "</text><text x=\"" << coord(kx + 9 * 14 + 4)
    << "\" y=\"35\">" << html_escape("+" + fmt(h.limit, 3) + " " + h.value_name)
    << "</text>\n</svg>\n";
  return s.str();
}

std::string plan_view(const PlanView& v) {
  Frame f;
  f.width = v.width;
  f.height = v.height;
  f.left = 56;
  f.top = 46;
  f.bottom = 44;
  std::vector<double> xs, ys;
  for (const auto& p : v.points) {
    xs.push_back(p.x);
    ys.push_back(p.y);
  }
  for (const auto& a : v.arrows) {
    xs.insert(xs.end(), {a.x0, a.x1});
    ys.insert(ys.end(), {a.y0, a.y1});
  }
  for (const auto& e : v.ellipses) {
    const double rx = std::sqrt(std::max(0.0, e.sxx)), ry = std::sqrt(std::max(0.0, e.syy));
    xs.insert(xs.end(), {e.x - rx, e.x + rx});
    ys.insert(ys.end(), {e.y - ry, e.y + ry});
  }
  for (const auto& b : v.boxes) {
    xs.insert(xs.end(), {b.x0, b.x1});
    ys.insert(ys.end(), {b.y0, b.y1});
  }
  f.x = range_of({&xs});
  f.y = range_of({&ys});
  // Pad, then widen the narrower range so that one metre is as long on both axes.
  const double pad = 0.06 * std::max(f.x.hi - f.x.lo, f.y.hi - f.y.lo);
  f.x = {f.x.lo - pad, f.x.hi + pad};
  f.y = {f.y.lo - pad, f.y.hi + pad};
  const double w = f.width - f.left - f.right, h = f.height - f.top - f.bottom;
  const double scale = std::min(w / (f.x.hi - f.x.lo), h / (f.y.hi - f.y.lo));  // px per unit
  const double cx = (f.x.lo + f.x.hi) / 2, cy = (f.y.lo + f.y.hi) / 2;
  f.x = {cx - w / scale / 2, cx + w / scale / 2};
  f.y = {cy - h / scale / 2, cy + h / scale / 2};
  std::string description = v.description;
  if (description.empty()) {
    description = std::to_string(v.points.size()) + " points, " + std::to_string(v.arrows.size()) +
                  " arrows, " + std::to_string(v.ellipses.size()) + " ellipses.";
  }
  std::ostringstream s;
  s << svg_open(f, v.title, description) << axes(f, v.title, v.xlabel, v.ylabel);
  for (const auto& b : v.boxes) {
    const double x0 = f.px(std::min(b.x0, b.x1)), x1 = f.px(std::max(b.x0, b.x1));
    const double y0 = f.py(std::max(b.y0, b.y1)), y1 = f.py(std::min(b.y0, b.y1));
    s << "<rect x=\"" << coord(x0) << "\" y=\"" << coord(y0) << "\" width=\"" << coord(x1 - x0)
      << "\" height=\"" << coord(y1 - y0) << "\" class=\"bx\"><title>" << html_escape(b.label)
      << "</title></rect>\n";
  }
  for (const auto& e : v.ellipses) {
    // Principal axes of the 2 x 2 covariance; the drawing's y axis points down.
    const double mean = (e.sxx + e.syy) / 2;
    const double d =
        std::sqrt(std::max(0.0, (e.sxx - e.syy) * (e.sxx - e.syy) / 4 + e.sxy * e.sxy));
    const double l1 = std::max(0.0, mean + d), l2 = std::max(0.0, mean - d);
    const double angle = 0.5 * std::atan2(2 * e.sxy, e.sxx - e.syy) * 180.0 / std::numbers::pi;
    const double rx = std::max(0.8, std::sqrt(l1) * scale),
                 ry = std::max(0.8, std::sqrt(l2) * scale);
    s << "<ellipse cx=\"" << coord(f.px(e.x)) << "\" cy=\"" << coord(f.py(e.y)) << "\" rx=\""
      << coord(rx) << "\" ry=\"" << coord(ry) << "\" transform=\"rotate(" << coord(-angle) << " "
      << coord(f.px(e.x)) << " " << coord(f.py(e.y)) << ")\" class=\"e\"><title>"
      << html_escape(e.label) << "</title></ellipse>\n";
  }
  for (const auto& a : v.arrows) {
    const double x0 = f.px(a.x0), y0 = f.py(a.y0), x1 = f.px(a.x1), y1 = f.py(a.y1);
    const double len = std::hypot(x1 - x0, y1 - y0);
    s << "<g><title>" << html_escape(a.label) << "</title><line x1=\"" << coord(x0) << "\" y1=\""
      << coord(y0) << "\" x2=\"" << coord(x1) << "\" y2=\"" << coord(y1) << "\" class=\"w\"/>";
    if (len > 3.0) {
      const double ux = (x1 - x0) / len, uy = (y1 - y0) / len, hl = std::min(8.0, len / 2);
      s << "<polygon points=\"" << coord(x1) << "," << coord(y1) << " "
        << coord(x1 - hl * ux - hl * 0.45 * uy) << "," << coord(y1 - hl * uy + hl * 0.45 * ux)
        << " " << coord(x1 - hl * ux + hl * 0.45 * uy) << ","
        << coord(y1 - hl * uy - hl * 0.45 * ux) << "\" fill=\"#d62728\"/>";
    }
    s << "</g>\n";
  }
  for (const auto& p : v.points) {
    const double x = f.px(p.x), y = f.py(p.y);
    if (p.cls == "o") {
      s << "<rect x=\"" << coord(x - 4) << "\" y=\"" << coord(y - 4)
        << "\" width=\"8\" height=\"8\" class=\"o\"><title>" << html_escape(p.label)
        << "</title></rect>\n";
    } else {
      s << "<circle cx=\"" << coord(x) << "\" cy=\"" << coord(y) << "\" r=\""
        << (p.cls == "p" ? "3" : "3.5") << "\" class=\"" << html_escape(p.cls) << "\"><title>"
        << html_escape(p.label) << "</title></circle>\n";
    }
  }
  s << legend(f, v.legend) << "</svg>\n";
  return s.str();
}

}  // namespace cdpr::report::svg

namespace cdpr::report {

std::string html_escape(const std::string& text) {
  const std::string s = valid_utf8(text);
  std::string o;
  o.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&':
        o += "&amp;";
        break;
      case '<':
        o += "&lt;";
        break;
      case '>':
        o += "&gt;";
        break;
      case '"':
        o += "&quot;";
        break;
      case '\'':
        o += "&#39;";
        break;
      default:
        o += c;
    }
  }
  return o;
}

}  // namespace cdpr::report
