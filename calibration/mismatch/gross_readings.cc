// Stage 0 of the locator, the gross readings (find_gross_readings, diagnosis.hpp): the standard
// model refitted with a Cauchy loss and the readings it leaves far out, one at a time, and their
// words.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "cdpr/calibration/diagnosis.hpp"
#include "diagnosis_internal.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr {

using diagnosis_detail::identify_from;
using mismatch_detail::format;

namespace {
// Every normalised residual of a fit, with where it comes from (the equilibrium of a pose is one
// reading: its whitened rows mix the cables' tensions).
std::vector<GrossReading> normalised_readings(const IdentificationReport& rep) {
  std::vector<GrossReading> all;
  auto add = [&](int j, const char* channel, int index, double si, double sigmas) {
    if (std::isfinite(sigmas)) all.push_back({j, channel, index, si, std::abs(sigmas)});
  };
  for (int j = 0; j < static_cast<int>(rep.residuals.size()); ++j) {
    const PoseResiduals& r = rep.residuals[static_cast<std::size_t>(j)];
    for (Eigen::Index i = 0; i < r.length_normalized.size(); ++i) {
      add(j, "cable length", static_cast<int>(i), r.length_m(i), r.length_normalized(i));
    }
    for (Eigen::Index i = 0; i < r.laser_normalized.size(); ++i) {
      add(j, "laser distance", static_cast<int>(i), r.laser_m(i), r.laser_normalized(i));
    }
    if (r.wrench_normalized.allFinite()) {
      add(j, "equilibrium", -1, r.wrench_si.head<3>().norm(),
          r.wrench_normalized.cwiseAbs().maxCoeff());
    }
    for (Eigen::Index i = 0; i < r.swivel_normalized.size(); ++i) {
      add(j, "swivel angle", static_cast<int>(i), r.swivel_rad(i), r.swivel_normalized(i));
    }
    if (r.inclination_normalized.allFinite()) {
      const int c =
          std::abs(r.inclination_normalized(0)) >= std::abs(r.inclination_normalized(1)) ? 0 : 1;
      add(j, "inclination", -1, r.inclination_rad(c), r.inclination_normalized(c));
    }
    add(j, "IMU yaw", -1, r.imu_yaw_rad, r.imu_yaw_normalized);
  }
  return all;
}

// The gate of each channel: max(gross_sigmas, gross_spread x the 95th percentile of the channel's
// normalised residuals). Each channel against its own spread: missing physics can leave the
// lengths thousands of their (sub-micrometre) sigmas out while a wild laser reading is hundreds of
// its own.
std::map<std::string, double> channel_gates(const std::vector<GrossReading>& all,
                                            const DiagnosisOptions& options) {
  std::map<std::string, std::vector<double>> mags;
  for (const auto& g : all) mags[g.channel].push_back(g.sigmas);
  std::map<std::string, double> gate;
  for (auto& [channel, v] : mags) {
    const auto q95 = v.begin() + static_cast<std::ptrdiff_t>(0.95 * (v.size() - 1));
    std::nth_element(v.begin(), q95, v.end());
    gate[channel] = std::max(options.gross_sigmas, options.gross_spread * *q95);
  }
  return gate;
}
}  // namespace

bool diagnosis_detail::explained_by_effects(const std::vector<GrossReading>& gross,
                                            const IdentificationReport& fit,
                                            const DiagnosisOptions& options) {
  const std::vector<GrossReading> all = normalised_readings(fit);
  for (const GrossReading& g : gross) {
    const auto r = std::find_if(all.begin(), all.end(), [&](const GrossReading& a) {
      return a.pose == g.pose && a.channel == g.channel && a.index == g.index;
    });
    if (r == all.end() || !(r->sigmas <= options.gross_sigmas)) return false;
  }
  return true;
}

