#include <cmath>
#include <cstdio>

#include "cdpr/report/format.hpp"
#include "report_internal.hpp"
#include "svg.hpp"

namespace cdpr::report {
namespace {

constexpr const char* kStyle = R"(
body{font-family:sans-serif;max-width:1000px;margin:.6em auto;padding:0 1em;color:#222;
line-height:1.35}
h1{font-size:1.3em;margin:.3em 0}h2{font-size:1.15em;margin-top:1.4em;border-bottom:1px solid #ccc}
.verdict{padding:.5em 1em;border-radius:4px;font-weight:bold;margin:.4em 0;
border-left:6px solid #888}
.v-no_mismatch{background:#e3f4e3;border-left-color:#2a7d2a}
.v-mismatch_named{background:#fdf0d7;border-left-color:#c77c00}
.v-mismatch_unexplained{background:#fde2dc;border-left-color:#b3261e}
.v-inconclusive{background:#eee}
.next{margin:.4em 0 .6em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 8px}
th{background:#f4f4f4;text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
caption{text-align:left;font-weight:bold;padding:2px 0}
table.keys th{width:11em}table.keys,table.effects{width:100%}td.vals{font-size:.92em}
tr.acc td{font-weight:bold}tr.flag td{background:#fff4e5}
svg{display:block;margin:.5em 0;max-width:100%;height:auto}
.pair{display:flex;flex-wrap:wrap;gap:16px}.pair svg{margin:.3em 0}
.small{color:#555;font-size:.9em}nav{margin:.5em 0}
details{margin:.4em 0}summary{cursor:pointer;color:#1f4e79}
.scroll{overflow-x:auto;max-width:100%}
@media print{body{max-width:none;margin:0;font-size:10pt}nav,details.data{display:none}
h2{break-after:avoid}svg,table,.verdict{break-inside:avoid}a{color:inherit;text-decoration:none}
.verdict{-webkit-print-color-adjust:exact;print-color-adjust:exact}
@page{margin:12mm}}
)";

}  // namespace

nlohmann::json number_or_null(double v) {
  if (!std::isfinite(v)) return nullptr;
  return v;
}

nlohmann::json to_json(const Eigen::VectorXd& v) {
  nlohmann::json a = nlohmann::json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back(number_or_null(v(i)));
  return a;
}

nlohmann::json to_json(const Eigen::Matrix3Xd& m) {
  nlohmann::json a = nlohmann::json::array();
  for (Eigen::Index c = 0; c < m.cols(); ++c) a.push_back(to_json(Eigen::VectorXd(m.col(c))));
  return a;
}

std::string valid_utf8(std::string_view s) {
  std::string o;
  o.reserve(s.size());
  const auto byte = [&](std::size_t i) { return static_cast<unsigned char>(s[i]); };
  std::size_t i = 0;
  while (i < s.size()) {
    const unsigned char c = byte(i);
    std::size_t len = 0;
    unsigned char lo = 0x80, hi = 0xBF;  // the allowed range of the second byte
    if (c < 0x80) {
      len = 1;
    } else if (c >= 0xC2 && c <= 0xDF) {
      len = 2;
    } else if (c >= 0xE0 && c <= 0xEF) {
      len = 3;
      if (c == 0xE0) lo = 0xA0;  // no overlong forms
      if (c == 0xED) hi = 0x9F;  // no surrogates
    } else if (c >= 0xF0 && c <= 0xF4) {
      len = 4;
      if (c == 0xF0) lo = 0x90;
      if (c == 0xF4) hi = 0x8F;  // not above U+10FFFF
    }
    bool ok = len > 0 && i + len <= s.size();
    for (std::size_t k = 1; ok && k < len; ++k) {
      const unsigned char b = byte(i + k);
      ok = k == 1 ? (b >= lo && b <= hi) : (b >= 0x80 && b <= 0xBF);
    }
    if (ok) {
      o.append(s.substr(i, len));
      i += len;
    } else {
      o += "\xEF\xBF\xBD";  // U+FFFD REPLACEMENT CHARACTER, for this one byte
      ++i;
    }
  }
  return o;
}

std::string json_text(const nlohmann::json& j, int indent) {
  // nlohmann::json replaces invalid UTF-8 in strings and keys by U+FFFD while writing.
  return j.dump(indent, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string fmt(double v, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

std::vector<double> cable_rms(const std::vector<PoseResiduals>& residuals, int num_cables) {
  std::vector<double> out;
  for (int i = 0; i < num_cables; ++i) {
    std::vector<double> v;
    for (const PoseResiduals& r : residuals) {
      if (i < r.length_normalized.size()) v.push_back(r.length_normalized(i));
    }
    out.push_back(svg::rms_finite(v));
  }
  return out;
}

std::string page_head(const std::string& title) {
  return std::string("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n") +
         "<title>" + html_escape(title) + "</title>\n<style>" + kStyle +
         "</style>\n</head>\n<body>\n";
}

std::string td(const std::string& text, bool numeric) {
  return std::string(numeric ? "<td class=\"n\">" : "<td>") + html_escape(text) + "</td>";
}

std::string th(const std::string& text) {
  return "<th>" + html_escape(text) + "</th>";
}

}  // namespace cdpr::report
