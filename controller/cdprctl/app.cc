#include "app.hpp"

#include <fcntl.h>
#include <grp.h>
#include <sys/stat.h>
#include <unistd.h>

// GCC 12 reports a false "potential null pointer dereference" in std::string code that CLI11's
// CLI::detail::split inlines at -O2; the warning is not about this file's code.
#pragma GCC diagnostic ignored "-Wnull-dereference"
#include <CLI/CLI.hpp>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <thread>

#include "cdpr/controller/control_client.hpp"
#include "cdpr/controller/control_protocol.hpp"
#include "cdpr/io/bounded_read.hpp"
#include "cdpr/version.hpp"
#include "render.hpp"

namespace cdpr::ctl {

namespace {

using json = nlohmann::json;
using control::ControlClient;
using control::ControlErrorCode;
using control::ControlEvent;
using control::ControlReply;

// What the command line asked for.
struct Invocation {
  std::string socket;
  bool json_out = false;
  double timeout_s = 0;  // 0: not given
  std::string name;      // as typed: "geometry rollback"
  std::string cmd;       // protocol command: "geometry_rollback"
  json args = json::object();
  bool wait = false;
  bool watch = false;
  std::string poses_file;
  std::string program_file;  // run FILE
  std::string html_file;
};

std::string errno_text(int e) {
  return std::strerror(e);
}

// Writes `content` to `path` so that readers see the old file or the whole new one: a temporary
// file in the same directory, fsync, rename, fsync of the directory.
Status write_file_atomically(const std::string& path, std::string_view content) {
  const std::size_t slash = path.find_last_of('/');
  const std::string dir =
      slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
  std::string tmpl = path + ".XXXXXX";
  const int fd = ::mkstemp(tmpl.data());
  if (fd < 0) {
    return Status(ErrorCode::kIoError,
                  "cannot create a temporary file beside " + path + ": " + errno_text(errno));
  }
  auto fail = [&](const char* what) {
    const int e = errno;
    ::close(fd);
    ::unlink(tmpl.c_str());
    return Status(ErrorCode::kIoError, std::string(what) + " " + tmpl + ": " + errno_text(e));
  };
  std::size_t done = 0;
  while (done < content.size()) {
    const ssize_t n = ::write(fd, content.data() + done, content.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      return fail("cannot write");
    }
    done += static_cast<std::size_t>(n);
  }
  const mode_t mask = ::umask(0);
  ::umask(mask);
  if (::fchmod(fd, 0666 & ~mask) != 0) return fail("cannot chmod");
  if (::fsync(fd) != 0) return fail("cannot fsync");
  if (::close(fd) != 0) {
    const int e = errno;
    ::unlink(tmpl.c_str());
    return Status(ErrorCode::kIoError, "cannot close " + tmpl + ": " + errno_text(e));
  }
  if (::rename(tmpl.c_str(), path.c_str()) != 0) {
    const int e = errno;
    ::unlink(tmpl.c_str());
    return Status(ErrorCode::kIoError,
                  "cannot rename " + tmpl + " to " + path + ": " + errno_text(e));
  }
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    (void)::fsync(dfd);
    ::close(dfd);
  }
  return Status::success();
}

// The hint for a socket we may not open: its group and mode.
std::string permission_hint(const std::string& path) {
  struct stat sb {};
  if (::stat(path.c_str(), &sb) != 0) {
    return "cdprctl: permission denied on " + path + " (its directory is closed to you)";
  }
  std::string group = std::to_string(sb.st_gid);
  if (const struct group* g = ::getgrgid(sb.st_gid); g != nullptr) group = g->gr_name;
  char mode[8];
  std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(sb.st_mode & 07777));
  return "cdprctl: permission denied on " + path + " (group '" + group + "', mode " + mode +
         "): membership of group '" + group + "' is needed (then log in again)";
}

class Session {
 public:
  Session(const Invocation& inv, std::ostream& out, std::ostream& err, const Environment& env)
      : inv_(inv), out_(out), err_(err), env_(env) {}

