// Daemon: the state directory (geometry versions, the active one, recordings) and the hot swap
// from one geometry version to another.
#include <spdlog/spdlog.h>

#include "cdpr/calibration/simulate.hpp"
#include "cdpr/controller/daemon.hpp"
#include "daemon_text.hpp"

namespace cdpr::controller {
using json = nlohmann::json;

const Geometry* Daemon::make_geometry(int version, const RobotModel& model) {
  auto g = std::make_unique<Geometry>();
  g->version = version;
  g->model = model;
  g->reference_tension = default_reference_tension(model);
  geometries_.push_back(std::move(g));
  return geometries_.back().get();
}

Status Daemon::load_state() {
  auto store = StateStore::open(config_.state_directory);
  if (!store.ok()) return store.status();
  store_ = std::make_unique<StateStore>(std::move(*store));
  // A crash or a power loss between a write and its rename left its temporary file: never read,
  // removed here (logged) before anything is written.
  auto temps = store_->remove_leftover_temporaries();
  if (!temps.ok()) return temps.status();
  for (const std::string& t : *temps) {
    spdlog::warn(
        "state directory: leftover temporary file {} removed (a write interrupted before "
        "its rename)",
        t);
  }
  auto active = store_->active_version();
  if (!active.ok() && active.status().code() != ErrorCode::kNotFound) return active.status();
  if (!active.ok()) {
    if (Status s = first_start(active); !s.ok()) return s;
  }
  auto model = store_->load_geometry(*active);
  if (!model.ok()) return model.status();
  if (model->num_cables() != nominal_.num_cables()) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "active geometry version %d has %d cables, %s has %d", *active,
                         model->num_cables(), config_.robot.c_str(), nominal_.num_cables());
  }
  active_version_ = *active;
  active_ = make_geometry(*active, *model);
  repair_recordings();
  return Status::success();
}

// No version is active: the first start (or one interrupted), or a damaged directory.
Status Daemon::first_start(Result<int>& active) {
  if (store_->geometry_versions().empty()) {
    // First start: the nominal robot description becomes version 1.
    auto v = store_->add_geometry(nominal_, {{"source", "nominal"}, {"file", config_.robot}});
    if (!v.ok()) return v.status();
    if (Status s = store_->activate(*v, {{"why", "first start: nominal geometry"}}); !s.ok()) {
      return s;
    }
    active = *v;
    return Status::success();
  }
  if (store_->geometry_versions() == std::vector<int>{1} && store_->geometry_meta(1).ok() &&
      store_->geometry_meta(1)->value("source", std::string()) == "nominal") {
    // A first start killed between writing version 1 and activating it: finish it.
    spdlog::warn(
        "state directory: version 1 (the nominal geometry) exists but was never made "
        "active (a first start interrupted); activating it");
    if (Status s = store_->activate(1, {{"why",
                                         "first start: nominal geometry (completed after "
                                         "an interrupted first start)"}});
        !s.ok()) {
      return s;
    }
    active = 1;
    return Status::success();
  }
  return Status::error(ErrorCode::kFailedPrecondition,
                       "%s: geometry versions exist but none is active (file 'active' missing);"
                       " restore it or remove the folder to start from the nominal geometry",
                       config_.state_directory.c_str());
}

void Daemon::repair_recordings() {
  // Rows are appended whole with an fsync each; only a power loss in the middle of an append
  // leaves part of a row, without its newline, at the end. It is cut off, so the recording reads
  // back with every row measured before.
  for (int id : store_->calibrations()) {
    const std::string path = store_->calibration_dir(id) + "/recording.csv";
    auto cut = recording::RecordingAppender::cut_torn_row(path);
    if (!cut.ok()) {
      spdlog::error("{}", cut.status().message());
    } else if (*cut > 0) {
      spdlog::warn("{}: torn last row ({} bytes, a power loss while it was written) cut off", path,
                   *cut);
    }
  }
}

