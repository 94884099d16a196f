// Slow hidden changes of the virtual robot during a long run (scenario `drifts:`,
// docs/sim-scenarios.md): a pulley (frame anchor) that moves, a force sensor whose offset and gain
// drift, an encoder that slips against its drum. Each starts at `at` and grows linearly to its full
// size over `duration` (0: a step), then stays. The physics applies them at every step
// (Physics::step); the daemon's model never knows them, so in-service monitoring has to notice.
//
// Adding a kind is one entry of kDriftKinds (drift.cc): its name, its fields and how they are read.
#pragma once

#include <Eigen/Core>
#include <string_view>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::config {
class YamlField;
}

namespace cdpr::sim {

enum class DriftKind {
  kPulleyMove,   // frame anchor a_i moves by `by` (m, world)
  kForceSensor,  // force sensor i: true gain x (1 + gain), true offset + offset (raw units)
  kEncoderSlip,  // drum of winch i turns `counts` further than its encoder reports
};
std::string_view to_string(DriftKind k);

struct Drift {
  DriftKind kind = DriftKind::kPulleyMove;
  int cable = 0;            // 0-based
  double at_s = 0.0;        // scenario time the change starts, s
  double duration_s = 0.0;  // s over which it grows to its full size; 0: a step at `at`
  Eigen::Vector3d by = Eigen::Vector3d::Zero();  // kPulleyMove, m
  double gain = 0.0;                             // kForceSensor, relative
  double offset = 0.0;                           // kForceSensor, raw units
  double counts = 0.0;                           // kEncoderSlip, counts
  int line = 0;                                  // in the scenario file

  // 0 before `at`, rising linearly to 1 at `at + duration`, 1 after.
  double fraction_at(double t) const {
    if (t < at_s) return 0.0;
    if (!(duration_s > 0.0) || t >= at_s + duration_s) return 1.0;
    return (t - at_s) / duration_s;
  }
};

// Reads one entry of `drifts:`. The message of an error names the file, line and field.
Status parse_drift(const config::YamlField& n, Drift& out);

}  // namespace cdpr::sim
