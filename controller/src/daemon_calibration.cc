// Daemon: the calibration run on the worker thread — the poses, the measuring sequence
// (measuring_sequence.hpp) on the RT loop, the identification and diagnosis rounds on the rows in
// memory, the report and the wait for acceptance.
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>

#include "cdpr/calibration/diagnosis.hpp"
#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/calibration_report.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/controller/measuring_sequence.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/report/report.hpp"
#include "daemon_text.hpp"

namespace cdpr::controller {
using json = nlohmann::json;
using detail::fault_text;

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
}  // namespace

struct Daemon::Identified {
  explicit Identified(CalibratedModel before) : initial(std::move(before)) {}
  CalibratedModel initial;  // the active geometry's
  MeasurementSet set;       // the rows identified (rows measured again left out)
  Result<IdentificationReport> report = Status(ErrorCode::kInternal, "not run");
  Result<Diagnosis> diagnosis = Status(ErrorCode::kInternal, "not run");
  std::vector<RemeasuredPose> remeasured;
};

// The measuring sequence's robot: the daemon's RT loop, waits abortable by the operator.
class Daemon::SequenceRobot final : public MeasuringRobot {
 public:
  SequenceRobot(Daemon& d, int id) : d_(d), id_(id) {}
  // The tension control's trims are held from the regulate step (in band) to the end of the
  // sample: they must not move the drives while a pose is averaged.
  ~SequenceRobot() override { d_.rt_->hold_tension_trims(false); }
  Status move(const Pose& pose, double pretension) override {
    d_.rt_->hold_tension_trims(false);
    return d_.move_to(pose, pretension, true);
  }
  Status settle() override { return d_.hold_still(true); }
  Status regulate(int pose_index) override { return d_.regulate_tensions(pose_index); }
  Status sample(recording::RecordedPose& row) override {
    const Status s = d_.sample_pose(row);
    d_.rt_->hold_tension_trims(false);
    return s;
  }
  double now_s() const override { return d_.now_s(); }
  void measured(const recording::RecordedPose& row, int done, int total, double elapsed_s,
                double remaining_s) override {
    const RtSnapshot r = d_.rt_->snapshot();
    json tensions = json::array();
    for (int i = 0; i < r.num_cables; ++i)
      tensions.push_back(r.tensions[static_cast<std::size_t>(i)]);
    {
      std::lock_guard lock(d_.mu_);
      d_.calibration_->pose = done;
      d_.calibration_->elapsed_s = elapsed_s;
      d_.calibration_->remaining_s = remaining_s;
    }
    d_.publish("progress",
               {{"phase", "measuring"},
                {"calibration", id_},
                {"pose", done},
                {"poses", std::max(total, done)},
                {"elapsed_s", elapsed_s},
                {"remaining_s", remaining_s},
                {"tensions", tensions},
                {"laser_m", row.lasers.size() > 0 ? json(row.lasers(0)) : json(nullptr)}});
  }

 private:
  Daemon& d_;
  int id_;
};

Result<std::vector<Pose>> Daemon::plan_poses(const std::string& poses_csv) {
  const Geometry* g = active_geometry();
  std::vector<Pose> poses;
  if (!poses_csv.empty()) {
    auto list = recording::parse_pose_list(poses_csv, "calibrate request (poses_csv)");
    if (!list.ok()) return list.status();
    poses = list->poses;
  } else if (!config_.measuring.pose_file.empty()) {
    auto list = recording::read_pose_list(config_.measuring.pose_file);
    if (!list.ok()) return list.status();
    poses = list->poses;
  } else {
    auto d = design_poses(CalibratedModel::from_robot(g->model),
                          measuring_design_options(config_, g->model));
    if (!d.ok()) return d.status();
    poses = d->poses;
  }
  // Every pose must be reachable with the tension margin; a designed pose that is not is dropped
  // (the design's own test has no margin), a pose the operator gave is refused.
  PathCheckOptions pc = path_check_options();
  std::vector<Pose> kept;
  const bool designed = poses_csv.empty() && config_.measuring.pose_file.empty();
  for (std::size_t j = 0; j < poses.size(); ++j) {
    if (Status s = check_pose(g->model, poses[j], pc); !s.ok()) {
      if (!designed || j == 0) return s.prepend("pose " + std::to_string(j) + ": ");
      spdlog::warn("designed pose {} dropped: {}", j, s.to_string());
      continue;
    }
    kept.push_back(poses[j]);
  }
  return kept;
}

