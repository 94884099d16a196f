#include "daemon_text.hpp"

#include <cstdio>

namespace cdpr::controller::detail {

using json = nlohmann::json;

json pose_json(const Pose& p) {
  return json::array(
      {p.position.x(), p.position.y(), p.position.z(), p.rpy.x(), p.rpy.y(), p.rpy.z()});
}

json anchors_json(const RobotModel& m) {
  json a = json::array();
  for (Eigen::Index i = 0; i < m.frame_anchors.cols(); ++i) {
    const Eigen::Vector3d c = m.frame_anchors.col(i);
    a.push_back(json::array({c.x(), c.y(), c.z()}));
  }
  return a;
}

json peer_json(const PeerInfo& peer) {
  return {{"pid", peer.pid}, {"uid", peer.uid}, {"gid", peer.gid}};
}

std::string fault_text(const RtFault& f) {
  std::string s = to_string(f.kind);
  if (f.node > 0) s += " at node " + std::to_string(f.node);
  if (f.cable >= 0) s += " on cable " + std::to_string(f.cable + 1);
  char safety[80] = "";
  switch (f.kind) {
    case FaultKind::kEStop:
      std::snprintf(safety, sizeof safety, ": source %d open, silent or stale", int{f.code});
      return s + safety;
    case FaultKind::kCableLimit:
      std::snprintf(safety, sizeof safety, " (length %.4f m outside the winch's limits)", f.value);
      return s + safety;
    case FaultKind::kWorkspace:
      std::snprintf(safety, sizeof safety, ": %c = %.4f m outside the workspace box",
                    "xyz"[f.code % 3], f.value);
      return s + safety;
    default:
      break;
  }
  if (f.code != 0) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "0x%04X", f.code);
    s += std::string(" (EMCY ") + buf + ")";
  }
  if (f.kind == FaultKind::kSlackCable || f.kind == FaultKind::kOverload) {
    char buf[32];
    std::snprintf(buf, sizeof buf, " at %.1f N", f.value);
    s += buf;
  }
  if (f.kind == FaultKind::kForceStuck) {
    char buf[96];
    std::snprintf(buf, sizeof buf,
                  " (reading unchanged at %.1f N while the tension was made to change)", f.value);
    s += buf;
  }
  return s;
}

}  // namespace cdpr::controller::detail
