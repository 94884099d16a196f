// Small helpers that read typed YAML fields and report "file:line:col: field 'a.b': reason".
// Internal to cdpr_modbus.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/modbus/register_map.hpp"
#include "cdpr/status.hpp"

namespace cdpr::modbus::detail {

class YamlFields {
 public:
  explicit YamlFields(std::string_view file) : file_(file) {}

  // Error at a node's position (YAML marks are 0-based; files count from 1).
  Status error(const YAML::Node& at, std::string_view field, std::string_view reason) const {
    const YAML::Mark m = at.Mark();
    if (m.line >= 0) {
      return Status::Error(ErrorCode::kParseError, "%s:%d:%d: field '%.*s': %.*s", file_.c_str(),
                           m.line + 1, m.column + 1, static_cast<int>(field.size()), field.data(),
                           static_cast<int>(reason.size()), reason.data());
    }
    return Status::Error(ErrorCode::kParseError, "%s: field '%.*s': %.*s", file_.c_str(),
                         static_cast<int>(field.size()), field.data(),
                         static_cast<int>(reason.size()), reason.data());
  }

  // Every key of `map` must be one of `known` (catches misspelt fields).
  Status only_known(const YAML::Node& map, std::string_view prefix,
                    std::initializer_list<std::string_view> known) const {
    for (auto it = map.begin(); it != map.end(); ++it) {
      const std::string key = it->first.Scalar();
      bool found = false;
      for (auto k : known) found = found || k == key;
      if (!found) {
        std::string list;
        for (auto k : known) {
          if (!list.empty()) list += ", ";
          list += k;
        }
        return error(it->first, join(prefix, key), "unknown field (known: " + list + ")");
      }
    }
    return Status::Ok();
  }

  Status require_map(const YAML::Node& parent, const YAML::Node& n, std::string_view field) const {
    if (!n) return error(parent, field, "is missing");
    if (!n.IsMap()) return error(n, field, "must be a mapping");
    return Status::Ok();
  }

  Status get_string(const YAML::Node& parent, const char* key, std::string_view prefix,
                    std::string& out, bool required) const {
    const YAML::Node n = parent[key];
    if (!n) return required ? error(parent, join(prefix, key), "is missing") : Status::Ok();
    if (!n.IsScalar()) return error(n, join(prefix, key), "must be a string");
    out = n.Scalar();
    return Status::Ok();
  }

  Status get_int(const YAML::Node& parent, const char* key, std::string_view prefix, long long lo,
                 long long hi, long long& out, bool required) const {
    const YAML::Node n = parent[key];
    if (!n) return required ? error(parent, join(prefix, key), "is missing") : Status::Ok();
    return to_int(n, join(prefix, key), lo, hi, out);
  }

  Status to_int(const YAML::Node& n, const std::string& field, long long lo, long long hi,
                long long& out) const {
    long long v = 0;
    if (!n.IsScalar() || !YAML::convert<long long>::decode(n, v)) {
      return error(n, field,
                   "'" + (n.IsScalar() ? n.Scalar() : std::string("<not a scalar>")) +
                       "' is not an integer");
    }
    if (v < lo || v > hi) {
      return error(
          n, field,
          std::to_string(v) + " is outside " + std::to_string(lo) + ".." + std::to_string(hi));
    }
    out = v;
    return Status::Ok();
  }

  Status get_double(const YAML::Node& parent, const char* key, std::string_view prefix, double& out,
                    bool required) const {
    const YAML::Node n = parent[key];
    if (!n) return required ? error(parent, join(prefix, key), "is missing") : Status::Ok();
    return to_double(n, join(prefix, key), out);
  }

  // Accepts decimal, exponent and hexadecimal integer notation (0xFFFF).
  Status to_double(const YAML::Node& n, const std::string& field, double& out) const {
    long long i = 0;
    double d = 0.0;
    if (n.IsScalar() && YAML::convert<long long>::decode(n, i)) {
      out = static_cast<double>(i);
      return Status::Ok();
    }
    if (n.IsScalar() && YAML::convert<double>::decode(n, d) && !std::isnan(d)) {
      out = d;
      return Status::Ok();
    }
    return error(
        n, field,
        "'" + (n.IsScalar() ? n.Scalar() : std::string("<not a scalar>")) + "' is not a number");
  }

  Status get_bool(const YAML::Node& parent, const char* key, std::string_view prefix,
                  bool& out) const {
    const YAML::Node n = parent[key];
    if (!n) return Status::Ok();
    bool v = false;
    if (!n.IsScalar() || !YAML::convert<bool>::decode(n, v)) {
      return error(n, join(prefix, key), "must be true or false");
    }
    out = v;
    return Status::Ok();
  }

  // One of `choices`; returns its index.
  Status get_choice(const YAML::Node& parent, const char* key, std::string_view prefix,
                    std::initializer_list<std::string_view> choices, int& index,
                    bool required) const {
    const YAML::Node n = parent[key];
    if (!n) return required ? error(parent, join(prefix, key), "is missing") : Status::Ok();
    const std::string v = n.IsScalar() ? n.Scalar() : std::string();
    int i = 0;
    std::string list;
    for (auto c : choices) {
      if (c == v) {
        index = i;
        return Status::Ok();
      }
      if (!list.empty()) list += ", ";
      list += c;
      ++i;
    }
    return error(n, join(prefix, key), "'" + v + "' is not one of " + list);
  }

  static std::string join(std::string_view prefix, std::string_view key) {
    std::string s(prefix);
    if (!s.empty()) s += '.';
    s += key;
    return s;
  }

  const std::string& file() const { return file_; }

 private:
  std::string file_;
};

// Reads a register map from a YAML mapping node (register_map_yaml.cc).
Status parse_register_map_node(const YamlFields& f, const YAML::Node& root, RegisterMap& m);

}  // namespace cdpr::modbus::detail