// With tension control in the RT cycle (config tension_control.gain > 0) the trims already act
// during the move and the settling: the step waits until every cable is inside the controller's
// band [f_min + margin, f_max - margin], then holds the trims (released after the sample) and
// waits for stillness again. Without it, the old
// pose-by-pose regulation below takes each cable into [f_min - band, f_max + band] by trims.
Status Daemon::regulate_tensions(int pose_index) {
  if (master_->force_sensors().empty()) return Status::success();
  if (config_.tension_control.gain > 0.0) {
    const Status s = wait_rt(
        [](const RtSnapshot& r) {
          return r.tension_control.state == TensionControlState::kActive &&
                 r.tension_control.in_band;
        },
        config_.measuring.settle_timeout_s, "tension control", true);
    if (s.code() == ErrorCode::kTimeout) {
      spdlog::warn("pose {}: a tension is still outside [f_min + {:.1f}, f_max - {:.1f}] N: {}",
                   pose_index, config_.motion.tension_margin, config_.motion.tension_margin,
                   s.to_string());
    } else if (!s.ok()) {
      return s;
    }
    rt_->hold_tension_trims(true);
    return hold_still(true);
  }
  const double band = config_.measuring.tension_band;
  if (band <= 0.0) return Status::success();
  const Geometry* g = active_geometry();
  const int m = g->model.num_cables();
  std::array<double, kMaxAxes> trim{};
  // Before calibration the nominal geometry can be several mm off the robot's (MINI: 14.5 mm RMS
  // at the anchors), so at a tilted pose a cable can hang several mm slack: the steps for a slack
  // cable grow to take that up (about 20 mm in all on the MINI) and are capped, so a cable that
  // catches mid-step ends at most half-way up its band.
  constexpr int kRegulationSteps = 8;
  for (int iteration = 0; iteration < kRegulationSteps; ++iteration) {
    const std::uint64_t id = rt_->request_average();
    const int n = std::max(3, config_.measuring.average_cycles / 2);
    if (Status s = wait_rt(
            [id, n](const RtSnapshot& r) { return r.average_id == id && r.average_cycles >= n; },
            config_.measuring.settle_timeout_s, "tension reading", true);
        !s.ok()) {
      return s;
    }
    const RtSnapshot r = rt_->snapshot();
    trim = r.trim_counts;
    // Into the planned band of each cable, [f_min - band, f_max + band] (the planner itself puts
    // tensions on f_min): a cable below it is shortened, one above it lengthened, by the tension
    // missing over the cable's stiffness (mostly internal force: the platform barely moves).
    bool inside = true;
    for (int i = 0; i < m; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const CableModel& c = g->model.cables[k];
      const double lo = c.f_min - band, hi = c.f_max + band;
      const double f = r.average_tensions[k];
      const double want = std::clamp(f, lo, std::max(lo, hi));
      if (want == f) continue;
      inside = false;
      spdlog::debug(
          "pose {}: regulation {}: cable {} at {:.2f} N, band [{:.1f}, {:.1f}] N, trim {:.0f} "
          "counts",
          pose_index, iteration, i + 1, f, lo, hi, trim[k]);
      const double ea = c.ea > 0.0 ? c.ea : 1e9;
      const double length = loaded_length(
          c, std::max(0.05,
                      winch_counts_to_length<double>(
                          g->model.winches[k], r.average_counts[k] - rt_->encoder_offsets()[k])));
      // A slack cable (no tension) has an unknown slack length to take up: the step grows with
      // each iteration, up to half the band's worth of stretch.
      const double cap = 0.5 * (std::max(lo, hi) - lo) * length / ea;
      const double dl = std::clamp(
          -(want + (want > f ? 1.5 : -1.5) * band - f) * length / ea * (1 << iteration), -cap, cap);
      trim[k] += winch_counts_change<double>(g->model.winches[k], dl);
    }
    if (inside) return Status::success();
    auto c = std::make_unique<MotionCommand>();
    c->type = MotionCommand::Type::kTrim;
    c->trim = trim;
    const std::uint64_t seq = post(std::move(c));
    if (Status s = wait_rt([seq](const RtSnapshot& rs) { return rs.command_done >= seq; },
                           config_.measuring.settle_timeout_s, "tension regulation", true);
        !s.ok()) {
      return s;
    }
    if (Status s = hold_still(true); !s.ok()) return s;
  }
  spdlog::warn(
      "pose {}: a tension is still outside [f_min - {:.1f}, f_max + {:.1f}] N after {} "
      "regulation steps",
      pose_index, band, band, kRegulationSteps);
  return Status::success();
}

