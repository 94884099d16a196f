// Daemon: the homing record, the pose check at start-up, `home`, `enable` and `disable`
// (docs/daemon.md "Start-up", "Homing", "The homing record"). Nothing here moves the robot: every
// hold is of the drives' actual positions (MotionCommand::hold_actual).
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <thread>

#include "cdpr/calibration/forward_kinematics.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/recording/recording.hpp"
#include "daemon_text.hpp"

namespace cdpr::controller {
using json = nlohmann::json;
using control::ControlErrorCode;

namespace {

std::array<double, 6> pose_array(const Pose& p) {
  return {p.position.x(), p.position.y(), p.position.z(), p.rpy.x(), p.rpy.y(), p.rpy.z()};
}

Pose pose_of(const std::array<double, 6>& a) {
  return Pose{Eigen::Vector3d(a[0], a[1], a[2]), Eigen::Vector3d(a[3], a[4], a[5])};
}

double platform_radius(const RobotModel& model) {
  double r = 1e-3;
  for (Eigen::Index i = 0; i < model.platform_anchors.cols(); ++i) {
    r = std::max(r, model.platform_anchors.col(i).norm());
  }
  return r;
}

}  // namespace

std::vector<double> Daemon::actual_counts() {
  const RtSnapshot snap = rt_->snapshot();
  std::vector<double> out;
  for (int i = 0; i < nominal_.num_cables(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    out.push_back(snap.cycle > 0 ? snap.actual_counts[k]
                                 : static_cast<double>(master_->drives()[k].actual_counts()));
  }
  return out;
}

// The pose from the encoders, checked: forward kinematics from several starts (the persisted
// pose, home) whose lengths miss the encoders' by at most the encoder tolerance plus the model
// uncertainty, all starts agreeing; with a persisted state whose counts the drives still read,
// the pose must agree with the persisted pose, which is then the one held.
Daemon::PoseTrust Daemon::verify_pose(const RobotModel& model,
                                      const std::array<double, kMaxAxes>& offsets,
                                      const std::vector<double>* counts, const Pose* persisted) {
  PoseTrust t;
  const int m = model.num_cables();
  const double mpc = winch_metres_per_count(model.winches[0]);
  const double count_tol = std::ceil(rt_options().settle_counts) + 2.0;
  const double r_max = std::sqrt(m) * count_tol * mpc + config_.start.model_uncertainty_m;
  const double pos_tol = 2.0 * r_max, ang_tol = 2.0 * r_max / platform_radius(model);
  Eigen::VectorXd lengths, tensions;
  encoder_lengths(rt_->snapshot(), model, offsets, lengths, tensions);
  std::vector<Pose> starts{model.home};
  if (persisted != nullptr) starts.insert(starts.begin(), *persisted);
  std::optional<ForwardKinematicsSummary> best, from_persisted;
  bool ambiguous = false;
  ForwardKinematicsData data(model);
  char buf[256];
  for (const Pose& start : starts) {
    ForwardKinematicsOptions options;
    options.initial_pose = start;
    options.max_residual = r_max;
    const ForwardKinematicsSummary fk =
        forward_kinematics_elastic(model, lengths, tensions, options, data);
    if (!fk.success()) continue;
    if (persisted != nullptr && &start == &starts.front()) from_persisted = fk;
    if (best && ((fk.pose.position - best->pose.position).norm() > pos_tol ||
                 (fk.pose.rpy - best->pose.rpy).cwiseAbs().maxCoeff() > ang_tol)) {
      ambiguous = true;
    }
    if (!best) best = fk;
  }
  double moved = -1.0;  // largest count change since the persisted state (-1: none)
  if (counts != nullptr && persisted != nullptr && counts->size() == static_cast<size_t>(m)) {
    moved = 0.0;
    const std::vector<double> now = actual_counts();
    for (std::size_t i = 0; i < now.size(); ++i) {
      moved = std::max(moved, std::abs(now[i] - (*counts)[i]));
    }
  }
  const bool still = moved >= 0.0 && moved <= count_tol;
  if (!best && !still) {
    std::snprintf(buf, sizeof buf,
                  "the encoders' lengths fit no pose of geometry version %d within %.2f mm",
                  active_version(), r_max * 1e3);
    t.reason = buf;
    return t;
  }
  if (!still && ambiguous) {
    t.reason =
        "the encoders' lengths fit two poses of the geometry (forward kinematics from "
        "several starts disagree)";
    return t;
  }
  if (!still) {
    t.trusted = true;
    t.pose = best->pose;
    std::snprintf(buf, sizeof buf, "encoders (forward kinematics within %.2f mm%s)", r_max * 1e3,
                  moved > 0.0 ? "; the drives moved since the persisted state" : "");
    t.source = buf;
    return t;
  }
  // The drives read the persisted counts: the platform stands where the daemon held it, so the
  // persisted pose is the one held. The forward kinematics started there is logged when it
  // lands elsewhere (its orientation is weakly determined at tilted poses: degrees within 1 mm).
  if (from_persisted) {
    const double dp = (from_persisted->pose.position - persisted->position).norm();
    const double da = (from_persisted->pose.rpy - persisted->rpy).cwiseAbs().maxCoeff();
    if (dp > pos_tol || da > ang_tol) {
      spdlog::warn(
          "pose check: forward kinematics lands {:.2f} mm and {:.3f} deg from the "
          "persisted pose at the same counts; the persisted pose is held",
          dp * 1e3, da * 180.0 / M_PI);
    }
  }
  t.trusted = true;
  t.pose = *persisted;
  t.source = from_persisted
                 ? "the persisted pose (the drives read its counts; forward kinematics agrees)"
                 : "the persisted pose (the drives read its counts)";
  return t;
}

void Daemon::set_trust(PoseTrust trust, const std::string& why) {
  if (trust.trusted) {
    spdlog::info("pose: {}: from {}", why, trust.source);
  } else {
    spdlog::warn("pose not trusted ({}): {}; holding, motion refused until cdprctl home", why,
                 trust.reason);
  }
  std::lock_guard lock(mu_);
  trust_ = std::move(trust);
}

// At start-up: the record, checked against these drives and this geometry, then the pose.
Status Daemon::restore_homing() {
  const int m = nominal_.num_cables();
  // The drives' positions come with their TPDOs once SYNC runs after the boot: the offsets and the
  // pose check read none older than this call (on a slow bus they may not have come yet).
  const can::Timestamp asked = io_.clock->now();
  CDPR_RETURN_IF_ERROR(master_->wait_for(
      [&] {
        for (const canopen::Drive& d : master_->drives()) {
          if (master_->last_state_tpdo(d.node()) <= asked) return false;
        }
        return true;
      },
      std::chrono::seconds(10), "start-up: every drive's position (a TPDO after the boot)"));
  auto rec = store_->load_homing();
  PoseTrust untrusted;
  untrusted.pose = active_->model.home;
  if (!rec.ok() && rec.status().code() == ErrorCode::kNotFound &&
      config_.start.home_without_record) {
    spdlog::warn(
        "homing: no homing record; start.home_without_record: reference takes the "
        "platform to stand on its reference platform at home");
    auto offsets = reference_offsets();
    if (!offsets.ok()) return offsets.status();
    HomingRecord r = new_record("reference (start.home_without_record)", *offsets);
    if (Status s = store_->save_homing(r); !s.ok()) return s;
    {
      std::lock_guard lock(mu_);
      offsets_ = *offsets;
      record_ = r;
    }
    PoseTrust t;
    t.trusted = true;
    t.pose = active_->model.home;
    t.source = "homing at start-up (reference platform)";
    set_trust(t, "start-up");
    return Status::success();
  }
  std::string why;
  if (!rec.ok()) {
    why = rec.status().code() == ErrorCode::kNotFound ? "not homed (no homing.json)"
                                                      : rec.status().to_string();
  } else if (rec->format != HomingRecord::kFormat) {
    why =
        "homing.json has the old format (no drive identities, no geometry version): cdprctl "
        "home (--method absolute keeps its offsets after the pose check)";
  } else if (static_cast<int>(rec->offsets_counts.size()) != m) {
    why = "homing.json has " + std::to_string(rec->offsets_counts.size()) + " offsets for " +
          std::to_string(m) + " cables";
  } else if (rec->drives != identities_) {
    why = "the drives are not those of homing.json (node, vendor, product or serial differ)";
  } else if (rec->geometry_version != active_version()) {
    why = "homing.json belongs to geometry version " + std::to_string(rec->geometry_version) +
          ", version " + std::to_string(active_version()) + " is active";
  }
  std::array<double, kMaxAxes> offsets{};
  if (rec.ok()) {
    for (int i = 0; i < m && i < static_cast<int>(rec->offsets_counts.size()); ++i) {
      offsets[static_cast<size_t>(i)] = rec->offsets_counts[static_cast<size_t>(i)];
    }
  }
  {
    std::lock_guard lock(mu_);
    offsets_ = offsets;
    if (why.empty()) record_ = *rec;
  }
  if (!why.empty()) {
    untrusted.reason = why;
    set_trust(untrusted, "start-up");
    return Status::success();
  }
  const Pose persisted = pose_of(rec->pose);
  const bool have = !rec->counts.empty();
  PoseTrust t = verify_pose(active_->model, offsets, have ? &rec->counts : nullptr,
                            have ? &persisted : nullptr);
  if (!t.trusted) t.pose = have ? persisted : active_->model.home;
  set_trust(t, "start-up");
  return Status::success();
}

HomingRecord Daemon::new_record(const std::string& method,
                                const std::array<double, kMaxAxes>& offsets) {
  HomingRecord r;
  r.method = method;
  r.time = recording::utc_timestamp();
  r.geometry_version = active_version();
  r.offsets_counts.assign(offsets.begin(), offsets.begin() + nominal_.num_cables());
  r.drives = identities_;
  return r;
}

// The reference platform: the platform stands at the active model's home, so the encoders read
// the model's commands there.
Result<std::array<double, kMaxAxes>> Daemon::reference_offsets() {
  const Geometry* g = active_geometry();
  CommandData data(g->model);
  if (Status s = command_counts(g->model, g->model.home, g->reference_tension, data); !s.ok()) {
    return s.prepend("homing at the home pose: ");
  }
  const std::vector<double> now = actual_counts();
  std::array<double, kMaxAxes> offsets{};
  for (int i = 0; i < g->model.num_cables(); ++i) {
    offsets[static_cast<size_t>(i)] = now[static_cast<size_t>(i)] - data.cable.counts(i);
  }
  return offsets;
}

Result<std::array<double, kMaxAxes>> Daemon::drive_homing() {
  const Geometry* g = active_geometry();
  CommandData data(g->model);
  if (Status s = command_counts(g->model, g->model.home, g->reference_tension, data); !s.ok()) {
    return s.prepend("homing at the home pose: ");
  }
  const int m = g->model.num_cables();
  std::array<double, kMaxAxes> offsets{};
  Status failed;
  rt_paused_.store(true);
  while (in_cycle_.load()) std::this_thread::yield();
  for (int i = 0; i < m && failed.ok(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    const canopen::Drive& d = master_->drives()[k];
    const auto counts = static_cast<std::int32_t>(std::lround(data.cable.counts(i)));
    failed = master_->set_actual_counts(d.node(), counts, std::chrono::seconds(10));
    offsets[k] = static_cast<double>(d.actual_counts()) - data.cable.counts(i);
  }
  // The RT loop's first cycle after the pause takes a hold of the counts the drives read now:
  // with the new offsets, or (a drive failed: some counts changed, others not) untrusted.
  PoseTrust t;
  t.pose = g->model.home;
  if (failed.ok()) {
    t.trusted = true;
    std::lock_guard lock(mu_);
    offsets_ = offsets;
  } else {
    t.reason = "the drives' homing failed: " + failed.to_string();
    std::lock_guard lock(mu_);
    record_.reset();
  }
  t.source = "the drives' own homing";
  set_trust(t, "home --method drive");
  post_hold(t, true);
  rt_paused_.store(false);
  if (!failed.ok()) return failed.prepend("home --method drive: ");
  return offsets;
}

void Daemon::post_hold(const PoseTrust& trust, bool first) {
  auto c = std::make_unique<MotionCommand>();
  c->type = MotionCommand::Type::kReference;
  c->hold_actual = true;
  c->from_actual = true;
  c->counts_only = !trust.trusted;
  c->pose = trust.pose;
  c->geometry = active_geometry();
  {
    std::lock_guard lock(mu_);
    c->offsets = offsets_;
  }
  post(std::move(c), first);
}

std::string Daemon::motion_refusal() const {
  std::lock_guard lock(mu_);
  if (!trust_.trusted) return "the pose is not trusted (" + trust_.reason + "): cdprctl home";
  return "";
}

// The state of a robot holding still with a trusted pose, persisted (atomically) when the counts
// changed since the last write, or at a clean stop.
void Daemon::persist_hold(const RtSnapshot& s, bool clean_stop) {
  HomingRecord r;
  {
    std::lock_guard lock(mu_);
    if (!record_ || !trust_.trusted || s.mode != RtMode::kHolding) return;
    bool changed = record_->counts.size() != static_cast<size_t>(s.num_cables);
    for (int i = 0; i < s.num_cables && !changed; ++i) {
      changed = std::abs(record_->counts[static_cast<size_t>(i)] -
                         s.actual_counts[static_cast<size_t>(i)]) > 0.5;
    }
    if (!changed && !clean_stop) return;
    record_->counts.assign(s.actual_counts.begin(), s.actual_counts.begin() + s.num_cables);
    record_->pose = pose_array(s.pose());
    record_->geometry_version = active_version_;
    record_->clean_stop = clean_stop;
    record_->persisted = recording::utc_timestamp();
    r = *record_;
  }
  if (Status st = store_->save_homing(r); !st.ok()) {
    spdlog::error("homing record: {}", st.to_string());
  }
}

void Daemon::persist_stop() {
  const RtSnapshot s = rt_->snapshot();
  if (!s.settled) spdlog::warn("stopping while not holding still: the last persisted pose stays");
  if (s.settled) persist_hold(s, true);
}

// Disabled -> holding once the RT loop took the hold (every drive enabled); the persisted state
// follows the robot while it holds still.
void Daemon::follow_enable(const RtSnapshot& s) {
  const DaemonState st = state();
  if (st == DaemonState::kDisabled && s.mode != RtMode::kDisabled && s.all_enabled) {
    transition(SupervisorEvent::kEnabled, "drives enabled; holding where they are");
  }
  if (st == DaemonState::kHolding && s.settled) persist_hold(s, false);
}

Reply Daemon::cmd_enable(const json&, const PeerInfo& peer) {
  const DaemonState st = state();
  if (st != DaemonState::kDisabled) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string("enable: the drives are enabled (state ") + to_string(st) + ")");
  }
  spdlog::info("enable requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
  PoseTrust trust;
  {
    std::lock_guard lock(mu_);
    trust = trust_;
  }
  post_hold(trust);
  rt_->request_enable();
  return Reply::success({{"enabling", true}});
}

Reply Daemon::cmd_disable(const json&, const PeerInfo& peer) {
  const DaemonState st = state();
  if (st != DaemonState::kHolding || worker_running_.load()) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string("disable only while holding (state ") + to_string(st) + "): stop first");
  }
  spdlog::info("disable requested by pid {} uid {} gid {}", peer.pid, peer.uid, peer.gid);
  persist_hold(rt_->snapshot(), false);
  rt_->request_disable();
  transition(SupervisorEvent::kDisable, "drives disabled by the operator");
  return Reply::success({{"disabled", true}});
}

