// cdprctl against a fake daemon: a ControlServer with a scripted handler in this process.
#include "app.hpp"

#include <grp.h>
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>
#include <utility>

#include "cdpr/controller/control_server.hpp"
#include "render.hpp"

namespace cdpr::ctl {
namespace {

using json = nlohmann::json;
using control::ControlErrorCode;
using control::ControlReply;
using control::ControlRequest;
using namespace std::chrono_literals;

struct Outcome {
  int code = -1;
  std::string out, err;
};

// cdprctl's standard output, which the scripted daemon's thread may wait on: a `watch` is ended
// (daemon gone, Ctrl-C) once what it must show was printed, not after a guessed delay.
class WatchedOutput : public std::streambuf {
 public:
  bool wait_for(const std::string& text) {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, 60s, [&] { return text_.find(text) != std::string::npos; });
  }
  std::string take() {
    std::lock_guard lock(mu_);
    return std::exchange(text_, {});
  }

 protected:
  int_type overflow(int_type c) override {
    if (traits_type::eq_int_type(c, traits_type::eof())) return traits_type::not_eof(c);
    const char ch = traits_type::to_char_type(c);
    xsputn(&ch, 1);
    return c;
  }
  std::streamsize xsputn(const char* s, std::streamsize n) override {
    {
      std::lock_guard lock(mu_);
      text_.append(s, static_cast<std::size_t>(n));
    }
    cv_.notify_all();
    return n;
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  std::string text_;
};

class CdprctlTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/cdprctl-XXXXXX";
    ASSERT_NE(::mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    ::chmod(dir_.c_str(), 0755);
    socket_ = dir_ + "/cdprd.sock";
  }
  void TearDown() override {
    std::vector<std::thread> threads;
    {
      std::lock_guard lock(mu_);
      threads.swap(publishers_);
    }
    for (auto& t : threads) t.join();
    if (server_) server_->stop();
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }

  // The fake daemon: scripted replies by command (default: ok with {"echo": cmd}), and an action
  // run on a thread after the reply of a command (to publish events).
  void start_daemon(control::ControlServerOptions o = {}) {
    o.path = socket_;
    auto s = control::ControlServer::start(o, [this](const ControlRequest& r) {
      std::function<void()> after;
      ControlReply reply = ControlReply::ok({{"echo", r.cmd}});
      {
        std::lock_guard lock(mu_);
        requests_.push_back(r);
        if (auto it = replies_.find(r.cmd); it != replies_.end()) reply = it->second;
        if (auto it = after_.find(r.cmd); it != after_.end()) after = it->second;
        if (r.cmd == "status" && status_delay_ > 0ms) std::this_thread::sleep_for(status_delay_);
        if (after) publishers_.emplace_back(after);
      }
      return reply;
    });
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    server_ = std::move(s.value());
  }

  Outcome ctl(std::vector<std::string> args, Environment env = {}) {
    std::vector<std::string> argv = {"cdprctl"};
    if (env.socket_env.empty()) {
      argv.push_back("--socket");
      argv.push_back(socket_);
    }
    argv.insert(argv.end(), args.begin(), args.end());
    std::vector<const char*> raw;
    for (const auto& a : argv) raw.push_back(a.c_str());
    std::ostream out(&out_);
    std::ostringstream err;
    Outcome o;
    o.code = run(static_cast<int>(raw.size()), raw.data(), out, err, env);
    o.out = out_.take();
    o.err = err.str();
    return o;
  }

  std::vector<ControlRequest> requests() {
    std::lock_guard lock(mu_);
    return requests_;
  }
  void script(const std::string& cmd, ControlReply reply) {
    std::lock_guard lock(mu_);
    replies_.insert_or_assign(cmd, std::move(reply));
  }
  void after(const std::string& cmd, std::function<void()> f) {
    std::lock_guard lock(mu_);
    after_[cmd] = std::move(f);
  }

