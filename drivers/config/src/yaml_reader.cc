#include "cdpr/config/yaml_reader.hpp"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>

namespace cdpr::config {
namespace {

std::string join_names(std::initializer_list<std::string_view> names) {
  std::string s;
  for (std::string_view n : names) {
    if (!s.empty()) s += ", ";
    s += n;
  }
  return s;
}

// "(N)" for a unit, "" for none.
std::string unit_text(std::string_view unit) {
  return unit.empty() ? std::string() : " (" + std::string(unit) + ")";
}

// An integer in decimal or 0x hexadecimal, with an optional sign. False when `s` is not one or
// does not fit in 64 bits.
bool parse_integer(const std::string& s, std::int64_t& out) {
  const char* b = s.c_str();
  bool negative = false;
  if (*b == '-' || *b == '+') negative = *b++ == '-';
  const bool hex = b[0] == '0' && (b[1] == 'x' || b[1] == 'X');
  const char* digits = hex ? b + 2 : b;
  if (*digits == '\0' || *digits == '-' || *digits == '+' || *digits == ' ') return false;
  errno = 0;
  char* end = nullptr;
  const unsigned long long v = std::strtoull(digits, &end, hex ? 16 : 10);
  if (*end != '\0' || errno != 0) return false;
  constexpr auto kMax = static_cast<unsigned long long>(std::numeric_limits<std::int64_t>::max());
  if (v > kMax + (negative ? 1u : 0u)) return false;
  out = negative ? static_cast<std::int64_t>(0 - v) : static_cast<std::int64_t>(v);
  return true;
}

const char* sign_words(Sign sign) {
  switch (sign) {
    case Sign::kAny:
      return "a number";
    case Sign::kPositive:
      return "a positive number";
    case Sign::kNonNegative:
      return "a non-negative number";
    case Sign::kNonZero:
      return "a non-zero number";
  }
  return "a number";
}

bool sign_ok(Sign sign, double v) {
  switch (sign) {
    case Sign::kAny:
      return true;
    case Sign::kPositive:
      return v > 0.0;
    case Sign::kNonNegative:
      return v >= 0.0;
    case Sign::kNonZero:
      return v != 0.0;
  }
  return false;
}

// "%g" without trailing noise: 1000 -> "1000", 0.001 -> "0.001".
std::string short_number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// YamlDocument
// ---------------------------------------------------------------------------------------------

Result<YamlDocument> YamlDocument::parse(std::string_view text, std::string_view file) {
  auto name = std::make_shared<const std::string>(file);
  try {
    return YamlDocument(YAML::Load(std::string(text)), std::move(name));
  } catch (const YAML::Exception& e) {
    std::string where(file);
    if (!e.mark.is_null()) {
      where += ":" + std::to_string(e.mark.line + 1) + ":" + std::to_string(e.mark.column + 1);
    }
    return Status(ErrorCode::kParseError, where + ": YAML syntax error: " + e.msg);
  }
}

Result<YamlDocument> YamlDocument::load(const std::string& path, std::string_view what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    const int err = errno;
    return Status::error(err == ENOENT ? ErrorCode::kNotFound : ErrorCode::kIoError,
                         "cannot open %.*s %s: %s", static_cast<int>(what.size()), what.data(),
                         path.c_str(), std::strerror(err));
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) {
    return Status::error(ErrorCode::kIoError, "cannot read %.*s %s", static_cast<int>(what.size()),
                         what.data(), path.c_str());
  }
  return parse(text.str(), path);
}

YamlDocument& YamlDocument::operator=(const YamlDocument& other) {
  if (this != &other) {
    root_.reset(other.root_);
    file_ = other.file_;
  }
  return *this;
}

YamlField YamlDocument::root() const {
  return YamlField(root_, "(top level)", file_, YAML::Mark::null_mark());
}

// ---------------------------------------------------------------------------------------------
// YamlField: where
// ---------------------------------------------------------------------------------------------

YamlField& YamlField::operator=(const YamlField& other) {
  if (this != &other) {
    node_.reset(other.node_);
    path_ = other.path_;
    file_ = other.file_;
    parent_mark_ = other.parent_mark_;
  }
  return *this;
}

int YamlField::line() const {
  // An absent node from a const lookup allows IsDefined() only.
  const YAML::Mark m = node_.IsDefined() ? node_.Mark() : parent_mark_;
  return m.is_null() || m.line < 0 ? 0 : m.line + 1;
}

const std::string& YamlField::scalar() const {
  static const std::string kEmpty;
  return is_scalar() ? node_.Scalar() : kEmpty;
}

std::string YamlField::describe() const {
  if (!present()) return "nothing";
  switch (node_.Type()) {
    case YAML::NodeType::Scalar:
      return node_.Scalar().empty() ? std::string("an empty value") : node_.Scalar();
    case YAML::NodeType::Sequence:
      return "a list of " + std::to_string(node_.size());
    case YAML::NodeType::Map:
      return "a map";
    case YAML::NodeType::Null:
    case YAML::NodeType::Undefined:
      return "nothing";
  }
  return "?";
}

Status YamlField::error(std::string_view reason) const {
  return error_at(path_, reason);
}

Status YamlField::error_at(std::string_view path, std::string_view reason) const {
  const int l = line();
  std::string text = *file_;
  if (l > 0) text += ":" + std::to_string(l);
  text += ": ";
  text += path;
  text += ": ";
  text += reason;
  return Status(ErrorCode::kInvalidArgument, text);
}

// ---------------------------------------------------------------------------------------------
// YamlField: structure
// ---------------------------------------------------------------------------------------------

Status YamlField::expect_map(std::string_view what) const {
  if (is_map()) return Status::success();
  return error("expected " + std::string(what) + ", got " + describe());
}

Status YamlField::expect_list(std::string_view what) const {
  if (is_list()) return Status::success();
  return error("expected " + std::string(what) + ", got " + describe());
}

Status YamlField::check_keys(std::initializer_list<std::string_view> known) const {
  CDPR_RETURN_IF_ERROR(expect_map());
  std::set<std::string> seen;
  for (auto it = node_.begin(); it != node_.end(); ++it) {
    const std::string key = it->first.Scalar();
    const YamlField k(it->first, path_ == "(top level)" ? key : path_ + "." + key, file_,
                      parent_mark_);
    bool ok = false;
    for (std::string_view name : known) ok = ok || key == name;
    if (!ok) return k.error("unknown field (known fields: " + join_names(known) + ")");
    if (!seen.insert(key).second) return k.error("field given twice");
  }
  return Status::success();
}

YamlField YamlField::operator[](std::string_view key) const {
  const std::string path =
      path_ == "(top level)" ? std::string(key) : path_ + "." + std::string(key);
  const YAML::Mark here = node_.IsDefined() ? node_.Mark() : parent_mark_;
  if (!is_map()) return YamlField(YAML::Node(YAML::NodeType::Undefined), path, file_, here);
  const YAML::Node& n = node_;
  return YamlField(n[std::string(key)], path, file_, here);
}

YamlField YamlField::operator[](std::size_t i) const {
  const std::string path = path_ + "[" + std::to_string(i) + "]";
  const YAML::Mark here = node_.IsDefined() ? node_.Mark() : parent_mark_;
  if (!is_list() || i >= node_.size()) {
    return YamlField(YAML::Node(YAML::NodeType::Undefined), path, file_, here);
  }
  const YAML::Node& n = node_;
  return YamlField(n[i], path, file_, here);
}

std::size_t YamlField::size() const {
  return is_list() ? node_.size() : 0;
}

Result<YamlField> YamlField::required(std::string_view key, std::string_view meaning) const {
  YamlField f = (*this)[key];
  if (f.present()) return f;
  return f.error(meaning.empty() ? std::string("missing")
                                 : "missing (" + std::string(meaning) + ")");
}

YamlField YamlField::renamed(std::string path) const {
  return YamlField(node_, std::move(path), file_, parent_mark_);
}

int YamlField::key_line(std::string_view key) const {
  if (!is_map()) return 0;
  for (auto it = node_.begin(); it != node_.end(); ++it) {
    if (it->first.Scalar() == key) return it->first.Mark().line + 1;
  }
  return 0;
}

// ---------------------------------------------------------------------------------------------
// YamlField: values
// ---------------------------------------------------------------------------------------------

Result<double> YamlField::number(Sign sign, std::string_view unit) const {
  const std::string expectation = std::string("expected ") + sign_words(sign) + unit_text(unit);
  if (!present()) return error("missing" + unit_text(unit));
  double v = 0.0;
  std::int64_t i = 0;
  if (!node_.IsScalar()) return error(expectation + ", got " + describe());
  if (parse_integer(node_.Scalar(), i)) {
    v = static_cast<double>(i);
  } else if (!YAML::convert<double>::decode(node_, v)) {
    return error(expectation + ", got " + describe());
  }
  if (!std::isfinite(v))
    return error("expected a finite number" + unit_text(unit) + ", got " + describe());
  if (!sign_ok(sign, v)) return error(expectation + ", got " + describe());
  return v;
}

Result<double> YamlField::number_in(double lo, double hi, std::string_view unit) const {
  Result<double> v = number(Sign::kAny, unit);
  if (!v.ok()) return v;
  if (*v < lo || *v > hi) {
    return error("expected a number within " + short_number(lo) + ".." + short_number(hi) +
                 unit_text(unit) + ", got " + describe());
  }
  return v;
}

Result<std::int64_t> YamlField::integer(std::int64_t lo, std::int64_t hi) const {
  if (!present()) return error("missing");
  std::int64_t v = 0;
  if (!node_.IsScalar()) return error("expected an integer, got " + describe());
  if (!parse_integer(node_.Scalar(), v)) return error("'" + node_.Scalar() + "' is not an integer");
  if (v < lo || v > hi) {
    return error(node_.Scalar() + " is outside " + std::to_string(lo) + ".." + std::to_string(hi));
  }
  return v;
}

Result<bool> YamlField::boolean() const {
  if (!present()) return error("missing");
  bool v = false;
  if (!node_.IsScalar() || !YAML::convert<bool>::decode(node_, v)) {
    return error("expected true or false, got " + describe());
  }
  return v;
}

Result<std::string> YamlField::text() const {
  if (!present()) return error("missing");
  if (!node_.IsScalar() || node_.Scalar().empty())
    return error("expected a text, got " + describe());
  return node_.Scalar();
}

Result<int> YamlField::choice(std::initializer_list<std::string_view> choices) const {
  if (!present()) return error("missing (one of " + join_names(choices) + ")");
  const std::string v = is_scalar() ? node_.Scalar() : describe();
  int i = 0;
  for (std::string_view c : choices) {
    if (c == v) return i;
    ++i;
  }
  return error("'" + v + "' is not one of " + join_names(choices));
}

Result<std::array<double, 3>> YamlField::vector3(std::string_view unit) const {
  if (!present()) return error("missing" + unit_text(unit));
  if (!node_.IsSequence() || node_.size() != 3) {
    return error("expected a list of 3 numbers" + unit_text(unit) + ", got " + describe());
  }
  std::array<double, 3> v{};
  for (std::size_t k = 0; k < 3; ++k) {
    Result<double> x = (*this)[k].number(Sign::kAny, unit);
    if (!x.ok()) return x.status();
    v[k] = *x;
  }
  return v;
}

Result<std::vector<double>> YamlField::numbers(Sign sign, std::string_view unit,
                                               bool scalar_allowed) const {
  if (!present()) return error("missing" + unit_text(unit));
  std::vector<double> out;
  if (scalar_allowed && node_.IsScalar()) {
    Result<double> v = number(sign, unit);
    if (!v.ok()) return v.status();
    out.push_back(*v);
    return out;
  }
  if (!node_.IsSequence()) {
    return error(std::string(scalar_allowed ? "expected a number or a list of numbers"
                                            : "expected a list of numbers") +
                 unit_text(unit) + ", got " + describe());
  }
  for (std::size_t k = 0; k < node_.size(); ++k) {
    Result<double> v = (*this)[k].number(sign, unit);
    if (!v.ok()) return v.status();
    out.push_back(*v);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// YamlField: optional fields
// ---------------------------------------------------------------------------------------------

Status YamlField::optional(std::string_view key, double& out, Sign sign,
                           std::string_view unit) const {
  const YamlField f = (*this)[key];
  if (!f.present()) return Status::success();
  Result<double> v = f.number(sign, unit);
  if (!v.ok()) return v.status();
  out = *v;
  return Status::success();
}

Status YamlField::optional(std::string_view key, bool& out) const {
  const YamlField f = (*this)[key];
  if (!f.present()) return Status::success();
  Result<bool> v = f.boolean();
  if (!v.ok()) return v.status();
  out = *v;
  return Status::success();
}

Status YamlField::optional(std::string_view key, std::string& out) const {
  const YamlField f = (*this)[key];
  if (!f.present()) return Status::success();
  Result<std::string> v = f.text();
  if (!v.ok()) return v.status();
  out = std::move(*v);
  return Status::success();
}

Status YamlField::optional_choice(std::string_view key, int& index,
                                  std::initializer_list<std::string_view> choices) const {
  const YamlField f = (*this)[key];
  if (!f.present()) return Status::success();
  Result<int> v = f.choice(choices);
  if (!v.ok()) return v.status();
  index = *v;
  return Status::success();
}

}  // namespace cdpr::config
