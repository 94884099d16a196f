// One way to read a YAML configuration file field by field, with the house's error messages.
//
// Every cdpr YAML reader (robot description, CANopen network, laser and register map, simulation
// scenario, daemon config) is written with this header. It does the parts that are the same in
// all of them: typed values with the unit in the message, required and optional fields, refusal
// of unknown and repeated keys, and the position of every error. A message always reads
//
//   <file>:<line>: <field path>: <what is wrong>
//   config/mini.yaml:42: cables[3].ea: expected a positive number (N), got -5
//
// (line from 1; the line of the enclosing map for a missing field). Errors are kInvalidArgument;
// a YAML syntax error is kParseError "<file>:<line>:<column>: YAML syntax error: <reason>";
// a file that cannot be opened is kNotFound or kIoError naming the path. Nothing throws.
//
// Example (a section `motion: {max_speed: 0.5, mode: csp, axes: 8}` of a file):
//
//   CDPR_ASSIGN_OR_RETURN(config::YamlDocument doc, config::YamlDocument::load(path));
//   const config::YamlField root = doc.root();
//   CDPR_RETURN_IF_ERROR(root.check_keys({"motion", "name"}));  // a map with only these keys
//   CDPR_ASSIGN_OR_RETURN(config::YamlField motion, root.required("motion", "motion limits"));
//   CDPR_RETURN_IF_ERROR(motion.check_keys({"max_speed", "mode", "axes"}));
//   Settings s;                                                  // defaults live in the struct
//   CDPR_RETURN_IF_ERROR(motion.optional("max_speed", s.max_speed, Sign::kPositive, "m/s"));
//   CDPR_RETURN_IF_ERROR(motion.optional("axes", s.axes, 1, 64));
//   int mode = 0;  // index into the choices
//   CDPR_RETURN_IF_ERROR(motion.optional_choice("mode", mode, {"csp", "pp"}));
//   CDPR_ASSIGN_OR_RETURN(std::string name, root["name"].text());  // required: "name: missing"
//
// A YamlField is a cheap handle (a yaml-cpp node, its path and the document's file name); it may
// stand for an absent field, whose values are "missing" errors. A key written with no value
// (`ea:`) counts as absent. Checks that involve several fields stay with the caller, which words
// them with field.error("..."), so they carry the same position and path.
#pragma once

#include <yaml-cpp/yaml.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::config {

// The sign a number must have. Messages read "expected a positive number (N), got -5".
enum class Sign { kAny, kPositive, kNonNegative, kNonZero };

class YamlField;

// A parsed YAML file (or text) and its name for messages.
class YamlDocument {
 public:
  // Parses `text`; `file` names it in every message (a path, or "<stdin>").
  static Result<YamlDocument> parse(std::string_view text, std::string_view file);
  // Reads and parses the file at `path`. kNotFound when it does not exist, kIoError otherwise,
  // both as "cannot open <what> <path>: <reason>".
  static Result<YamlDocument> load(const std::string& path, std::string_view what = "YAML file");

  // The top level, with the path "(top level)".
  YamlField root() const;
  const std::string& file() const { return *file_; }

 private:
  YamlDocument(YAML::Node root, std::shared_ptr<const std::string> file)
      : root_(std::move(root)), file_(std::move(file)) {}

 public:
  // yaml-cpp nodes are references: assigning one to another would overwrite the document, so
  // assignment rebinds instead.
  YamlDocument(const YamlDocument&) = default;
  YamlDocument(YamlDocument&&) = default;
  YamlDocument& operator=(const YamlDocument& other);
  YamlDocument& operator=(YamlDocument&& other) { return *this = other; }
  ~YamlDocument() = default;

 private:
  YAML::Node root_;
  std::shared_ptr<const std::string> file_;
};

class YamlField {
 public:
  // Copies are handles to the same node; assignment rebinds (see YamlDocument).
  YamlField(const YamlField&) = default;
  YamlField(YamlField&&) = default;
  YamlField& operator=(const YamlField& other);
  YamlField& operator=(YamlField&& other) { return *this = other; }
  ~YamlField() = default;

  // --- Where it is ------------------------------------------------------------------------
  // "cables[3].winch.drum_diameter"; "(top level)" for the root.
  const std::string& path() const { return path_; }
  // The line (from 1) of the value; of the enclosing map when absent; 0 when unknown.
  int line() const;
  const std::string& file() const { return *file_; }
  // The field is given with a value (a key with no value counts as absent).
  bool present() const { return node_.IsDefined() && !node_.IsNull(); }
  explicit operator bool() const { return present(); }
  bool is_map() const { return present() && node_.IsMap(); }
  bool is_list() const { return present() && node_.IsSequence(); }
  bool is_scalar() const { return present() && node_.IsScalar(); }
  // The text of a scalar ("" otherwise).
  const std::string& scalar() const;
  // What the value looks like, for "got ..." in messages: the scalar, "a list of 2", "a map",
  // "nothing".
  std::string describe() const;
  // The underlying yaml-cpp node, for what this header does not cover.
  const YAML::Node& node() const { return node_; }

