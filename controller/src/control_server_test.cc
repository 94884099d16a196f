#include "cdpr/controller/control_server.hpp"

#include <fcntl.h>
#include <grp.h>
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <thread>
#include <vector>

#include "cdpr/controller/control_client.hpp"

namespace cdpr::control {
namespace {

using json = nlohmann::json;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

class TempDir {
 public:
  TempDir() {
    char tmpl[] = "/tmp/cdpr-ctl-XXXXXX";
    const char* d = ::mkdtemp(tmpl);
    if (d != nullptr) path_ = d;
    ::chmod(path_.c_str(), 0755);  // a test child with another uid must reach the socket
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// A scripted daemon: answers every command with {"cmd": ..., "args": ...} and records requests.
class ControlServerTest : public ::testing::Test {
 protected:
  ControlServerOptions options() const {
    ControlServerOptions o;
    o.path = dir_.path() + "/cdprd.sock";
    return o;
  }

  void start(ControlServerOptions o) {
    auto s = ControlServer::start(std::move(o), [this](const ControlRequest& r) {
      {
        std::lock_guard lock(mu_);
        seen_.push_back(r);
      }
      if (r.cmd == "status" && r.args.empty() && throw_on_status_) {
        throw std::runtime_error("scripted failure");
      }
      return ControlReply::ok({{"cmd", r.cmd}, {"args", r.args}});
    });
    ASSERT_TRUE(s.ok()) << s.status().to_string();
    server_ = std::move(s.value());
  }

  ControlClient connect() {
    auto c = ControlClient::connect(server_->path(), deadline_after(5));
    EXPECT_TRUE(c.ok()) << c.status().to_string();
    return std::move(c.value());
  }

  std::vector<ControlRequest> seen() {
    std::lock_guard lock(mu_);
    return seen_;
  }

  TempDir dir_;
  std::unique_ptr<ControlServer> server_;
  std::mutex mu_;
  std::vector<ControlRequest> seen_;
  bool throw_on_status_ = false;
};

json reply_of(ControlClient& c, std::string_view raw) {
  EXPECT_TRUE(c.send_raw(raw, deadline_after(5)).ok());
  auto line = c.read_line(deadline_after(5));
  EXPECT_TRUE(line.ok()) << line.status().to_string();
  if (!line.ok()) return nullptr;
  return json::parse(*line);
}

TEST_F(ControlServerTest, RepliesCarryTheRequestIdAndComeInOrder) {
  start(options());
  ControlClient c = connect();
  // Three requests in one write, integer and string ids.
  ASSERT_TRUE(c.send_raw("{\"id\":1,\"cmd\":\"status\"}\n"
                         "{\"id\":\"two\",\"cmd\":\"geometry_show\",\"args\":{\"version\":4}}\n"
                         "{\"id\":3,\"cmd\":\"geometry_history\"}\n",
                         deadline_after(5))
                  .ok());
  const json expected_ids[] = {1, "two", 3};
  const char* expected_cmds[] = {"status", "geometry_show", "geometry_history"};
  for (int i = 0; i < 3; ++i) {
    auto line = c.read_line(deadline_after(5));
    ASSERT_TRUE(line.ok()) << line.status().to_string();
    const json j = json::parse(*line);
    EXPECT_EQ(j["id"], expected_ids[i]);
    EXPECT_EQ(j["ok"], json(true));
    EXPECT_EQ(j["result"]["cmd"], json(expected_cmds[i]));
  }
  const auto reqs = seen();
  ASSERT_EQ(reqs.size(), 3u);
  EXPECT_EQ(reqs[1].args["version"], json(4));
  EXPECT_EQ(reqs[0].peer.uid, ::geteuid());
  EXPECT_EQ(reqs[0].peer.pid, ::getpid());
  EXPECT_TRUE(reqs[0].peer.privileged_allowed);
}

TEST_F(ControlServerTest, CreatesTheSocketWithMode0660AndTheGroup) {
  const group* g = ::getgrgid(::getegid());
  ASSERT_NE(g, nullptr);
  ControlServerOptions o = options();
  o.group = g->gr_name;
  const gid_t gid = g->gr_gid;
  start(o);
  struct stat sb {};
  ASSERT_EQ(::stat(o.path.c_str(), &sb), 0);
  EXPECT_TRUE(S_ISSOCK(sb.st_mode));
  EXPECT_EQ(sb.st_mode & 07777, 0660u);
  EXPECT_EQ(sb.st_gid, gid);
  // No temporary name is left behind.
  std::size_t entries = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator(dir_.path())) ++entries;
  EXPECT_EQ(entries, 1u);
}

TEST_F(ControlServerTest, RefusesAGroupThatDoesNotExist) {
  ControlServerOptions o = options();
  o.group = "cdpr-no-such-group-xyz";
  auto s = ControlServer::start(o, [](const ControlRequest&) { return ControlReply::ok(); });
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.status().code(), ErrorCode::kNotFound);
  EXPECT_NE(s.status().to_string().find("cdpr-no-such-group-xyz"), std::string::npos);
}

TEST_F(ControlServerTest, RefusesToStartWhenADaemonAlreadyAnswers) {
  start(options());
  auto second =
      ControlServer::start(options(), [](const ControlRequest&) { return ControlReply::ok(); });
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.status().code(), ErrorCode::kUnavailable);
  EXPECT_NE(second.status().to_string().find("already answering"), std::string::npos);
  // The first one still serves.
  ControlClient c = connect();
  auto r = c.call("status", json::object(), deadline_after(5));
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->is_ok());
}

