// The control socket's request parser (control::parse_request) on one arbitrary line: never
// throws; a request it accepts was valid UTF-8 and names a known command with valid args; the
// reply the server would send (echoing the id, and the parser's own message for a refusal) is one
// line that a client parses back. The client's parser (parse_server_message) gets the same bytes.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "cdpr/controller/control_protocol.hpp"
#include "fuzz_util.hpp"

namespace ctl = cdpr::control;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view line(reinterpret_cast<const char*>(data), size);
  ctl::ParsedRequest parsed = ctl::parse_request(line);
  CDPR_FUZZ_CHECK(parsed.id.is_null() || parsed.id.is_number_integer() || parsed.id.is_string(),
                  "the id to answer is null, an integer or a string");
  ctl::ControlReply reply = ctl::ControlReply::ok();
  if (parsed.request) {
    CDPR_FUZZ_CHECK(!ctl::find_invalid_utf8(line).has_value(), "accepted lines are UTF-8");
    const ctl::CommandSpec* spec = ctl::find_command(parsed.request->cmd);
    CDPR_FUZZ_CHECK(spec != nullptr, "an accepted command is known");
    CDPR_FUZZ_CHECK(parsed.request->args.is_object(), "args is an object");
    CDPR_FUZZ_CHECK(ctl::validate_args(*spec, parsed.request->args).ok(), "args are valid");
    reply = ctl::ControlReply::ok({{"cmd", parsed.request->cmd}, {"args", parsed.request->args}});
  } else {
    CDPR_FUZZ_CHECK(!parsed.error_message.empty(), "a refusal names its reason");
    reply = ctl::ControlReply::error(parsed.error_code, parsed.error_message);
  }
  const std::string encoded = ctl::encode_reply(parsed.id, reply);
  CDPR_FUZZ_CHECK(!encoded.empty() && encoded.back() == '\n', "a reply is one line");
  CDPR_FUZZ_CHECK(encoded.find('\n') == encoded.size() - 1, "a reply has no inner newline");
  auto back = ctl::parse_server_message(std::string_view(encoded).substr(0, encoded.size() - 1));
  CDPR_FUZZ_CHECK(back.ok() && !back->is_event, "the client reads the reply back");
  CDPR_FUZZ_CHECK(back->reply.is_ok() == reply.is_ok(), "the reply keeps ok/error");
  // The same bytes as a server message (the client's side of the socket).
  auto server = ctl::parse_server_message(line);
  if (!server.ok()) {
    CDPR_FUZZ_CHECK(!server.status().message().empty(), "a refusal names its reason");
  }
  return 0;
}