Status Daemon::sample_pose(recording::RecordedPose& row) {
  const std::uint64_t id = rt_->request_average();
  double laser = kNaN;
  if (io_.laser != nullptr) {
    modbus::MeasureOptions mo;
    mo.interval_s = config_.measuring.laser_interval_s;
    auto r = io_.laser->measure(config_.measuring.laser_samples, mo);
    if (!r.ok()) {
      Status s = r.status();
      return s.prepend("laser: ");
    }
    laser = r->mean_m;
  }
  const int n = config_.measuring.average_cycles;
  if (Status s = wait_rt(
          [id, n](const RtSnapshot& r) { return r.average_id == id && r.average_cycles >= n; },
          config_.measuring.settle_timeout_s + 0.01 * n, "encoder averaging", true);
      !s.ok()) {
    return s;
  }
  const RtSnapshot r = rt_->snapshot();
  if (r.fault.kind != FaultKind::kNone) {  // (e.g. a stuck force reading: the row is refused)
    return Status::error(ErrorCode::kAborted, "encoder averaging: robot fault: %s",
                         fault_text(r.fault).c_str());
  }
  if (!r.settled) return Status(ErrorCode::kAborted, "the platform moved while it was measured");

  const Geometry* g = active_geometry();
  const int m = g->model.num_cables();
  row.lengths.resize(m);
  row.tensions.resize(m);
  for (int i = 0; i < m; ++i) {
    const auto k = static_cast<std::size_t>(i);
    row.lengths(i) = winch_counts_to_length<double>(
        g->model.winches[k], r.average_counts[k] - rt_->encoder_offsets()[k]);
    row.tensions(i) = master_->force_sensors().empty() ? kNaN : r.average_tensions[k];
  }
  row.lasers = Eigen::VectorXd::Constant(static_cast<int>(g->model.lasers.size()), laser);
  row.reference = Pose{Eigen::Vector3d::Constant(kNaN), Eigen::Vector3d::Constant(kNaN)};
  return Status::success();
}