TEST_F(ControlServerTest, ReplacesAStaleSocketLeftByADeadDaemon) {
  const std::string path = options().path;
  {
    const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path.c_str(), sizeof addr.sun_path - 1);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    ::close(fd);  // the file stays, nobody listens
  }
  start(options());
  ControlClient c = connect();
  auto r = c.call("status", json::object(), deadline_after(5));
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_TRUE(r->is_ok());
}

TEST_F(ControlServerTest, NeverReplacesAFileThatIsNotASocket) {
  const std::string path = options().path;
  std::ofstream(path) << "precious";
  auto s =
      ControlServer::start(options(), [](const ControlRequest&) { return ControlReply::ok(); });
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.status().code(), ErrorCode::kFailedPrecondition);
  std::ifstream in(path);
  std::string content;
  in >> content;
  EXPECT_EQ(content, "precious");
}

TEST_F(ControlServerTest, StopRemovesTheSocketAndClosesClients) {
  start(options());
  ControlClient c = connect();
  server_->stop();
  EXPECT_FALSE(std::filesystem::exists(options().path));
  auto line = c.read_line(deadline_after(5));
  ASSERT_FALSE(line.ok());
  EXPECT_EQ(line.status().code(), ErrorCode::kUnavailable);
  auto again = ControlClient::connect(options().path, deadline_after(1));
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.status().code(), ErrorCode::kNotFound);
}

TEST_F(ControlServerTest, EventsGoOnlyToWatchersAndAfterTheWatchReply) {
  start(options());
  ControlClient watcher = connect();
  ControlClient other = connect();
  auto w = watcher.call("watch", json::object(), deadline_after(5));
  ASSERT_TRUE(w.ok());
  ASSERT_TRUE(w->is_ok());
  server_->publish("progress", {{"pose", 3}, {"poses", 25}});
  server_->publish(json{{"event", "state"}, {"data", {{"state", "moving"}}}});
  auto e1 = watcher.next_event(deadline_after(5));
  ASSERT_TRUE(e1.ok()) << e1.status().to_string();
  EXPECT_EQ(e1->type, "progress");
  EXPECT_EQ(e1->data["pose"], json(3));
  auto e2 = watcher.next_event(deadline_after(5));
  ASSERT_TRUE(e2.ok());
  EXPECT_EQ(e2->type, "state");
  EXPECT_EQ(e2->data["state"], json("moving"));
  // The other client's next line is its reply, not an event.
  ASSERT_TRUE(other.send_raw("{\"id\":5,\"cmd\":\"status\"}\n", deadline_after(5)).ok());
  auto line = other.read_line(deadline_after(5));
  ASSERT_TRUE(line.ok());
  EXPECT_EQ(json::parse(*line)["id"], json(5));
  auto nothing = other.read_line(deadline_after(0.2));
  ASSERT_FALSE(nothing.ok());
  EXPECT_EQ(nothing.status().code(), ErrorCode::kTimeout);
  EXPECT_EQ(server_->stats().events_published, 2u);
}

