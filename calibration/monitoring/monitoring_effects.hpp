// The candidate changes of in-service monitoring: one table (kMonitorEffects,
// monitoring_effects.cc) of their locator id, words, columns, signature and what to re-identify.
// Internal to calibration/monitoring.
#pragma once

#include <Eigen/Core>
#include <span>

#include "cdpr/calibration/monitoring.hpp"

namespace cdpr::monitoring {

// What a signature needs at one sample (all SI, world frame).
struct SampleGeometry {
  int m = 0;
  const KinematicsData* kinematics = nullptr;
  const RobotModel* robot = nullptr;
  const double* lengths = nullptr;     // measured, m
  const double* tensions = nullptr;    // measured, N
  const double* compliance = nullptr;  // d(elongation)/dF of each cable at its tension, m/N
};

struct EffectEntry {
  MonitorEffect effect;
  const char* id;     // the mismatch locator's id where it has one
  const char* words;  // printf format with %d for the cable (1-based) when per_cable
  bool per_cable;
  int columns;             // per cable (per_cable) or in all
  bool moves_platform;     // changes where the commanded lengths put the platform
  const char* parameters;  // what to re-identify (printf with %d when per_cable)
  const char* unit;        // for people: "mm", "N", "mm/m", "1/N"
  double to_people;        // SI value x to_people = the value in `unit`
  // Writes the columns of cable `cable` (or the shared columns, cable -1) into `s` from column
  // `col` on, rows: m lengths, then 6 equilibrium, then the lasers (zero).
  void (*fill)(const SampleGeometry& g, int cable, Monitor::Signature& s, int col);
};

std::span<const EffectEntry> effect_table();

// First signature column of (entry, cable) for a robot with m cables.
int first_column(const EffectEntry& e, int cable, int m);
// Total columns for m cables.
int total_columns(int m);

// The projected precision W = S^-1 - S^-1 B (B' S^-1 B)^-1 B' S^-1 of a linearisation (S its
// covariance, B its nuisance columns): the information left once the pose error is profiled out.
// False when S is not positive definite. Allocates nothing.
bool projected_precision(const Monitor::Linearisation& lin, Monitor::RowMatrix& w);

}  // namespace cdpr::monitoring