// The recording's header: noise of the averaged readings and provenance.
recording::Recording Daemon::recording_header(const Geometry& g) const {
  const MeasuringSettings& ms = config_.measuring;
  recording::Recording rec;
  rec.num_cables = g.model.num_cables();
  rec.num_lasers = std::max(static_cast<int>(g.model.lasers.size()), 1);
  rec.metadata.set(recording::key::kFormat, "cdpr-recording 1");
  rec.metadata.set(recording::key::kUnits, "SI");
  rec.metadata.set(recording::key::kRobot, g.model.name);
  rec.metadata.set(recording::key::kDate, recording::utc_timestamp());
  rec.metadata.set(recording::key::kConfigFile, store_->geometry_path(g.version));
  if (auto h = recording::file_hash(store_->geometry_path(g.version)); h.ok()) {
    rec.metadata.set(recording::key::kConfigHash, *h);
  }
  rec.metadata.set(recording::key::kSource, "robot (cdprd)");
  rec.metadata.set("daemon", kDaemonVersion);
  rec.metadata.set("geometry_version", std::to_string(g.version));
  // The noise of an average: white noise shrinks with the number of readings, the quantisation of
  // a reading does not when the noise is too small to dither it (a force node's raw unit is
  // 1/gain N, an encoder's one count), so both add up.
  const double n_avg = static_cast<double>(ms.average_cycles);
  double q_force = 0.0, q_length = winch_metres_per_count(g.model.winches[0]);
  for (const canopen::NodeConfig& n : network_.nodes) {
    for (double gain : n.force.gain)
      q_force = std::max(q_force, gain != 0.0 ? 1.0 / std::abs(gain) : 0.0);
  }
  const double sigma_length =
      std::sqrt(ms.noise_length_m * ms.noise_length_m / n_avg + q_length * q_length / 12.0);
  const double sigma_force =
      std::sqrt(ms.noise_force_n * ms.noise_force_n / n_avg + q_force * q_force / 12.0);
  rec.metadata.set_number(recording::key::kNoiseLength, sigma_length);
  rec.metadata.set_number(recording::key::kNoiseForce, sigma_force);
  rec.metadata.set_number(recording::key::kNoiseLaser,
                          ms.noise_laser_m / std::sqrt(static_cast<double>(ms.laser_samples)));
  return rec;
}

void Daemon::run_calibration(std::vector<Pose> poses, PeerInfo peer) {
  // The worker yields to the RT loop and the supervisor (it computes for seconds when it
  // identifies; on one CPU, e.g. inside user-mode-linux, it would otherwise delay the cycles).
  if (::setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), 10) != 0) {
    spdlog::debug("calibration worker: setpriority: {}", std::strerror(errno));
  }
  int id = 0;
  const Geometry* g;
  {
    std::lock_guard lock(mu_);
    id = calibration_->id;
    g = active_;
  }
  transition(SupervisorEvent::kCalibrationStarted,
             "calibration " + std::to_string(id) + ": " + std::to_string(poses.size()) + " poses");
  SequenceRobot robot(*this, id);
  MeasuringSequence seq(robot,
                        recording::RecordingAppender(store_->calibration_dir(id) + "/recording.csv",
                                                     recording_header(*g)));
  seq.add_round(std::move(poses), {});
  if (Status s = seq.run_round(); !s.ok()) return fail_calibration(s);

  // Identification and diagnosis; extra poses when the locator asks for them.
  transition(SupervisorEvent::kMeasured, "calibration " + std::to_string(id) + ": identifying");
  Identified result(CalibratedModel::from_robot(g->model));
  if (Status s = identify_rounds(id, seq, result); !s.ok()) return fail_calibration(s);

  // A fault or an abort while the worker identified ends the sequence here (the recording is
  // kept): nothing may await acceptance, let alone be accepted automatically, while the robot
  // is stopped or the operator asked to stop.
  if (const RtSnapshot r = rt_->snapshot(); r.fault.kind != FaultKind::kNone) {
    return fail_calibration(
        Status(ErrorCode::kAborted, "robot fault while identifying: " + fault_text(r.fault)));
  }
  if (abort_.load()) {
    return fail_calibration(Status(ErrorCode::kAborted, "identification: aborted by the operator"));
  }

  // The result and the gates.
  const CalibrationOutcome out = evaluate_calibration(
      g->model, result.set, *result.report, result.diagnosis.ok() ? &*result.diagnosis : nullptr,
      config_.acceptance, config_.identification.options);
  auto summary = write_report(id, *g, seq, result, out);
  if (!summary.ok()) return fail_calibration(summary.status());
  await_acceptance(id, *g, out, std::move(*summary), peer);
}