TEST_F(ControlServerTest, AnswersBadRequestsWithNamedErrorsAndKeepsTheConnection) {
  ControlServerOptions o = options();
  o.max_line = 1024;
  start(o);
  ControlClient c = connect();
  struct Case {
    std::string raw;
    const char* code;
  };
  const std::vector<Case> cases = {
      {"this is not json\n", "bad_request"},
      {"{\"id\":1,\"cmd\":\"status\",\"args\":{\"x\":\"\xC3\x28\"}}\n", "bad_request"},
      {"{\"id\":2}\n", "bad_request"},
      {"{\"id\":3,\"cmd\":\"geometry_rollback\",\"args\":{\"version\":\"latest\"}}\n",
       "bad_request"},
      {"{\"id\":4,\"cmd\":\"self_destruct\"}\n", "unknown_command"},
      {"{\"id\":5,\"cmd\":\"status\",\"pad\":\"" + std::string(4000, 'x') + "\"}\n", "bad_request"},
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(k.raw.substr(0, 60));
    const json j = reply_of(c, k.raw);
    EXPECT_EQ(j["ok"], json(false));
    EXPECT_EQ(j["error"]["code"], json(k.code));
    EXPECT_FALSE(j["error"]["message"].get<std::string>().empty());
  }
  // A request cut into pieces is served once its newline arrives.
  ASSERT_TRUE(c.send_raw("{\"id\":9,", deadline_after(5)).ok());
  std::this_thread::sleep_for(30ms);
  ASSERT_TRUE(c.send_raw("\"cmd\":\"sta", deadline_after(5)).ok());
  std::this_thread::sleep_for(30ms);
  const json j = reply_of(c, "tus\"}\r\n");
  EXPECT_EQ(j["id"], json(9));
  EXPECT_EQ(j["ok"], json(true));
  EXPECT_EQ(server_->stats().bad_requests, cases.size());
  const auto reqs = seen();
  EXPECT_TRUE(std::none_of(reqs.begin(), reqs.end(),
                           [](const ControlRequest& r) { return r.cmd == "self_destruct"; }));
}

TEST_F(ControlServerTest, ResynchronisesAfterALineTooLongSentInPieces) {
  ControlServerOptions o = options();
  o.max_line = 1000;
  start(o);
  ControlClient c = connect();
  // 5000 bytes without a newline, in pieces: one bad_request, the rest discarded up to '\n'.
  for (int i = 0; i < 5; ++i) {
    ASSERT_TRUE(c.send_raw(std::string(1000, 'y'), deadline_after(5)).ok());
    std::this_thread::sleep_for(10ms);
  }
  auto first = c.read_line(deadline_after(5));
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(json::parse(*first)["error"]["code"], json("bad_request"));
  EXPECT_NE(json::parse(*first)["error"]["message"].get<std::string>().find("longer than 1000"),
            std::string::npos);
  const json j = reply_of(c, "tail of the long line\n{\"id\":10,\"cmd\":\"status\"}\n");
  EXPECT_EQ(j["id"], json(10));
  EXPECT_EQ(j["ok"], json(true));
}

TEST_F(ControlServerTest, AHandlerExceptionBecomesAnInternalError) {
  throw_on_status_ = true;
  start(options());
  ControlClient c = connect();
  auto r = c.call("status", json::object(), deadline_after(5));
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->is_ok());
  EXPECT_EQ(r->code(), ControlErrorCode::kInternal);
  EXPECT_NE(r->message().find("scripted failure"), std::string::npos);
}

TEST_F(ControlServerTest, ALastRequestWithoutNewlineBeforeShutdownIsAnswered) {
  start(options());
  ControlClient c = connect();
  ASSERT_TRUE(c.send_raw("{\"id\":77,\"cmd\":\"status\"}", deadline_after(5)).ok());
  ::shutdown(c.fd(), SHUT_WR);
  auto line = c.read_line(deadline_after(5));
  ASSERT_TRUE(line.ok()) << line.status().to_string();
  EXPECT_EQ(json::parse(*line)["id"], json(77));
  auto end = c.read_line(deadline_after(5));
  EXPECT_EQ(end.status().code(), ErrorCode::kUnavailable);  // closed after the answer
}

TEST(ControlPeerPolicy, AllowsRootTheDaemonUserAndGroupMembersOnly) {
  const std::optional<gid_t> group = 500;
  EXPECT_TRUE(peer_may_run_privileged(0, 0, 999, true, group, {}));
  EXPECT_TRUE(peer_may_run_privileged(999, 999, 999, true, group, {}));
  EXPECT_FALSE(peer_may_run_privileged(999, 999, 999, false, group, {}));
  EXPECT_TRUE(peer_may_run_privileged(1000, 500, 999, true, group, {}));          // primary
  EXPECT_TRUE(peer_may_run_privileged(1000, 1000, 999, true, group, {27, 500}));  // suppl.
  EXPECT_FALSE(peer_may_run_privileged(1000, 1000, 999, true, group, {27, 100}));
  EXPECT_FALSE(peer_may_run_privileged(1000, 500, 999, true, std::nullopt, {500}));
}