// ---- Stage 0, gross readings (DiagnosisOptions::gross_sigmas): the standard model refitted with
// a Cauchy loss, which a few wild readings cannot drag, and the readings it leaves far out.
std::vector<GrossReading> find_gross_readings(const CalibratedModel& nominal,
                                              const MeasurementSet& set,
                                              const IdentificationReport& standard,
                                              const IdentificationOptions& identification,
                                              const DiagnosisOptions& options) {
  if (!(options.gross_sigmas > 0)) return {};
  IdentificationOptions robust = identification;
  robust.loss = RobustLoss::kCauchy;
  robust.loss_scale = 3.0;
  robust.progress = {};
  IdentificationOptions plain = identification;
  plain.progress = {};
  // The robust cost is not convex: from the nominal model (LARGE's anchors 3 cm = 300 sigmas off)
  // it flattens every residual and a pose can settle far off, leaving its clean readings metres
  // out; from the least-squares estimate it cannot reach a fit that a wild reading dragged to a
  // bound. Both starts, the lower robust cost kept.
  auto robust_fit = [&](const MeasurementSet& s) -> Result<IdentificationReport> {
    auto a = identify(nominal, s, robust);
    auto b = identify_from(nominal, standard.estimate, s, robust);
    if (!a.ok() || (b.ok() && b->final_cost < a->final_cost)) return b;
    return a;
  };
  // One reading at a time: the worst is taken out (marked missing) and the rest refitted, so a
  // wild length reading does not also flag the equilibrium it tilted.
  MeasurementSet rest = set;
  std::vector<GrossReading> out;
  while (true) {
    auto rep = robust_fit(rest);
    if (!rep) return {};
    std::vector<GrossReading> all = normalised_readings(*rep);
    if (all.empty()) return {};
    const std::size_t isolated = std::max<std::size_t>(1, all.size() / 50);
    const std::map<std::string, double> gate = channel_gates(all, options);
    const auto worst =
        std::max_element(all.begin(), all.end(), [&](const GrossReading& a, const GrossReading& b) {
          return a.sigmas / gate.at(a.channel) < b.sigmas / gate.at(b.channel);
        });
    if (!(worst->sigmas > gate.at(worst->channel))) break;
    out.push_back(*worst);
    if (out.size() > isolated) return {};  // structure, not a few wild readings
    PoseMeasurement& pm = rest.poses[static_cast<std::size_t>(worst->pose)];
    const double nan = std::numeric_limits<double>::quiet_NaN();
    if (worst->channel == "cable length") {
      pm.cable_lengths(worst->index) = nan;
    } else if (worst->channel == "laser distance") {
      pm.laser_distances(worst->index) = nan;
    } else if (worst->channel == "equilibrium") {
      pm.tensions.setConstant(nan);
    } else if (worst->channel == "swivel angle") {
      pm.swivel_angles(worst->index) = nan;
    } else if (worst->channel == "inclination") {
      pm.inclination.setConstant(nan);
    } else {
      pm.imu_yaw = nan;
    }
  }
  if (out.empty()) return out;
  // Taking them out must lower the least-squares chi^2 as wild readings do (at least a quarter of
  // gross_sigmas^2 each), not as clean readings of a misplaced robust fit would, and without them
  // the rest must fit within the noise or the drop must be most of the misfit (else: physics,
  // which can also leave a few readings far out of a robust fit where it sits in a few poses).
  auto rest_fit = identify(nominal, rest, plain);
  if (!rest_fit || rest_fit->dof <= 0) return {};
  const double drop = standard.chi2 - rest_fit->chi2;
  if (!(drop >=
        0.25 * options.gross_sigmas * options.gross_sigmas * static_cast<double>(out.size()))) {
    return {};
  }
  const bool rest_fits = chi2_upper_tail(rest_fit->chi2, rest_fit->dof) >= options.gross_rest_p;
  // When the rest does not fit, the readings must carry gross_share of the whole misfit beyond
  // the noise (chi^2 - dof): a wild reading beside a real effect carries nearly all of it (a laser
  // reading 100 mm off beside 20-30 % softer cables: 0.98), physics that a robust fit puts into
  // one reading a part (MINI's pulley friction at 3x noise: one length reading 60 sigmas out,
  // 0.30-0.34 of the misfit, the rest in the equilibrium).
  const double excess = standard.chi2 - static_cast<double>(standard.dof);
  if (!rest_fits && !(drop >= options.gross_share * excess)) return {};
  return out;
}

namespace {
// "the 3rd pose": people count the recording's poses from 1.
std::string nth_pose(int j) {
  const int n = j + 1;
  const char* suffix = (n % 100 >= 11 && n % 100 <= 13) ? "th"
                       : n % 10 == 1                    ? "st"
                       : n % 10 == 2                    ? "nd"
                       : n % 10 == 3                    ? "rd"
                                                        : "th";
  return format("the %d%s pose", n, suffix);
}
}  // namespace

std::string describe(const GrossReading& g) {
  std::string what = g.channel;
  if (g.index >= 0) what += format(" %d", g.index + 1);
  std::string size;
  if (g.channel == "equilibrium") {
    size = format("the force readings out of balance by %.0f N", g.residual);
  } else if (g.channel == "cable length" || g.channel == "laser distance") {
    size = format("off by %.1f mm", 1e3 * std::abs(g.residual));
  } else {
    size = format("off by %.1f mrad", 1e3 * std::abs(g.residual));
  }
  return format("%s of %s: %s (%.0f sigmas)", what.c_str(), nth_pose(g.pose).c_str(), size.c_str(),
                g.sigmas);
}

std::string describe(const std::vector<GrossReading>& readings) {
  std::string list;
  for (const GrossReading& g : readings) list += (list.empty() ? "" : "; ") + describe(g);
  return std::string(readings.size() == 1 ? "a reading is" : "readings are") +
         " far from every model (" + list +
         "): a corrupted or mistyped value, a unit slip or a sensor glitch";
}

}  // namespace cdpr
