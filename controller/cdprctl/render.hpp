// cdprctl's human output: a generic rendering of result objects (key: value lines, nested objects
// indented, arrays of flat objects as tables) and one-line renderings of events.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "cdpr/controller/control_client.hpp"

namespace cdpr::ctl {

// A result as indented "key: value" lines (keys in the daemon's order, which is alphabetical).
std::string render_result(const nlohmann::json& result);

// A scalar as text: strings raw, integers as they are, other numbers with 6 significant digits.
std::string render_scalar(const nlohmann::json& v);

// An event as one plain line (no newline).
std::string event_line(const control::ControlEvent& ev);

// The live progress bar of a `progress` event, at most `width` columns (no newline).
std::string progress_bar(const nlohmann::json& progress, int width);

// "1:23" or "1:02:03" for seconds; "-" when not a number.
std::string format_duration(const nlohmann::json& seconds);

}  // namespace cdpr::ctl