Reply Daemon::cmd_home(const json& args, const PeerInfo& peer) {
  const std::string method = args.value("method", std::string("reference"));
  const DaemonState st = state();
  if ((st != DaemonState::kHolding && st != DaemonState::kDisabled) || worker_running_.load() ||
      (st == DaemonState::kHolding && rt_->snapshot().mode == RtMode::kMoving)) {
    return Reply::failure(
        ControlErrorCode::kInvalidState,
        std::string("home only while holding or disabled (state ") + to_string(st) + ")");
  }
  std::array<double, kMaxAxes> offsets{};
  PoseTrust t;
  if (method == "reference") {
    auto o = reference_offsets();
    if (!o.ok()) return Reply::failure(ControlErrorCode::kInvalidState, o.status().to_string());
    offsets = *o;
    t.trusted = true;
    t.pose = active_geometry()->model.home;
    t.source = "homing (reference platform)";
  } else if (method == "absolute") {
    auto rec = store_->load_homing();
    if (!rec.ok() || static_cast<int>(rec->offsets_counts.size()) != nominal_.num_cables()) {
      return Reply::failure(
          ControlErrorCode::kInvalidState,
          "home --method absolute takes the offsets of homing.json: " +
              (rec.ok() ? std::string("wrong number of offsets") : rec.status().to_string()));
    }
    std::copy(rec->offsets_counts.begin(), rec->offsets_counts.end(), offsets.begin());
    t = verify_pose(active_geometry()->model, offsets, nullptr, nullptr);
    if (!t.trusted) {
      return Reply::failure(ControlErrorCode::kInvalidState,
                            "home --method absolute: the pose check failed: " + t.reason);
    }
    t.source = "homing (absolute encoders, pose checked)";
  } else if (method == "drive") {
    if (st != DaemonState::kHolding) {
      return Reply::failure(ControlErrorCode::kInvalidState,
                            "home --method drive: a drive homes only while enabled (CiA 402 "
                            "homing mode): cdprctl enable first");
    }
    auto o = drive_homing();
    if (!o.ok()) return Reply::failure(ControlErrorCode::kFault, o.status().to_string());
    offsets = *o;
    t.trusted = true;
    t.pose = active_geometry()->model.home;
    t.source = "homing (the drives' own homing, platform on its reference)";
  } else {
    return Reply::failure(ControlErrorCode::kBadRequest,
                          "home: method '" + method + "' (reference, drive or absolute)");
  }
  const HomingRecord r = new_record(method, offsets);
  if (Status s = store_->save_homing(r); !s.ok()) {
    return Reply::failure(ControlErrorCode::kInternal, s.to_string());
  }
  {
    std::lock_guard lock(mu_);
    offsets_ = offsets;
    record_ = r;
  }
  spdlog::info("home --method {} by pid {} uid {} gid {}", method, peer.pid, peer.uid, peer.gid);
  set_trust(t, "home");
  post_hold(t);
  transition(SupervisorEvent::kHomed, "homed (" + method + "); pose from " + t.source);
  return Reply::success({{"method", method}, {"pose", detail::pose_json(t.pose)}});
}

}  // namespace cdpr::controller
