#include "cdpr/controller/config_check.hpp"

#include <grp.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <string_view>

#include "cdpr/calibration/winch.hpp"
#include "cdpr/canopen/master.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/canopen_robot_io.hpp"
#include "cdpr/controller/safety_config.hpp"
#include "cdpr/modbus/laser_sensor.hpp"

namespace cdpr::controller {
namespace {

using Errors = std::vector<Status>;
namespace fs = std::filesystem;

template <typename... Args>
void add(Errors& out, const char* fmt, Args... args) {
  out.push_back(Status::error(ErrorCode::kInvalidArgument, fmt, args...));
}

std::vector<const canopen::NodeConfig*> nodes_of(const canopen::MasterConfig& net,
                                                 canopen::NodeKind kind) {
  std::vector<const canopen::NodeConfig*> out;
  for (const canopen::NodeConfig& n : net.nodes) {
    if (n.kind == kind) out.push_back(&n);
  }
  return out;
}

// A field of the network file: its own place when the file gave it, else the file and the node.
std::string net_field(const LoadedFiles& f, const std::string& where, const canopen::NodeConfig& n,
                      const char* key) {
  if (!where.empty()) return where;
  return f.daemon->canopen + ": nodes: node " + std::to_string(n.id) + " (" + n.name + ")." + key +
         " (not given)";
}

// One cia402 drive per cable, one force channel per cable (CanopenRobotIO::fits).
void check_cables(const LoadedFiles& f, Errors& out) {
  const int m = f.robot->num_cables();
  const auto drives = nodes_of(*f.network, canopen::NodeKind::kCia402Drive);
  if (static_cast<int>(drives.size()) != m) {
    add(out, "%s: nodes: %d cia402 drives, but the robot %s has %d cables",
        f.daemon->canopen.c_str(), static_cast<int>(drives.size()), f.daemon->robot.c_str(), m);
  }
  for (const canopen::NodeConfig* n : nodes_of(*f.network, canopen::NodeKind::kForceSensor)) {
    if (static_cast<int>(n->force.gain.size()) != m) {
      add(out, "%s: nodes: node %u (%s) has %d force channels, but the robot %s has %d cables",
          f.daemon->canopen.c_str(), unsigned{n->id}, n->name.c_str(),
          static_cast<int>(n->force.gain.size()), f.daemon->robot.c_str(), m);
    }
  }
}

// A value of the network that disagrees with the robot file for some cables. The drives or
// channels that share one (a profile's) are one error that lists the cables.
struct Mismatch {
  std::string field;
  double net = 0.0, robot = 0.0;
  std::string cables;  // "1, 2, 3"
};

void note(std::vector<Mismatch>& found, const std::string& field, double net, double robot,
          std::size_t cable) {
  const auto same = std::find_if(found.begin(), found.end(), [&](const Mismatch& m) {
    return m.field == field && m.net == net && m.robot == robot;
  });
  if (same != found.end()) {
    same->cables += ", " + std::to_string(cable + 1);
  } else {
    found.push_back({field, net, robot, std::to_string(cable + 1)});
  }
}

// The k-th drive drives cable k: its counts per metre are the robot file's winch's.
void check_counts(const LoadedFiles& f, Errors& out) {
  std::vector<Mismatch> found;
  const auto drives = nodes_of(*f.network, canopen::NodeKind::kCia402Drive);
  for (std::size_t k = 0; k < drives.size() && k < f.robot->winches.size(); ++k) {
    const canopen::NodeConfig& n = *drives[k];
    const double robot = 1.0 / winch_metres_per_count(f.robot->winches[k]);
    const double net = std::abs(n.drive.counts_per_unit);
    if (std::abs(net - robot) <= 1e-6 * robot) continue;
    note(found, net_field(f, n.drive.counts_per_unit_where, n, "counts_per_unit"), net, robot, k);
  }
  for (const Mismatch& m : found) {
    add(out,
        "%s: %.9g counts per metre, but %s gives %.9g for cable %s (winch: counts_per_rev x "
        "gear_ratio / length per drum revolution): write %.10g",
        m.field.c_str(), m.net, f.daemon->robot.c_str(), m.robot, m.cables.c_str(), m.robot);
  }
}

// Channel k of the force node measures cable k: its gain and offset are the robot file's.
void check_force(const LoadedFiles& f, Errors& out) {
  for (const canopen::NodeConfig* n : nodes_of(*f.network, canopen::NodeKind::kForceSensor)) {
    const canopen::ForceConfig& fc = n->force;
    for (const char* key : {"gain", "offset"}) {
      const bool gain = std::string_view(key) == "gain";
      const std::vector<double>& values = gain ? fc.gain : fc.offset;
      std::vector<Mismatch> found;
      for (std::size_t k = 0; k < values.size() && k < f.robot->force_sensors.size(); ++k) {
        const ForceSensorModel& s = f.robot->force_sensors[k];
        const double robot = gain ? s.gain : s.offset;
        if (std::abs(values[k] - robot) <= 1e-9 * std::max(1.0, std::abs(robot))) continue;
        note(found, net_field(f, gain ? fc.gain_where : fc.offset_where, *n, key), values[k], robot,
             k);
      }
      for (const Mismatch& m : found) {
        add(out, "%s: %s %g, but %s has force_sensor.%s %g for cable %s", m.field.c_str(), key,
            m.net, f.daemon->robot.c_str(), key, m.robot, m.cables.c_str());
      }
    }
  }
}

// The cycle the daemon runs (its realtime.sync_period_ms or the network's) must fit on the bus.
void check_bus_load(const LoadedFiles& f, Errors& out) {
  canopen::MasterConfig net = *f.network;
  const bool own = f.daemon->realtime.sync_period.count() > 0;
  if (own) net.sync_period = f.daemon->realtime.sync_period;
  const canopen::BusLoad load = canopen::bus_load(net);
  if (load.load <= 1.0) return;
  const std::string field = own ? f.daemon->file + ": realtime.sync_period_ms"
                                : f.daemon->canopen + ": master.sync_period_ms";
  add(out,
      "%s: a SYNC period of %g ms carries %.0f bits of PDOs and heartbeats, %.0f %% of the bus "
      "at %.0f bit/s (%.3g ms needed)",
      field.c_str(), load.cycle_s * 1e3, load.bits_per_cycle, 100.0 * load.load, net.bitrate,
      load.busy_s * 1e3);
}

// The planner's and the design's tension margins need room inside every cable's [f_min, f_max].
void check_tensions(const LoadedFiles& f, Errors& out) {
  const DaemonConfig& d = *f.daemon;
  const struct {
    double margin;
    const char* field;
  } margins[] = {{d.motion.tension_margin, "motion.tension_margin"},
                 {d.measuring.design_tension_margin, "measuring.design_tension_margin"}};
  for (std::size_t i = 0; i < f.robot->cables.size(); ++i) {
    const CableModel& c = f.robot->cables[i];
    for (const auto& m : margins) {
      if (2.0 * m.margin < c.f_max - c.f_min) continue;
      add(out, "%s: %s: %g N on both sides leaves nothing of cable %zu's [%g, %g] N (%s)",
          d.file.c_str(), m.field, m.margin, i + 1, c.f_min, c.f_max, d.robot.c_str());
    }
    const double over = d.tension_watch.overload_above;
    if (over > 0.0 && over <= c.f_min) {
      add(out, "%s: tension_watch.overload_above: %g N is at or below cable %zu's f_min %g N (%s)",
          d.file.c_str(), over, i + 1, c.f_min, d.robot.c_str());
    }
    if (d.tension_watch.slack_below >= c.f_max) {
      add(out, "%s: tension_watch.slack_below: %g N is at or above cable %zu's f_max %g N (%s)",
          d.file.c_str(), d.tension_watch.slack_below, i + 1, c.f_max, d.robot.c_str());
    }
  }
}

// A directory the daemon writes into: it exists and is writable, or its nearest existing parent is
// (the daemon creates the rest). "" when fine, else why not.
std::string writable_dir(const std::string& dir) {
  std::error_code ec;
  fs::path p = dir.empty() ? fs::path(".") : fs::path(dir);
  if (!fs::exists(p, ec)) {
    while (!p.empty() && p != p.root_path() && !fs::exists(p, ec)) p = p.parent_path();
    if (p.empty()) p = ".";
  }
  if (!fs::is_directory(p, ec)) return "'" + p.string() + "' is not a directory";
  if (::access(p.c_str(), W_OK | X_OK) != 0) {
    return "'" + p.string() + "' is not writable for this user (" + std::strerror(errno) + ")";
  }
  return "";
}

void check_control(const LoadedFiles& f, Errors& out) {
  const ControlSettings& c = f.daemon->control;
  const std::string dir = fs::path(c.socket).parent_path().string();
  if (const std::string why = writable_dir(dir); !why.empty()) {
    add(out, "%s: control.socket: the directory '%s' cannot be made: %s", f.daemon->file.c_str(),
        dir.c_str(), why.c_str());
  }
  // The server binds PATH.tmp<pid> first, then renames it (ControlServer::start).
  const std::size_t room = sizeof(sockaddr_un{}.sun_path) - 1 - 12;
  if (c.socket.size() > room) {
    add(out, "%s: control.socket: the path has %zu bytes, at most %zu fit a socket address",
        f.daemon->file.c_str(), c.socket.size(), room);
  }
  if (!c.group.empty()) {
    group grp{}, *found = nullptr;
    std::vector<char> buf(1 << 16);
    (void)::getgrnam_r(c.group.c_str(), &grp, buf.data(), buf.size(), &found);
    if (found == nullptr) {
      add(out, "%s: control.group: no group '%s' on this host (getent group %s)",
          f.daemon->file.c_str(), c.group.c_str(), c.group.c_str());
    }
  }
}

void check_state_directory(const LoadedFiles& f, Errors& out) {
  const std::string& dir = f.daemon->state_directory;
  if (const std::string why = writable_dir(dir); !why.empty()) {
    add(out, "%s: state_directory: '%s': %s", f.daemon->file.c_str(), dir.c_str(), why.c_str());
  }
}

void check_safety(const LoadedFiles& f, Errors& out) {
  const SafetySettings& s = f.daemon->safety;
  if (Status st = check_safety_io(s, *f.network); !st.ok()) out.push_back(st);
  if (Status st = check_safety_limits(s, f.robot->num_cables()); !st.ok()) out.push_back(st);
}

struct FileCheck {
  const char* what;
  bool needs_files;  // robot and network loaded
  void (*run)(const LoadedFiles&, Errors&);
};
// Adding a check: one entry here and a line in docs/daemon.md ("Checked before the bus").
constexpr FileCheck kChecks[] = {
    {"one drive and one force channel per cable", true, check_cables},
    {"counts per metre: robot file and network agree", true, check_counts},
    {"force-sensor gains and offsets: robot file and network agree", true, check_force},
    {"the SYNC period fits on the bus", true, check_bus_load},
    {"tension settings inside [f_min, f_max]", true, check_tensions},
    {"control socket directory and group", false, check_control},
    {"state directory", false, check_state_directory},
    {"safety chain: e-stop sources and brake outputs on the network, limits per cable", true,
     check_safety},
};

}  // namespace

std::vector<Status> check_loaded_files(const LoadedFiles& files) {
  Errors out;
  if (files.daemon == nullptr) return out;
  for (const FileCheck& c : kChecks) {
    if (c.needs_files && (files.robot == nullptr || files.network == nullptr)) continue;
    c.run(files, out);
  }
  return out;
}

std::vector<Status> check_daemon_files(const std::string& path) {
  auto daemon = load_daemon_config(path);
  if (!daemon.ok()) return {daemon.status()};
  Errors out;
  LoadedFiles files;
  files.daemon = &*daemon;
  auto robot = config::check_robot_config(daemon->robot);
  if (robot.ok()) {
    files.robot = &robot->model;
    out.insert(out.end(), robot->findings.begin(), robot->findings.end());
  } else {
    out.push_back(robot.status());
  }
  auto network = canopen::load_config(daemon->canopen);
  if (network.ok()) {
    files.network = &*network;
  } else {
    out.push_back(network.status());
  }
  if (!daemon->laser.empty()) {
    if (auto laser = modbus::load_laser_config(daemon->laser); !laser.ok()) {
      out.push_back(laser.status());
    }
  }
  for (Status& s : check_loaded_files(files)) out.push_back(std::move(s));
  return out;
}

}  // namespace cdpr::controller
