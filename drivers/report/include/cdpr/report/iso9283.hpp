// The ISO 9283 figures measured on the virtual robot (bench/iso9283_bench.cc, docs/motion.md
// "ISO 9283 on the virtual robot") as a small JSON file the calibration report can show
// (docs/daemon.md "Acceptance gates and the report"), and the reference paper's figures beside
// them. One format, written by `iso9283_bench --out FILE` and read by cdprd:
//
//   {"format": "cdpr-iso9283-v1", "setup": "virtual MINI, scenario ..., seed 7, ...",
//    "nominal":    {"ap_m": ..., "rp_m": ..., "at_line_m": ..., "at_circle_m": ...,
//                   "rt_line_m": ..., "rt_circle_m": ...},
//    "calibrated": {... the same keys ...}}
//
// All figures in metres, finite and >= 0. AP, RP: largest over ISO 9283's five points; AT, RT:
// largest over a path's points (ISO 9283's definitions, as the bench computes them).
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "cdpr/status.hpp"

namespace cdpr::report {

// The paper (Jin et al. 2018, MINI): "the robot position control accuracy is increased by 58%"
// (calibrated against uncalibrated); "the path accuracy is 1.284 mm and the path repeatability
// is 0.18 mm after calibration" (a circle and a line, rotation 0).
inline constexpr double kPaperPositionAccuracyGain = 0.58;  // 1 - calibrated / uncalibrated
inline constexpr double kPaperPathAccuracyM = 1.284e-3;
inline constexpr double kPaperPathRepeatabilityM = 0.18e-3;
inline constexpr const char* kIso9283Format = "cdpr-iso9283-v1";

struct Iso9283Figures {
  double ap_m = 0.0, rp_m = 0.0;
  double at_line_m = 0.0, at_circle_m = 0.0;
  double rt_line_m = 0.0, rt_circle_m = 0.0;
};

struct Iso9283Measured {
  std::string setup;  // one line: the robot, scenario, seed, cycles, identification
  Iso9283Figures nominal, calibrated;
};

nlohmann::json iso9283_json(const Iso9283Measured& m);
// kParseError naming `file` and the field ("iso.json: calibrated.at_line_m: expected a number
// of metres >= 0").
Result<Iso9283Measured> parse_iso9283(std::string_view text, std::string_view file);

}  // namespace cdpr::report