  int run() {
    deadline_ = control::deadline_after(inv_.timeout_s > 0          ? inv_.timeout_s
                                        : (inv_.wait || inv_.watch) ? 0
                                                                    : kDefaultTimeoutS);
    if (!inv_.poses_file.empty()) {
      if (int code = attach_file(inv_.poses_file, "poses_csv"); code != kExitOk) return code;
    }
    if (!inv_.program_file.empty()) {
      inv_.args["source"] = inv_.program_file;  // for the daemon's messages only
      if (int code = attach_file(inv_.program_file, "program"); code != kExitOk) return code;
    }
    auto client = ControlClient::connect(inv_.socket, deadline_);
    if (!client.ok()) return connect_failed(client.status());
    client_.emplace(std::move(client.value()));
    if (inv_.watch) return watch();
    if (inv_.wait) return calibrate_and_wait();
    Result<ControlReply> reply = client_->call(inv_.cmd, inv_.args, deadline_, env_.interrupted);
    if (!reply.ok()) return transport_failed(reply.status());
    if (!reply->is_ok()) return refused(*reply);
    if (inv_.cmd == "fault_reset") return await_fault_reset(reply->result());
    return print_result(reply->result());
  }

 private:
  // After fault_reset: the state, until it leaves `fault` (or the timeout): exit 1 naming what
  // still blocks while the robot stays in fault.
  int await_fault_reset(const json& result) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(3);
    json st;
    for (;;) {
      Result<ControlReply> s = client_->call("status", json::object(), deadline_, env_.interrupted);
      if (!s.ok()) return transport_failed(s.status());
      if (!s->is_ok()) return refused(*s);
      st = s->result();
      if (st.value("state", "") != "fault") break;
      if (std::chrono::steady_clock::now() > until) {
        const json f = st.value("fault", json());
        const std::string why =
            f.is_object() ? f.value("message", st.value("reason", "")) : st.value("reason", "");
        return fail(kExitFailed, "fault-reset: the robot stays in fault: " + why);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    json r = result;
    r["state"] = st.value("state", "");
    r["reason"] = st.value("reason", "");
    return print_result(r);
  }

  // The content of a local file as args[field]: a regular file no larger than one request may
  // carry (/dev/zero or a FIFO is refused at once: never read unboundedly, never waited on past
  // --timeout), UTF-8 text. The daemon never opens a file a client names.
  int attach_file(const std::string& file, const char* field) {
    Result<std::string> text = io::read_regular_file(file, control::kDefaultMaxLine);
    if (!text.ok()) return fail(kExitUsage, std::string(text.status().message()));
    if (const auto bad = control::find_invalid_utf8(*text)) {
      return fail(kExitUsage, file + " is not UTF-8 text (byte " + std::to_string(*bad) + ")");
    }
    inv_.args[field] = std::move(*text);
    const std::size_t size = control::encode_request(1, inv_.cmd, inv_.args).size();
    if (size > control::kDefaultMaxLine) {
      return fail(kExitUsage, file + " is too large for one request (" + std::to_string(size) +
                                  " bytes encoded, at most " +
                                  std::to_string(control::kDefaultMaxLine) + ")");
    }
    return kExitOk;
  }

  int fail(int code, const std::string& message) {
    err_ << "cdprctl: " << message << "\n";
    return code;
  }

  int connect_failed(const Status& st) {
    switch (st.code()) {
      case ErrorCode::kNotFound:
        return fail(kExitNotRunning, "cdprd is not running (no socket at " + inv_.socket + ")");
      case ErrorCode::kUnavailable:
        return fail(kExitNotRunning,
                    "cdprd is not running (nothing accepts connections at " + inv_.socket + ")");
      case ErrorCode::kFailedPrecondition:
        err_ << permission_hint(inv_.socket) << "\n";
        return kExitPermission;
      case ErrorCode::kTimeout:
        return fail(kExitTimeout, "cdprd did not accept the connection before the timeout");
      default:
        return fail(kExitFailed, st.to_string());
    }
  }

  int transport_failed(const Status& st) {
    switch (st.code()) {
      case ErrorCode::kTimeout:
        return fail(kExitTimeout, inv_.name + ": no answer from cdprd before the timeout");
      case ErrorCode::kUnavailable:
        return fail(kExitNotRunning, inv_.name + ": cdprd closed the connection");
      case ErrorCode::kAborted:
        return fail(kExitCancelled, inv_.name + ": interrupted");
      default:
        return fail(kExitFailed, inv_.name + ": " + st.to_string());
    }
  }

  int refused(const ControlReply& r) {
    const std::string code(control::to_string(r.code()));
    if (inv_.json_out) {
      out_ << control::dump_safely(
                  {{"ok", false}, {"error", {{"code", code}, {"message", r.message()}}}}, 2)
           << "\n";
    }
    err_ << "cdprctl: " << inv_.name << ": " << code << ": " << r.message() << "\n";
    return r.code() == ControlErrorCode::kNotPermitted ? kExitPermission : kExitFailed;
  }

  // Human headline of a successful command, before the generic rendering of its result.
  std::string headline(const json& r) const {
    auto version = [&](const char* key) {
      const auto it = r.find(key);
      return it == r.end() ? std::string() : " " + render_scalar(*it);
    };
    // cdprd numbers calibrations ("calibration"); "version" from older daemons.
    auto number = [&] {
      const std::string c = version("calibration");
      return c.empty() ? version("version") : c;
    };
    if (inv_.cmd == "calibrate") {
      return inv_.args.value("dry_run", false) ? "calibration dry run done"
                                               : "calibration" + number() + " started";
    }
    if (inv_.cmd == "abort") return "abort requested";
    if (inv_.cmd == "accept") return "calibration" + number() + " accepted";
    if (inv_.cmd == "reject") return "calibration" + number() + " rejected";
    if (inv_.cmd == "geometry_rollback") {
      return "geometry rolled back to version " + render_scalar(inv_.args["version"]);
    }
    if (inv_.cmd == "stop") return "quick stop requested";
    if (inv_.cmd == "fault_reset") return "fault reset requested";
    return "";
  }

  int print_result(json result) {
    if (inv_.cmd == "report" && !inv_.html_file.empty()) {
      const auto html = result.find("html");
      if (html == result.end() || !html->is_string()) {
        return fail(kExitFailed, "report: the daemon's reply has no \"html\" page");
      }
      if (Status st = write_file_atomically(inv_.html_file, html->get_ref<const std::string&>());
          !st.ok()) {
        return fail(kExitFailed, "report: " + std::string(st.message()));
      }
      if (!inv_.json_out) {
        out_ << "report" << (result.contains("version") ? " of calibration " : "")
             << (result.contains("version") ? render_scalar(result["version"]) : "")
             << " written to " << inv_.html_file << " ("
             << html->get_ref<const std::string&>().size() << " bytes)\n";
        result.erase("html");
      }
    }
    if (inv_.json_out) {
      out_ << control::dump_safely(result, 2) << "\n";
      return kExitOk;
    }
    const std::string head = headline(result);
    if (!head.empty()) out_ << head << "\n";
    out_ << render_result(result);
    return kExitOk;
  }

  // ---- events -------------------------------------------------------------------------------

  // Shows an event: the live bar for progress on a terminal, plain lines otherwise (progress only
  // when its phase or pose changed). `quiet_progress`: no progress lines at all off a terminal.
  void show(const ControlEvent& ev) {
    if (inv_.json_out && inv_.watch) {
      out_ << control::dump_safely({{"event", ev.type}, {"data", ev.data}}) << "\n" << std::flush;
      return;
    }
    if (inv_.json_out) return;  // --wait --json prints only the outcome
    if (ev.type == "progress") {
      if (env_.terminal) {
        bar_ = progress_bar(ev.data, env_.terminal_width);
        out_ << "\r" << bar_ << "\x1b[K" << std::flush;
        return;
      }
      const std::string key =
          ev.data.value("phase", json()).dump() + "/" + ev.data.value("pose", json()).dump();
      if (key == last_progress_key_) return;
      last_progress_key_ = key;
    }
    if (env_.terminal && !bar_.empty()) out_ << "\r\x1b[K";
    out_ << event_line(ev) << "\n";
    if (env_.terminal && !bar_.empty()) out_ << bar_ << "\x1b[K";
    out_ << std::flush;
  }

  void end_bar() {
    if (env_.terminal && !bar_.empty()) out_ << "\n" << std::flush;
    bar_.clear();
  }

  int watch() {
    Result<ControlReply> reply =
        client_->call("watch", json::object(), deadline_, env_.interrupted);
    if (!reply.ok()) return transport_failed(reply.status());
    if (!reply->is_ok()) return refused(*reply);
    for (;;) {
      Result<ControlEvent> ev = client_->next_event(deadline_, env_.interrupted);
      if (!ev.ok()) {
        end_bar();
        switch (ev.status().code()) {
          case ErrorCode::kAborted:  // Ctrl-C: the normal end of watching
          case ErrorCode::kTimeout:  // --timeout S: watch for S seconds
            return kExitOk;
          default:
            return transport_failed(ev.status());
        }
      }
      show(*ev);
    }
  }

  int calibrate_and_wait() {
    // Subscribe first, on the same connection, so that no event of this calibration is missed.
    Result<ControlReply> w = client_->call("watch", json::object(), deadline_, env_.interrupted);
    if (!w.ok()) return transport_failed(w.status());
    if (!w->is_ok()) return refused(*w);
    Result<ControlReply> started = client_->call(inv_.cmd, inv_.args, deadline_, env_.interrupted);
    if (!started.ok()) return transport_failed(started.status());
    if (!started->is_ok()) return refused(*started);
    const json& start = started->result();
    // The run to follow: cdprd numbers calibrations ("calibration"); "version" for older daemons.
    const char* const key = start.contains("calibration") ? "calibration" : "version";
    const json version = start.value(key, json());
    if (!inv_.json_out) {
      out_ << headline(start) << "\n" << render_result(start) << std::flush;
    }
    for (;;) {
      Result<ControlEvent> ev = client_->next_event(deadline_, env_.interrupted);
      if (!ev.ok()) {
        end_bar();
        if (ev.status().code() == ErrorCode::kTimeout) {
          return fail(kExitTimeout,
                      "calibrate: no outcome before the timeout (the calibration "
                      "goes on; cdprctl watch follows it, cdprctl abort stops it)");
        }
        if (ev.status().code() == ErrorCode::kAborted) {
          return fail(kExitCancelled,
                      "calibrate: stopped waiting (the calibration goes on; "
                      "cdprctl abort stops it)");
        }
        return transport_failed(ev.status());
      }
      show(*ev);
      if (ev->type == "fault") {
        end_bar();
        if (inv_.json_out) print_outcome(start, ev->data, "fault");
        return fail(kExitInterrupted, "calibrate: " + event_line(*ev));
      }
      if (ev->type != "calibration") continue;
      const json& d = ev->data;
      if (!version.is_null() && d.value(key, json()) != version) continue;  // another run
      const std::string outcome = d.value("outcome", "");
      int code = -1;
      if (outcome == "applied") {
        code = kExitOk;
      } else if (outcome == "awaiting_acceptance") {
        code = d.value("gates_passed", false) ? kExitOk : kExitRejected;
      } else if (outcome == "rejected" || outcome == "failed") {
        code = kExitRejected;
      } else if (outcome == "aborted") {
        code = kExitInterrupted;
      }
      if (code < 0) continue;  // not a final outcome
      end_bar();
      if (inv_.json_out) print_outcome(start, d, "calibration");
      if (code != kExitOk) err_ << "cdprctl: calibrate: " << event_line(*ev) << "\n";
      if (code == kExitOk && outcome == "awaiting_acceptance" && !inv_.json_out) {
        out_ << "gates passed: review the report (cdprctl report), then cdprctl accept or "
                "cdprctl reject\n";
      }
      return code;
    }
  }

  void print_outcome(const json& start, const json& data, const char* key) {
    out_ << control::dump_safely({{"calibrate", start}, {key, data}}, 2) << "\n";
  }

  Invocation inv_;
  std::ostream& out_;
  std::ostream& err_;
  const Environment& env_;
  ControlClient::Deadline deadline_;
  std::optional<ControlClient> client_;
  std::string bar_;
  std::string last_progress_key_;
};

constexpr const char* kExitNote =
    "Exit status: 0 success; 1 the daemon refused or failed the command; 2 usage error; 3 cdprd "
    "is not running; 4 permission denied; 5 --wait: gates failed, rejected or failed; 6 --wait: "
    "aborted or robot fault; 7 timeout; 130 --wait interrupted (docs/control-protocol.md).";

}  // namespace

