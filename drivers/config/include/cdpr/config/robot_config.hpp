// Robot description files (YAML, SI units) <-> cdpr::RobotModel.
//
// The format is documented field by field in docs/config.md; config/mini.yaml is a complete
// example. In short: a `cables:` list with one entry per cable (frame anchor, platform anchor,
// pulley, winch, cable material, force sensor), an optional `defaults:` block with the same keys
// as a cable entry that every cable inherits (nested maps merge key by key), and `platform:`,
// `home:`, `lasers:`.
//
// Loading never throws. Every error names the file, the line and the field and says what was
// expected, e.g.
//   config/mini.yaml:42: cables[3].ea: expected a positive number (N), got -5
// The loaded model is then checked with cdpr::check_model (calibration/model_check.hpp), whose
// field names the loader maps back to a line of the file.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/model_plausibility.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr::config {

// Reads and checks a robot description file. Errors: kNotFound / kIoError (file),
// kParseError (YAML syntax), kInvalidArgument (a field is missing, wrong or inconsistent).
Result<RobotModel> load_robot_config(const std::string& path);

// The same for text already in memory; `name_for_messages` stands for the file name in errors.
Result<RobotModel> parse_robot_config(std::string_view text, std::string_view name_for_messages);

// load_robot_config, then check_model_plausible (model_plausibility.hpp) on the model: every
// finding located at the file, line and field it names ("mini.yaml:55: cables[0].frame_anchor:
// the frame anchors span 1538.31 m, ... (looks like mm, expected m)"). An error: the file does not
// load at all. cdprd --check-config.
struct CheckedRobot {
  RobotModel model;
  std::vector<Status> findings;  // empty: plausible
};
Result<CheckedRobot> check_robot_config(const std::string& path,
                                        const ModelPlausibility& limits = {});

// Writes `model` as YAML that parse_robot_config reads back into exactly the same model (numbers
// in the shortest form that round-trips, so up to 17 significant digits). Properties shared by
// all cables go to `defaults:`, per-cable differences to the cable entries.
std::string save_robot_config(const RobotModel& model);

// Writes `header` (comment lines, each starting with '#', may be empty) and
// save_robot_config(model) to `path`, atomically (cdpr/io/atomic_file.hpp): a crash leaves the old
// file or the new one.
Status write_robot_config(const std::string& path, const RobotModel& model,
                          std::string_view header = {});

}  // namespace cdpr::config
