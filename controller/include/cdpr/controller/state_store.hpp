// The daemon's state directory (docs/daemon.md): versioned geometries, the active one, the
// encoder offsets of the last homing, and one folder per calibration (recording, reports, models
// before and after, what was decided). Files that matter are written atomically (temporary file
// in the same directory, fsync, rename, fsync of the directory), so a crash or a power loss at
// any moment leaves either the old file or the new one: cdpr/io/atomic_file.hpp); the recording is
// appended row by row with an fsync per row.
//
//   state/
//     active                     "<version>\n": the geometry the daemon commands with
//     history.jsonl              one line per activation (time, version, why, who)
//     homing.json                the homing record: encoder offsets (counts), what they belong to
//                                (drive identities, geometry version, method, time) and the
//                                counts and pose last persisted while holding still
//     geometry/000001.yaml       robot description of version 1 (docs/config.md)
//     geometry/000001.json       its metadata (created, source, calibration, parent)
//     calibrations/000001/       recording.csv, report.json, report.html, model_before.yaml,
//                                model_after.yaml, calibration.json
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

// A file of the state directory (geometry, reports served to clients, recordings): a regular
// file of at most kMaxStateFileBytes (io::read_regular_file), else an error naming it.
inline constexpr std::size_t kMaxStateFileBytes = 256u << 20;
Result<std::string> read_text_file(const std::string& path);

// One drive as identified at boot (object 0x1018).
struct DriveIdentity {
  int node = 0;
  std::uint32_t vendor = 0, product = 0, serial = 0;
  bool operator==(const DriveIdentity&) const = default;
};

// homing.json (docs/daemon.md "The homing record"). Format 2; format 1 (offsets, "how" and time
// only, written before the record named what it belongs to) is read with `format` = 1 and the
// fields it lacks left empty, so the daemon can refuse it with its reason.
struct HomingRecord {
  static constexpr int kFormat = 2;
  int format = kFormat;
  std::string method;  // reference | drive | absolute (format 1: its "how")
  std::string time;    // UTC, when homed
  int geometry_version = 0;
  std::vector<double> offsets_counts;  // per cable
  std::vector<DriveIdentity> drives;   // per cable, in cable order
  // The last persisted state (a clean stop, or holding still): each drive's counts and the pose
  // the daemon held there (x, y, z in m; roll, pitch, yaw in rad). Empty counts: none yet.
  std::vector<double> counts;
  std::array<double, 6> pose{};
  bool clean_stop = false;  // written by an orderly stop (else while holding still)
  std::string persisted;    // UTC, when counts and pose were written
};

class StateStore {
 public:
  // Opens (creating the folders of) a state directory.
  static Result<StateStore> open(const std::string& directory);

  const std::string& directory() const { return dir_; }

  // Geometry versions: 1, 2, ... Each is written once and never changed.
  Result<int> add_geometry(const RobotModel& model, nlohmann::json meta);
  Result<RobotModel> load_geometry(int version) const;
  Result<nlohmann::json> geometry_meta(int version) const;
  std::vector<int> geometry_versions() const;
  std::string geometry_path(int version) const;

  // The active version (kNotFound when none was ever activated).
  Result<int> active_version() const;
  // Makes `version` active: writes `active` atomically, then appends to history.jsonl.
  Status activate(int version, nlohmann::json why);
  Result<std::vector<nlohmann::json>> history() const;

  // The homing record, written atomically; kNotFound when there is none, kParseError naming
  // the file and field when it cannot be read.
  Status save_homing(const HomingRecord& record);
  Result<HomingRecord> load_homing() const;

  // Removes the temporary files of cdpr/io/atomic_file.hpp that a crash or a power loss between
  // a write and its rename left in the state directory (its folders, no symbolic link followed;
  // only regular files with exactly those names; not those of a process still running, other
  // than this one). For start-up, before anything is written. Returns what was removed (paths
  // relative to the state directory), or what could not be removed as an error naming it.
  Result<std::vector<std::string>> remove_leftover_temporaries() const;

  // Calibrations: 1, 2, ...
  Result<int> new_calibration();
  std::string calibration_dir(int id) const;
  std::vector<int> calibrations() const;

 private:
  explicit StateStore(std::string dir) : dir_(std::move(dir)) {}
  std::string dir_;
};

}  // namespace cdpr::controller
