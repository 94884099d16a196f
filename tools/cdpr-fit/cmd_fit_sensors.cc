// cdpr-fit fit-cable and fit-force-sensor: the pre-calibration helpers.
#include <cmath>
#include <map>
#include <sstream>

#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/force_sensor.hpp"
#include "cdpr/recording/recording.hpp"
#include "commands.hpp"
#include "common.hpp"

namespace cdpr::fit {

namespace {

// The YAML the config loader reads for a polynomial elongation (docs/config.md), all digits.
std::string polynomial_yaml(const PolynomialSurface& p) {
  using recording::format_number;
  std::string s =
      "elongation: {model: polynomial, order: " + std::to_string(p.order) + ", coefficients: [";
  for (std::size_t k = 0; k < p.coefficients.size(); ++k) {
    if (k > 0) s += ", ";
    s += format_number(p.coefficients[k]);
  }
  s += "], length_center: " + format_number(p.length_center) +
       ", length_scale: " + format_number(p.length_scale) +
       ", tension_center: " + format_number(p.tension_center) +
       ", tension_scale: " + format_number(p.tension_scale) + "}";
  return s;
}

}  // namespace

Result<Output> fit_cable(const FitCableArgs& args) {
  auto e = recording::read_cable_experiment(args.experiment);
  if (!e.ok()) return e.status();
  std::vector<ElongationSample> samples;
  samples.reserve(e->samples.size());
  for (const auto& s : e->samples) samples.push_back({s.length_m, s.tension_n, s.elongation_m});
  PolynomialFitOptions options;
  options.min_order = args.min_order;
  options.max_order = args.max_order;
  options.folds = args.folds;
  options.seed = args.seed;
  options.selection = args.minimum_error ? PolynomialFitOptions::Selection::kMinimumError
                                         : PolynomialFitOptions::Selection::kOneStandardError;
  auto fit = fit_polynomial_surface(samples, options);
  if (!fit.ok()) return with_context(fit.status(), args.experiment);
  const PolynomialFitSummary& f = *fit;

  Output out;
  nlohmann::json table = nlohmann::json::array();
  for (std::size_t k = 0; k < f.orders.size(); ++k) {
    table.push_back({{"order", f.orders[k]},
                     {"cv_rmse_m", number_or_null(f.cv_rmse[k])},
                     {"cv_rmse_stderr_m", number_or_null(f.cv_rmse_stderr[k])},
                     {"chosen", f.orders[k] == f.order}});
  }
  out.json = {{"command", "fit-cable"},
              {"experiment", args.experiment},
              {"samples", f.num_samples},
              {"folds", args.folds},
              {"selection", args.minimum_error ? "minimum-error" : "one-standard-error"},
              {"cross_validation", table},
              {"order", f.order},
              {"training_rmse_m", f.training_rmse},
              {"condition_number", number_or_null(f.condition_number)},
              {"surface",
               {{"order", f.surface.order},
                {"coefficients", f.surface.coefficients},
                {"length_center", f.surface.length_center},
                {"length_scale", f.surface.length_scale},
                {"tension_center", f.surface.tension_center},
                {"tension_scale", f.surface.tension_scale}}},
              {"yaml", polynomial_yaml(f.surface)}};

  std::ostringstream h;
  h << "cable elongation surface dL = f(L, F) from " << f.num_samples << " samples of "
    << args.experiment << "\n"
    << args.folds << "-fold cross-validation (seed " << args.seed << "), "
    << (args.minimum_error ? "minimum CV error" : "one-standard-error rule") << ":\n"
    << "  order   CV RMSE (m)    std err (m)\n";
  for (std::size_t k = 0; k < f.orders.size(); ++k) {
    char line[128];
    if (std::isfinite(f.cv_rmse[k])) {
      std::snprintf(line, sizeof line, "  %5d   %11.4e    %11.4e%s\n", f.orders[k], f.cv_rmse[k],
                    f.cv_rmse_stderr[k], f.orders[k] == f.order ? "   <- chosen" : "");
    } else {
      std::snprintf(line, sizeof line, "  %5d   not identifiable from these samples\n",
                    f.orders[k]);
    }
    h << line;
  }
  h << "chosen order " << f.order << ": training RMSE " << fmt(f.training_rmse, 4)
    << " m, condition number " << fmt(f.condition_number, 3) << "\n"
    << "config snippet (under `defaults:` for every cable, or under one cable):\n  "
    << polynomial_yaml(f.surface) << "\n";
  out.human = h.str();
  return out;
}

Result<Output> fit_force_sensor(const FitForceArgs& args) {
  auto e = recording::read_force_experiment(args.experiment);
  if (!e.ok()) return e.status();
  double g = 9.81;
  if (std::isfinite(args.gravity)) {
    g = args.gravity;
  } else if (e->metadata.has("gravity_m_s2")) {
    auto v = e->metadata.number("gravity_m_s2");
    if (!v.ok()) return with_context(v.status(), args.experiment);
    g = *v;
  }
  // A gravity far from any planet's makes every mass read as the same 0 kg: refuse it here.
  constexpr double kMaxGravity = 100.0;  // m/s^2
  if (!(g > 0.0 && g <= kMaxGravity)) {
    return Status::error(
        ErrorCode::kInvalidArgument,
        "%s: gravity %.6g m/s^2 (%s) is outside the plausible range (0, %.6g] m/s^2",
        args.experiment.c_str(), g, std::isfinite(args.gravity) ? "--gravity" : "gravity_m_s2",
        kMaxGravity);
  }
  std::map<int, std::vector<ForceCalibrationSample>> channels;
  for (const auto& s : e->samples) channels[s.channel].push_back({s.mass_kg, s.raw});

  Output out;
  nlohmann::json fits = nlohmann::json::array();
  std::ostringstream h, yaml;
  h << "force sensors raw = gain * m * g + offset (g = " << g << " m/s^2) from " << args.experiment
    << "\n"
    << "  channel   n        gain (raw/N)   std err       offset (raw)   std err      rms (raw)\n";
  for (const auto& [channel, samples] : channels) {
    auto fit = cdpr::fit_force_sensor(samples, g);
    if (!fit.ok()) {
      return with_context(fit.status(), args.experiment + ": channel " + std::to_string(channel));
    }
    fits.push_back({{"channel", channel},
                    {"samples", fit->num_samples},
                    {"gain", fit->sensor.gain},
                    {"gain_stderr", fit->gain_stderr},
                    {"offset", fit->sensor.offset},
                    {"offset_stderr", fit->offset_stderr},
                    {"residual_rms", fit->residual_rms},
                    {"max_abs_residual", fit->max_abs_residual}});
    char line[200];
    std::snprintf(line, sizeof line, "  %7d %3d   %13.6g  %11.3g   %13.6g  %11.3g  %11.3g\n",
                  channel, fit->num_samples, fit->sensor.gain, fit->gain_stderr, fit->sensor.offset,
                  fit->offset_stderr, fit->residual_rms);
    h << line;
    yaml << "  # cable " << channel
         << "\n  force_sensor: {gain: " << recording::format_number(fit->sensor.gain)
         << ", offset: " << recording::format_number(fit->sensor.offset) << "}\n";
  }
  h << "config snippet (into each cable's entry):\n" << yaml.str();
  out.json = {{"command", "fit-force-sensor"},
              {"experiment", args.experiment},
              {"gravity_m_s2", g},
              {"channels", fits}};
  out.human = h.str();
  return out;
}

}  // namespace cdpr::fit
