// What the daemon's files share to name things in logs, events and replies (daemon_*.cc).
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/controller/rt_controller.hpp"

namespace cdpr::controller::detail {

// "slack_cable on cable 3 at 2.1 N", "drive_fault at node 4 (EMCY 0x2310)", ...
std::string fault_text(const RtFault& f);
// [x, y, z, roll, pitch, yaw]
nlohmann::json pose_json(const Pose& p);
// [[x, y, z] per cable]
nlohmann::json anchors_json(const RobotModel& m);
nlohmann::json peer_json(const PeerInfo& peer);

}  // namespace cdpr::controller::detail
