#include "cdpr/controller/control_protocol.hpp"

#include <gtest/gtest.h>

#include <random>
#include <set>
#include <string>

namespace cdpr::control {
namespace {

using json = nlohmann::json;

TEST(ControlProtocol, ParsesARequestWithIntegerIdAndArgs) {
  const ParsedRequest p = parse_request(R"({"id": 7, "cmd": "calibrate", "args": {"dry_run": true,
                                            "poses_csv": "pose,x\n"}})");
  ASSERT_TRUE(p.request.has_value()) << p.error_message;
  EXPECT_EQ(p.request->id, json(7));
  EXPECT_EQ(p.request->cmd, "calibrate");
  EXPECT_EQ(p.request->args["dry_run"], json(true));
  EXPECT_EQ(p.request->args["poses_csv"], json("pose,x\n"));
}

TEST(ControlProtocol, ParsesAStringIdAndGivesAnEmptyObjectWithoutArgs) {
  const ParsedRequest p = parse_request(R"({"id":"abc","cmd":"status"})");
  ASSERT_TRUE(p.request.has_value()) << p.error_message;
  EXPECT_EQ(p.request->id, json("abc"));
  EXPECT_TRUE(p.request->args.is_object());
  EXPECT_TRUE(p.request->args.empty());
}

struct BadCase {
  const char* line;
  ControlErrorCode code;
  const char* message_part;
  bool id_kept;
};

TEST(ControlProtocol, RefusesMalformedRequestsWithANamedReason) {
  const BadCase cases[] = {
      {"not json", ControlErrorCode::kBadRequest, "not JSON", false},
      {"[1,2]", ControlErrorCode::kBadRequest, "JSON object", false},
      {R"({"cmd":"status"})", ControlErrorCode::kBadRequest, "no \"id\"", false},
      {R"({"id":1.5,"cmd":"status"})", ControlErrorCode::kBadRequest, "\"id\"", false},
      {R"({"id":null,"cmd":"status"})", ControlErrorCode::kBadRequest, "\"id\"", false},
      {R"({"id":1})", ControlErrorCode::kBadRequest, "no \"cmd\"", true},
      {R"({"id":1,"cmd":5})", ControlErrorCode::kBadRequest, "\"cmd\" must be a string", true},
      {R"({"id":1,"cmd":"fly"})", ControlErrorCode::kUnknownCommand, "fly", true},
      {R"({"id":1,"cmd":"status","extra":1})", ControlErrorCode::kBadRequest, "extra", true},
      {R"({"id":1,"cmd":"status","args":[]})", ControlErrorCode::kBadRequest, "object", true},
      {R"({"id":1,"cmd":"status","args":{"x":1}})", ControlErrorCode::kBadRequest, "takes none",
       true},
      {R"({"id":1,"cmd":"calibrate","args":{"dry_run":"yes"}})", ControlErrorCode::kBadRequest,
       "args.dry_run of calibrate must be a boolean", true},
      {R"({"id":1,"cmd":"calibrate","args":{"dryrun":true}})", ControlErrorCode::kBadRequest,
       "dry_run poses_csv", true},
      {R"({"id":1,"cmd":"geometry_rollback"})", ControlErrorCode::kBadRequest, "needs args.version",
       true},
      {R"({"id":1,"cmd":"geometry_rollback","args":{"version":0}})", ControlErrorCode::kBadRequest,
       "integer version >= 1", true},
      {R"({"id":1,"cmd":"geometry_rollback","args":{"version":"3"}})",
       ControlErrorCode::kBadRequest, "integer version >= 1", true},
      {R"({"id":1,"cmd":"geometry_diff","args":{"from":1}})", ControlErrorCode::kBadRequest,
       "needs args.to", true},
      {R"({"id":1,"cmd":"report","args":{"html":1}})", ControlErrorCode::kBadRequest, "args.html",
       true},
  };
  for (const BadCase& c : cases) {
    SCOPED_TRACE(c.line);
    const ParsedRequest p = parse_request(c.line);
    ASSERT_FALSE(p.request.has_value());
    EXPECT_EQ(p.error_code, c.code);
    EXPECT_NE(p.error_message.find(c.message_part), std::string::npos) << p.error_message;
    if (c.id_kept) {
      EXPECT_EQ(p.id, json(1));
    } else {
      EXPECT_TRUE(p.id.is_null());
    }
  }
}