namespace {

// The poses of the gross readings of `d` to measure again (rows not measured again before);
// marks their rows left out and names them in `remeasured`.
void gross_readings_again(const Diagnosis& d, const std::vector<int>& rows,
                          const MeasuringSequence& seq, int first, std::vector<bool>& left_out,
                          std::vector<RemeasuredPose>& remeasured, std::vector<Pose>& again,
                          std::vector<double>& pretensions) {
  for (GrossReading gr : d.gross_readings) {
    const int row = rows[static_cast<std::size_t>(gr.pose)];
    gr.pose = row;  // in words, the recording's row (rows left out before shift the set's)
    if (left_out[static_cast<std::size_t>(row)]) {  // (two readings of one pose)
      for (RemeasuredPose& r : remeasured) {
        if (r.row == row) r.reading += "; " + describe(gr);
      }
      continue;
    }
    left_out[static_cast<std::size_t>(row)] = true;
    remeasured.push_back({row, first + static_cast<int>(again.size()), describe(gr)});
    again.push_back(seq.recording().poses[static_cast<std::size_t>(row)].commanded);
    pretensions.push_back(seq.pretension(row));
  }
}

}  // namespace

// Identify (and diagnose) the rows measured so far; measure again the poses of gross readings
// (`measuring.remeasure_rounds`) and the extra poses the locator asks for
// (`measuring.extra_pose_rounds`), then identify again. The rows come from the sequence's
// recording in memory.
Status Daemon::identify_rounds(int id, MeasuringSequence& seq, Identified& result) {
  const MeasuringSettings& ms = config_.measuring;
  // Rows of the recording left out of the identification (a gross reading, measured again as a
  // new row); the file keeps them as evidence.
  std::vector<bool> left_out;
  int remeasure_round = 0;
  // After the follow-up poses of a suspect beside named effects, the next diagnosis is
  // confirmatory (follow_up_groups): it decides the suspect beside the named effects. A suspect
  // held back for weak evidence beside named effects (FollowUp::held_back): the confirmatory
  // diagnosis after its follow-up poses names it only with strong evidence.
  std::vector<std::string> confirm_groups;
  std::string confirm_suspect;
  for (int round = 0;;) {
    auto all = recording::to_measurement_set(seq.recording());
    if (!all.ok()) return all.status();
    left_out.resize(static_cast<std::size_t>(all->num_poses()), false);
    std::vector<int> rows;  // the recording's row of each pose of the set
    result.set = MeasurementSet{};
    result.set.noise = all->noise;
    for (int j = 0; j < static_cast<int>(all->poses.size()); ++j) {
      if (left_out[static_cast<std::size_t>(j)]) continue;
      result.set.poses.push_back(std::move(all->poses[static_cast<std::size_t>(j)]));
      rows.push_back(j);
    }
    result.report = identify(result.initial, result.set, config_.identification.options);
    if (!result.report.ok()) return result.report.status();
    if (!config_.identification.diagnose) return Status::success();
    DiagnosisOptions dopt;
    dopt.bootstrap_samples = config_.identification.bootstrap;
    dopt.cv_folds = config_.identification.folds;
    dopt.screen.only_groups = confirm_groups;
    dopt.confirm_suspect = confirm_suspect;
    result.diagnosis =
        diagnose(result.initial, result.set, nullptr, config_.identification.options, dopt);
    if (!result.diagnosis.ok()) return result.diagnosis.status();
    if (!result.diagnosis->gross_readings.empty() && remeasure_round < ms.remeasure_rounds) {
      // A gross reading (a beam on the wrong target, a glitch): its pose is measured again and the
      // row is left out; the extra-pose rounds are not spent on it.
      ++remeasure_round;
      std::vector<Pose> again;
      std::vector<double> pretensions;
      const int first = static_cast<int>(seq.recording().poses.size());
      gross_readings_again(*result.diagnosis, rows, seq, first, left_out, result.remeasured, again,
                           pretensions);
      for (std::size_t j = result.remeasured.size() - again.size(); j < result.remeasured.size();
           ++j) {
        const RemeasuredPose& r = result.remeasured[j];
        spdlog::warn(
            "calibration {}: pose {} is measured again as pose {} ({}); its row stays in "
            "the recording and is left out of the identification",
            id, r.row + 1, r.again + 1, r.reading);
      }
      const std::string what =
          std::to_string(again.size()) + " poses measured again (gross reading)";
      CDPR_RETURN_IF_ERROR(measure_more(id, std::move(again), std::move(pretensions), what, seq));
      continue;
    }
    if (round++ >= ms.extra_pose_rounds) return Status::success();
    // Separating poses of the confounded pairs; a suspect's follow-up poses (with nothing named;
    // beside named effects when held back for weak evidence, or follow_up_beside_named).
    ExtraPoseRound more = extra_pose_round(*result.diagnosis);
    confirm_groups = std::move(more.confirm_groups);
    confirm_suspect = std::move(more.confirm_suspect);
    if (more.poses.empty()) return Status::success();
    spdlog::info("calibration {}: the mismatch locator asks for {} extra poses", id,
                 more.poses.size());
    const std::string what = std::to_string(more.poses.size()) + " extra poses";
    CDPR_RETURN_IF_ERROR(
        measure_more(id, std::move(more.poses), std::move(more.pretensions), what, seq));
  }
}

