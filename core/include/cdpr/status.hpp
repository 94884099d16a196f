// Errors as values at every boundary of cdpr.
//
// A Status is a code plus a human message that names what is wrong (the file, line, field, CAN node
// or interface). The message lives in a fixed buffer, so creating, copying and returning a Status
// never allocates: the RT loop may use it. Result<T> carries either a value or a non-ok Status
// (std::expected is C++23; this is the small subset we need).
//
// Propagating an error is written with one of two macros, in a function that returns Status or
// Result<U>:
//
//   CDPR_RETURN_IF_ERROR(bus.send(frame));               // a Status: returned when not ok
//   CDPR_ASSIGN_OR_RETURN(RobotModel m, load(path));     // a Result<T>: declares m, or returns
//   CDPR_ASSIGN_OR_RETURN(auto list, read_pose_list(p)); //   the Status
//   CDPR_ASSIGN_OR_RETURN(config.period, period(node));  // assigns to an existing lvalue
//
// CDPR_ASSIGN_OR_RETURN is several statements (its left-hand side may be a declaration in the
// enclosing scope): give it a line of its own, never the unbraced body of an `if` or a loop.
// Neither macro allocates, so both may be used on the RT path.
#pragma once

#include <array>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

namespace cdpr {

enum class ErrorCode {
  kOk = 0,
  kInvalidArgument,   // the caller's input is wrong (config field, frame, parameter)
  kNotFound,          // an interface, file, node or object does not exist
  kTimeout,           // nothing arrived in time
  kIoError,           // the operating system refused (errno given in the message)
  kProtocolError,     // a peer answered with something the protocol forbids
  kAborted,           // a peer aborted (SDO abort, Modbus exception), or an operator abort
  kUnavailable,       // the resource exists but cannot be used now (interface down, bus-off)
  kParseError,        // a file or message could not be read
  kNumericalFailure,  // a solver did not converge or the problem is singular
  kOutOfRange,        // a value is outside its allowed range
  kFailedPrecondition,
  kInternal,  // a bug of ours
};

constexpr std::string_view to_string(ErrorCode c) {
  switch (c) {
    case ErrorCode::kOk:
      return "ok";
    case ErrorCode::kInvalidArgument:
      return "invalid argument";
    case ErrorCode::kNotFound:
      return "not found";
    case ErrorCode::kTimeout:
      return "timeout";
    case ErrorCode::kIoError:
      return "I/O error";
    case ErrorCode::kProtocolError:
      return "protocol error";
    case ErrorCode::kAborted:
      return "aborted";
    case ErrorCode::kUnavailable:
      return "unavailable";
    case ErrorCode::kParseError:
      return "parse error";
    case ErrorCode::kNumericalFailure:
      return "numerical failure";
    case ErrorCode::kOutOfRange:
      return "out of range";
    case ErrorCode::kFailedPrecondition:
      return "failed precondition";
    case ErrorCode::kInternal:
      return "internal error";
  }
  return "unknown";
}

class Status {
 public:
  static constexpr std::size_t kMaxMessage = 512;

  constexpr Status() = default;
  Status(ErrorCode code, std::string_view message) : code_(code) { set(message); }

  // printf-style constructor for messages with values: Status::error(kTimeout, "node %d ...", id).
  // A message longer than the buffer loses its middle ("...") so that both the file and field at
  // its start and the end of the reason survive.
  [[gnu::format(printf, 2, 3)]] static Status error(ErrorCode code, const char* fmt, ...) {
    Status s;
    s.code_ = code;
    std::array<char, kFormatBuffer> wide;  // on the stack: no allocation
    va_list args;
    va_start(args, fmt);
    const int n = std::vsnprintf(wide.data(), wide.size(), fmt, args);
    va_end(args);
    const std::size_t len =
        n < 0 ? 0 : (static_cast<std::size_t>(n) < wide.size() ? n : wide.size() - 1);
    s.set(std::string_view(wide.data(), len));
    return s;
  }
  static constexpr Status success() { return {}; }

