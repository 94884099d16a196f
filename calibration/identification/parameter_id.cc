// The names of the identification's parameters for people, derived from their typed ids, and the
// words of --estimate with the kinds they switch on.
#include <string>
#include <vector>

#include "cdpr/calibration/identification.hpp"

namespace cdpr {
namespace {

// "_3" for index 2; "" for one shared by every cable.
std::string numbered(int index) {
  return index < 0 ? std::string() : "_" + std::to_string(index + 1);
}

using K = ParameterKind;
using O = IdentificationOptions;

std::vector<EstimateItem> make_estimate_items() {
  std::vector<EstimateItem> v;
  v.push_back({"anchors",
               {K::kFrameAnchor},
               [](O& o, bool on) { o.estimate_frame_anchors = on; },
               [](const O& o) { return o.estimate_frame_anchors; }});
  // The paper's 16-coordinate subset of an 8-cable robot's frame anchors.
  v.push_back(
      {"paper-anchors",
       {K::kFrameAnchor},
       [](O& o, bool on) {
         o.estimate_frame_anchors = on;
         if (on) o.frame_anchor_mask = paper_anchor_mask();
       },
       [](const O& o) { return o.estimate_frame_anchors && o.frame_anchor_mask.size() > 0; },
       8});
  v.push_back({"platform-anchors",
               {K::kPlatformAnchor},
               [](O& o, bool on) { o.estimate_platform_anchors = on; },
               [](const O& o) { return o.estimate_platform_anchors; }});
  v.push_back({"offsets",
               {K::kLengthOffset},
               [](O& o, bool on) { o.estimate_length_offsets = on; },
               [](const O& o) { return o.estimate_length_offsets; }});
  v.push_back({"scales",
               {K::kLengthScale},
               [](O& o, bool on) { o.estimate_length_scales = on; },
               [](const O& o) { return o.estimate_length_scales; }});
  v.push_back({"stiffness",
               {K::kStiffness},
               [](O& o, bool on) {
                 o.estimate_stiffness = on ? StiffnessEstimate::kShared : StiffnessEstimate::kFixed;
               },
               [](const O& o) { return o.estimate_stiffness == StiffnessEstimate::kShared; }});
  v.push_back({"stiffness-per-cable",
               {K::kStiffness},
               [](O& o, bool on) {
                 o.estimate_stiffness =
                     on ? StiffnessEstimate::kPerCable : StiffnessEstimate::kFixed;
               },
               [](const O& o) { return o.estimate_stiffness == StiffnessEstimate::kPerCable; }});
  v.push_back({"force-gains",
               {K::kForceGain},
               [](O& o, bool on) { o.estimate_force_gains = on; },
               [](const O& o) { return o.estimate_force_gains; }});
  v.push_back({"force-offsets",
               {K::kForceOffset},
               [](O& o, bool on) { o.estimate_force_offsets = on; },
               [](const O& o) { return o.estimate_force_offsets; }});
  v.push_back({"laser-origin",
               {K::kLaserOrigin},
               [](O& o, bool on) { o.estimate_laser_origin = on; },
               [](const O& o) { return o.estimate_laser_origin; }});
  v.push_back({"laser-direction",
               {K::kLaserDirection},
               [](O& o, bool on) { o.estimate_laser_direction = on; },
               [](const O& o) { return o.estimate_laser_direction; }});
  v.push_back({"laser-plane",
               {K::kLaserPlaneNormal, K::kLaserPlaneOffset},
               [](O& o, bool on) { o.estimate_laser_plane = on; },
               [](const O& o) { return o.estimate_laser_plane; }});
  v.push_back({"swivel-zeros",
               {K::kSwivelZero},
               [](O& o, bool on) { o.estimate_swivel_zeros = on; },
               [](const O& o) { return o.estimate_swivel_zeros; }});
  v.push_back({"inclinometer-mounting",
               {K::kInclinometerMount},
               [](O& o, bool on) { o.estimate_inclinometer_mounting = on; },
               [](const O& o) { return o.estimate_inclinometer_mounting; }});
  v.push_back({"imu-yaw-zero",
               {K::kImuYawZero},
               [](O& o, bool on) { o.estimate_imu_yaw_zero = on; },
               [](const O& o) { return o.estimate_imu_yaw_zero; }});
  v.push_back({"mass",
               {K::kPlatformMass},
               [](O& o, bool on) { o.estimate_platform_mass = on; },
               [](const O& o) { return o.estimate_platform_mass; }});
  v.push_back({"com",
               {K::kPlatformCom},
               [](O& o, bool on) { o.estimate_platform_com = on; },
               [](const O& o) { return o.estimate_platform_com; }});
  return v;
}

}  // namespace

const std::vector<EstimateItem>& estimate_items() {
  static const std::vector<EstimateItem> items = make_estimate_items();
  return items;
}

const EstimateItem* find_estimate_item(std::string_view word) {
  for (const EstimateItem& item : estimate_items()) {
    if (item.word == word) return &item;
  }
  return nullptr;
}

Status set_estimate(const std::vector<std::string>& words, int num_cables,
                    IdentificationOptions& options) {
  if (words.empty()) return Status::success();
  IdentificationOptions o = options;
  for (const EstimateItem& item : estimate_items()) item.set(o, false);
  if (words.size() == 1 && words[0] == "none") {  // a fixed model: only the poses are fitted
    options = o;
    return Status::success();
  }
  for (const std::string& w : words) {
    if (w == "none") {
      return Status(ErrorCode::kInvalidArgument,
                    "none is a fixed model: give it alone, not with other items");
    }
    const EstimateItem* item = find_estimate_item(w);
    if (item == nullptr) {
      std::string all;
      for (const EstimateItem& k : estimate_items()) {
        all += (all.empty() ? "" : ", ") + std::string(k.word);
      }
      return Status::error(ErrorCode::kInvalidArgument, "unknown estimate item '%s' (one of %s)",
                           w.c_str(), all.c_str());
    }
    if (item->required_cables > 0 && num_cables > 0 && num_cables != item->required_cables) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%.*s is only for a robot of %d cables; this one has %d",
                           static_cast<int>(item->word.size()), item->word.data(),
                           item->required_cables, num_cables);
    }
    item->set(o, true);
  }
  options = o;
  return Status::success();
}

