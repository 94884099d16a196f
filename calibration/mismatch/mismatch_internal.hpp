// Shared by the sources of calibration/mismatch (not installed): the screen's residual layout and
// design (mismatch_design.cc), the column-space basis and the put of a wrench effect into a
// candidate's columns, and the description of unexplained structure (structure.cc).
#pragma once

#include <Eigen/Dense>
#include <limits>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/mismatch.hpp"

namespace cdpr::mismatch_detail {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Orthonormal basis of the column space of X (columns scaled to unit norm first), with the
// singular-value threshold `tol` relative to 1 (no columns when X is zero).
Eigen::MatrixXd column_basis(const Eigen::MatrixXd& X, double tol);

// A pose's effect on the net wrench, `delta` (SI), into column `col` of the candidate: whitened
// with the equilibrium rows' covariance `cov` in X, as is in si, rows kw..kw+5. False when the
// covariance is not positive definite.
// `si_delta` (optional): what goes into si instead of `delta` (an effect whose correction of the
// data differs from its effect on the residual, e.g. pulley friction, whose length-row correction
// also removes the equilibrium rows' conditional correction).
bool put_wrench_effect(Eigen::Matrix<double, 6, 6> cov, const Eigen::Matrix<double, 6, 1>& delta,
                       int kw, int col, CandidateColumns& c,
                       const Eigen::Matrix<double, 6, 1>* si_delta = nullptr);

// The residual layout (identification_problem.hpp's row order per pose: lengths, lasers, wrench,
// reference, then the orientation sensors).
using RowKind = ResidualKind;

struct Row {
  RowKind kind;
  int pose;
  int index;  // cable, laser or wrench/reference component
};

using Candidate = CandidateColumns;

// Everything the screen needs, in residual space.
struct DesignData {
  std::vector<Row> rows;
  std::vector<double> si;  // SI residual per row (NaN where mixed or unknown)
  std::vector<std::vector<int>> length_row;
  std::vector<int> pose_start;
  Eigen::VectorXd r, sigma_len;
  Eigen::VectorXd tension, kin_len, loaded, reading, time, tilt, horizontal;
  Eigen::MatrixXd direction;
  GeometryInformation base;
  std::vector<Candidate> lib;
  // Per (pose, cable), poses x cables: the direction of the last move and the measured variables
  // of the structure scan (NaN where unknown).
  Eigen::MatrixXd move, pc_length, pc_tension, pc_time, pc_tilt, pc_temperature;
  // Per pose (its rows x cables): the whitened residual change for a 1 N error of each cable's
  // tension reading (equilibrium rows and, through the elongation, the cable's length row), and
  // the SI correction of the equilibrium rows that removes it (see put_wrench_effect).
  std::vector<Eigen::MatrixXd> tension_white, tension_si;
  // The same for a 1 m length error of each cable (the true length longer than the reading).
  std::vector<Eigen::MatrixXd> length_white;
};

// The design at `poses` of the model: the residual layout, the normalised residuals (when
// `residuals` is given), the explanatory variables and the candidate library's columns.
Result<DesignData> build_design(const CalibratedModel& model, const MeasurementSet& set,
                                const std::vector<Pose>& poses,
                                const std::vector<PoseResiduals>* residuals,
                                const IdentificationOptions& options, const MismatchOptions& mopt);

// The DESCRIBE step of locate_mismatch (mismatch.hpp): structure of the residual `D.r` that no
// candidate explains. `Q1` is the basis of the identification's Jacobian, `bases` the screened
// candidates' projected column bases (the library's order).
std::vector<UnexplainedStructure> describe_structure(const DesignData& D, const Eigen::MatrixXd& Q1,
                                                     const std::vector<Eigen::MatrixXd>& bases,
                                                     const MismatchSummary& summary,
                                                     const MismatchOptions& mopt);

}  // namespace cdpr::mismatch_detail
