// The fault matrix's cell (fault_matrix_test.cc): the phases, a row's fault and what it takes to
// run one cell (MatrixCell: reach the phase, inject, observe, judge, find the way back), with the
// pose files and the log capture the cells share. Included by fault_matrix_test.cc only: its
// definitions sit in that test's anonymous namespace.
#pragma once

#include <gtest/gtest.h>
#include <signal.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/controller/state_store.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/recording/recording.hpp"
#include "virtual_cell.hpp"

namespace cdpr::controller {
namespace {

using namespace std::chrono_literals;
using json = nlohmann::json;
namespace fs = std::filesystem;

const std::string kSource = CDPR_SOURCE_DIR;
constexpr int kCable = 2;              // 0-based: cable 3, node 3
constexpr int kForceNode = 9;          // config/canopen-mini.yaml
constexpr int kMeasuringPose = 3;      // the fault comes while pose 4 of 25 is measured
constexpr int kIdentifyingPoses = 10;  // the identifying phase's calibration
constexpr double kObserve = 3.0;       // s of robot time between the injection and the verdict
// The measuring cell's bound of a fault that acts in real time (FaultRow::real_time): generous
// beside the laser driver's 5 readings x 3 tries x VirtualCell::kLaserAnswerTimeoutS.
constexpr auto kRealTimeBound = std::chrono::seconds(120);

enum class Phase { kStartup, kHolding, kMoving, kMeasuring, kIdentifying, kHotSwap };
const std::vector<Phase> kPhases = {Phase::kStartup,   Phase::kHolding,     Phase::kMoving,
                                    Phase::kMeasuring, Phase::kIdentifying, Phase::kHotSwap};
const char* phase_name(Phase p) {
  switch (p) {
    case Phase::kStartup:
      return "start-up";
    case Phase::kHolding:
      return "holding";
    case Phase::kMoving:
      return "moving";
    case Phase::kMeasuring:
      return "measuring pose 4 of 25";
    case Phase::kIdentifying:
      return "identifying";
    case Phase::kHotSwap:
      return "hot swap";
  }
  return "?";
}

// What the log said (every cell's daemon logs through spdlog's default logger).
class LogCapture {
 public:
  LogCapture() {
    sink_ = std::make_shared<spdlog::sinks::ostream_sink_mt>(text_);
    logger_ = std::make_shared<spdlog::logger>("matrix", sink_);
    logger_->set_level(spdlog::level::info);
    spdlog::set_default_logger(logger_);
  }
  std::string take() {
    std::lock_guard lock(mu_);
    logger_->flush();
    std::string s = text_.str();
    text_.str("");
    return s;
  }