TEST(ControlPeerPolicy, GroupsOfRootIncludeItsPrimaryGroup) {
  const std::vector<gid_t> g = groups_of_uid(0);
  EXPECT_NE(std::find(g.begin(), g.end(), gid_t{0}), g.end());
}

// ---- peer credentials with a real second uid (root) or the own-uid switch (not root) --------

struct ChildOutcome {
  bool connected = false;
  std::string connect_error;  // ErrorCode name when not connected
  std::vector<json> replies;
};

// Forks; the child takes uid/gid (when given), connects and sends each request line; the replies
// come back through a pipe as JSON lines.
ChildOutcome run_as(std::optional<std::pair<uid_t, gid_t>> ids, const std::string& path,
                    const std::vector<std::string>& requests) {
  int fds[2];
  if (::pipe(fds) != 0) return {};
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(fds[0]);
    auto say = [&](const std::string& s) { (void)!::write(fds[1], s.data(), s.size()); };
    if (ids) {
      if (::setgroups(0, nullptr) != 0 || ::setgid(ids->second) != 0 || ::setuid(ids->first) != 0) {
        say("setid-failed\n");
        ::_exit(1);
      }
    }
    auto c = ControlClient::connect(path, deadline_after(5));
    if (!c.ok()) {
      say("connect-failed " + std::string(to_string(c.status().code())) + "\n");
      ::_exit(0);
    }
    say("connected\n");
    for (const auto& request : requests) {
      if (!c->send_raw(request + "\n", deadline_after(5)).ok()) break;
      auto line = c->read_line(deadline_after(5));
      if (!line.ok()) break;
      say(*line + "\n");
    }
    ::_exit(0);
  }
  ::close(fds[1]);
  std::string all;
  char buf[4096];
  ssize_t n;
  while ((n = ::read(fds[0], buf, sizeof buf)) > 0) all.append(buf, static_cast<std::size_t>(n));
  ::close(fds[0]);
  int status = 0;
  ::waitpid(pid, &status, 0);
  ChildOutcome out;
  std::istringstream in(all);
  std::string line;
  while (std::getline(in, line)) {
    if (line == "connected") {
      out.connected = true;
    } else if (line.rfind("connect-failed ", 0) == 0) {
      out.connect_error = line.substr(15);
    } else if (!line.empty() && line[0] == '{') {
      out.replies.push_back(json::parse(line));
    }
  }
  return out;
}

TEST_F(ControlServerTest, RefusesPrivilegedCommandsFromOutsidersBeforeTheHandlerAndLogsIt) {
  std::ostringstream log;
  auto previous = spdlog::default_logger();
  spdlog::set_default_logger(std::make_shared<spdlog::logger>(
      "test", std::make_shared<spdlog::sinks::ostream_sink_mt>(log)));
  ControlServerOptions o = options();
  std::optional<std::pair<uid_t, gid_t>> outsider;
  if (::geteuid() == 0) {
    o.mode = 0666;              // the outsider may connect, but is in no allowed group
    outsider = {65534, 65534};  // nobody
  } else {
    o.allow_own_uid = false;  // simulate: this uid is not the daemon's...
    const group* root_group = ::getgrgid(0);
    ASSERT_NE(root_group, nullptr);
    o.group = root_group->gr_name;  // ...and the group is one this user is not in
    const auto mine = groups_of_uid(::geteuid());
    ASSERT_EQ(std::find(mine.begin(), mine.end(), gid_t{0}), mine.end());
    ASSERT_NE(::getegid(), gid_t{0});
  }
  start(o);
  const ChildOutcome out = run_as(outsider, o.path,
                                  {R"({"id":1,"cmd":"stop"})", R"({"id":2,"cmd":"status"})",
                                   R"({"id":3,"cmd":"geometry_rollback","args":{"version":2}})"});
  const ControlServerStats stats = server_->stats();
  server_->stop();  // joins the server thread: nothing logs while the logger is swapped back
  spdlog::set_default_logger(previous);
  ASSERT_TRUE(out.connected) << out.connect_error;
  ASSERT_EQ(out.replies.size(), 3u);
  EXPECT_EQ(out.replies[0]["error"]["code"], json("not_permitted"));
  EXPECT_NE(out.replies[0]["error"]["message"].get<std::string>().find("stop"), std::string::npos);
  EXPECT_EQ(out.replies[1]["ok"], json(true));  // reading is allowed
  EXPECT_EQ(out.replies[2]["error"]["code"], json("not_permitted"));
  const auto reqs = seen();
  ASSERT_EQ(reqs.size(), 1u);
  EXPECT_EQ(reqs[0].cmd, "status");
  EXPECT_FALSE(reqs[0].peer.privileged_allowed);
  if (outsider) {
    EXPECT_EQ(reqs[0].peer.uid, outsider->first);
  }
  EXPECT_EQ(stats.refused, 2u);
  EXPECT_NE(log.str().find("refused stop from pid"), std::string::npos) << log.str();
}