TEST(ControlProtocol, RefusesInvalidUtf8AndNamesTheByte) {
  std::string line = R"({"id":1,"cmd":"status","args":{"x":"ab)";
  const std::size_t bad_at = line.size();
  line += "\xC3\x28";  // a 2-byte lead followed by a non-continuation byte
  line += R"("}})";
  const ParsedRequest p = parse_request(line);
  ASSERT_FALSE(p.request.has_value());
  EXPECT_EQ(p.error_code, ControlErrorCode::kBadRequest);
  EXPECT_NE(p.error_message.find("UTF-8 (byte " + std::to_string(bad_at) + ")"), std::string::npos)
      << p.error_message;
}

TEST(ControlProtocol, Utf8ValidatorFollowsRfc3629) {
  EXPECT_FALSE(find_invalid_utf8("plain ascii").has_value());
  EXPECT_FALSE(find_invalid_utf8("\xC3\xA9\xE2\x82\xAC\xF0\x9F\x98\x80").has_value());  // é € 😀
  EXPECT_EQ(find_invalid_utf8("ab\xC0\xAF"), 2u);        // overlong '/'
  EXPECT_EQ(find_invalid_utf8("\xE0\x80\xAF"), 0u);      // overlong 3-byte
  EXPECT_EQ(find_invalid_utf8("x\xED\xA0\x80"), 1u);     // UTF-16 surrogate
  EXPECT_EQ(find_invalid_utf8("\xF4\x90\x80\x80"), 0u);  // above U+10FFFF
  EXPECT_EQ(find_invalid_utf8("\x80"), 0u);              // lone continuation
  EXPECT_EQ(find_invalid_utf8("abc\xE2\x82"), 3u);       // truncated at the end
  EXPECT_EQ(find_invalid_utf8("\xFF"), 0u);
}

TEST(ControlProtocol, RefusesNestingDeeperThanTheLimit) {
  std::string deep = R"({"id":1,"cmd":"status","args":{"x":)";
  std::string tail;
  for (int i = 0; i < kMaxRequestDepth; ++i) {
    deep += '[';
    tail += ']';
  }
  deep += tail + "}}";
  const ParsedRequest p = parse_request(deep);
  ASSERT_FALSE(p.request.has_value());
  EXPECT_NE(p.error_message.find("nests deeper"), std::string::npos) << p.error_message;
}

TEST(ControlProtocol, EveryPrivilegedCommandIsMarkedAndOnlyThose) {
  // Those that move the robot or change the geometry (docs/control-protocol.md, Permissions).
  const std::set<std::string> privileged = {
      "calibrate", "abort",       "accept", "reject", "geometry_rollback",
      "stop",      "fault_reset", "move",   "enable", "disable",
      "home",      "run",         "stream"};
  const std::set<std::string> open = {
      "status", "watch", "geometry_show", "geometry_diff", "geometry_history", "report", "health"};
  std::set<std::string> seen;
  for (const CommandSpec& c : commands()) {
    const std::string name(c.name);
    EXPECT_TRUE(privileged.count(name) + open.count(name) == 1) << name << " is not documented";
    EXPECT_EQ(c.privileged, privileged.count(name) == 1) << name;
    EXPECT_EQ(is_privileged(c.name), c.privileged);
    EXPECT_TRUE(seen.insert(name).second) << name << " twice";
  }
  EXPECT_EQ(seen.size(), privileged.size() + open.size());
  EXPECT_FALSE(is_privileged("no_such_command"));
}