  std::string dir_, socket_;
  WatchedOutput out_;
  std::unique_ptr<control::ControlServer> server_;
  std::mutex mu_;
  std::vector<ControlRequest> requests_;
  std::map<std::string, ControlReply> replies_;
  std::map<std::string, std::function<void()>> after_;
  std::vector<std::thread> publishers_;
  std::chrono::milliseconds status_delay_{0};
};

TEST_F(CdprctlTest, EverySubcommandSendsItsRequest) {
  start_daemon();
  const std::string poses = dir_ + "/poses.csv";
  const std::string csv = "pose,x,y,z,roll,pitch,yaw\n1,0.1,0.2,0.3,0,0,0\n";
  std::ofstream(poses) << csv;
  const std::string program_file = dir_ + "/square.path";
  const std::string program = "G1 X0.1 F0.05\nY0.1\n";
  std::ofstream(program_file) << program;
  struct Case {
    std::vector<std::string> argv;
    const char* cmd;
    json args;
  };
  const std::vector<Case> cases = {
      {{"status"}, "status", json::object()},
      {{"calibrate"}, "calibrate", json::object()},
      {{"calibrate", "--dry-run", "--poses", poses},
       "calibrate",
       {{"dry_run", true}, {"poses_csv", csv}}},
      {{"abort"}, "abort", json::object()},
      {{"accept"}, "accept", json::object()},
      {{"reject"}, "reject", json::object()},
      {{"geometry", "show"}, "geometry_show", json::object()},
      {{"geometry", "show", "3"}, "geometry_show", {{"version", 3}}},
      {{"geometry", "diff", "2", "5"}, "geometry_diff", {{"from", 2}, {"to", 5}}},
      {{"geometry", "history"}, "geometry_history", json::object()},
      {{"geometry", "rollback", "4"}, "geometry_rollback", {{"version", 4}}},
      {{"report"}, "report", {{"html", false}}},
      {{"report", "2"}, "report", {{"version", 2}, {"html", false}}},
      {{"stop"}, "stop", json::object()},
      {{"enable"}, "enable", json::object()},
      {{"disable"}, "disable", json::object()},
      {{"home"}, "home", {{"method", "reference"}}},
      {{"home", "--method", "absolute"}, "home", {{"method", "absolute"}}},
      {{"move", "0.1", "0.2", "0.3"}, "move", {{"pose", {0.1, 0.2, 0.3, 0.0, 0.0, 0.0}}}},
      {{"move", "0.1", "0.2", "0.3", "0", "0", "0.05"},
       "move",
       {{"pose", {0.1, 0.2, 0.3, 0.0, 0.0, 0.05}}}},
      {{"run", program_file}, "run", {{"program", program}, {"source", program_file}}},
      {{"stream", "start"}, "stream", {{"action", "start"}}},
      {{"stream", "stop"}, "stream", {{"action", "stop"}}},
      {{"health"}, "health", json::object()},
      {{"status", "--json"}, "status", json::object()},  // global options after the command
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.argv.front() + (c.argv.size() > 1 ? " " + c.argv[1] : ""));
    const std::size_t before = requests().size();
    const Outcome o = ctl(c.argv);
    EXPECT_EQ(o.code, kExitOk) << o.err;
    const auto reqs = requests();
    ASSERT_EQ(reqs.size(), before + 1);
    EXPECT_EQ(reqs.back().cmd, c.cmd);
    EXPECT_EQ(reqs.back().args, c.args);
  }
  // fault-reset sends its request, then follows the state with status.
  const std::size_t before = requests().size();
  const Outcome o = ctl({"fault-reset"});
  EXPECT_EQ(o.code, kExitOk) << o.err;
  ASSERT_GE(requests().size(), before + 2);
  EXPECT_EQ(requests()[before].cmd, "fault_reset");
  EXPECT_EQ(requests().back().cmd, "status");
}