// Every privileged command of the table (not just a sample), each with valid args, is refused
// for an outsider before the handler; every other command reaches the handler.
TEST_F(ControlServerTest, RefusesEveryPrivilegedCommandOfTheTableFromOutsiders) {
  ControlServerOptions o = options();
  std::optional<std::pair<uid_t, gid_t>> outsider;
  if (::geteuid() == 0) {
    o.mode = 0666;
    outsider = {65534, 65534};
  } else {
    o.allow_own_uid = false;
    const group* root_group = ::getgrgid(0);
    ASSERT_NE(root_group, nullptr);
    o.group = root_group->gr_name;
    const auto mine = groups_of_uid(::geteuid());
    ASSERT_EQ(std::find(mine.begin(), mine.end(), gid_t{0}), mine.end());
  }
  start(o);
  std::vector<std::string> lines;
  std::vector<std::string> names;
  std::size_t privileged = 0;
  for (const CommandSpec& c : commands()) {
    json args = json::object();
    for (const ArgSpec& a : c.args) {
      if (!a.required) continue;
      switch (a.type) {
        case ArgType::kBool:
          args[std::string(a.name)] = true;
          break;
        case ArgType::kString:
          args[std::string(a.name)] = "";
          break;
        case ArgType::kVersion:
          args[std::string(a.name)] = 1;
          break;
        case ArgType::kPose:
          args[std::string(a.name)] = json::array({0, 0, 0, 0, 0, 0});
          break;
      }
    }
    lines.push_back(json{{"id", lines.size()}, {"cmd", c.name}, {"args", args}}.dump());
    names.emplace_back(c.name);
    privileged += c.privileged ? 1 : 0;
  }
  const ChildOutcome out = run_as(outsider, o.path, lines);
  const ControlServerStats stats = server_->stats();
  server_->stop();
  ASSERT_TRUE(out.connected) << out.connect_error;
  ASSERT_EQ(out.replies.size(), lines.size());
  std::vector<std::string> handled;
  for (const auto& r : seen()) handled.push_back(r.cmd);
  for (std::size_t i = 0; i < names.size(); ++i) {
    const bool refused = out.replies[i]["ok"] == json(false) &&
                         out.replies[i]["error"]["code"] == json("not_permitted");
    EXPECT_EQ(refused, is_privileged(names[i])) << names[i] << ": " << out.replies[i].dump();
    EXPECT_EQ(std::count(handled.begin(), handled.end(), names[i]), is_privileged(names[i]) ? 0 : 1)
        << names[i];
  }
  EXPECT_GE(privileged,
            8u);  // calibrate abort accept reject geometry_rollback stop fault_reset move
  EXPECT_EQ(stats.refused, privileged);
}