TEST(ControlProtocol, MoveTakesSixFiniteNumbers) {
  EXPECT_TRUE(parse_request(R"({"id":1,"cmd":"move","args":{"pose":[0.1,0.2,0.3,0,0,0.05]}})")
                  .request.has_value());
  for (const char* bad :
       {R"({"id":1,"cmd":"move"})", R"({"id":1,"cmd":"move","args":{"pose":[0.1,0.2,0.3]}})",
        R"({"id":1,"cmd":"move","args":{"pose":[0.1,0.2,0.3,0,0,"x"]}})",
        R"({"id":1,"cmd":"move","args":{"pose":[0.1,0.2,0.3,0,0,null]}})"}) {
    const ParsedRequest p = parse_request(bad);
    EXPECT_FALSE(p.request.has_value()) << bad;
    EXPECT_EQ(p.error_code, ControlErrorCode::kBadRequest) << bad;
    EXPECT_NE(p.error_message.find("pose"), std::string::npos) << p.error_message;
  }
}

TEST(ControlProtocol, ErrorCodesRoundTripThroughTheirNames) {
  for (ControlErrorCode c : {ControlErrorCode::kBadRequest, ControlErrorCode::kUnknownCommand,
                             ControlErrorCode::kNotPermitted, ControlErrorCode::kInvalidState,
                             ControlErrorCode::kNotFound, ControlErrorCode::kBusy,
                             ControlErrorCode::kFault, ControlErrorCode::kInternal}) {
    EXPECT_EQ(control_error_from_string(to_string(c)), c);
  }
  EXPECT_FALSE(control_error_from_string("nope").has_value());
}

TEST(ControlProtocol, EncodersWriteOneLineAndReplaceInvalidUtf8InsteadOfThrowing) {
  const std::string bad = std::string("tension \xFF") + "\n";
  const std::string reply = encode_reply(3, ControlReply::ok({{"text", bad}}));
  ASSERT_FALSE(reply.empty());
  EXPECT_EQ(reply.back(), '\n');
  EXPECT_EQ(reply.find('\n'), reply.size() - 1);  // the embedded newline is escaped
  EXPECT_FALSE(find_invalid_utf8(reply).has_value());
  const json j = json::parse(reply);
  EXPECT_EQ(j["id"], json(3));
  EXPECT_EQ(j["ok"], json(true));
  EXPECT_EQ(j["result"]["text"].get<std::string>(), "tension \xEF\xBF\xBD\n");

  const std::string event = encode_event("log", {{"message", std::string("\xC3")}});
  EXPECT_EQ(json::parse(event)["event"], json("log"));
  const std::string err =
      encode_reply("x", ControlReply::error(ControlErrorCode::kInvalidState, "moving"));
  const json e = json::parse(err);
  EXPECT_EQ(e["error"]["code"], json("invalid_state"));
  EXPECT_EQ(e["error"]["message"], json("moving"));
}

TEST(ControlProtocol, ServerMessagesParseBackIntoRepliesAndEvents) {
  auto r = parse_server_message(
      encode_reply(9, ControlReply::error(ControlErrorCode::kFault, "drive 3 in fault")));
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->is_event);
  EXPECT_EQ(r->id, json(9));
  EXPECT_FALSE(r->reply.is_ok());
  EXPECT_EQ(r->reply.code(), ControlErrorCode::kFault);
  EXPECT_EQ(r->reply.message(), "drive 3 in fault");

  auto e = parse_server_message(encode_event("progress", {{"pose", 4}}));
  ASSERT_TRUE(e.ok());
  EXPECT_TRUE(e->is_event);
  EXPECT_EQ(e->event, "progress");
  EXPECT_EQ(e->data["pose"], json(4));

  EXPECT_FALSE(parse_server_message("garbage").ok());
  EXPECT_FALSE(parse_server_message(R"({"id":1})").ok());
  auto unknown = parse_server_message(R"({"id":1,"ok":false,"error":{"code":"new_code"}})");
  ASSERT_TRUE(unknown.ok());
  EXPECT_EQ(unknown->error_code_name, "new_code");
}

