// Identifiability of a parameter choice: from the weighted Jacobian with the poses profiled out
// (GeometryInformation, identification.hpp) the singular values, rank, condition number, the
// observability indices O1-O5 and the unidentifiable (or weak) directions in words.
//
// Two scalings are reported:
// - SI: the whitened Jacobian with the parameters in their SI units (m, rad, -, N). O1-O5 use it.
// - column-normalised: every column scaled to unit norm (the usual equilibration). The rank,
//   condition number and named directions use it, so they do not depend on the units.
//
// Observability indices (Sun & Hollerbach's family; sigma_1 >= ... >= sigma_L, L parameters,
// n residuals): O1 = (prod sigma)^(1/L) / sqrt(n) (D-optimality), O2 = sigma_L / sigma_1 (inverse
// condition number), O3 = sigma_L (minimum singular value, E-optimality), O4 = sigma_L^2 / sigma_1
// (noise amplification index), O5 = 1 / sum(1 / sigma_i) (A-optimality-like).
#pragma once

#include <Eigen/Core>
#include <string>
#include <utility>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/status.hpp"

namespace cdpr {

struct IdentifiabilityOptions {
  // Normalised singular values below rank_tolerance * sigma_max count as zero (unidentifiable);
  // below weak_tolerance * sigma_max as weak. Both directions are named.
  double rank_tolerance = 1e-7;
  double weak_tolerance = 1e-3;
  int max_components = 4;             // components named per direction
  double component_threshold = 0.15;  // |component| of the unit direction to be named
};

struct DirectionComponent {
  std::string description;  // "a_3 along cable 3", "the length offset of cable 3"
  double weight = 0.0;      // signed component in the unit direction
};

struct ParameterDirection {
  double singular_value = 0.0;  // normalised
  bool null = false;            // below rank_tolerance
  bool gauge = false;           // a rigid motion of the whole frame
  std::vector<DirectionComponent> components;
  std::string description;  // one sentence in words
};

// What one measurement channel contributes (issue 18): the analysis repeated without it.
struct ChannelContribution {
  std::string channel;   // "cable lengths", "laser", "equilibrium", "swivel angles", ...
  int rows = 0;          // residual rows of the channel
  int rank_without = 0;  // rank of the information without the channel
  // Parameters whose Cramer-Rao std the channel lowers the most: (name, std without / std with),
  // largest first; infinity when the parameter is unidentifiable without the channel.
  std::vector<std::pair<std::string, double>> gains;
  std::string description;  // one line in words
};

struct IdentifiabilityReport {
  std::vector<ParameterId> parameter_ids;      // what each parameter is (code reads these)
  std::vector<std::string> parameter_names;    // parameter_name of each id, for people
  Eigen::VectorXd singular_values;             // SI, descending
  Eigen::VectorXd normalized_singular_values;  // column-normalised, descending
  int num_parameters = 0;
  int num_residuals = 0;
  int rank = 0;                   // column-normalised
  double condition_number = 0.0;  // column-normalised, infinity when rank deficient
  double o1 = 0.0, o2 = 0.0, o3 = 0.0, o4 = 0.0, o5 = 0.0;  // SI
  std::vector<int> unobserved;                              // parameters with an all-zero column
  std::vector<ParameterDirection> directions;               // null first, then weak, weakest first
  // What fixes the world frame, in words (the gauge), from the channels present.
  std::vector<std::string> notes;
  // Filled by the (model, set) overload: what each channel present makes observable.
  std::vector<ChannelContribution> channels;

  bool identifiable() const { return rank == num_parameters; }
  std::string summary() const;
};

// From precomputed information.
IdentifiabilityReport analyze_identifiability(const GeometryInformation& information,
                                              const IdentifiabilityOptions& options = {});

// Evaluates the information at the commanded poses of `set` with `model`, then analyses it,
// and repeats the analysis without each channel present (IdentifiabilityReport::channels).
Result<IdentifiabilityReport> analyze_identifiability(const CalibratedModel& model,
                                                      const MeasurementSet& set,
                                                      const IdentificationOptions& identification,
                                                      const IdentifiabilityOptions& options = {});

// Refuses (kFailedPrecondition) when the report is rank deficient; the message lists the null
// directions in words (as many as fit in a Status).
Status require_identifiable(const IdentifiabilityReport& report);

}  // namespace cdpr