TEST_F(CdprctlTest, PrintsResultsForHumansAndRawJsonWithTheFlag) {
  start_daemon();
  const json status = {{"state", "holding"},
                       {"reason", "homed"},
                       {"geometry_version", 3},
                       {"rt", {{"overruns", 0}, {"p999_us", 12.5}}},
                       {"tensions_n", {10.5, 20.25}}};
  script("status", ControlReply::ok(status));
  const Outcome human = ctl({"status"});
  ASSERT_EQ(human.code, kExitOk) << human.err;
  EXPECT_NE(human.out.find("state: holding\n"), std::string::npos) << human.out;
  EXPECT_NE(human.out.find("rt:\n  overruns: 0\n  p999_us: 12.5\n"), std::string::npos)
      << human.out;
  EXPECT_NE(human.out.find("tensions_n: [10.5, 20.25]"), std::string::npos) << human.out;

  const Outcome raw = ctl({"--json", "status"});
  ASSERT_EQ(raw.code, kExitOk);
  EXPECT_EQ(json::parse(raw.out), status);

  script("geometry_history",
         ControlReply::ok({{"versions",
                            {{{"version", 1}, {"origin", "nominal"}, {"active", false}},
                             {{"version", 2}, {"origin", "calibration"}, {"active", true}}}}}));
  const Outcome table = ctl({"geometry", "history"});
  ASSERT_EQ(table.code, kExitOk);
  EXPECT_NE(table.out.find("versions:\n  active  origin       version\n"), std::string::npos)
      << table.out;
  EXPECT_NE(table.out.find("  yes     calibration  2\n"), std::string::npos) << table.out;

  script("geometry_rollback", ControlReply::ok({{"version", 1}}));
  const Outcome rb = ctl({"geometry", "rollback", "1"});
  EXPECT_EQ(rb.code, kExitOk);
  EXPECT_NE(rb.out.find("geometry rolled back to version 1"), std::string::npos) << rb.out;
}

TEST_F(CdprctlTest, ARefusedCommandExitsOneWithTheNamedError) {
  start_daemon();
  script("accept", ControlReply::error(ControlErrorCode::kInvalidState,
                                       "nothing awaits acceptance (state holding)"));
  const Outcome o = ctl({"accept"});
  EXPECT_EQ(o.code, kExitFailed);
  EXPECT_NE(o.err.find("accept: invalid_state: nothing awaits acceptance"), std::string::npos)
      << o.err;
  const Outcome j = ctl({"--json", "accept"});
  EXPECT_EQ(j.code, kExitFailed);
  const json e = json::parse(j.out);
  EXPECT_EQ(e["ok"], json(false));
  EXPECT_EQ(e["error"]["code"], json("invalid_state"));
}

TEST_F(CdprctlTest, NotPermittedExitsFourWithTheDaemonsReason) {
  start_daemon();
  script("stop", ControlReply::error(ControlErrorCode::kNotPermitted,
                                     "stop needs membership of group 'cdpr'"));
  const Outcome o = ctl({"stop"});
  EXPECT_EQ(o.code, kExitPermission);
  EXPECT_NE(o.err.find("group 'cdpr'"), std::string::npos) << o.err;
}

TEST_F(CdprctlTest, ADaemonThatIsNotRunningExitsThree) {
  const Outcome absent = ctl({"status"});
  EXPECT_EQ(absent.code, kExitNotRunning);
  EXPECT_EQ(absent.err, "cdprctl: cdprd is not running (no socket at " + socket_ + ")\n");
  // A stale socket file: nobody accepts.
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::strncpy(addr.sun_path, socket_.c_str(), sizeof addr.sun_path - 1);
  ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  ::close(fd);
  const Outcome stale = ctl({"status"});
  EXPECT_EQ(stale.code, kExitNotRunning);
  EXPECT_NE(stale.err.find("nothing accepts connections at " + socket_), std::string::npos);
}

TEST_F(CdprctlTest, UsesCdprSocketFromTheEnvironment) {
  start_daemon();
  Environment env;
  env.socket_env = socket_;
  const Outcome o = ctl({"status"}, env);
  EXPECT_EQ(o.code, kExitOk) << o.err;
  env.socket_env = dir_ + "/elsewhere.sock";
  EXPECT_EQ(ctl({"status"}, env).code, kExitNotRunning);
}

