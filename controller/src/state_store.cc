#include "cdpr/controller/state_store.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/append_only_file.hpp"
#include "cdpr/io/atomic_file.hpp"
#include "cdpr/io/bounded_read.hpp"
#include "cdpr/recording/recording.hpp"

namespace cdpr::controller {
namespace fs = std::filesystem;

namespace {

Status errno_status(const char* what, const std::string& path) {
  return Status::error(ErrorCode::kIoError, "%s %s: %s", what, path.c_str(), std::strerror(errno));
}

std::string numbered(int n) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%06d", n);
  return buf;
}

std::vector<int> numbers_in(const std::string& dir, std::string_view suffix) {
  std::vector<int> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    std::string name = e.path().filename().string();
    if (!suffix.empty()) {
      if (name.size() <= suffix.size() ||
          name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0) {
        continue;
      }
      name.resize(name.size() - suffix.size());
    }
    if (name.size() != 6 || !std::all_of(name.begin(), name.end(), ::isdigit)) continue;
    out.push_back(std::stoi(name));
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace

Result<std::string> read_text_file(const std::string& path) {
  return io::read_regular_file(path, kMaxStateFileBytes);
}

Result<StateStore> StateStore::open(const std::string& directory) {
  std::error_code ec;
  for (const char* sub : {"", "geometry", "calibrations"}) {
    const fs::path p = fs::path(directory) / sub;
    fs::create_directories(p, ec);
    if (ec) {
      return Status::error(ErrorCode::kIoError, "state directory %s: %s", p.string().c_str(),
                           ec.message().c_str());
    }
  }
  if (::access(directory.c_str(), W_OK) != 0) {
    return errno_status("state directory is not writable:", directory);
  }
  return StateStore(directory);
}

Result<std::vector<std::string>> StateStore::remove_leftover_temporaries() const {
  std::vector<std::string> removed;
  std::error_code ec;
  // (a recursive_directory_iterator does not follow symbolic links to folders by default)
  fs::recursive_directory_iterator it(dir_, ec), end;
  if (ec) {
    return Status::error(ErrorCode::kIoError, "state directory %s: %s", dir_.c_str(),
                         ec.message().c_str());
  }
  for (; it != end; it.increment(ec)) {
    if (ec) {
      return Status::error(ErrorCode::kIoError, "state directory %s: %s", dir_.c_str(),
                           ec.message().c_str());
    }
    int pid = 0;
    if (!io::is_temporary_name(it->path().filename().string(), &pid)) continue;
    if (!fs::is_regular_file(it->symlink_status())) continue;
    if (pid != ::getpid() && ::kill(pid, 0) == 0) continue;  // a writer that is still running
    const std::string rel = fs::relative(it->path(), dir_).string();
    if (!fs::remove(it->path(), ec) && ec) {
      return Status::error(ErrorCode::kIoError, "cannot remove %s/%s: %s", dir_.c_str(),
                           rel.c_str(), ec.message().c_str());
    }
    removed.push_back(rel);
  }
  std::sort(removed.begin(), removed.end());
  return removed;
}

std::string StateStore::geometry_path(int version) const {
  return (fs::path(dir_) / "geometry" / (numbered(version) + ".yaml")).string();
}

std::vector<int> StateStore::geometry_versions() const {
  return numbers_in((fs::path(dir_) / "geometry").string(), ".yaml");
}

Result<int> StateStore::add_geometry(const RobotModel& model, nlohmann::json meta) {
  const std::vector<int> v = geometry_versions();
  const int version = v.empty() ? 1 : v.back() + 1;
  meta["version"] = version;
  meta["created"] = recording::utc_timestamp();
  const std::string yaml = "# cdprd geometry version " + std::to_string(version) + " (" +
                           meta.value("source", std::string("?")) + ")\n" +
                           config::save_robot_config(model);
  // The metadata first: a version exists once its YAML does.
  const std::string meta_path =
      (fs::path(dir_) / "geometry" / (numbered(version) + ".json")).string();
  if (Status s = io::write_file_atomically(
          meta_path, meta.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
      !s.ok())
    return s;
  if (Status s = io::write_file_atomically(geometry_path(version), yaml); !s.ok()) return s;
  return version;
}

Result<RobotModel> StateStore::load_geometry(int version) const {
  const std::string path = geometry_path(version);
  if (!fs::exists(path)) {
    return Status::error(ErrorCode::kNotFound, "geometry version %d does not exist (%s)", version,
                         path.c_str());
  }
  return config::load_robot_config(path);
}

Result<nlohmann::json> StateStore::geometry_meta(int version) const {
  const std::string path = (fs::path(dir_) / "geometry" / (numbered(version) + ".json")).string();
  auto text = read_text_file(path);
  if (!text.ok()) return text.status();
  nlohmann::json j = nlohmann::json::parse(*text, nullptr, false);
  if (j.is_discarded()) return Status::error(ErrorCode::kParseError, "%s: not JSON", path.c_str());
  return j;
}

Result<int> StateStore::active_version() const {
  const std::string path = (fs::path(dir_) / "active").string();
  if (!fs::exists(path)) return Status(ErrorCode::kNotFound, "no active geometry yet");
  auto text = read_text_file(path);
  if (!text.ok()) return text.status();
  int v = 0;
  if (std::sscanf(text->c_str(), "%d", &v) != 1 || v < 1) {
    return Status::error(ErrorCode::kParseError, "%s: expected a version number", path.c_str());
  }
  if (!fs::exists(geometry_path(v))) {
    return Status::error(ErrorCode::kNotFound, "%s names version %d, which does not exist",
                         path.c_str(), v);
  }
  return v;
}

Status StateStore::activate(int version, nlohmann::json why) {
  if (!fs::exists(geometry_path(version))) {
    return Status::error(ErrorCode::kNotFound, "geometry version %d does not exist", version);
  }
  if (Status s = io::write_file_atomically((fs::path(dir_) / "active").string(),
                                           std::to_string(version) + "\n");
      !s.ok()) {
    return s;
  }
  why["version"] = version;
  why["time"] = recording::utc_timestamp();
  io::AppendOnlyFile log;
  if (Status s = log.open((fs::path(dir_) / "history.jsonl").string(), false); !s.ok()) return s;
  return log.append(why.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

Result<std::vector<nlohmann::json>> StateStore::history() const {
  std::vector<nlohmann::json> out;
  const std::string path = (fs::path(dir_) / "history.jsonl").string();
  if (!fs::exists(path)) return out;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    nlohmann::json j = nlohmann::json::parse(line, nullptr, false);
    if (!j.is_discarded()) out.push_back(std::move(j));  // a torn last line is skipped
  }
  return out;
}

Status StateStore::save_homing(const HomingRecord& r) {
  nlohmann::json drives = nlohmann::json::array();
  for (const DriveIdentity& d : r.drives) {
    drives.push_back(
        {{"node", d.node}, {"vendor", d.vendor}, {"product", d.product}, {"serial", d.serial}});
  }
  nlohmann::json j = {{"format", HomingRecord::kFormat},
                      {"method", r.method},
                      {"time", r.time},
                      {"geometry_version", r.geometry_version},
                      {"offsets_counts", r.offsets_counts},
                      {"drives", drives}};
  if (!r.counts.empty()) {
    j["last"] = {{"counts", r.counts},
                 {"pose", r.pose},
                 {"clean_stop", r.clean_stop},
                 {"time", r.persisted}};
  }
  return io::write_file_atomically(
      (fs::path(dir_) / "homing.json").string(),
      j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
}

namespace {

Status numbers(const nlohmann::json& j, const char* key, const std::string& path,
               std::vector<double>& out) {
  if (!j.contains(key) || !j[key].is_array()) {
    return Status::error(ErrorCode::kParseError, "%s: %s: expected an array of numbers",
                         path.c_str(), key);
  }
  for (const auto& v : j[key]) {
    if (!v.is_number() || !std::isfinite(v.get<double>())) {
      return Status::error(ErrorCode::kParseError, "%s: %s: expected finite numbers", path.c_str(),
                           key);
    }
    out.push_back(v.get<double>());
  }
  return Status::success();
}

Status read_drives(const nlohmann::json& j, const std::string& path, HomingRecord& r) {
  if (!j.contains("drives") || !j["drives"].is_array()) {
    return Status::error(ErrorCode::kParseError, "%s: drives: expected an array", path.c_str());
  }
  for (const auto& d : j["drives"]) {
    DriveIdentity id;
    const auto u32 = [&](const char* k, std::uint32_t& out) {
      if (!d.is_object() || !d.contains(k) || !d[k].is_number_unsigned()) return false;
      out = static_cast<std::uint32_t>(d[k].get<std::uint64_t>());
      return true;
    };
    std::uint32_t node = 0;
    if (!u32("node", node) || !u32("vendor", id.vendor) || !u32("product", id.product) ||
        !u32("serial", id.serial)) {
      return Status::error(ErrorCode::kParseError,
                           "%s: drives: each is {node, vendor, product, serial} (unsigned)",
                           path.c_str());
    }
    id.node = static_cast<int>(node);
    r.drives.push_back(id);
  }
  return Status::success();
}

}  // namespace

Result<HomingRecord> StateStore::load_homing() const {
  const std::string path = (fs::path(dir_) / "homing.json").string();
  if (!fs::exists(path)) return Status(ErrorCode::kNotFound, "not homed (no homing.json)");
  auto text = read_text_file(path);
  if (!text.ok()) return text.status();
  const nlohmann::json j = nlohmann::json::parse(*text, nullptr, false);
  if (j.is_discarded() || !j.is_object()) {
    return Status::error(ErrorCode::kParseError, "%s: not a JSON object", path.c_str());
  }
  HomingRecord r;
  CDPR_RETURN_IF_ERROR(numbers(j, "offsets_counts", path, r.offsets_counts));
  r.time = j.value("time", std::string());
  if (!j.contains("format")) {  // format 1: {"offsets_counts", "how", "time"}
    r.format = 1;
    r.method = j.value("how", std::string());
    return r;
  }
  if (!j["format"].is_number_integer() || j["format"].get<int>() != HomingRecord::kFormat) {
    return Status::error(ErrorCode::kParseError, "%s: format: %d is the one this cdprd reads",
                         path.c_str(), HomingRecord::kFormat);
  }
  r.method = j.value("method", std::string());
  if (!j.contains("geometry_version") || !j["geometry_version"].is_number_integer()) {
    return Status::error(ErrorCode::kParseError, "%s: geometry_version: expected an integer",
                         path.c_str());
  }
  r.geometry_version = j["geometry_version"].get<int>();
  CDPR_RETURN_IF_ERROR(read_drives(j, path, r));
  if (j.contains("last")) {
    const nlohmann::json& last = j["last"];
    std::vector<double> pose;
    CDPR_RETURN_IF_ERROR(numbers(last, "counts", path, r.counts));
    CDPR_RETURN_IF_ERROR(numbers(last, "pose", path, pose));
    if (pose.size() != 6) {
      return Status::error(ErrorCode::kParseError, "%s: last.pose: expected 6 numbers",
                           path.c_str());
    }
    std::copy(pose.begin(), pose.end(), r.pose.begin());
    r.clean_stop = last.value("clean_stop", false);
    r.persisted = last.value("time", std::string());
  }
  return r;
}

Result<int> StateStore::new_calibration() {
  const std::vector<int> v = calibrations();
  const int id = v.empty() ? 1 : v.back() + 1;
  std::error_code ec;
  fs::create_directories(calibration_dir(id), ec);
  if (ec) {
    return Status::error(ErrorCode::kIoError, "cannot create %s: %s", calibration_dir(id).c_str(),
                         ec.message().c_str());
  }
  return id;
}

std::string StateStore::calibration_dir(int id) const {
  return (fs::path(dir_) / "calibrations" / numbered(id)).string();
}

std::vector<int> StateStore::calibrations() const {
  return numbers_in((fs::path(dir_) / "calibrations").string(), "");
}

}  // namespace cdpr::controller
