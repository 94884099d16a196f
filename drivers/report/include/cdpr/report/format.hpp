// Small formatting helpers shared by the reports and cdpr-fit's other documents.
#pragma once

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <string>

namespace cdpr::report {

// A JSON number, or null for NaN and infinity.
nlohmann::json number_or_null(double v);
// JSON arrays of Eigen vectors and matrices (NaN and infinity become null).
nlohmann::json to_json(const Eigen::VectorXd& v);
nlohmann::json to_json(const Eigen::Matrix3Xd& m);  // list of columns
// A number for people: "%.*g".
std::string fmt(double v, int digits = 6);
// Text for HTML element content and attribute values (& < > " ').
std::string html_escape(const std::string& s);

}  // namespace cdpr::report