TEST_F(ControlServerTest, AllowsPrivilegedCommandsToGroupMembersAndLogsThem) {
  std::ostringstream log;
  auto previous = spdlog::default_logger();
  spdlog::set_default_logger(std::make_shared<spdlog::logger>(
      "test", std::make_shared<spdlog::sinks::ostream_sink_mt>(log)));
  ControlServerOptions o = options();
  std::optional<std::pair<uid_t, gid_t>> member;
  if (::geteuid() == 0) {
    const group* g = ::getgrgid(65534);
    ASSERT_NE(g, nullptr);
    o.group = g->gr_name;  // mode 0660: the member connects through the group
    member = {65534, 65534};
  } else {
    o.allow_own_uid = false;
    const group* g = ::getgrgid(::getegid());
    ASSERT_NE(g, nullptr);
    o.group = g->gr_name;
  }
  start(o);
  const ChildOutcome out = run_as(member, o.path, {R"({"id":1,"cmd":"stop"})"});
  const ControlServerStats stats = server_->stats();
  server_->stop();  // joins the server thread: nothing logs while the logger is swapped back
  spdlog::set_default_logger(previous);
  ASSERT_TRUE(out.connected) << out.connect_error;
  ASSERT_EQ(out.replies.size(), 1u);
  EXPECT_EQ(out.replies[0]["ok"], json(true));
  const auto reqs = seen();
  ASSERT_EQ(reqs.size(), 1u);
  EXPECT_TRUE(reqs[0].peer.privileged_allowed);
  EXPECT_EQ(stats.refused, 0u);
  EXPECT_NE(log.str().find("control: stop from pid"), std::string::npos) << log.str();
}

TEST_F(ControlServerTest, APeerOutsideTheGroupCannotOpenTheSocket) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to run a client under a second uid";
  const group* g = ::getgrgid(::getegid());
  ASSERT_NE(g, nullptr);
  ControlServerOptions o = options();
  o.group = g->gr_name;
  start(o);
  const ChildOutcome out =
      run_as(std::pair<uid_t, gid_t>{65534, 65534}, o.path, {R"({"id":1,"cmd":"status"})"});
  EXPECT_FALSE(out.connected);
  EXPECT_EQ(out.connect_error, std::string(to_string(ErrorCode::kFailedPrecondition)));
  EXPECT_TRUE(seen().empty());
}

// ---- abuse ------------------------------------------------------------------------------------

// Latency of one status round trip.
//
// The two flood tests below hold the flood until the stalled client is dropped (stall_timeout,
// 3 s) and bound the probe's worst round trip and the slowest publish below that: a server that
// waited on the stalled client (up to its stall_timeout) fails, a loaded host does not.
constexpr auto kStall = std::chrono::seconds(3);
constexpr double kNotBlockedMs = 2000.0;