  bool ok() const { return code_ == ErrorCode::kOk; }
  explicit operator bool() const { return ok(); }
  ErrorCode code() const { return code_; }
  std::string_view message() const { return std::string_view(msg_.data()); }
  // "timeout: SDO upload 0x6064:00 from node 3 got no answer in 100 ms"
  std::string to_string() const {
    std::string s(cdpr::to_string(code_));
    if (msg_[0] != '\0') {
      s += ": ";
      s += message();
    }
    return s;
  }
  // Prefixes context to the message: "reading config.yaml: " + old message. When both do not
  // fit, each loses its middle ("..."), never its ends: the context (usually a long path) keeps
  // its start and its file name, the message keeps the start and the end of the reason. The
  // context gets what the message leaves, and at least a third of the buffer.
  Status& prepend(std::string_view context) {
    constexpr std::size_t kCap = kMaxMessage - 1;
    const std::size_t old_len = std::strlen(msg_.data());
    std::size_t ctx_budget = context.size();
    if (ctx_budget + old_len > kCap) {
      const std::size_t left = kCap > old_len ? kCap - old_len : 0;
      const std::size_t share = left > kCap / 3 ? left : kCap / 3;
      ctx_budget = context.size() < share ? context.size() : share;
    }
    std::array<char, kMaxMessage> out{};
    const std::size_t n = elide(context, out.data(), ctx_budget, /*head_thirds=*/1);
    const std::size_t m =
        elide(std::string_view(msg_.data(), old_len), out.data() + n, kCap - n, /*head_thirds=*/2);
    out[n + m] = '\0';
    msg_ = out;
    return *this;
  }

 private:
  // Size of the stack buffer error() formats into before shortening to kMaxMessage.
  static constexpr std::size_t kFormatBuffer = 4096;

  // Copies `src` to `dst` (no terminator), at most `budget` characters: when longer, its start
  // (head_thirds / 3 of the budget), "..." and its end. Returns the characters written.
  static std::size_t elide(std::string_view src, char* dst, std::size_t budget, int head_thirds) {
    constexpr std::string_view kEllipsis = "...";
    if (src.size() <= budget) {
      std::memcpy(dst, src.data(), src.size());
      return src.size();
    }
    if (budget <= kEllipsis.size()) {
      std::memcpy(dst, src.data(), budget);
      return budget;
    }
    const std::size_t keep = budget - kEllipsis.size();
    const std::size_t head = keep * static_cast<std::size_t>(head_thirds) / 3, tail = keep - head;
    std::memcpy(dst, src.data(), head);
    std::memcpy(dst + head, kEllipsis.data(), kEllipsis.size());
    std::memcpy(dst + head + kEllipsis.size(), src.data() + src.size() - tail, tail);
    return budget;
  }
  void set(std::string_view m) {
    const std::size_t n = elide(m, msg_.data(), kMaxMessage - 1, /*head_thirds=*/2);
    msg_[n] = '\0';
  }
  ErrorCode code_ = ErrorCode::kOk;
  std::array<char, kMaxMessage> msg_{};
};

// A value or the reason there is none.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : value_(std::move(value)) {}         // NOLINT(google-explicit-constructor)
  Result(Status status) : status_(std::move(status)) {  // NOLINT(google-explicit-constructor)
    if (status_.ok()) status_ = Status(ErrorCode::kInternal, "Result built from an ok Status");
  }

  bool ok() const { return value_.has_value(); }
  explicit operator bool() const { return ok(); }
  const Status& status() const { return status_; }
  T& value() & { return *value_; }
  const T& value() const& { return *value_; }
  T&& value() && { return std::move(*value_); }
  T* operator->() { return &*value_; }
  const T* operator->() const { return &*value_; }
  T& operator*() & { return *value_; }
  const T& operator*() const& { return *value_; }

 private:
  std::optional<T> value_;
  Status status_;
};

}  // namespace cdpr

// Returns the Status `expr` from the enclosing function when it is not ok.
#define CDPR_RETURN_IF_ERROR(expr)                               \
  do {                                                           \
    const ::cdpr::Status& cdpr_return_if_error_status_ = (expr); \
    if (!cdpr_return_if_error_status_.ok()) {                    \
      return cdpr_return_if_error_status_;                       \
    }                                                            \
  } while (false)

// Evaluates the Result<T> `...`; returns its Status from the enclosing function when it holds
// none, else moves its value into `lhs` (a declaration such as `auto x` or an lvalue).
#define CDPR_ASSIGN_OR_RETURN(lhs, ...)                                                   \
  CDPR_ASSIGN_OR_RETURN_IMPL_(CDPR_STATUS_CONCAT_(cdpr_assign_or_return_, __LINE__), lhs, \
                              __VA_ARGS__)

// Implementation details of the macros above.
#define CDPR_STATUS_CONCAT_INNER_(a, b) a##b
#define CDPR_STATUS_CONCAT_(a, b) CDPR_STATUS_CONCAT_INNER_(a, b)
#define CDPR_ASSIGN_OR_RETURN_IMPL_(result, lhs, ...) \
  auto result = (__VA_ARGS__);                        \
  if (!result.ok()) return result.status();           \
  lhs = std::move(result).value()
