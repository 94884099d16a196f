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
//     homing.json                encoder offsets (counts) of the last homing
//     geometry/000001.yaml       robot description of version 1 (docs/config.md)
//     geometry/000001.json       its metadata (created, source, calibration, parent)
//     calibrations/000001/       recording.csv, report.json, report.html, model_before.yaml,
//                                model_after.yaml, calibration.json
#pragma once

#include <cstddef>
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

  // Encoder offsets of the last homing (counts per cable).
  Status save_offsets(const std::vector<double>& offsets, std::string_view how);
  Result<std::vector<double>> load_offsets() const;

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