// Another round of the sequence while identifying: measuring, then identifying again.
Status Daemon::measure_more(int id, std::vector<Pose> poses, std::vector<double> pretensions,
                            const std::string& what, MeasuringSequence& seq) {
  transition(SupervisorEvent::kMorePoses, "calibration " + std::to_string(id) + ": " + what);
  {
    std::lock_guard lock(mu_);
    calibration_->poses += static_cast<int>(poses.size());
  }
  seq.add_round(std::move(poses), std::move(pretensions));
  CDPR_RETURN_IF_ERROR(seq.run_round());
  transition(SupervisorEvent::kMeasured, "calibration " + std::to_string(id) + ": identifying");
  return Status::success();
}

// The calibration report of cdpr-fit (the library) under the daemon's decision, the models
// before and after, beside the recording; returns the summary (report.json).
Result<json> Daemon::write_report(int id, const Geometry& g, const MeasuringSequence& seq,
                                  const Identified& result, const CalibrationOutcome& out) {
  const std::string dir = store_->calibration_dir(id);
  const recording::Metadata& md = seq.recording().metadata;
  CalibrationReportContext ctx;
  ctx.calibration = id;
  ctx.daemon = kDaemonVersion;
  ctx.geometry_version = g.version;
  ctx.recording = seq.path();
  ctx.robot_config = config_.robot;
  ctx.canopen_config = config_.canopen;
  ctx.laser_config = config_.laser;
  ctx.daemon_config = config_.file;
  ctx.started = md.get(recording::key::kDate);
  ctx.measuring_s = now_s() - seq.started_s();
  ctx.remeasured = result.remeasured;
  load_iso9283_measured(config_.report.iso9283_measured, ctx);
  const Diagnosis* diagnosis = result.diagnosis.ok() ? &*result.diagnosis : nullptr;
  const CalibratedModel after_model =
      diagnosis != nullptr ? diagnosis->model_after : result.report->estimate;
  report::CalibrationReportInput rin;
  rin.before = &result.initial;
  rin.after = &after_model;
  rin.identification = &*result.report;
  rin.set = &result.set;
  rin.diagnosis = diagnosis;
  rin.context.title = "cdprd calibration " + std::to_string(id);
  // Files named relative to the report's directory (the page sits beside the recording).
  rin.context.config =
      std::filesystem::path(store_->geometry_path(g.version)).lexically_relative(dir).string();
  rin.context.config_hash = md.get(recording::key::kConfigHash);
  rin.context.recording = std::filesystem::path(seq.path()).lexically_relative(dir).string();
  rin.context.identification = config_.identification.options;
  if (auto h = recording::file_hash(seq.path()); h.ok()) rin.context.recording_hash = *h;
  rin.context.bootstrap = config_.identification.bootstrap;
  rin.context.folds = config_.identification.folds;
  const report::Rendered rendered = report::render_calibration_report(rin);
  json summary = calibration_json(out, ctx);
  summary["calibration_report"] = rendered.json;
  const std::pair<std::string, std::string> files[] = {
      {"report.json", summary.dump(2, ' ', false, json::error_handler_t::replace) + "\n"},
      {"report.html", calibration_html(out, ctx, rendered.html)},
      {"report.txt", rendered.text + "\n" + iso9283_text(out, ctx)},
      {"model_before.yaml", config::save_robot_config(g.model)},
      {"model_after.yaml", config::save_robot_config(out.model)},
  };
  for (const auto& [name, text] : files) {
    CDPR_RETURN_IF_ERROR(io::write_file_atomically(dir + "/" + name, text));
  }
  return summary;
}

