#include "cdpr/controller/control_protocol.hpp"

#include <array>
#include <cmath>
#include <utility>

namespace cdpr::control {

namespace {

using json = nlohmann::json;

constexpr std::array<std::pair<ControlErrorCode, std::string_view>, 8> kErrorNames{{
    {ControlErrorCode::kBadRequest, "bad_request"},
    {ControlErrorCode::kUnknownCommand, "unknown_command"},
    {ControlErrorCode::kNotPermitted, "not_permitted"},
    {ControlErrorCode::kInvalidState, "invalid_state"},
    {ControlErrorCode::kNotFound, "not_found"},
    {ControlErrorCode::kBusy, "busy"},
    {ControlErrorCode::kFault, "fault"},
    {ControlErrorCode::kInternal, "internal"},
}};

constexpr ArgSpec kCalibrateArgs[] = {{"dry_run", ArgType::kBool, false},
                                      {"poses_csv", ArgType::kString, false}};
constexpr ArgSpec kOptionalVersion[] = {{"version", ArgType::kVersion, false}};
constexpr ArgSpec kRequiredVersion[] = {{"version", ArgType::kVersion, true}};
constexpr ArgSpec kDiffArgs[] = {{"from", ArgType::kVersion, true},
                                 {"to", ArgType::kVersion, true}};
constexpr ArgSpec kReportArgs[] = {{"version", ArgType::kVersion, false},
                                   {"html", ArgType::kBool, false}};

constexpr ArgSpec kMoveArgs[] = {{"pose", ArgType::kPose, true}};
constexpr ArgSpec kHomeArgs[] = {{"method", ArgType::kString, false}};
// run: the path program's text (cdprctl reads the file) and the name its messages give it.
constexpr ArgSpec kRunArgs[] = {{"program", ArgType::kString, true},
                                {"source", ArgType::kString, false}};
constexpr ArgSpec kStreamArgs[] = {{"action", ArgType::kString, true}};

constexpr std::array<CommandSpec, kCommandCount> kCommands{{
    {"status", false, {}, Command::kStatus},
    {"calibrate", true, kCalibrateArgs, Command::kCalibrate},
    {"watch", false, {}, Command::kWatch},
    {"abort", true, {}, Command::kAbort},
    {"accept", true, {}, Command::kAccept},
    {"reject", true, {}, Command::kReject},
    {"geometry_show", false, kOptionalVersion, Command::kGeometryShow},
    {"geometry_diff", false, kDiffArgs, Command::kGeometryDiff},
    {"geometry_history", false, {}, Command::kGeometryHistory},
    {"geometry_rollback", true, kRequiredVersion, Command::kGeometryRollback},
    {"report", false, kReportArgs, Command::kReport},
    {"stop", true, {}, Command::kStop},
    {"fault_reset", true, {}, Command::kFaultReset},
    {"move", true, kMoveArgs, Command::kMove},
    {"enable", true, {}, Command::kEnable},
    {"disable", true, {}, Command::kDisable},
    {"home", true, kHomeArgs, Command::kHome},
    {"run", true, kRunArgs, Command::kRun},
    {"stream", true, kStreamArgs, Command::kStream},
    {"health", false, {}, Command::kHealth},
}};

constexpr bool commands_in_enum_order() {
  for (std::size_t i = 0; i < kCommands.size(); ++i) {
    if (kCommands[i].command != static_cast<Command>(i)) return false;
  }
  return true;
}
static_assert(commands_in_enum_order(), "kCommands[i].command must be Command(i)");

std::string_view type_name(ArgType t) {
  switch (t) {
    case ArgType::kBool:
      return "a boolean";
    case ArgType::kString:
      return "a string";
    case ArgType::kVersion:
      return "an integer version >= 1";
    case ArgType::kPose:
      return "[x, y, z, roll, pitch, yaw] (6 finite numbers: m, rad)";
  }
  return "?";
}

bool has_type(const json& v, ArgType t) {
  switch (t) {
    case ArgType::kBool:
      return v.is_boolean();
    case ArgType::kString:
      return v.is_string();
    case ArgType::kVersion:
      if (v.is_number_unsigned()) return v.get<std::uint64_t>() >= 1;
      if (v.is_number_integer()) return v.get<std::int64_t>() >= 1;
      return false;
    case ArgType::kPose:
      if (!v.is_array() || v.size() != 6) return false;
      for (const json& x : v) {
        if (!x.is_number() || !std::isfinite(x.get<double>())) return false;
      }
      return true;
  }
  return false;
}

// The nesting depth of `text` outside strings (valid JSON or not), stopping early past `limit`.
int nesting_depth(std::string_view text, int limit) {
  int depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    if (c == '"') {
      in_string = true;
    } else if (c == '{' || c == '[') {
      if (++depth > deepest) deepest = depth;
      if (deepest > limit) return deepest;
    } else if (c == '}' || c == ']') {
      --depth;
    }
  }
  return deepest;
}

ParsedRequest refuse(json id, ControlErrorCode code, std::string message) {
  ParsedRequest p;
  p.id = std::move(id);
  p.error_code = code;
  p.error_message = std::move(message);
  return p;
}

}  // namespace