TEST(ControlProtocol, RequestEncoderAndParserAgree) {
  const std::string line = encode_request(42, "geometry_diff", {{"from", 1}, {"to", 2}});
  ASSERT_EQ(line.back(), '\n');
  const ParsedRequest p = parse_request(std::string_view(line).substr(0, line.size() - 1));
  ASSERT_TRUE(p.request.has_value()) << p.error_message;
  EXPECT_EQ(p.request->cmd, "geometry_diff");
  EXPECT_EQ(p.request->args["to"], json(2));
}

// Security: the daemon never opens a path that comes from a request. The protocol enforces it:
// versions are integers (a path, a file name or a number in a string is refused), no command takes
// a field that could name a file, and the only string argument is the pose list's content.
TEST(ControlProtocol, RefusesPathLikeValuesWhereAVersionIsExpected) {
  const json path_like[] = {"../../etc/passwd",   "/etc/shadow", "1/../../x", "000001.yaml",
                            "geometry/000001",    "1",           "",          json::array({1}),
                            json{{"path", ".."}}, 1.5,           -1,          0};
  std::size_t checked = 0;
  for (const CommandSpec& c : commands()) {
    for (const ArgSpec& a : c.args) {
      if (a.type != ArgType::kVersion) continue;
      for (const json& v : path_like) {
        json args = json::object();
        for (const ArgSpec& other : c.args) {
          if (other.type == ArgType::kVersion) args[std::string(other.name)] = 1;
        }
        args[std::string(a.name)] = v;
        const std::string line = json{{"id", 1}, {"cmd", c.name}, {"args", args}}.dump();
        const ParsedRequest p = parse_request(line);
        ASSERT_FALSE(p.request.has_value()) << line;
        EXPECT_EQ(p.error_code, ControlErrorCode::kBadRequest) << line;
        EXPECT_NE(p.error_message.find(std::string(a.name)), std::string::npos) << p.error_message;
        ++checked;
      }
    }
  }
  // geometry_show, geometry_diff (from, to), geometry_rollback, report.
  EXPECT_EQ(checked, 5 * std::size(path_like));
}

TEST(ControlProtocol, NoCommandTakesAFieldThatCouldNameAFile) {
  const char* fields[] = {"path",   "file",  "poses", "pose_file", "output", "state_directory",
                          "socket", "config"};
  for (const CommandSpec& c : commands()) {
    for (const char* f : fields) {
      const std::string line =
          json{{"id", 1}, {"cmd", c.name}, {"args", {{f, "/etc/passwd"}}}}.dump();
      const ParsedRequest p = parse_request(line);
      ASSERT_FALSE(p.request.has_value()) << line;
      EXPECT_EQ(p.error_code, ControlErrorCode::kBadRequest) << line;
    }
  }
  // Every string argument in the table is reviewed here: a new one must be content, not a path.
  // (run's `source` only labels the program's messages, e.g. "demo.path:4: X1.2.3: ...")
  const std::set<std::string> content_strings = {"poses_csv", "method", "program", "source",
                                                 "action"};
  for (const CommandSpec& c : commands()) {
    for (const ArgSpec& a : c.args) {
      if (a.type == ArgType::kString) {
        EXPECT_EQ(content_strings.count(std::string(a.name)), 1u)
            << c.name << " takes the string argument " << a.name
            << ": if it can name a file, the daemon must not open it";
      }
    }
  }
}

TEST(ControlProtocol, RandomBytesNeverCrashTheParser) {
  std::mt19937 rng(12345);
  std::uniform_int_distribution<int> byte(0, 255), len(0, 200);
  const std::string alphabet = R"({}[]":,0123456789 idcmdargstrue\)";
  std::size_t refused = 0;
  for (int i = 0; i < 20000; ++i) {
    std::string s;
    const int n = len(rng);
    for (int k = 0; k < n; ++k) {
      const int b = byte(rng);
      s += (i % 2 == 0) ? static_cast<char>(b)
                        : alphabet[static_cast<std::size_t>(b) % alphabet.size()];
    }
    const ParsedRequest p = parse_request(s);
    if (!p.request) {
      ++refused;
      EXPECT_FALSE(p.error_message.empty());
    }
  }
  EXPECT_GT(refused, 0u);
}

}  // namespace
}  // namespace cdpr::control