 private:
  std::mutex mu_;
  std::ostringstream text_;
  std::shared_ptr<spdlog::sinks::ostream_sink_mt> sink_;
  std::shared_ptr<spdlog::logger> logger_;
};

LogCapture& log_capture() {
  static LogCapture c;
  return c;
}

using Cell = testing::VirtualCell;

// One row of the matrix: how to inject the fault and how to take it away again.
struct FaultRow {
  std::string name;
  std::function<void(Cell&)> inject;
  std::function<void(Cell&)> clear;
  // Phases where it does not apply, with the reason.
  std::map<Phase, std::string> not_applicable;
  // Process-level rows run their own cells.
  std::function<std::string(Phase)> custom;
  // Injected before the phase's request (a disk full must be there before the save).
  bool inject_before_save = false;
  // Extra daemon configuration for this row's cells.
  std::string config = {};
  // The daemon runs on the network with the safety chain's objects mapped
  // (VirtualCell::write_safety_network).
  bool safety_network = false;
  // The fault acts through a thread that waits in real time (the laser driver's timeouts): the
  // measuring cell is observed until the sequence stops or moves on, bounded in real time, not in
  // robot time (which the cell steps as fast as it can), so that no race between the bound and
  // the fault's real timeouts decides the outcome.
  bool real_time = false;
};

std::string numbers_hidden(std::string s) {
  static const std::regex number(R"([-+]?[0-9]+\.[0-9]+(e[-+]?[0-9]+)?)");
  static const std::regex cell_dir(R"(/[^ ]*/cdpr-matrix-[0-9]+/(state/)?)");
  // Temporary files of cdpr/io/atomic_file.hpp: ".<name>.tmp-<pid>-<n>".
  static const std::regex temp(R"(\.tmp-[0-9]+-[0-9]+)");
  s = std::regex_replace(s, cell_dir, "");
  s = std::regex_replace(s, temp, ".tmp-*");
  s = std::regex_replace(s, number, "#");
  if (s.size() > 90) s = s.substr(0, 87) + "...";
  for (char& c : s) {
    if (c == '|' || c == '\n') c = ' ';
  }
  return s;
}

// The measuring group of the identifying phase's calibration (identification only).
const std::string kIdentifyingMeasuring =
    "{poses: " + std::to_string(kIdentifyingPoses) +
    ", laser_samples: 3, laser_interval_s: 0.002, average_cycles: 25, noise_length_m: 4e-7, "
    "noise_force_n: 0.1, noise_laser_m: 1e-4, tension_band: 1}";

// The scratch folder of this process's pose lists (removed at exit; a forked child leaves with
// _exit and keeps it).
class PoseFiles {
 public:
  PoseFiles()
      : dir_(fs::temp_directory_path() / ("cdpr-matrix-poses-" + std::to_string(::getpid()))) {
    fs::create_directories(dir_);
  }
  ~PoseFiles() {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  const fs::path& dir() const { return dir_; }

 private:
  fs::path dir_;
};
PoseFiles& pose_files() {
  static PoseFiles pf;
  return pf;
}

// `poses` written as a pose list in the scratch folder; "" when there is none or it fails.
std::string pose_file(const std::vector<Pose>& poses, const std::string& name) {
  if (poses.empty()) return "";
  recording::PoseList list;
  list.poses = poses;
  const std::string file = (pose_files().dir() / name).string();
  return recording::write_pose_list(list, file).ok() ? file : "";
}

// The first `count` of the poses cdprd designs for the cell's default measuring group on the
// nominal geometry, as a pose list: designed once per process by a dry run of a cell's daemon,
// and given to the measuring phase's calibration (all of them) and the identifying phase's (the
// first kIdentifyingPoses) as measuring.pose_file. Each `calibrate` would design them again, and
// the design took most of a cell's time; the faults act on the sequence, not on the design. ""
// when the design failed (the cells then design their own, as cdprd does).
std::string designed_pose_file(std::size_t count) {
  static const std::vector<Pose> designed = [] {
    std::vector<Pose> poses;
    const fs::path scratch = pose_files().dir() / "design";
    if (auto c = testing::VirtualCell::create(kSource, scratch); c.ok()) {
      Reply dry;
      dry.ok = false;
      if ((*c)->start_daemon().ok()) dry = (*c)->request("calibrate", {{"dry_run", true}});
      if (dry.ok) {
        for (const json& p : dry.result["poses"]) {
          Eigen::Matrix<double, 6, 1> v;
          for (int a = 0; a < 6; ++a) v(a) = p[a].get<double>();
          poses.push_back(Pose::from_vector(v));
        }
      }
    }
    std::error_code ec;
    fs::remove_all(scratch, ec);
    return poses;
  }();
  count = std::min(count, designed.size());
  return pose_file({designed.begin(), designed.begin() + static_cast<std::ptrdiff_t>(count)},
                   "designed-" + std::to_string(count) + ".csv");
}

// The nominal home alone, as a pose list: the calibration of the phases that calibrate only on
// their way back (taken, then aborted at once), which needs no designed sequence. The platform
// holds there on either geometry of the hot swap (whose way back calibrates on the one then
// active).
const std::string& home_pose_file() {
  static const std::string file = [] {
    auto nominal = config::load_robot_config(kSource + "/config/mini.yaml");
    return nominal.ok() ? pose_file({nominal->home}, "home.csv") : std::string();
  }();
  return file;
}

// `measuring` (a flow mapping) with `file` as its pose_file ("": as it is).
std::string with_pose_file(const std::string& measuring, const std::string& file) {
  if (file.empty()) return measuring;
  return measuring.substr(0, measuring.rfind('}')) + ", pose_file: " + file + "}";
}

// The state a cell is in, and the verdict.
class MatrixCell {
 public:
  MatrixCell(const FaultRow& row, Phase phase) : row_(row), phase_(phase) {
    dir_ = fs::temp_directory_path() / ("cdpr-matrix-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    (void)extra_config();  // the poses designed before the cell's log is watched (and the fork)
  }
  ~MatrixCell() {
    cell_.reset();
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  // Process level: a child process runs the cell to the phase and is SIGKILLed there (`power_loss`:
  // exactly between a save's write and its rename, through the state store's test hook); then
  // the daemon restarts on the same state directory (the virtual robot restarts with it: it lived
  // in the child) and the state directory is judged.
  std::string run_killed(bool power_loss) {
    int fds[2];
    if (::pipe(fds) != 0) return "UNSAFE: pipe";
    std::fflush(stdout);
    const pid_t pid = ::fork();
    if (pid < 0) return "UNSAFE: fork";
    if (pid == 0) {
      ::close(fds[0]);
      signal_fd() = fds[1];
      auto c = Cell::create(kSource, dir_);
      if (!c.ok()) ::_exit(2);
      cell_ = std::move(*c);
      if (phase_ == Phase::kHotSwap && !prepare_second_version().ok()) ::_exit(3);
      // While measuring, rows are appended (no rename): the child is killed mid-phase and the
      // parent tears the last row.
      const bool at_rename = power_loss && phase_ != Phase::kMeasuring;
      if (at_rename) {
        const char* target = phase_ == Phase::kStartup       ? "/homing.json"
                             : phase_ == Phase::kIdentifying ? "/report.json"
                                                             : "/active";
        std::snprintf(kill_target(), 64, "%s", target);
        io::set_before_rename_hook(&MatrixCell::stop_here);
      }
      // SIGKILL during start-up: somewhere in the boot, the identity check, the enable or the
      // homing of a first start.
      if (!at_rename && phase_ == Phase::kStartup) signal_parent();
      if (!cell_->start_daemon(extra_config()).ok()) ::_exit(4);
      if (const std::string why = reach_phase(); !why.empty()) {
        std::fprintf(stderr, "[matrix] child: %s\n", why.c_str());  // the parent says UNSAFE
        ::_exit(5);
      }
      if (!at_rename && phase_ != Phase::kStartup) signal_parent();
      for (;;) cell_->cycle();  // until killed
    }
    ::close(fds[1]);
    char x = 0;
    const bool reached = ::read(fds[0], &x, 1) == 1;
    ::close(fds[0]);
    const bool at_rename = power_loss && phase_ != Phase::kMeasuring;
    if (reached && !at_rename) ::usleep(20000);  // somewhere in the middle of it
    ::kill(pid, SIGKILL);
    int status = 0;
    ::waitpid(pid, &status, 0);
    if (!reached) {
      return "UNSAFE: the child did not reach the phase (exit " +
             std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) + ")";
    }
    std::vector<std::string> parts;
    parts.push_back(power_loss ? "killed between write and rename" : "SIGKILL");
    // A power loss while a row is appended tears it: half a row without its newline.
    const std::string rec_path =
        (dir_ / "state" / "calibrations" / "000001" / "recording.csv").string();
    if (power_loss && phase_ == Phase::kMeasuring) {
      std::ofstream torn(rec_path, std::ios::app);
      torn << "4,0.0123,0.45";
      parts.back() = "torn last row";
    }
    auto count_temps = [&] {
      std::size_t n = 0;
      if (!fs::exists(dir_ / "state")) return n;
      for (const auto& e : fs::recursive_directory_iterator(dir_ / "state")) {
        if (e.path().filename().string().find(".tmp-") != std::string::npos) ++n;
      }
      return n;
    };
    const std::size_t temps = count_temps();
    bool unsafe = false;
    auto c = Cell::create(kSource, dir_);
    if (!c.ok()) return "UNSAFE: cell: " + c.status().to_string();
    cell_ = std::move(*c);
    (void)log_capture().take();
    if (Status s = cell_->start_daemon(extra_config()); !s.ok()) {
      return "UNSAFE: " + parts.front() + "; restart: " + numbers_hidden(s.to_string());
    }
    if (temps > 0) {
      const std::size_t left = count_temps();
      const bool logged = log_capture().take().find("leftover temporary file") != std::string::npos;
      // (a SIGKILL at a wall-clock moment may or may not land while a file is written: its cells
      // name only a temporary that stays)
      if (left > 0 || !logged) {
        parts.push_back(std::to_string(left) + " of " + std::to_string(temps) +
                        " temp file left after restart" + (logged ? "" : ", not logged"));
      } else if (power_loss) {
        parts.push_back("temp file removed at restart");
      }
    }
    const int v = daemon().status()["geometry_version"].get<int>();
    auto v1 = daemon().store().load_geometry(1);
    const bool intact = v1.ok() && Cell::anchor_rms(*v1, cell_->nominal) == 0.0;
    parts.push_back("restart → holding, v" + std::to_string(v) + (intact ? "" : ", V1 CHANGED"));
    if (!intact || (v != 1 && phase_ != Phase::kHotSwap)) unsafe = true;
    if (fs::exists(rec_path)) {
      auto r = recording::read_recording(rec_path);
      if (r.ok()) {
        parts.push_back("recording " + std::to_string(r->poses.size()) + " rows readable");
      } else {
        parts.push_back("RECORDING UNREADABLE: " + numbers_hidden(r.status().to_string()));
        unsafe = true;
      }
    }
    const std::string back = recalibrates();
    if (back.rfind("NO WAY BACK", 0) == 0) unsafe = true;
    parts.push_back(back);
    std::string out;
    for (std::size_t i = 0; i < parts.size(); ++i) out += (i ? "; " : "") + parts[i];
    return (unsafe ? "UNSAFE: " : "") + out;
  }

  std::string run() {
    auto c = Cell::create(kSource, dir_);
    if (!c.ok()) return "UNSAFE: cell: " + c.status().to_string();
    cell_ = std::move(*c);
    (void)log_capture().take();
    if (phase_ == Phase::kHotSwap) {
      if (Status s = prepare_second_version(); !s.ok()) return "UNSAFE: set-up: " + s.to_string();
    }
    if (phase_ == Phase::kStartup) return run_startup();
    if (Status s = cell_->start_daemon(extra_config()); !s.ok()) {
      return "UNSAFE: set-up: " + s.to_string();
    }
    previous_version_ = daemon().status()["geometry_version"].get<int>();
    previous_yaml_ = read(daemon().store().geometry_path(previous_version_));
    if (std::string why = reach_phase(); !why.empty()) return "UNSAFE: set-up: " + why;
    if (!row_.inject_before_save || phase_ != Phase::kHotSwap) row_.inject(*cell_);
    observe();
    return verdict();
  }

 private:
  Daemon& daemon() { return *cell_->daemon; }
  static int& signal_fd() {
    static int fd = -1;
    return fd;
  }
  static char* kill_target() {
    static char target[64] = {};
    return target;
  }
  static void signal_parent() {
    const char x = 'x';
    (void)!::write(signal_fd(), &x, 1);
  }
  // The before-rename hook in the child: tell the parent, then wait for the SIGKILL.
  static void stop_here(const std::string& path) {
    const std::string target = kill_target();
    if (path.size() < target.size() ||
        path.compare(path.size() - target.size(), target.size(), target) != 0) {
      return;
    }
    signal_parent();
    for (;;) ::pause();
  }
  std::string extra_config() const {
    std::string config = row_.config;
    if (row_.safety_network && cell_ != nullptr) {
      auto network = cell_->write_safety_network();
      if (network.ok()) config += "canopen: " + *network + "\n";
    }
    const std::string measuring = Cell::Settings{}.measuring;
    if (phase_ == Phase::kIdentifying) {
      return config + "measuring: " +
             with_pose_file(kIdentifyingMeasuring, designed_pose_file(kIdentifyingPoses)) +
             "\nidentification: {diagnose: false}\n";
    }
    if (phase_ == Phase::kMeasuring) {
      const std::size_t all = std::numeric_limits<std::size_t>::max();
      return "measuring: " + with_pose_file(measuring, designed_pose_file(all)) + "\n" + config;
    }
    return "measuring: " + with_pose_file(measuring, home_pose_file()) + "\n" + config;
  }
  static std::string read(const std::string& path) {
    auto t = read_text_file(path);
    return t.ok() ? *t : std::string();
  }

  // v1: the nominal description (active), v2: the measured geometry, to hot-swap to.
  Status prepare_second_version() {
    auto store = StateStore::open((dir_ / "state").string());
    if (!store.ok()) return store.status();
    auto measured = config::load_robot_config(kSource + "/config/mini-measured.yaml");
    if (!measured.ok()) return measured.status();
    auto v1 = store->add_geometry(cell_->nominal, {{"source", "nominal"}});
    if (!v1.ok()) return v1.status();
    auto v2 = store->add_geometry(*measured, {{"source", "test"}});
    if (!v2.ok()) return v2.status();
    return store->activate(*v1, {{"why", "fault matrix"}});
  }

  std::string reach_phase() {
    switch (phase_) {
      case Phase::kStartup:
      case Phase::kHolding:
        cell_->run_until([] { return false; }, 0.5);
        return "";
      case Phase::kMoving: {
        const Pose home = cell_->nominal.home;
        const Reply r =
            cell_->request("move", {{"pose",
                                     {home.position.x() + 0.05, home.position.y() - 0.04,
                                      home.position.z() + 0.03, 0.0, 0.0, 0.0}}});
        if (!r.ok) return "move: " + r.message;
        if (!cell_->run_until([&] { return daemon().rt().snapshot().mode == RtMode::kMoving; },
                              2.0)) {
          return "the move did not start";
        }
        cell_->run_until([] { return false; }, 0.2);
        return "";
      }
      case Phase::kMeasuring:
      case Phase::kIdentifying: {
        const Reply r = cell_->request("calibrate");
        if (!r.ok) return "calibrate: " + r.message;
        const bool ok = cell_->run_until(
            [&] {
              if (phase_ == Phase::kIdentifying) {
                return daemon().state() == DaemonState::kIdentifying;
              }
              return daemon().status()["calibration"]["pose"].get<int>() >= kMeasuringPose;
            },
            300.0);
        if (!ok) {
          return std::string("did not reach ") + phase_name(phase_) + ": " +
                 daemon().status()["calibration"].dump();
        }
        return "";
      }
      case Phase::kHotSwap: {
        if (row_.inject_before_save) row_.inject(*cell_);
        const Reply r = cell_->request("geometry_rollback", {{"version", 2}});
        if (!r.ok) {
          refused_ = "rollback refused: " + r.code + "; `" + numbers_hidden(r.message) + "`";
          return "";
        }
        // Inject while the targets slew to the new geometry (or, if the slew is shorter than a
        // cycle of observation, as soon as it was taken).
        cell_->run_until(
            [&] {
              const RtSnapshot s = daemon().rt().snapshot();
              return s.mode == RtMode::kSlewing || s.geometry_version == 2;
            },
            5.0);
        return "";
      }
    }
    return "";
  }

  std::string run_startup() {
    row_.inject(*cell_);
    const Status s = cell_->start_daemon(extra_config());
    std::string out;
    if (s.ok()) {
      cell_->run_until([] { return false; }, kObserve);
      out = "started";
      const json st = daemon().status();
      if (st["state"] == "fault") {
        out = "started, then quick stop; `" + st["fault"]["message"].get<std::string>() + "`";
      }
    } else {
      // (cdprd's main logs the error it exits with; a failure after Daemon::create is also a
      // `fault` state in the log)
      out = "start-up refused; `" + numbers_hidden(s.to_string()) + "`";
    }
    if (row_.clear) row_.clear(*cell_);
    // The way back: start again once the fault is gone.
    const Status again = cell_->start_daemon(extra_config());
    if (!again.ok()) return "UNSAFE: " + out + "; restart after the fault: " + again.to_string();
    const int v = daemon().status()["geometry_version"].get<int>();
    return out + "; restart → holding, geometry v" + std::to_string(v);
  }

  std::string verdict() {
    std::vector<std::string> parts;
    bool unsafe = false;
    const json st = daemon().status();
    const RtSnapshot snap = daemon().rt().snapshot();
    const std::string log = log_capture().take();
    const std::string state = st["state"].get<std::string>();
    const json cal = st["calibration"];
    const bool sequence = phase_ == Phase::kMeasuring || phase_ == Phase::kIdentifying;

    // The reaction and its name.
    std::string named;
    if (!refused_.empty()) {
      parts.push_back(refused_ + " (" + state + ")");
    } else if (state == "fault") {
      named = st["fault"]["fault"].get<std::string>();
      const int node = st["fault"]["node"].get<int>(), cable = st["fault"]["cable"].get<int>();
      if (node > 0) named += " node " + std::to_string(node);
      if (cable > 0) named += " cable " + std::to_string(cable);
      // A quick stop, or a hold: the drives keep the pose and the latched fault lets no
      // command through (a fault found on a still robot, e.g. a stuck force reading).
      const char* reaction = snap.mode == RtMode::kDisabled  ? "quick stop"
                             : snap.mode == RtMode::kHolding ? "hold"
                                                             : "FAULT, NOT STOPPED";
      parts.push_back(std::string(reaction) + "; `" + named + "`");
      if (snap.mode != RtMode::kDisabled && snap.mode != RtMode::kHolding) unsafe = true;
      if (log.find("fault: " + st["fault"]["fault"].get<std::string>()) == std::string::npos) {
        parts.push_back("NOT IN LOG");
        unsafe = true;
      }
    } else if (sequence && !cal.is_null() &&
               (cal["outcome"] == "failed" || cal["outcome"] == "aborted")) {
      named = numbers_hidden(cal["message"].get<std::string>());
      parts.push_back(std::string(state == "holding" ? "hold" : state) + ", calibration " +
                      cal["outcome"].get<std::string>() + "; `" + named + "`");
      if (log.find("calibration " + std::to_string(cal["id"].get<int>()) + ": " +
                   cal["outcome"].get<std::string>()) == std::string::npos) {
        parts.push_back("NOT IN LOG");
        unsafe = true;
      }
    } else if (st["warning"].is_string() && state != "measuring") {
      // (while measuring, a cable can be slack for a moment before the tension regulation takes
      // it up: a passing warning, not the fault's outcome)
      const std::string w = st["warning"].get<std::string>();
      parts.push_back(state + " with a warning; `" + numbers_hidden(w) + "`");
      if (log.find("warning: " + w.substr(0, w.find(' '))) == std::string::npos) {
        parts.push_back("NOT IN LOG");
        unsafe = true;
      }
    } else {
      std::string what = "no reaction (" + state;
      if (sequence && !cal.is_null()) what += ", calibration " + cal["outcome"].get<std::string>();
      parts.push_back(what + ")");
    }

    // The recording.
    if (sequence && !cal.is_null()) {
      const std::string rec =
          daemon().store().calibration_dir(cal["id"].get<int>()) + "/recording.csv";
      auto r = recording::read_recording(rec);
      if (r.ok()) {
        parts.push_back("recording " + std::to_string(r->poses.size()) + " rows readable");
      } else {
        parts.push_back("RECORDING UNREADABLE");
        unsafe = true;
      }
    }

    // The way back, then the geometry (status, disk and RT loop agree once the robot is back).
    const std::string back = way_back(state);
    if (back.rfind("NO WAY BACK", 0) == 0) unsafe = true;
    // The geometry.
    const int in_memory = daemon().status()["geometry_version"].get<int>();
    auto on_disk = daemon().store().active_version();
    const bool intact = read(daemon().store().geometry_path(previous_version_)) == previous_yaml_;
    const int rt_version = daemon().rt().snapshot().geometry_version;
    if (phase_ == Phase::kHotSwap && in_memory == 2 && on_disk.ok() && *on_disk == 2 &&
        rt_version == 2 && intact) {
      parts.push_back("swap completed (v2)");
    } else if (in_memory == previous_version_ && on_disk.ok() && *on_disk == previous_version_ &&
               rt_version == previous_version_ && intact) {
      parts.push_back("v" + std::to_string(previous_version_) + " active, intact");
    } else {
      parts.push_back("GEOMETRY: status v" + std::to_string(in_memory) + ", disk v" +
                      (on_disk.ok() ? std::to_string(*on_disk) : std::string("?")) + ", RT v" +
                      std::to_string(rt_version) + (intact ? "" : ", FILE CHANGED"));
      unsafe = true;
    }

    parts.push_back(back);

    std::string out;
    for (std::size_t i = 0; i < parts.size(); ++i) out += (i ? "; " : "") + parts[i];
    return (unsafe ? "UNSAFE: " : "") + out;
  }

  // After the injection: while measuring, until the sequence stops or has measured two more
  // poses; while identifying, until the identification ends; then (and otherwise) kObserve.
  void observe() {
    if (phase_ == Phase::kMeasuring) {
      auto stopped_or_moved_on = [&] {
        const json c = daemon().status()["calibration"];
        return daemon().state() == DaemonState::kFault || c["outcome"] != "measuring" ||
               c["pose"].get<int>() >= kMeasuringPose + 2;
      };
      if (row_.real_time) {
        const auto end = std::chrono::steady_clock::now() + kRealTimeBound;
        while (!stopped_or_moved_on() && std::chrono::steady_clock::now() < end) cell_->cycle();
      } else {
        cell_->run_until(stopped_or_moved_on, 300.0);
      }
    } else if (phase_ == Phase::kIdentifying) {
      cell_->run_until([&] { return daemon().state() != DaemonState::kIdentifying; }, 300.0);
    }
    cell_->run_until([] { return false; }, kObserve);
    if (std::getenv("CDPR_MATRIX_DEBUG") != nullptr) {
      const auto& t = cell_->physics->state().tensions;
      std::printf(
          "[debug] true tension of cable %d: %.1f N, measured %.1f N; physics failures %llu\n",
          kCable + 1, t(kCable), daemon().rt().snapshot().tensions[kCable],
          static_cast<unsigned long long>(cell_->robot->stats().physics_failures));
    }
  }
  bool worker_busy() {
    const json c = daemon().status()["calibration"];
    return !c.is_null() && (c["outcome"] == "measuring" || c["outcome"] == "identifying");
  }
  // The way back after a fault: a new calibration is taken (then aborted) and the robot holds
  // again. A start that cannot trust its pose refuses motion naming the documented action
  // (`cdprctl home`, docs/daemon.md "Start-up, enable, homing and restart"): holding and refusing
  // with its reason is safe (issue 39), and the cell says so instead of recalibrating.
  std::string recalibrates() {
    const Reply cal = cell_->request("calibrate");
    if (!cal.ok && cal.code == "invalid_state" &&
        cal.message.find("cdprctl home") != std::string::npos) {
      return "motion refused until homed";
    }
    if (!cal.ok) return "NO WAY BACK: calibrate " + cal.code;
    (void)cell_->request("abort");
    if (!holds_settled(60.0)) return "NO WAY BACK: the restarted sequence hangs";
    return "recalibrates";
  }
  static std::string after(const std::string& how, const std::string& back) {
    return back.rfind("NO WAY BACK", 0) == 0 ? "NO WAY BACK: " + how + ", " + back.substr(13)
                                             : how + ", " + back;
  }

  bool holds_settled(double max_s) {
    return cell_->run_until(
        [&] {
          return daemon().state() == DaemonState::kHolding &&
                 daemon().rt().snapshot().mode == RtMode::kHolding &&
                 daemon().rt().snapshot().settled;
        },
        max_s);
  }

  // cdprd restarted on the same state directory, as an operator does it: when the new daemon
  // comes up in fault (a reading or an event of the fault's aftermath at its first cycles), one
  // fault reset, then it must hold. What the reset cleared is printed, not part of the cell.
  Status restart_daemon() {
    Status s = cell_->start_daemon(extra_config());
    if (s.ok() || cell_->daemon == nullptr || daemon().state() != DaemonState::kFault) return s;
    std::printf("[matrix-note] %s / %s: the restarted daemon came up in fault (%s); fault_reset\n",
                row_.name.c_str(), phase_name(phase_), s.to_string().c_str());
    (void)cell_->request("fault_reset");
    if (!cell_->run_until(
            [&] {
              const RtMode m = daemon().rt().snapshot().mode;
              return m == RtMode::kHolding || m == RtMode::kHoldingCounts;
            },
            30.0)) {
      return s;
    }
    return Status::success();
  }

  std::string way_back(const std::string& state) {
    if (row_.clear) row_.clear(*cell_);
    std::string how;
    if (state == "fault") {
      // As an operator would: wait for a running worker to end, let the cause go away, then
      // fault_reset (and once more if the first came too early).
      // The worker identifies in real time while the cell steps robot time as fast as it can
      // (slowed only in the state `identifying`; this one is `fault`): paced, robot time runs
      // with the wall clock, so the bound is real seconds. Unpaced, 300 s of robot time went by
      // in a few real seconds on a loaded machine, the worker was still identifying at the reset,
      // and its end turned the reset's outcome ("fault_reset leaves fault" or "leaves holding").
      cell_->pace(true);
      cell_->run_until([&] { return !worker_busy(); }, 300.0);
      cell_->pace(false);
      cell_->run_until([] { return false; }, 0.5);
      const Reply r = cell_->request("fault_reset");
      if (!r.ok) {
        // A refused fault reset must say why; the way back is then a restart of cdprd.
        if (Status s = restart_daemon(); !s.ok()) {
          return "NO WAY BACK: fault_reset: " + r.message + "; restart: " + s.to_string();
        }
        how = "fault_reset refused (`" + numbers_hidden(r.message) + "`); cdprd restart → holding";
        return after(how, recalibrates());
      }
      // Paced again: the reset's re-enable and settling are judged in real seconds (at robot
      // speed 5 s went by before a loaded machine's daemon settled: "fault_reset leaves holding").
      cell_->pace(true);
      bool back = holds_settled(8.0);
      if (!back && daemon().state() == DaemonState::kFault) {
        (void)cell_->request("fault_reset");
        back = holds_settled(15.0);
      }
      cell_->pace(false);
      if (back) {
        how = "fault_reset → holding";
      } else {
        // A restart of cdprd is the way back when the network itself needs configuring again.
        const std::string after = daemon().status()["state"].get<std::string>();
        if (Status s = restart_daemon(); !s.ok()) {
          return "NO WAY BACK: fault_reset, then " + after + "; restart: " + s.to_string();
        }
        how = "fault_reset leaves " + after + "; cdprd restart → holding";
      }
    } else if (state == "measuring") {
      // The sequence goes on: the operator aborts it.
      const Reply r = cell_->request("abort");
      if (!r.ok) return "NO WAY BACK: abort: " + r.message;
      if (!holds_settled(60.0)) {
        return "NO WAY BACK: abort, then " + daemon().status()["state"].get<std::string>();
      }
      how = "abort → holds";
    } else {
      // A sequence that failed or a hot swap that goes on: wait until the daemon is back.
      if (!cell_->run_until(
              [&] {
                const DaemonState s = daemon().state();
                return s == DaemonState::kHolding || s == DaemonState::kAwaitingAcceptance;
              },
              phase_ == Phase::kIdentifying ? 120.0 : 30.0)) {
        return "NO WAY BACK: stays " + daemon().status()["state"].get<std::string>();
      }
      if (daemon().state() == DaemonState::kAwaitingAcceptance) {
        const Reply r = cell_->request("reject");
        if (!r.ok) return "NO WAY BACK: reject: " + r.message;
        how = "sequence completed, rejected";
      } else {
        how = "holds";
      }
      if (!holds_settled(20.0)) {
        return "NO WAY BACK: " + how + ", then " + daemon().status()["state"].get<std::string>();
      }
    }
    // Restart the sequence (it is taken, then aborted) and move.
    return after(how, recalibrates());
  }

  const FaultRow& row_;
  Phase phase_;
  fs::path dir_;
  std::unique_ptr<Cell> cell_;
  int previous_version_ = 0;
  std::string previous_yaml_;
  std::string refused_;  // the request that starts the phase was refused (with its reason)
};
}  // namespace
}  // namespace cdpr::controller
