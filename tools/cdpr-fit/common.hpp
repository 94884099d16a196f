// Helpers shared by cdpr-fit's commands.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"
#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/report/format.hpp"
#include "cdpr/status.hpp"

namespace cdpr::fit {

// Where a running command reports progress and early warnings (set by run() for one command):
// `progress` is empty unless progress is shown (progress.hpp); `warn` prints one line on stderr
// ("cdpr-fit <command>: warning: ...") before long work starts.
struct Console {
  ProgressCallback progress;
  std::function<void(const std::string&)> warn = [](const std::string&) {};
};
Console& console();

// load_robot_config with the file named in the message.
Result<RobotModel> load_config(const std::string& path);

// "fnv1a64:..." of a file, or "unknown" when it cannot be read.
std::string hash_or_unknown(const std::string& path);

// Status with "<context>: " in front (Status::prepend trips -Wformat-truncation in GCC 12).
Status with_context(const Status& s, const std::string& context);

// JSON arrays of Eigen vectors/matrices (NaN and infinity become null), numbers for people.
using report::fmt;
using report::number_or_null;
using report::to_json;

// Applies --estimate items (estimate_names()) to `options`; an empty list keeps its defaults.
Status apply_estimate(const std::vector<std::string>& names, int num_cables,
                      IdentificationOptions* options);
// Without --estimate items (`names` empty), fits the defaults to the channels `set` has: no
// laser-plane without laser readings; swivel-zeros, inclinometer-mounting and imu-yaw-zero when
// those channels are present (issue 18). With items, leaves `options` as they set it.
void adapt_to_channels(const MeasurementSet& set, const std::vector<std::string>& names,
                       IdentificationOptions* options);
// --channels words (laser, swivel, inclinometer, imu-yaw; "none" alone or no word: none of them)
// checked against `robot` (loaded from `config`): the laser needs a laser in the config, swivel
// a swivel pulley on every cable. kInvalidArgument names the word and the config.
Result<SensorChannels> parse_channels(const std::vector<std::string>& words,
                                      const RobotModel& robot, const std::string& config);
// The estimated items of `options`, for reports.
std::vector<std::string> estimated_items(const IdentificationOptions& options);

}  // namespace cdpr::fit
