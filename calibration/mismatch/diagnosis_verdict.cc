// The locator's verdict (diagnosis_internal.hpp): the model with the accepted effects and its
// proof on held-out data, the verdict and the findings in words.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <utility>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/effect_library.hpp"
#include "cdpr/calibration/model_validation.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/suspended_statics.hpp"
#include "diagnosis_internal.hpp"
#include "mismatch_internal.hpp"
#include "text_format.hpp"

namespace cdpr::diagnosis_detail {

using mismatch_detail::column_basis;
using mismatch_detail::format;
using mismatch_detail::kNaN;

void state_gross_readings(Diagnosis& d) {
  d.verdict = Diagnosis::Verdict::kInconclusive;
  d.headline = "Inconclusive: " + describe(d.gross_readings) + ", not missing physics. Check " +
               (d.gross_readings.size() == 1 ? "that reading" : "those readings") +
               ", measure the pose again or leave it out, and diagnose again.";
  d.findings.push_back(d.headline);
  for (const auto& g : d.gross_readings) {
    d.findings.push_back("Gross reading: " + describe(g) +
                         " from the standard model refitted with a robust (Cauchy) loss.");
  }
}

Status model_the_effects(Diagnosis& d, const State& current, const CvRms& cv_before, int K,
                         bool leave_one_out, const MeasurementSet* validation,
                         const CalibratedModel& nominal,
                         const IdentificationOptions& identification, int nl) {
  d.held_out_source = validation != nullptr ? "validation recording"
                      : leave_one_out       ? "leave-one-pose-out cross-validation"
                                            : format("%d-fold cross-validation", K);
  d.held_out_rms_before = cv_before.length_m;
  d.held_out_rms_after = cv_before.length_m;
  if (!d.accepted.empty()) {
    d.after = current.report;
    d.model_after = current.report.estimate;
    for (std::size_t q = 0; q < current.gn_ids.size(); ++q) {
      write_effect(current.gn_ids[q], current.gn_theta[q], d.model_after);
    }
    RobotModel& after = d.model_after.robot;
    if (after.suspended && after.num_cables() < 6 && !current.gn_ids.empty()) {
      // The effects written may move where the platform hangs: the config's home must stay an
      // equilibrium (the model check of the config loader), at the same position and heading.
      if (const auto hang = suspended_equilibrium_pose(after, after.home); hang.ok()) {
        after.home = hang->pose;
      }
    }
    d.held_out_rms_after = current.cv.length_m;
  }
  if (validation != nullptr) {
    // Held-out = the validation recording: its poses re-located with the geometry fixed.
    IdentificationOptions fixed = identification;
    fixed.estimate_frame_anchors = false;
    fixed.estimate_platform_anchors = false;
    // identify() needs at least one estimated parameter: the encoder zeros are re-estimated on
    // the validation recording (a new recording is homed again), everything else is fixed.
    fixed.estimate_length_offsets = true;
    fixed.estimate_length_scales = false;
    fixed.estimate_stiffness = StiffnessEstimate::kFixed;
    fixed.estimate_force_gains = false;
    fixed.estimate_force_offsets = false;
    fixed.estimate_laser_origin = false;
    fixed.estimate_laser_direction = false;
    fixed.estimate_laser_plane = false;
    fixed.gauge = Gauge::kNone;
    fixed.compute_covariance = false;
    // The validation's tensions were read with the nominal's force sensors; identify() reads them
    // with its initial model's (which carries the gains and offsets estimated, if any).
    auto vb =
        identify(d.before.estimate,
                 tensions_read_with(*validation, nominal.robot, d.before.estimate.robot), fixed);
    if (!vb) {
      Status st = vb.status();
      st.prepend("diagnose: re-locating the validation poses: ");
      return st;
    }
    d.held_out_rms_before = vb->rms_length_m;
    d.held_out_rms_after = vb->rms_length_m;
    if (d.after) {
      auto va =
          identify(d.model_after,
                   tensions_read_with(*validation, nominal.robot, d.model_after.robot), fixed);
      if (va) d.held_out_rms_after = va->rms_length_m;
    }
  }
  const IdentificationReport& aft = d.after ? *d.after : d.before;
  d.channels.push_back({"cable lengths", "m", d.before.rms_length_m, aft.rms_length_m});
  // A channel is listed when the recording has it (a laser in the config need not be measured).
  auto measured = [&](auto rows_of) {
    for (const PoseResiduals& pr : d.before.residuals) {
      if (rows_of(pr)) return true;
    }
    return false;
  };
  if (nl > 0 && identification.use_laser && measured([](const PoseResiduals& pr) {
        return pr.laser_normalized.size() > 0 && !pr.laser_normalized.array().isNaN().all();
      })) {
    d.channels.push_back({"laser", "m", d.before.rms_laser_m, aft.rms_laser_m});
  }
  if (identification.use_equilibrium && d.before.rms_wrench_n > 0) {
    d.channels.push_back({"equilibrium (force)", "N", d.before.rms_wrench_n, aft.rms_wrench_n});
  }
  if (identification.use_swivel && measured([](const PoseResiduals& pr) {
        return pr.swivel_normalized.size() > 0 && !pr.swivel_normalized.array().isNaN().all();
      })) {
    d.channels.push_back({"swivel angles", "rad", d.before.rms_swivel_rad, aft.rms_swivel_rad});
  }
  if (identification.use_inclinometer &&
      measured([](const PoseResiduals& pr) { return !std::isnan(pr.inclination_normalized(0)); })) {
    d.channels.push_back(
        {"inclinometer", "rad", d.before.rms_inclination_rad, aft.rms_inclination_rad});
  }
  if (identification.use_imu_yaw &&
      measured([](const PoseResiduals& pr) { return !std::isnan(pr.imu_yaw_normalized); })) {
    d.channels.push_back({"IMU yaw", "rad", d.before.rms_imu_yaw_rad, aft.rms_imu_yaw_rad});
  }
  return Status::success();
}

namespace {

// "the direction of the last move of cables 2 and 5 (cable tensions); ...": what the structures
// follow, for a headline.
std::string unexplained_words(const std::vector<UnexplainedStructure>& structures) {
  std::vector<std::string> variables;
  for (const auto& u : structures) {
    if (std::find(variables.begin(), variables.end(), u.variable) == variables.end()) {
      variables.push_back(u.variable);
    }
  }
  std::string what;
  for (const std::string& v : variables) {
    std::vector<int> cables;
    std::string where;
    for (const auto& u : structures) {
      if (u.variable != v) continue;
      for (int c : u.cables) {
        if (std::find(cables.begin(), cables.end(), c) == cables.end()) cables.push_back(c);
      }
      where += (where.empty() ? "" : ", ") + u.channel;
    }
    std::sort(cables.begin(), cables.end());
    std::string list;
    for (std::size_t q = 0; q < cables.size(); ++q) {
      if (q > 0) list += q + 1 == cables.size() ? " and " : ", ";
      list += std::to_string(cables[q] + 1);
    }
    if (!what.empty()) what += "; ";
    what += "the " + v + " of cable" + (cables.size() > 1 ? "s " : " ") + list + " (" + where + ")";
  }
  return what;
}

}  // namespace

void state_verdict(Diagnosis& d, double alpha) {
  const bool misfit = d.screen.p_value < alpha;
  if (!d.accepted.empty()) {
    d.verdict = Diagnosis::Verdict::kMismatchNamed;
    std::string names;
    for (const auto& f : d.accepted) {
      if (!names.empty()) names += "; ";
      names += f.name;
    }
    d.headline = "Missing physics found: " + names + ".";
    if (d.screen_after && !d.screen_after->unexplained.empty()) {
      d.headline += " Unexplained structure remains, following " +
                    unexplained_words(d.screen_after->unexplained) + " (details below).";
    }
  } else if (!d.screen.unexplained.empty()) {
    // Structure that no candidate of the library explains: say what it follows.
    d.verdict = Diagnosis::Verdict::kMismatchUnexplained;
    d.headline = "Unexplained structure following " + unexplained_words(d.screen.unexplained) +
                 ": no candidate effect of the library explains it (details below).";
  } else if (misfit) {
    d.verdict = Diagnosis::Verdict::kMismatchUnexplained;
    d.headline = format(
        "The model does not explain the recording (chi^2 = %.1f for %d degrees of freedom), and "
        "no candidate effect explains the misfit.",
        d.screen.chi2, d.screen.dof);
  } else {
    d.verdict = Diagnosis::Verdict::kNoMismatch;
    d.headline = format(
        "No missing physics found: the residuals are consistent with the sensor noise (chi^2 = "
        "%.1f for %d degrees of freedom, p = %.3g).",
        d.screen.chi2, d.screen.dof, d.screen.p_value);
  }
  d.findings.push_back(d.headline);
  if (d.follow_up && d.follow_up->held_back) {
    const FollowUp& fu = *d.follow_up;
    d.findings.push_back(format(
        "Suspected, not proven: %s passed the tests beside the effects named, but with weak "
        "evidence (BIC %+.1f; p = %.3g on the second screen, %.3g after Holm's correction). "
        "Measure the %d proposed follow-up poses (they multiply the information on its parameters "
        "by %.1f), append them to this recording and diagnose again to decide.",
        fu.name.c_str(), fu.bic_delta, fu.p_value, fu.p_adjusted, static_cast<int>(fu.poses.size()),
        std::exp((fu.information_after - fu.information_before) / std::max(1, fu.parameters))));
  } else if (d.follow_up) {
    const FollowUp& fu = *d.follow_up;
    d.findings.push_back(format(
        "Suspected, not proven: %s (p = %.3g for it alone, %.3g after Holm's correction over the "
        "candidates). Measure the %d proposed follow-up poses (they multiply the information on "
        "its parameters by %.1f), append them to this recording and diagnose again to decide.",
        fu.name.c_str(), fu.p_value, fu.p_adjusted, static_cast<int>(fu.poses.size()),
        std::exp((fu.information_after - fu.information_before) / std::max(1, fu.parameters))));
  }
  for (const auto& f : d.accepted) {
    std::string s = f.name + ": ";
    for (std::size_t q = 0; q < f.parameters.size(); ++q) {
      if (q > 0) s += "; ";
      s += f.parameters[q].text;
    }
    s += format(
        " (LRT %.1f on %d parameters, p = %.3g; BIC %+.1f; held-out RMS %.3f -> %.3f mm; "
        "its family '%s' selected in %.0f %% of the bootstrap resamples%s)%s.",
        f.lrt_statistic, f.extra_parameters, f.lrt_p_value, f.bic_delta, 1e3 * f.cv_rms_before,
        1e3 * f.cv_rms_after, f.family.c_str(), 100 * f.family_inclusion_probability,
        f.round == 2 ? "; found by the second screening round, on what the effects before it leave"
                     : "",
        f.modelled_in_config ? "" : "; the config cannot carry it (report only)");
    d.findings.push_back(s);
  }
  if (!d.accepted.empty() && d.screen_after) {
    for (const auto& u : d.screen_after->unexplained) {
      d.findings.push_back("With the effects above modelled: " + u.description);
    }
  }
  for (const auto& c : d.confounded) {
    d.findings.push_back(format(
        "%s. Both fits: %s (chi^2 %.1f) and %s (chi^2 %.1f). %d extra poses would lower their "
        "canonical correlation from %.4f to %.4f.",
        c.description.c_str(), c.first.c_str(), c.first_fit.chi2_after, c.second.c_str(),
        c.second_fit.chi2_after, static_cast<int>(c.separating_poses.size()), c.correlation,
        c.correlation_with_extra));
  }
  if (d.verdict != Diagnosis::Verdict::kNoMismatch) {
    d.findings.push_back(format("Held-out length residual RMS (%s): %.3f mm before, %.3f mm after.",
                                d.held_out_source.c_str(), 1e3 * d.held_out_rms_before,
                                1e3 * d.held_out_rms_after));
  }
  for (std::size_t q = 0; q < d.screen.findings.size(); ++q) {
    // With nothing found, the headline already is the screen's overall fit test (its first line).
    if (q == 0 && d.verdict == Diagnosis::Verdict::kNoMismatch) continue;
    d.findings.push_back(d.screen.findings[q]);
  }
}

}  // namespace cdpr::diagnosis_detail