TEST_F(CdprctlTest, PermissionDeniedOnTheSocketExitsFourAndNamesTheGroup) {
  const group* g = ::getgrgid(::getegid());
  ASSERT_NE(g, nullptr);
  const std::string group_name = g->gr_name;
  control::ControlServerOptions o;
  o.group = group_name;
  start_daemon(o);
  if (::geteuid() != 0) {
    // The owner without write permission is refused like anyone else.
    ASSERT_EQ(::chmod(socket_.c_str(), 0), 0);
    const Outcome out = ctl({"status"});
    EXPECT_EQ(out.code, kExitPermission);
    EXPECT_NE(out.err.find("group '" + group_name + "'"), std::string::npos) << out.err;
    return;
  }
  // Root passes every permission check: run cdprctl as nobody in a child.
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(fds[0]);
    if (::setgroups(0, nullptr) != 0 || ::setgid(65534) != 0 || ::setuid(65534) != 0) _exit(99);
    const Outcome out = ctl({"status"});
    (void)!::write(fds[1], out.err.data(), out.err.size());
    _exit(out.code);
  }
  ::close(fds[1]);
  std::string err;
  char buf[1024];
  ssize_t n;
  while ((n = ::read(fds[0], buf, sizeof buf)) > 0) err.append(buf, static_cast<std::size_t>(n));
  ::close(fds[0]);
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), kExitPermission) << err;
  EXPECT_NE(err.find("permission denied on " + socket_), std::string::npos) << err;
  EXPECT_NE(err.find("membership of group '" + group_name + "'"), std::string::npos) << err;
}

TEST_F(CdprctlTest, NoAnswerBeforeTheTimeoutExitsSeven) {
  status_delay_ = 1500ms;  // the scripted daemon is stuck
  start_daemon();
  const auto t0 = std::chrono::steady_clock::now();
  const Outcome o = ctl({"--timeout", "0.2", "status"});
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_EQ(o.code, kExitTimeout);
  EXPECT_NE(o.err.find("no answer from cdprd before the timeout"), std::string::npos) << o.err;
  EXPECT_LT(s, 1.2);
}

TEST_F(CdprctlTest, UsageErrorsExitTwoAndHelpExitsZero) {
  start_daemon();
  const std::vector<std::vector<std::string>> bad = {
      {},
      {"fly"},
      {"geometry"},
      {"geometry", "rollback"},
      {"geometry", "rollback", "zero"},
      {"geometry", "diff", "1"},
      {"calibrate", "--dry-run", "--wait"},
      {"calibrate", "--poses", "/no/such/file.csv"},
      {"--timeout", "-1", "status"},
      {"move", "0.1", "0.2"},
      {"move", "0.1", "0.2", "0.3", "0"},
      {"move", "0.1", "0.2", "0.3", "0", "0"},
      {"move", "0.1", "0.2", "0.3", "0", "0", "0", "0"},
      {"move", "0.1", "0.2", "0.3", "x"},
      {"run"},
      {"run", "/no/such/file.path"},
      {"stream"},
      {"stream", "pause"},
  };
  for (const auto& args : bad) {
    const Outcome o = ctl(args);
    EXPECT_EQ(o.code, kExitUsage) << (args.empty() ? "(none)" : args[0]) << ": " << o.err;
  }
  EXPECT_TRUE(requests().empty());
  const Outcome help = ctl({"--help"});
  EXPECT_EQ(help.code, kExitOk);
  EXPECT_NE(help.out.find("Exit status"), std::string::npos);
}

TEST_F(CdprctlTest, RefusesAPoseFileTooLargeForOneRequest) {
  start_daemon();
  const std::string poses = dir_ + "/huge.csv";
  std::ofstream(poses) << std::string(70000, '1');
  const Outcome o = ctl({"calibrate", "--poses", poses});
  EXPECT_EQ(o.code, kExitUsage);
  EXPECT_NE(o.err.find("too large"), std::string::npos) << o.err;
  EXPECT_TRUE(requests().empty());
}

// Issue 39 (6): a pose file that is a device or a FIFO is refused at once, before any request
// (it was read until the OOM killer came, or waited on past --timeout).
TEST_F(CdprctlTest, RefusesAPoseFileThatIsADeviceOrAFifo) {
  start_daemon();
  const Outcome zero = ctl({"--timeout", "5", "calibrate", "--poses", "/dev/zero"});
  EXPECT_EQ(zero.code, kExitUsage);
  EXPECT_NE(zero.err.find("/dev/zero is a character device, not a regular file"), std::string::npos)
      << zero.err;
  const std::string fifo = dir_ + "/poses.fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const Outcome f = ctl({"--timeout", "5", "calibrate", "--poses", fifo});  // no writer
  EXPECT_EQ(f.code, kExitUsage);
  EXPECT_NE(f.err.find("is a FIFO, not a regular file"), std::string::npos) << f.err;
  EXPECT_TRUE(requests().empty());
}

