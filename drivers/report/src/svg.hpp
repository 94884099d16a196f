// The SVG plotting primitives of the reports (internal to cdpr_report): axes with ticks and
// titles, reference lines, legends, scatter plots of before/after series and grouped bars with
// optional whiskers. Each plot is a self-contained <svg> element with its own style.
#pragma once

#include <string>
#include <utility>
#include <vector>

namespace cdpr::report::svg {

// A scatter plot of one or two series over the same x (e.g. residuals before and after).
struct Scatter {
  std::string title, xlabel, ylabel;
  std::vector<double> x;
  std::vector<int> cable;                  // 0-based, named in each point's tooltip
  std::vector<double> before, after;       // `after` may be empty
  double y_floor = -3.0, y_ceiling = 3.0;  // the y axis spans at least this
};
std::string scatter(const Scatter& s);

// Bars per cable, one or two series, with optional whiskers (+-) on the first series.
struct Bars {
  std::string title, xlabel, ylabel;
  std::vector<double> before, after;  // `after` may be empty
  std::vector<double> whiskers;       // half-lengths on `before`; empty: none
  double y_ceiling = 1.5;             // the y axis spans at least 0..y_ceiling
  double reference = 1.0;             // a dashed line at this value (NaN: none)
  std::string before_label = "before", after_label = "after";
};
std::string bars(const Bars& b);

}  // namespace cdpr::report::svg