void Daemon::await_acceptance(int id, const Geometry& g, const CalibrationOutcome& out,
                              json summary, const PeerInfo& peer) {
  {
    std::lock_guard lock(mu_);
    calibration_->outcome = CalibrationRunOutcome::kAwaitingAcceptance;
    calibration_->gates_passed = out.gates_passed;
    calibration_->summary = std::move(summary);
    calibration_->proposed = std::make_shared<RobotModel>(out.model);
    calibration_->before_version = g.version;
    calibration_->message = out.verdict;
  }
  transition(
      SupervisorEvent::kIdentified,
      "calibration " + std::to_string(id) + ": " + out.verdict +
          (out.gates_passed ? "; every gate passed" : "; gates failed: " + out.failed_gates));
  worker_running_ = false;  // (also when the state refused the event: see fail_calibration)
  publish("calibration", {{"calibration", id},
                          {"version", nullptr},
                          {"outcome", to_string(CalibrationRunOutcome::kAwaitingAcceptance)},
                          {"gates_passed", out.gates_passed},
                          {"message", out.verdict}});
  if (config_.acceptance.mode == AcceptanceMode::kAuto && out.gates_passed) {
    const Reply r = cmd_accept(json::object(), peer);
    if (!r.ok) spdlog::error("automatic acceptance failed: {}", r.message);
  }
}

void Daemon::finish_calibration(CalibrationRunOutcome outcome, const std::string& message) {
  int id = 0;
  {
    std::lock_guard lock(mu_);
    if (calibration_) {
      calibration_->outcome = outcome;
      calibration_->message = message;
      id = calibration_->id;
    }
  }
  spdlog::info("calibration {}: {}: {}", id, to_string(outcome), message);
  publish("calibration", {{"version", nullptr},
                          {"calibration", id},
                          {"outcome", to_string(outcome)},
                          {"gates_passed", false},
                          {"message", message}});
}

void Daemon::fail_calibration(const Status& s) {
  const bool aborted = s.code() == ErrorCode::kAborted && abort_.load() &&
                       rt_->snapshot().fault.kind == FaultKind::kNone;
  finish_calibration(aborted ? CalibrationRunOutcome::kAborted : CalibrationRunOutcome::kFailed,
                     s.to_string());
  // The worker's part is over before the state says so (the row's action): a request that follows
  // the state change at once (a script's next `calibrate`) must not find the worker running. In
  // fault the state stays; the worker is released all the same.
  if (rt_->snapshot().fault.kind == FaultKind::kNone) {
    transition(SupervisorEvent::kCalibrationEnded, std::string("calibration ") +
                                                       (aborted ? "aborted" : "failed") +
                                                       "; the active geometry is unchanged");
  }
  worker_running_ = false;
}

}  // namespace cdpr::controller