std::string_view to_string(ControlErrorCode code) {
  for (const auto& [c, name] : kErrorNames) {
    if (c == code) return name;
  }
  return "internal";
}

std::optional<ControlErrorCode> control_error_from_string(std::string_view name) {
  for (const auto& [c, n] : kErrorNames) {
    if (n == name) return c;
  }
  return std::nullopt;
}

ControlReply ControlReply::ok(nlohmann::json result) {
  ControlReply r;
  r.ok_ = true;
  r.result_ = result.is_null() ? json::object() : std::move(result);
  return r;
}

ControlReply ControlReply::error(ControlErrorCode code, std::string message) {
  ControlReply r;
  r.ok_ = false;
  r.code_ = code;
  r.message_ = std::move(message);
  return r;
}

std::span<const CommandSpec> commands() {
  return kCommands;
}

const CommandSpec* find_command(std::string_view name) {
  for (const auto& c : kCommands) {
    if (c.name == name) return &c;
  }
  return nullptr;
}

bool is_privileged(std::string_view cmd) {
  const CommandSpec* c = find_command(cmd);
  return c != nullptr && c->privileged;
}

std::optional<std::size_t> find_invalid_utf8(std::string_view text) {
  const auto* s = reinterpret_cast<const unsigned char*>(text.data());
  const std::size_t n = text.size();
  std::size_t i = 0;
  while (i < n) {
    const unsigned char c = s[i];
    if (c < 0x80) {
      ++i;
      continue;
    }
    std::size_t len = 0;
    unsigned char lo = 0x80, hi = 0xBF;  // allowed range of the second byte
    if (c >= 0xC2 && c <= 0xDF) {
      len = 2;
    } else if (c == 0xE0) {
      len = 3, lo = 0xA0;  // no overlong 3-byte forms
    } else if (c >= 0xE1 && c <= 0xEC) {
      len = 3;
    } else if (c == 0xED) {
      len = 3, hi = 0x9F;  // no UTF-16 surrogates
    } else if (c >= 0xEE && c <= 0xEF) {
      len = 3;
    } else if (c == 0xF0) {
      len = 4, lo = 0x90;  // no overlong 4-byte forms
    } else if (c >= 0xF1 && c <= 0xF3) {
      len = 4;
    } else if (c == 0xF4) {
      len = 4, hi = 0x8F;  // nothing above U+10FFFF
    } else {
      return i;  // continuation byte without a lead, 0xC0/0xC1, 0xF5..0xFF
    }
    if (i + len > n) return i;
    if (s[i + 1] < lo || s[i + 1] > hi) return i;
    for (std::size_t k = 2; k < len; ++k) {
      if (s[i + k] < 0x80 || s[i + k] > 0xBF) return i;
    }
    i += len;
  }
  return std::nullopt;
}