TEST_F(CdprctlTest, ReportWritesTheHtmlAtomically) {
  start_daemon();
  const std::string html =
      "<!doctype html><html><body>anchors " + std::string(100000, 'x') + "</body></html>";
  script("report", ControlReply::ok({{"version", 2}, {"html", html}, {"gates_passed", true}}));
  const std::string file = dir_ + "/report.html";
  std::ofstream(file) << "old";
  const Outcome o = ctl({"report", "2", "--html", file});
  ASSERT_EQ(o.code, kExitOk) << o.err;
  EXPECT_EQ(requests().back().args, json({{"version", 2}, {"html", true}}));
  std::ifstream in(file);
  std::stringstream got;
  got << in.rdbuf();
  EXPECT_EQ(got.str(), html);
  EXPECT_NE(o.out.find("report of calibration 2 written to " + file), std::string::npos) << o.out;
  EXPECT_EQ(o.out.find("<html>"), std::string::npos);  // the page is not printed too
  std::size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir_)) {
    if (e.path().filename().string().rfind("report.html", 0) == 0) ++files;
  }
  EXPECT_EQ(files, 1u);  // no temporary left

  const Outcome nodir = ctl({"report", "--html", dir_ + "/missing/r.html"});
  EXPECT_EQ(nodir.code, kExitFailed);
  EXPECT_NE(nodir.err.find("missing"), std::string::npos) << nodir.err;
}

// ---- calibrate --wait with a scripted event stream ------------------------------------------

struct WaitCase {
  const char* name;
  std::vector<std::pair<std::string, json>> events;  // after the two progress events
  int exit_code;
  const char* printed;  // in stdout (ok) or stderr (not ok)
};

class CdprctlWaitTest : public CdprctlTest, public ::testing::WithParamInterface<WaitCase> {};

TEST_P(CdprctlWaitTest, WaitsForTheOutcomeOfItsCalibrationAndExitsWithItsCode) {
  const WaitCase& c = GetParam();
  start_daemon();
  script("calibrate", ControlReply::ok({{"version", 7}, {"poses", 25}}));
  after("calibrate", [this, c] {
    std::this_thread::sleep_for(20ms);
    const json p = {{"phase", "measuring"}, {"pose", 1},
                    {"poses", 25},          {"elapsed_s", 12.0},
                    {"remaining_s", 288.0}, {"tensions", {20.0, 80.5}},
                    {"laser_m", 1.23456}};
    server_->publish("progress", p);
    server_->publish("progress", p);  // same pose: one plain line only
    server_->publish("state", {{"state", "measuring"}, {"reason", "pose 1 of 25"}});
    // A calibration event of an earlier run is not ours.
    server_->publish("calibration", {{"version", 6}, {"outcome", "applied"}});
    for (const auto& [type, data] : c.events) server_->publish(type, data);
  });
  const Outcome o = ctl({"calibrate", "--wait"});
  EXPECT_EQ(o.code, c.exit_code) << o.out << o.err;
  const auto reqs = requests();
  ASSERT_EQ(reqs.size(), 2u);
  EXPECT_EQ(reqs[0].cmd, "watch");  // subscribed before the calibration starts
  EXPECT_EQ(reqs[1].cmd, "calibrate");
  EXPECT_NE(o.out.find("calibration 7 started"), std::string::npos) << o.out;
  const std::string line =
      "progress: measuring pose 1/25, elapsed 0:12, remaining 4:48, "
      "T 20.0..80.5 N, laser 1.23456 m\n";
  const std::size_t first = o.out.find(line);
  EXPECT_NE(first, std::string::npos) << o.out;
  EXPECT_EQ(o.out.find(line, first + 1), std::string::npos) << o.out;
  EXPECT_NE(o.out.find("state: measuring (pose 1 of 25)"), std::string::npos) << o.out;
  EXPECT_NE((c.exit_code == kExitOk ? o.out : o.err).find(c.printed), std::string::npos)
      << o.out << o.err;
}