std::vector<std::string> estimate_words(const IdentificationOptions& options) {
  std::vector<std::string> v;
  for (const EstimateItem& item : estimate_items()) {
    if (item.is_set(options)) v.emplace_back(item.word);
  }
  return v;
}

const EstimateItem* estimate_item_of(ParameterKind kind) {
  for (const EstimateItem& item : estimate_items()) {
    if (item.kinds.size() == 1 && item.kinds[0] == kind) return &item;
  }
  return nullptr;
}

std::string parameter_name(const ParameterId& id) {
  static const char* const xyz[] = {"x", "y", "z"};
  static const char* const uv[] = {"u", "v"};
  static const char* const roll_pitch[] = {"roll", "pitch"};
  const int c = id.component;
  // ".x" for component 0 of {"x", "y", "z"}; "" for the whole vector (component -1).
  const auto part = [c](const char* const* names) {
    return c < 0 ? std::string() : std::string(".") + names[c];
  };
  const std::string laser = "laser" + numbered(id.index);
  switch (id.kind) {
    case ParameterKind::kFrameAnchor:
      return "a" + numbered(id.index) + part(xyz);
    case ParameterKind::kPlatformAnchor:
      return "b" + numbered(id.index) + part(xyz);
    case ParameterKind::kLengthOffset:
      return "o" + numbered(id.index);
    case ParameterKind::kLengthScale:
      return "s" + numbered(id.index);
    case ParameterKind::kStiffness:
      return "ea_scale" + numbered(id.index);
    case ParameterKind::kForceGain:
      return "force_gain" + numbered(id.index);
    case ParameterKind::kForceOffset:
      return "force_offset" + numbered(id.index);
    case ParameterKind::kLaserOrigin:
      return laser + ".origin" + part(xyz);
    case ParameterKind::kLaserDirection:
      return laser + ".direction" + part(uv);
    case ParameterKind::kLaserPlaneNormal:
      return laser + ".plane.normal" + part(uv);
    case ParameterKind::kLaserPlaneOffset:
      return laser + ".plane.c";
    case ParameterKind::kSwivelZero:
      return "swivel_zero" + numbered(id.index);
    case ParameterKind::kInclinometerMount:
      return "inclinometer.mount" + part(roll_pitch);
    case ParameterKind::kImuYawZero:
      return "imu.yaw_zero";
    case ParameterKind::kHomePose: {
      static const char* const pose[] = {"x", "y", "z", "roll", "pitch", "yaw"};
      return "home" + part(pose);
    }
    case ParameterKind::kPlatformMass:
      return "platform.mass";
    case ParameterKind::kPlatformCom:
      return "platform.com" + part(xyz);
  }
  return "unknown";
}

}  // namespace cdpr