Status validate_args(const CommandSpec& spec, const nlohmann::json& args) {
  if (!args.is_object()) {
    return Status::error(ErrorCode::kInvalidArgument, "\"args\" of %.*s must be an object",
                         static_cast<int>(spec.name.size()), spec.name.data());
  }
  for (const auto& [key, value] : args.items()) {
    const ArgSpec* a = nullptr;
    for (const auto& candidate : spec.args) {
      if (candidate.name == key) a = &candidate;
    }
    if (a == nullptr) {
      std::string msg = std::string(spec.name) + " takes no argument " + dump_safely(json(key));
      if (spec.args.empty()) {
        msg += " (it takes none)";
      } else {
        msg += " (it takes:";
        for (const auto& candidate : spec.args) (msg += ' ') += candidate.name;
        msg += ')';
      }
      return Status(ErrorCode::kInvalidArgument, msg);
    }
    if (!has_type(value, a->type)) {
      const std::string_view t = type_name(a->type);
      return Status::error(ErrorCode::kInvalidArgument, "args.%.*s of %.*s must be %.*s",
                           static_cast<int>(a->name.size()), a->name.data(),
                           static_cast<int>(spec.name.size()), spec.name.data(),
                           static_cast<int>(t.size()), t.data());
    }
  }
  for (const auto& a : spec.args) {
    if (a.required && !args.contains(a.name)) {
      const std::string_view t = type_name(a.type);
      return Status::error(ErrorCode::kInvalidArgument, "%.*s needs args.%.*s (%.*s)",
                           static_cast<int>(spec.name.size()), spec.name.data(),
                           static_cast<int>(a.name.size()), a.name.data(),
                           static_cast<int>(t.size()), t.data());
    }
  }
  return Status::success();
}

ParsedRequest parse_request(std::string_view line) {
  if (const auto bad = find_invalid_utf8(line)) {
    return refuse(nullptr, ControlErrorCode::kBadRequest,
                  "request is not valid UTF-8 (byte " + std::to_string(*bad) + ")");
  }
  if (nesting_depth(line, kMaxRequestDepth) > kMaxRequestDepth) {
    return refuse(nullptr, ControlErrorCode::kBadRequest,
                  "request nests deeper than " + std::to_string(kMaxRequestDepth) + " levels");
  }
  json j = json::parse(line, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) {
    // Parse again with exceptions for the position and reason (the invalid case only).
    std::string why = "request is not JSON";
    try {
      [[maybe_unused]] const json again = json::parse(line);
    } catch (const json::exception& e) {
      why += ": ";
      why += e.what();
    }
    return refuse(nullptr, ControlErrorCode::kBadRequest, std::move(why));
  }
  if (!j.is_object()) {
    return refuse(nullptr, ControlErrorCode::kBadRequest, "request must be a JSON object");
  }
  json id = nullptr;
  const auto id_it = j.find("id");
  if (id_it == j.end()) {
    return refuse(nullptr, ControlErrorCode::kBadRequest, "request has no \"id\"");
  }
  if (!id_it->is_number_integer() && !id_it->is_string()) {
    return refuse(nullptr, ControlErrorCode::kBadRequest, "\"id\" must be an integer or a string");
  }
  id = *id_it;
  const auto cmd_it = j.find("cmd");
  if (cmd_it == j.end()) {
    return refuse(std::move(id), ControlErrorCode::kBadRequest, "request has no \"cmd\"");
  }
  if (!cmd_it->is_string()) {
    return refuse(std::move(id), ControlErrorCode::kBadRequest, "\"cmd\" must be a string");
  }
  for (const auto& [key, value] : j.items()) {
    if (key != "id" && key != "cmd" && key != "args") {
      return refuse(
          std::move(id), ControlErrorCode::kBadRequest,
          "unknown request field " + dump_safely(json(key)) + " (a request has id, cmd and args)");
    }
  }
  const std::string& cmd = cmd_it->get_ref<const std::string&>();
  const CommandSpec* spec = find_command(cmd);
  if (spec == nullptr) {
    return refuse(std::move(id), ControlErrorCode::kUnknownCommand,
                  "unknown command " + dump_safely(json(cmd)));
  }
  json args = json::object();
  if (const auto args_it = j.find("args"); args_it != j.end()) args = std::move(*args_it);
  if (Status st = validate_args(*spec, args); !st.ok()) {
    return refuse(std::move(id), ControlErrorCode::kBadRequest, std::string(st.message()));
  }
  ParsedRequest p;
  p.id = id;
  p.request.emplace();
  p.request->id = std::move(id);
  p.request->cmd = cmd;
  p.request->args = std::move(args);
  return p;
}