INSTANTIATE_TEST_SUITE_P(
    Outcomes, CdprctlWaitTest,
    ::testing::Values(
        WaitCase{
            "applied",
            {{"calibration", {{"version", 7}, {"outcome", "applied"}, {"gates_passed", true}}}},
            kExitOk,
            "calibration 7: applied (gates passed)"},
        WaitCase{"awaiting_gates_passed",
                 {{"calibration",
                   {{"version", 7}, {"outcome", "awaiting_acceptance"}, {"gates_passed", true}}}},
                 kExitOk,
                 "cdprctl accept"},
        WaitCase{"awaiting_gates_failed",
                 {{"calibration",
                   {{"version", 7},
                    {"outcome", "awaiting_acceptance"},
                    {"gates_passed", false},
                    {"message", "chi2/dof 4.1 > 2"}}}},
                 kExitRejected,
                 "(gates failed): chi2/dof 4.1 > 2"},
        WaitCase{"rejected",
                 {{"calibration", {{"version", 7}, {"outcome", "rejected"}}}},
                 kExitRejected,
                 "calibration 7: rejected"},
        WaitCase{"failed",
                 {{"calibration",
                   {{"version", 7}, {"outcome", "failed"}, {"message", "not identifiable"}}}},
                 kExitRejected,
                 "failed: not identifiable"},
        WaitCase{"aborted",
                 {{"calibration", {{"version", 7}, {"outcome", "aborted"}}}},
                 kExitInterrupted,
                 "calibration 7: aborted"},
        WaitCase{"fault",
                 {{"fault", {{"fault", "drive_fault"}, {"node", 3}, {"message", "EMCY 0x2310"}}}},
                 kExitInterrupted,
                 "FAULT: drive_fault (node 3): EMCY 0x2310"}),
    [](const ::testing::TestParamInfo<WaitCase>& p) { return std::string(p.param.name); });

TEST_F(CdprctlTest, WaitWithJsonPrintsOneObjectWithTheStartAndTheOutcome) {
  start_daemon();
  script("calibrate", ControlReply::ok({{"version", 2}, {"poses", 25}}));
  after("calibrate", [this] {
    std::this_thread::sleep_for(20ms);
    server_->publish("progress", {{"phase", "moving"}, {"pose", 1}, {"poses", 25}});
    server_->publish("calibration", {{"version", 2}, {"outcome", "applied"}});
  });
  const Outcome o = ctl({"--json", "calibrate", "--wait"});
  ASSERT_EQ(o.code, kExitOk) << o.err;
  const json j = json::parse(o.out);
  EXPECT_EQ(j["calibrate"]["version"], json(2));
  EXPECT_EQ(j["calibration"]["outcome"], json("applied"));
}

TEST_F(CdprctlTest, WaitEndsWithThreeWhenTheDaemonGoesAway) {
  start_daemon();
  script("calibrate", ControlReply::ok({{"version", 1}}));
  after("calibrate", [this] {
    std::this_thread::sleep_for(50ms);
    server_->stop();
  });
  const Outcome o = ctl({"calibrate", "--wait"});
  EXPECT_EQ(o.code, kExitNotRunning);
  EXPECT_NE(o.err.find("cdprd closed the connection"), std::string::npos) << o.err;
}

TEST_F(CdprctlTest, WaitGivesUpAtTheTimeoutWithSeven) {
  start_daemon();
  script("calibrate", ControlReply::ok({{"version", 1}}));
  const Outcome o = ctl({"--timeout", "0.3", "calibrate", "--wait"});
  EXPECT_EQ(o.code, kExitTimeout);
  EXPECT_NE(o.err.find("no outcome before the timeout"), std::string::npos) << o.err;
}

// ---- watch ------------------------------------------------------------------------------------

