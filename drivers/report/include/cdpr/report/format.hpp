// Small formatting helpers shared by the reports and cdpr-fit's other documents.
#pragma once

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

namespace cdpr::report {

// A JSON number, or null for NaN and infinity.
nlohmann::json number_or_null(double v);
// JSON arrays of Eigen vectors and matrices (NaN and infinity become null).
nlohmann::json to_json(const Eigen::VectorXd& v);
nlohmann::json to_json(const Eigen::Matrix3Xd& m);  // list of columns
// A number for people: "%.*g".
std::string fmt(double v, int digits = 6);
// Text for HTML element content and attribute values (& < > " '); invalid UTF-8 replaced as
// valid_utf8 does.
std::string html_escape(const std::string& s);

// `s` with every byte that is not part of a valid UTF-8 sequence (a stray 0xFF, a truncated or
// overlong sequence, a surrogate) replaced by U+FFFD; valid text is returned unchanged. Paths,
// robot names and cells of input files may hold any byte; JSON and HTML may not.
std::string valid_utf8(std::string_view s);
// A JSON document as text (`indent` as nlohmann::json::dump) with every string made valid UTF-8
// (valid_utf8): never throws on bytes from the inputs. Every JSON cdpr-fit prints or writes goes
// through here.
std::string json_text(const nlohmann::json& j, int indent = 2);

}  // namespace cdpr::report
