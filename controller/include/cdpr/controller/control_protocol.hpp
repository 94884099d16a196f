// The control socket's protocol (docs/control-protocol.md): JSON lines over a Unix stream socket.
//
//   request  {"id": <int or string>, "cmd": "<name>", "args": {...}}        (args optional)
//   reply    {"id": <same>, "ok": true,  "result": {...}}
//            {"id": <same>, "ok": false, "error": {"code": "<code>", "message": "<text>"}}
//   event    {"event": "<type>", "data": {...}}       (only to clients that sent `watch`)
//
// This file holds what both ends share and what can be tested without a socket: the command table
// (names, privileged or not, the fields of `args` and their types), the error codes, the request
// parser (never throws, whatever the bytes) and the encoders (never throw either: strings that are
// not valid UTF-8 are written with U+FFFD in place of the bad bytes).
#pragma once

#include <sys/types.h>

#include <nlohmann/json.hpp>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "cdpr/status.hpp"

namespace cdpr::control {

// Longest request line the server accepts (without its '\n'); longer lines get bad_request.
inline constexpr std::size_t kDefaultMaxLine = 64 * 1024;
// Deepest nesting of arrays/objects accepted in a request (a guard against parser recursion).
inline constexpr int kMaxRequestDepth = 32;

// The error codes of a refused request ("error": {"code": ...}).
enum class ControlErrorCode {
  kBadRequest,      // not JSON, not an object, missing/invalid field, invalid UTF-8, too long
  kUnknownCommand,  // "cmd" names no command
  kNotPermitted,    // the peer may not run this (privileged) command
  kInvalidState,    // not possible in the daemon's current state (the message says why)
  kNotFound,        // a version or file does not exist
  kBusy,            // the daemon (or the server: too many clients) cannot take it now
  kFault,           // a robot fault prevents it
  kInternal,        // a bug of ours
};

std::string_view to_string(ControlErrorCode code);
std::optional<ControlErrorCode> control_error_from_string(std::string_view name);

// Who is at the other end of a connection (SO_PEERCRED at connect time).
struct PeerCredentials {
  pid_t pid = -1;
  uid_t uid = static_cast<uid_t>(-1);
  gid_t gid = static_cast<gid_t>(-1);
  // root, the daemon's own uid, or a member (primary or supplementary) of the configured group
  bool privileged_allowed = false;
};

// A request as the handler sees it: the command is known and its args are valid (types checked,
// no unknown fields; `args` is always an object, possibly empty).
struct ControlRequest {
  nlohmann::json id;  // integer or string, echoed in the reply
  std::string cmd;
  nlohmann::json args = nlohmann::json::object();
  PeerCredentials peer;
};

// What a handler returns: a result object, or a named error. No exceptions across the handler.
class ControlReply {
 public:
  static ControlReply ok(nlohmann::json result = nlohmann::json::object());
  static ControlReply error(ControlErrorCode code, std::string message);

  bool is_ok() const { return ok_; }
  const nlohmann::json& result() const { return result_; }  // an object when is_ok()
  ControlErrorCode code() const { return code_; }           // meaningful when !is_ok()
  const std::string& message() const { return message_; }   // idem

 private:
  bool ok_ = true;
  nlohmann::json result_ = nlohmann::json::object();
  ControlErrorCode code_ = ControlErrorCode::kInternal;
  std::string message_;
};

// ---- Command table ----------------------------------------------------------------------------

enum class ArgType { kBool, kString, kVersion /* integer >= 1 */, kPose /* 6 finite numbers */ };

struct ArgSpec {
  std::string_view name;
  ArgType type;
  bool required;
};

// Every command of the protocol, in documentation order (commands()[i].command == Command(i)):
// a handler table keyed by it (the daemon's) names each command's handler once.
enum class Command {
  kStatus,
  kCalibrate,
  kWatch,
  kAbort,
  kAccept,
  kReject,
  kGeometryShow,
  kGeometryDiff,
  kGeometryHistory,
  kGeometryRollback,
  kReport,
  kStop,
  kFaultReset,
  kMove,
  kEnable,
  kDisable,
  kHome,
  kRun,
  kStream,
  kHealth,
};
inline constexpr std::size_t kCommandCount = 20;

struct CommandSpec {
  std::string_view name;
  bool privileged;  // moves the robot or changes the geometry
  std::span<const ArgSpec> args;
  Command command;
};

// Every command of the protocol, in documentation order.
std::span<const CommandSpec> commands();
const CommandSpec* find_command(std::string_view name);
bool is_privileged(std::string_view cmd);

// ---- Requests (server side) -------------------------------------------------------------------

// The outcome of parsing one request line: either a request (command known, args valid) or the
// error to answer with, and the id to answer to (null when the line had no usable id).
struct ParsedRequest {
  nlohmann::json id;  // null, integer or string
  std::optional<ControlRequest> request;
  ControlErrorCode error_code = ControlErrorCode::kBadRequest;
  std::string error_message;
};

// Parses one line (without its '\n'). Never throws. Checks, in order: UTF-8 validity, nesting
// depth, JSON syntax, an object, "id" (integer or string), "cmd" (string, a known command),
// "args" (absent, or an object whose fields match the command's ArgSpecs).
ParsedRequest parse_request(std::string_view line);

// Checks `args` (an object) against `spec`; the message names the field and what it should be.
Status validate_args(const CommandSpec& spec, const nlohmann::json& args);

// Byte offset of the first byte that is not part of valid UTF-8 (RFC 3629: no overlong forms, no
// surrogates, nothing above U+10FFFF), or nullopt when all of `text` is valid.
std::optional<std::size_t> find_invalid_utf8(std::string_view text);

// ---- Encoders (never throw; each returns one line ending in '\n') ------------------------------

std::string encode_reply(const nlohmann::json& id, const ControlReply& reply);
std::string encode_event(std::string_view type, const nlohmann::json& data);
std::string encode_request(const nlohmann::json& id, std::string_view cmd,
                           const nlohmann::json& args);
// nlohmann's dump() with invalid UTF-8 replaced instead of thrown.
std::string dump_safely(const nlohmann::json& j, int indent = -1);

// ---- Server messages (client side) ------------------------------------------------------------

struct ServerMessage {
  bool is_event = false;
  // reply
  nlohmann::json id;
  ControlReply reply = ControlReply::ok();
  std::string error_code_name;  // the code as sent (also when this client does not know it)
  // event
  std::string event;
  nlohmann::json data;
};

// Parses one line from the server. kParseError with the reason when it is not a reply or event.
Result<ServerMessage> parse_server_message(std::string_view line);

}  // namespace cdpr::control