TEST_F(CdprctlTest, WatchPrintsPlainLinesAndEndsWhenTheDaemonCloses) {
  start_daemon();
  after("watch", [this] {
    std::this_thread::sleep_for(20ms);
    server_->publish("progress", {{"phase", "moving"}, {"pose", 2}, {"poses", 25}});
    server_->publish("log", {{"level", "warning"}, {"message", "laser retry"}});
    server_->publish("fault", {{"fault", "cable_slack"}, {"node", 5}, {"message", "f 0.4 N"}});
    out_.wait_for("FAULT: cable_slack");
    server_->stop();
  });
  const Outcome o = ctl({"watch"});
  EXPECT_EQ(o.code, kExitNotRunning);
  EXPECT_NE(o.out.find("progress: moving pose 2/25"), std::string::npos) << o.out;
  EXPECT_NE(o.out.find("[warning] laser retry\n"), std::string::npos) << o.out;
  EXPECT_NE(o.out.find("FAULT: cable_slack (node 5): f 0.4 N\n"), std::string::npos) << o.out;
  EXPECT_EQ(o.out.find('\r'), std::string::npos);  // no terminal: no bar
}

TEST_F(CdprctlTest, WatchDrawsALiveBarOnATerminalAndEndsAtCtrlC) {
  start_daemon();
  std::atomic<bool> interrupted{false};
  after("watch", [this, &interrupted] {
    std::this_thread::sleep_for(20ms);
    for (int pose = 1; pose <= 3; ++pose) {
      server_->publish("progress", {{"phase", "measuring"},
                                    {"pose", pose},
                                    {"poses", 4},
                                    {"elapsed_s", 10.0 * pose},
                                    {"remaining_s", 10.0 * (4 - pose)},
                                    {"tensions", {15.0, 60.0}},
                                    {"laser_m", 0.75}});
    }
    server_->publish("state", {{"state", "identifying"}, {"reason", "all poses measured"}});
    out_.wait_for("state: identifying (all poses measured)\nmeasuring  pose 3/4");
    interrupted = true;
  });
  Environment env;
  env.terminal = true;
  env.terminal_width = 120;
  env.interrupted = &interrupted;
  const Outcome o = ctl({"watch"}, env);
  EXPECT_EQ(o.code, kExitOk) << o.err;
  EXPECT_NE(o.out.find("\rmeasuring  pose 3/4 [###############-----]  0:30 elapsed  0:10 left  "
                       "T 15.0..60.0 N  laser 0.75000 m\x1b[K"),
            std::string::npos)
      << o.out;
  // Another event clears the bar, prints its line, and redraws the bar.
  EXPECT_NE(o.out.find("\r\x1b[Kstate: identifying (all poses measured)\nmeasuring  pose 3/4"),
            std::string::npos)
      << o.out;
}

TEST_F(CdprctlTest, WatchWithJsonPrintsEachEventAsOneLine) {
  start_daemon();
  std::atomic<bool> interrupted{false};
  after("watch", [this, &interrupted] {
    std::this_thread::sleep_for(20ms);
    server_->publish("state", {{"state", "holding"}});
    server_->publish("state", {{"state", "moving"}});
    out_.wait_for("\"moving\"");
    interrupted = true;
  });
  Environment env;
  env.interrupted = &interrupted;
  const Outcome o = ctl({"--json", "watch"}, env);
  EXPECT_EQ(o.code, kExitOk);
  std::istringstream lines(o.out);
  std::string line;
  std::vector<json> events;
  while (std::getline(lines, line)) events.push_back(json::parse(line));
  ASSERT_EQ(events.size(), 2u) << o.out;
  EXPECT_EQ(events[1]["data"]["state"], json("moving"));
}

TEST(CdprctlRender, FormatsDurationsAndProgressWithinTheWidth) {
  EXPECT_EQ(format_duration(json(0.4)), "0:00");
  EXPECT_EQ(format_duration(json(83)), "1:23");
  EXPECT_EQ(format_duration(json(3723)), "1:02:03");
  EXPECT_EQ(format_duration(json("x")), "-");
  const std::string bar =
      progress_bar({{"phase", "measuring"}, {"pose", 25}, {"poses", 25}, {"laser_m", 1.0}}, 40);
  EXPECT_LE(bar.size(), 39u);
  EXPECT_EQ(bar.rfind("measuring  pose 25/25 [####", 0), 0u) << bar;
}

}  // namespace
}  // namespace cdpr::ctl