namespace {

// What the subcommands' options fill in; it outlives the parse (the callbacks write into it).
struct CliValues {
  bool dry_run = false;
  std::int64_t show_version = 0, diff_a = 0, diff_b = 0, rollback_version = 0;
  std::int64_t report_version = 0;
  std::vector<double> move_pose;
  std::string home_method = "reference";
  std::string stream_action;
};

CLI::App* add_simple(CLI::App& app, Invocation& inv, const char* name, const char* cmd,
                     const char* help) {
  auto* s = app.add_subcommand(name, help);
  s->callback([&inv, name, cmd] {
    inv.name = name;
    inv.cmd = cmd;
  });
  return s;
}

void add_calibration_commands(CLI::App& app, Invocation& inv, CliValues& v) {
  auto* cal = add_simple(app, inv, "calibrate", "calibrate",
                         "start a calibration (moves the robot; privileged)");
  auto* dry = cal->add_flag("--dry-run", v.dry_run,
                            "plan and check the poses against the current model; nothing moves");
  cal->add_option("--poses", inv.poses_file, "pose list CSV (read here, sent as its content)")
      ->check(CLI::ExistingFile);
  auto* wait = cal->add_flag("--wait", inv.wait,
                             "follow the calibration and wait for its outcome (exit 0/5/6)");
  dry->excludes(wait);
  cal->callback([&inv, &v] {
    inv.name = "calibrate";
    inv.cmd = "calibrate";
    if (v.dry_run) inv.args["dry_run"] = true;
  });
  auto* w = add_simple(app, inv, "watch", "watch", "follow the daemon's events (Ctrl-C ends)");
  w->callback([&inv] {
    inv.name = "watch";
    inv.cmd = "watch";
    inv.watch = true;
  });
  add_simple(app, inv, "abort", "abort",
             "abort the running calibration, path run or stream: a smooth stop, then hold "
             "(privileged)");
  add_simple(app, inv, "accept", "accept",
             "accept the calibration awaiting acceptance (privileged)");
  add_simple(app, inv, "reject", "reject",
             "reject the calibration awaiting acceptance (privileged)");
}

void add_geometry_commands(CLI::App& app, Invocation& inv, CliValues& v) {
  auto* geo = app.add_subcommand("geometry", "the versions of the robot geometry");
  geo->require_subcommand(1);
  auto* show = geo->add_subcommand("show", "a geometry version (default: the active one)");
  show->add_option("VERSION", v.show_version, "version")->check(CLI::PositiveNumber);
  show->callback([&inv, &v] {
    inv.name = "geometry show";
    inv.cmd = "geometry_show";
    if (v.show_version > 0) inv.args["version"] = v.show_version;
  });
  auto* diff = geo->add_subcommand("diff", "what changed between two versions");
  diff->add_option("A", v.diff_a, "from version")->required()->check(CLI::PositiveNumber);
  diff->add_option("B", v.diff_b, "to version")->required()->check(CLI::PositiveNumber);
  diff->callback([&inv, &v] {
    inv.name = "geometry diff";
    inv.cmd = "geometry_diff";
    inv.args = {{"from", v.diff_a}, {"to", v.diff_b}};
  });
  auto* history = geo->add_subcommand("history", "every version with its origin");
  history->callback([&inv] {
    inv.name = "geometry history";
    inv.cmd = "geometry_history";
  });
  auto* rollback =
      geo->add_subcommand("rollback", "make an earlier version active (bumpless; privileged)");
  rollback->add_option("VERSION", v.rollback_version, "version")
      ->required()
      ->check(CLI::PositiveNumber);
  rollback->callback([&inv, &v] {
    inv.name = "geometry rollback";
    inv.cmd = "geometry_rollback";
    inv.args = {{"version", v.rollback_version}};
  });
}

void add_report_and_motion_commands(CLI::App& app, Invocation& inv, CliValues& v) {
  auto* rep = app.add_subcommand("report", "a calibration's report (default: the latest)");
  rep->add_option("VERSION", v.report_version, "version")->check(CLI::PositiveNumber);
  rep->add_option("--html", inv.html_file, "write the HTML page to this file (atomically)");
  rep->callback([&inv, &v] {
    inv.name = "report";
    inv.cmd = "report";
    if (v.report_version > 0) inv.args["version"] = v.report_version;
    inv.args["html"] = !inv.html_file.empty();
  });
  auto* mv = app.add_subcommand(
      "move", "move the platform to a pose: X Y Z [ROLL PITCH YAW] (m, rad; privileged)");
  mv->add_option("POSE", v.move_pose, "x y z in m, then optionally roll pitch yaw in rad")
      ->required()
      ->expected(3, 6);
  mv->callback([&inv, &v] {
    // Exactly a position (orientation 0) or a full pose: 4 or 5 numbers are a typo, not a pose.
    if (v.move_pose.size() != 3 && v.move_pose.size() != 6) {
      throw CLI::ValidationError(
          "POSE", "takes exactly 3 (x y z) or 6 (x y z roll pitch yaw) numbers, got " +
                      std::to_string(v.move_pose.size()));
    }
    inv.name = "move";
    inv.cmd = "move";
    std::vector<double> p = v.move_pose;
    p.resize(6, 0.0);
    inv.args = {{"pose", p}};
  });
  auto* run = app.add_subcommand(
      "run", "run a path file from the pose held; the whole path is checked first (privileged)");
  run->add_option("FILE", inv.program_file,
                  "path file (docs/motion.md \"Path files\"; read here, sent as its content)")
      ->required()
      ->check(CLI::ExistingFile);
  run->callback([&inv] {
    inv.name = "run";
    inv.cmd = "run";
  });
  auto* stream = app.add_subcommand(
      "stream", "start or stop following the setpoint stream (docs/motion.md; privileged)");
  stream->add_option("ACTION", v.stream_action, "start or stop")
      ->required()
      ->check(CLI::IsMember({"start", "stop"}));
  stream->callback([&inv, &v] {
    inv.name = "stream";
    inv.cmd = "stream";
    inv.args = {{"action", v.stream_action}};
  });
  add_simple(app, inv, "stop", "stop", "quick stop (privileged)");
  add_simple(app, inv, "fault-reset", "fault_reset",
             "clear a fault after its cause is gone; exit 1 while the robot stays in fault "
             "(privileged)");
  add_simple(app, inv, "enable", "enable",
             "enable the drives; the robot holds where it is (privileged)");
  add_simple(app, inv, "disable", "disable", "disable the drives while holding (privileged)");
  auto* home = app.add_subcommand(
      "home",
      "home: reference platform (the platform on it at home) or absolute encoders (the "
      "record's offsets, pose checked); privileged");
  home->add_option("--method", v.home_method, "reference, drive or absolute")
      ->check(CLI::IsMember({"reference", "drive", "absolute"}));
  home->callback([&inv, &v] {
    inv.name = "home";
    inv.cmd = "home";
    inv.args = {{"method", v.home_method}};
  });
}

}  // namespace

