#include "svg.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
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
    ".f{fill:#d62728;fill-opacity:.75;stroke:none}</style>\n";

std::string svg_open(const Frame& f, const std::string& label) {
  return "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + coord(f.width) + "\" height=\"" +
         coord(f.height) + "\" viewBox=\"0 0 " + coord(f.width) + " " + coord(f.height) +
         "\" role=\"img\" aria-label=\"" + html_escape(label) + "\">\n" + kSvgStyle +
         "<rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>\n";
}

}  // namespace

std::string scatter(const Scatter& p) {
  Frame f;
  f.x = range_of({&p.x});
  f.y = range_of({&p.before, &p.after});
  f.y.lo = std::min(f.y.lo, p.y_floor);
  f.y.hi = std::max(f.y.hi, p.y_ceiling);
  std::ostringstream s;
  s << svg_open(f, p.title);
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
  s << svg_open(f, m.title) << axes(f, m.title, m.xlabel, m.ylabel, false);
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