Status Daemon::activate(int version, const json& why, const PeerInfo* peer) {
  if (const RtSnapshot r = rt_->snapshot(); r.fault.kind != FaultKind::kNone) {
    return Status(
        ErrorCode::kFailedPrecondition,
        "the robot is in fault (" + detail::fault_text(r.fault) + "): run fault-reset first");
  }
  auto model = store_->load_geometry(version);
  if (!model.ok()) return model.status();
  json w = why;
  if (peer != nullptr) w["peer"] = detail::peer_json(*peer);
  // Durable first: after a crash the daemon comes back with the version it was applying.
  if (Status s = store_->activate(version, w); !s.ok()) return s;
  // The pose the platform is at, as the new geometry sees it; the RT loop slews the targets from
  // where they are to the new geometry's targets for it (bumpless), then holds.
  auto pose = pose_from_encoders(*model);
  if (!pose.ok()) return pose.status();
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    g = make_geometry(version, *model);
  }
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kReference;
  c->pose = *pose;
  c->geometry = g;
  const std::uint64_t seq = post(std::move(c));
  {
    std::lock_guard lock(mu_);
    swap_target_ = version;
    swap_seq_ = seq;
    swap_why_ = w.value("why", std::string("activation"));
  }
  transition(SupervisorEvent::kApply, "hot swap to geometry version " + std::to_string(version));
  return Status::success();
}

// A fault latched: a hot swap in progress did not complete.
void Daemon::interrupt_swap(const std::string& fault) {
  std::optional<int> interrupted;
  int previous = 0;
  {
    std::lock_guard lock(mu_);
    interrupted = swap_target_;
    swap_target_.reset();
    previous = active_version_;
    if (interrupted && calibration_ && calibration_->outcome == CalibrationRunOutcome::kApplying) {
      calibration_->outcome = CalibrationRunOutcome::kFailed;
      calibration_->message = "hot swap interrupted by a fault: " + fault;
    }
  }
  if (!interrupted || *interrupted == previous) return;
  // The new version was made durable before the swap; the swap did not complete, so the previous
  // version is the active one again, on disk too (the RT loop gets it back at the fault reset).
  const Status r =
      store_->activate(previous, {{"why", "hot swap to version " + std::to_string(*interrupted) +
                                              " interrupted by a fault: " + fault}});
  if (r.ok()) {
    spdlog::warn("hot swap to geometry version {} interrupted; version {} stays active",
                 *interrupted, previous);
  } else {
    spdlog::error("hot swap interrupted; cannot make version {} active again: {}", previous,
                  r.to_string());
  }
}

// While applying: the swap is complete once the RT loop has taken its command.
void Daemon::complete_swap(const RtSnapshot& s) {
  std::optional<int> target;
  int calibration = 0;
  std::string why;
  {
    std::lock_guard lock(mu_);
    if (!swap_target_ || s.command_done < swap_seq_) return;
    target = swap_target_;
    active_version_ = *target;
    for (const auto& g : geometries_) {
      if (g->version == *target) active_ = g.get();
    }
    swap_target_.reset();
    why = swap_why_;
    if (calibration_ && calibration_->outcome == CalibrationRunOutcome::kApplying) {
      calibration_->outcome = CalibrationRunOutcome::kApplied;
      calibration_->proposed_version = *target;
      calibration = calibration_->id;
    }
  }
  spdlog::info("geometry version {} applied; largest target step {:.1f} counts", *target,
               s.largest_reference_step);
  std::optional<HomingRecord> record;
  {
    std::lock_guard lock(mu_);
    if (record_) {
      record_->geometry_version = *target;  // the offsets hold for every version
      record = record_;
    }
  }
  if (record) {
    if (Status st = store_->save_homing(*record); !st.ok()) {
      spdlog::error("homing record: {}", st.to_string());
    }
  }
  publish("calibration", {{"version", *target},
                          {"calibration", calibration > 0 ? json(calibration) : json(nullptr)},
                          {"outcome", to_string(CalibrationRunOutcome::kApplied)},
                          {"largest_step_counts", s.largest_reference_step},
                          {"message", why}});
  transition(SupervisorEvent::kApplied, "geometry version " + std::to_string(*target) + " applied");
}

}  // namespace cdpr::controller