// Probes until `dropped` holds (at least 1.5 s, at most 60 s): the round trips in ms.
template <class Pred>
std::vector<double> probe_until(ControlClient& c, Pred dropped);
double round_trip_ms(ControlClient& c) {
  const auto t0 = Clock::now();
  auto r = c.call("status", json::object(), deadline_after(10));
  EXPECT_TRUE(r.ok()) << r.status().to_string();
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

template <class Pred>
std::vector<double> probe_until(ControlClient& c, Pred dropped) {
  std::vector<double> latencies;
  const auto t0 = Clock::now();
  while ((Clock::now() - t0 < 1500ms || !dropped()) && Clock::now() - t0 < 60s) {
    latencies.push_back(round_trip_ms(c));
    std::this_thread::sleep_for(5ms);
  }
  return latencies;
}

TEST_F(ControlServerTest, ServesTwoHundredConcurrentClients) {
  ControlServerOptions o = options();
  o.max_clients = 256;
  start(o);
  constexpr int kClients = 200;
  std::vector<ControlClient> clients;
  clients.reserve(kClients);
  for (int i = 0; i < kClients; ++i) clients.push_back(connect());
  // Everyone sends first, then everyone reads: all 200 are connected and pending at once.
  for (int i = 0; i < kClients; ++i) {
    ASSERT_TRUE(clients[static_cast<std::size_t>(i)]
                    .send_raw(encode_request(i, "status", json::object()), deadline_after(5))
                    .ok());
  }
  for (int i = 0; i < kClients; ++i) {
    auto line = clients[static_cast<std::size_t>(i)].read_line(deadline_after(10));
    ASSERT_TRUE(line.ok()) << i << ": " << line.status().to_string();
    EXPECT_EQ(json::parse(*line)["id"], json(i));
  }
  EXPECT_EQ(server_->stats().clients, static_cast<std::uint64_t>(kClients));
  EXPECT_EQ(server_->stats().clients_accepted, static_cast<std::uint64_t>(kClients));
}

TEST_F(ControlServerTest, TurnsAwayClientsBeyondTheLimitWithBusy) {
  ControlServerOptions o = options();
  o.max_clients = 3;
  start(o);
  std::vector<ControlClient> clients;
  for (int i = 0; i < 3; ++i) clients.push_back(connect());
  for (auto& c : clients) ASSERT_TRUE(c.call("status", json::object(), deadline_after(5)).ok());
  ControlClient extra = connect();  // the kernel accepts; the server answers busy and closes
  auto r = extra.call("status", json::object(), deadline_after(5));
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_FALSE(r->is_ok());
  EXPECT_EQ(r->code(), ControlErrorCode::kBusy);
  EXPECT_EQ(server_->stats().clients_rejected, 1u);
}

TEST_F(ControlServerTest, StaysResponsiveWhileAWatcherNeverReadsAndEventsFlood) {
  ControlServerOptions o = options();
  o.max_pending_bytes = 64 * 1024;
  o.stall_timeout = kStall;
  start(o);
  ControlClient sleeper = connect();  // watches, then never reads
  ASSERT_TRUE(sleeper.call("watch", json::object(), deadline_after(5)).ok());
  ControlClient probe = connect();
  round_trip_ms(probe);  // warm up

  std::atomic<bool> done{false};
  double slowest_publish_ms = 0;
  std::size_t published = 0;
  std::thread publisher([&] {
    const json data = {{"phase", "measuring"},
                       {"tensions", std::vector<double>(64, 123.456)},
                       {"message", std::string(512, 'p')}};
    while (!done.load()) {
      const auto t0 = Clock::now();
      server_->publish("progress", data);
      slowest_publish_ms = std::max(
          slowest_publish_ms, std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      ++published;
    }
  });
  std::vector<double> latencies =
      probe_until(probe, [&] { return server_->stats().clients_disconnected_slow >= 1; });
  done = true;
  publisher.join();
  std::sort(latencies.begin(), latencies.end());
  const double worst = latencies.back();
  const double median = latencies[latencies.size() / 2];
  std::printf(
      "[ figures  ] %zu events published (slowest publish %.3f ms); probe round trip over "
      "%zu calls: median %.3f ms, worst %.3f ms; events dropped %llu\n",
      published, slowest_publish_ms, latencies.size(), median, worst,
      static_cast<unsigned long long>(server_->stats().events_dropped));
  EXPECT_LT(worst, kNotBlockedMs);
  EXPECT_LT(slowest_publish_ms, kNotBlockedMs);
  const ControlServerStats s = server_->stats();
  EXPECT_GT(s.events_dropped, 0u);
  EXPECT_EQ(s.clients_disconnected_slow, 1u);  // the sleeper, after stall_timeout
  auto gone = sleeper.read_line(deadline_after(5));
  // It may still read what was queued before the disconnect, then end-of-stream.
  while (gone.ok()) gone = sleeper.read_line(deadline_after(5));
  EXPECT_EQ(gone.status().code(), ErrorCode::kUnavailable);
}

TEST_F(ControlServerTest, StaysResponsiveUnderARequestFloodFromAClientThatNeverReads) {
  ControlServerOptions o = options();
  o.max_pending_bytes = 64 * 1024;
  o.stall_timeout = kStall;
  start(o);
  ControlClient probe = connect();
  std::atomic<bool> done{false};
  std::atomic<std::size_t> flood_bytes{0};
  std::thread flooder([&] {
    auto c = ControlClient::connect(o.path, deadline_after(5));
    if (!c.ok()) return;
    const std::string line = encode_request(1, "status", json::object());
    std::string batch;
    for (int i = 0; i < 1000; ++i) batch += line;
    while (!done.load()) {
      const Status st = c->send_raw(batch, deadline_after(0.05));
      if (st.code() == ErrorCode::kTimeout) continue;  // back-pressure: the server stopped reading
      if (!st.ok()) break;                             // disconnected
      flood_bytes += batch.size();
    }
  });
  std::vector<double> latencies =
      probe_until(probe, [&] { return server_->stats().clients_disconnected_slow >= 1; });
  done = true;
  flooder.join();
  std::sort(latencies.begin(), latencies.end());
  std::printf(
      "[ figures  ] flood of %zu bytes of requests; probe round trip over %zu calls: "
      "median %.3f ms, worst %.3f ms; %llu requests served\n",
      flood_bytes.load(), latencies.size(), latencies[latencies.size() / 2], latencies.back(),
      static_cast<unsigned long long>(server_->stats().requests));
  EXPECT_LT(latencies.back(), kNotBlockedMs);
  EXPECT_EQ(server_->stats().clients_disconnected_slow, 1u);
}

}  // namespace
}  // namespace cdpr::control
