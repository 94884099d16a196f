// The SVG plotting primitives of the reports (internal to cdpr_report): axes with ticks and
// titles, reference lines, legends, scatter plots of before/after series, grouped bars with
// optional whiskers, heat maps (rows x columns of a signed value) and plan views (top or side view
// with equal scales: points, arrows, uncertainty ellipses, boxes). Each plot is a self-contained
// <svg> element with its own style, a <title> and a <desc> (its text alternative; the page adds a
// table of the same numbers).
#pragma once

#include <string>
#include <utility>
#include <vector>

namespace cdpr::report::svg {

// The RMS of the finite values of `v` (NaN when none is); `count`, when given, receives how many.
double rms_finite(const std::vector<double>& v, int* count = nullptr);

// A scatter plot of one or two series over the same x (e.g. residuals before and after).
struct Scatter {
  std::string title, xlabel, ylabel;
  std::string description;  // the text alternative; empty: counts and RMS of the series
  std::vector<double> x;
  std::vector<int> cable;                  // 0-based, named in each point's tooltip
  std::vector<double> before, after;       // `after` may be empty
  double y_floor = -3.0, y_ceiling = 3.0;  // the y axis spans at least this
};
std::string scatter(const Scatter& s);

// Bars per cable, one or two series, with optional whiskers (+-) on the first series.
struct Bars {
  std::string title, xlabel, ylabel;
  std::string description;            // the text alternative; empty: the values
  std::vector<double> before, after;  // `after` may be empty
  std::vector<double> whiskers;       // half-lengths on `before`; empty: none
  double y_ceiling = 1.5;             // the y axis spans at least 0..y_ceiling
  double reference = 1.0;             // a dashed line at this value (NaN: none)
  std::string before_label = "before", after_label = "after";
};
std::string bars(const Bars& b);

// A heat map of values[row][column] on a diverging scale clipped at +-limit (NaN: grey cell).
struct Heatmap {
  std::string title, description, xlabel, ylabel;
  std::vector<std::vector<double>> values;  // rows (e.g. cables) of columns (e.g. poses)
  std::vector<std::string> row_labels;      // one per row
  std::vector<int> column_labels;           // one per column (tick every few)
  double limit = 4.0;                       // |value| at full colour
  std::string value_name = "residual / sigma";
  double width = 980, height = 0;  // height 0: from the row count
};
std::string heatmap(const Heatmap& h);

// A plan view (x right, y up) with the same scale on both axes.
struct PlanView {
  struct Point {
    double x = 0, y = 0;
    std::string cls, label;  // cls: "b" (blue), "f" (red), "o" (open square), "p" (grey dot)
  };
  struct Arrow {
    double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
    std::string label;
  };
  struct Ellipse {
    double x = 0, y = 0;
    double sxx = 0, sxy = 0, syy = 0;  // covariance, already in drawing units (scaled)
    std::string label;
  };
  struct Box {
    double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
    std::string label;
  };
  std::string title, description, xlabel, ylabel;
  std::vector<Point> points;
  std::vector<Arrow> arrows;
  std::vector<Ellipse> ellipses;  // drawn as the 1-sigma contour
  std::vector<Box> boxes;
  std::vector<std::pair<std::string, std::string>> legend;  // label, class
  double width = 480, height = 420;
};
std::string plan_view(const PlanView& v);

}  // namespace cdpr::report::svg