std::string dump_safely(const nlohmann::json& j, int indent) {
  try {
    return j.dump(indent, ' ', false, json::error_handler_t::replace);
  } catch (...) {  // only allocation failure is left
    return "null";
  }
}

std::string encode_reply(const nlohmann::json& id, const ControlReply& reply) {
  json j;
  j["id"] = id;
  j["ok"] = reply.is_ok();
  if (reply.is_ok()) {
    j["result"] = reply.result().is_object() ? reply.result() : json{{"value", reply.result()}};
  } else {
    j["error"] = {{"code", to_string(reply.code())}, {"message", reply.message()}};
  }
  std::string s = dump_safely(j);
  s += '\n';
  return s;
}

std::string encode_event(std::string_view type, const nlohmann::json& data) {
  json j;
  j["event"] = type;
  j["data"] = data.is_null() ? json::object() : data;
  std::string s = dump_safely(j);
  s += '\n';
  return s;
}

std::string encode_request(const nlohmann::json& id, std::string_view cmd,
                           const nlohmann::json& args) {
  json j;
  j["id"] = id;
  j["cmd"] = cmd;
  if (!args.is_null() && !(args.is_object() && args.empty())) j["args"] = args;
  std::string s = dump_safely(j);
  s += '\n';
  return s;
}

Result<ServerMessage> parse_server_message(std::string_view line) {
  json j = json::parse(line, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) {
    return Status(ErrorCode::kParseError, "daemon sent a line that is not a JSON object");
  }
  ServerMessage m;
  if (const auto ev = j.find("event"); ev != j.end()) {
    if (!ev->is_string()) {
      return Status(ErrorCode::kParseError, "daemon sent an event whose \"event\" is no string");
    }
    m.is_event = true;
    m.event = ev->get<std::string>();
    if (const auto d = j.find("data"); d != j.end()) m.data = std::move(*d);
    if (m.data.is_null()) m.data = json::object();
    return m;
  }
  const auto id = j.find("id");
  const auto ok = j.find("ok");
  if (id == j.end() || ok == j.end() || !ok->is_boolean()) {
    return Status(ErrorCode::kParseError, "daemon sent a line that is neither reply nor event");
  }
  m.id = *id;
  if (ok->get<bool>()) {
    const auto r = j.find("result");
    m.reply = ControlReply::ok(r == j.end() ? json::object() : *r);
    return m;
  }
  const auto e = j.find("error");
  if (e == j.end() || !e->is_object()) {
    return Status(ErrorCode::kParseError, "daemon sent an error reply without \"error\"");
  }
  const json code = e->value("code", json());
  const json message = e->value("message", json());
  m.error_code_name = code.is_string() ? code.get<std::string>() : "internal";
  const auto known = control_error_from_string(m.error_code_name);
  m.reply = ControlReply::error(known.value_or(ControlErrorCode::kInternal),
                                message.is_string() ? message.get<std::string>() : "");
  return m;
}

}  // namespace cdpr::control