  // "<file>:<line>: <path>: <reason>" (kInvalidArgument).
  Status error(std::string_view reason) const;
  // The same at another path (e.g. the key "cables[2].pulley" of an error found in a value).
  Status error_at(std::string_view path, std::string_view reason) const;

  // --- Structure --------------------------------------------------------------------------
  // "expected <what>, got <describe()>" unless the field is a map (a list).
  Status expect_map(std::string_view what = "a map") const;
  Status expect_list(std::string_view what = "a list") const;
  // The field must be a map whose keys are all in `known`, none given twice. The message names
  // the key's own line and path: "t.yaml:2: master.sync_periode_ms: unknown field (known fields:
  // ...)", "cables[7].ea: field given twice".
  Status check_keys(std::initializer_list<std::string_view> known) const;
  // A child of a map, present or not (path "parent.key").
  YamlField operator[](std::string_view key) const;
  // An entry of a list (path "parent[i]"); absent past the end.
  YamlField operator[](std::size_t i) const;
  // Entries of a list, 0 for anything else.
  std::size_t size() const;
  // A child that must be present: "<path>.<key>: missing (<meaning>)" at the map's line.
  Result<YamlField> required(std::string_view key, std::string_view meaning = {}) const;
  // The same field as seen under another path (e.g. a default applied to a cable entry).
  YamlField renamed(std::string path) const;
  // The line of the key `key` of this map (the value of a block map or list starts on the next
  // line), 0 when the key is not there.
  int key_line(std::string_view key) const;

  // --- Values of this field ----------------------------------------------------------------
  // Any present field; "missing" when absent. `unit` goes into the message in parentheses ("" for
  // none). Decimal, exponent and 0x-hexadecimal integer notation; NaN and infinity are refused.
  Result<double> number(Sign sign = Sign::kAny, std::string_view unit = "") const;
  // A number within [lo, hi]: "expected a number within 0..1000 (ms), got 5000".
  Result<double> number_in(double lo, double hi, std::string_view unit = "") const;
  // An integer in decimal or 0x-hexadecimal within [lo, hi]: "'three' is not an integer",
  // "300 is outside 1..127".
  Result<std::int64_t> integer(std::int64_t lo, std::int64_t hi) const;
  // true/false (also yes/no, on/off): "expected true or false, got maybe".
  Result<bool> boolean() const;
  // A non-empty scalar: "expected a text, got a map".
  Result<std::string> text() const;
  // One of `choices`; returns its index: "'f64' is not one of u16, i16, u32".
  Result<int> choice(std::initializer_list<std::string_view> choices) const;
  // [x, y, z]: "expected a list of 3 numbers (m), got a list of 2".
  Result<std::array<double, 3>> vector3(std::string_view unit = "") const;
  // A list of numbers ("expected a list of numbers (<unit>), got ..."); with `scalar_allowed` a
  // single number is accepted as a list of one.
  Result<std::vector<double>> numbers(Sign sign, std::string_view unit, bool scalar_allowed) const;

  // --- Optional fields of this map: `out` keeps its value (the default) when absent ----------
  Status optional(std::string_view key, double& out, Sign sign = Sign::kAny,
                  std::string_view unit = "") const;
  Status optional(std::string_view key, bool& out) const;
  Status optional(std::string_view key, std::string& out) const;
  // An integer within [lo, hi] stored in any integer type that holds the range.
  template <typename Int>
  requires std::is_integral_v<Int> &&(!std::is_same_v<Int, bool>)Status
      optional(std::string_view key, Int& out, std::int64_t lo, std::int64_t hi) const {
    const YamlField f = (*this)[key];
    if (!f.present()) return Status::success();
    Result<std::int64_t> v = f.integer(lo, hi);
    if (!v.ok()) return v.status();
    out = static_cast<Int>(*v);
    return Status::success();
  }
  // The index into `choices`.
  Status optional_choice(std::string_view key, int& index,
                         std::initializer_list<std::string_view> choices) const;

 private:
  friend class YamlDocument;
  YamlField(YAML::Node node, std::string path, std::shared_ptr<const std::string> file,
            YAML::Mark parent_mark)
      : node_(std::move(node)),
        path_(std::move(path)),
        file_(std::move(file)),
        parent_mark_(parent_mark) {}

  YAML::Node node_;
  std::string path_;
  std::shared_ptr<const std::string> file_;
  YAML::Mark parent_mark_;  // where an absent field is reported
};

}  // namespace cdpr::config