int run(int argc, const char* const* argv, std::ostream& out, std::ostream& err,
        const Environment& env) {
  CLI::App app{"cdprctl: the maintenance command of the cable robot daemon cdprd"};
  app.footer(kExitNote);
  app.set_version_flag("--version", std::string("cdprctl ") + cdpr::kVersion);
  app.require_subcommand(1);
  app.fallthrough();
  Invocation inv;
  inv.socket = env.socket_env.empty() ? kDefaultSocket : env.socket_env;
  app.add_option("--socket", inv.socket,
                 "control socket (default $CDPR_SOCKET, else " + std::string(kDefaultSocket) + ")");
  app.add_flag("--json", inv.json_out, "print the daemon's raw result as JSON");
  app.add_option("--timeout", inv.timeout_s,
                 "seconds to wait for the answer (default 10; calibrate --wait and watch: no "
                 "limit, watch ends after S seconds with status 0)")
      ->check(CLI::NonNegativeNumber);
  CliValues values;
  add_simple(app, inv, "status", "status",
             "state, fault, geometry version, calibration progress, RT loop figures");
  add_simple(app, inv, "health", "health",
             "in-service monitoring: what changed since the calibration, which effect it looks "
             "like, the predicted position error and the re-identification it proposes");
  add_calibration_commands(app, inv, values);
  add_geometry_commands(app, inv, values);
  add_report_and_motion_commands(app, inv, values);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e, out, err);
    return code == 0 ? kExitOk : kExitUsage;
  }
  if (inv.cmd.empty()) {
    err << "cdprctl: no command given (cdprctl --help lists them)\n";
    return kExitUsage;
  }
  return Session(inv, out, err, env).run();
}

}  // namespace cdpr::ctl
