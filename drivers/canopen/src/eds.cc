#include "cdpr/canopen/eds.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

namespace cdpr::canopen::eds {

namespace {

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return s;
}

bool is_hex(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return std::isxdigit(static_cast<unsigned char>(c));
  });
}

// An unsigned number without $NODEID: decimal, 0x hex or leading-0 octal.
bool parse_plain(std::string_view s, std::int64_t& out) {
  s = trim(s);
  bool neg = false;
  if (!s.empty() && (s.front() == '-' || s.front() == '+')) {
    neg = s.front() == '-';
    s.remove_prefix(1);
  }
  if (s.empty()) return false;
  int base = 10;
  if (s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X')) {
    base = 16;
    s.remove_prefix(2);
  } else if (s.size() > 1 && s[0] == '0') {
    base = 8;
    s.remove_prefix(1);
  }
  const std::string str(s);
  errno = 0;
  char* end = nullptr;
  const unsigned long long v = std::strtoull(str.c_str(), &end, base);
  if (end == str.c_str() || *end != '\0' || errno != 0 || v > 0xFFFFFFFFFFFFFFFFull) return false;
  out = neg ? -static_cast<std::int64_t>(v) : static_cast<std::int64_t>(v);
  return true;
}

struct Line {
  std::string value;
  int line = 0;
};

struct RawSection {
  std::string name;  // as written
  int line = 0;
  std::vector<std::pair<std::string, Line>> keys;  // lower-case key, value
  const Line* get(std::string_view key) const {
    for (const auto& [k, v] : keys) {
      if (k == key) return &v;
    }
    return nullptr;
  }
};

}  // namespace

std::string_view type_name(std::uint16_t t) {
  switch (t) {
    case type::kBoolean:
      return "BOOLEAN";
    case type::kInteger8:
      return "INTEGER8";
    case type::kInteger16:
      return "INTEGER16";
    case type::kInteger32:
      return "INTEGER32";
    case type::kUnsigned8:
      return "UNSIGNED8";
    case type::kUnsigned16:
      return "UNSIGNED16";
    case type::kUnsigned32:
      return "UNSIGNED32";
    case type::kReal32:
      return "REAL32";
    case type::kVisibleString:
      return "VISIBLE_STRING";
    case type::kOctetString:
      return "OCTET_STRING";
    case type::kUnicodeString:
      return "UNICODE_STRING";
    case type::kTimeOfDay:
      return "TIME_OF_DAY";
    case type::kTimeDifference:
      return "TIME_DIFFERENCE";
    case type::kDomain:
      return "DOMAIN";
    case type::kInteger24:
      return "INTEGER24";
    case type::kReal64:
      return "REAL64";
    case type::kInteger64:
      return "INTEGER64";
    case type::kUnsigned24:
      return "UNSIGNED24";
    case type::kUnsigned64:
      return "UNSIGNED64";
    default:
      return "unknown";
  }
}

int type_size(std::uint16_t t) {
  switch (t) {
    case type::kBoolean:
    case type::kInteger8:
    case type::kUnsigned8:
      return 1;
    case type::kInteger16:
    case type::kUnsigned16:
      return 2;
    case type::kInteger24:
    case type::kUnsigned24:
      return 3;
    case type::kInteger32:
    case type::kUnsigned32:
    case type::kReal32:
      return 4;
    case type::kTimeOfDay:
    case type::kTimeDifference:
      return 6;
    case type::kReal64:
    case type::kInteger64:
    case type::kUnsigned64:
      return 8;
    case type::kVisibleString:
    case type::kOctetString:
    case type::kUnicodeString:
    case type::kDomain:
      return 0;
    default:
      return -1;
  }
}

bool type_is_signed(std::uint16_t t) {
  return t == type::kInteger8 || t == type::kInteger16 || t == type::kInteger24 ||
         t == type::kInteger32 || t == type::kInteger64;
}

std::uint16_t data_type_of(DataType t) {
  switch (t) {
    case DataType::kI8:
      return type::kInteger8;
    case DataType::kU8:
      return type::kUnsigned8;
    case DataType::kI16:
      return type::kInteger16;
    case DataType::kU16:
      return type::kUnsigned16;
    case DataType::kI32:
      return type::kInteger32;
    case DataType::kU32:
      return type::kUnsigned32;
  }
  return 0;
}

bool same_type(std::uint16_t data_type, DataType t) {
  return data_type == data_type_of(t);
}

std::string_view to_string(Access a) {
  switch (a) {
    case Access::kRo:
      return "ro";
    case Access::kWo:
      return "wo";
    case Access::kRw:
      return "rw";
    case Access::kRwr:
      return "rwr";
    case Access::kRww:
      return "rww";
    case Access::kConst:
      return "const";
  }
  return "?";
}

bool parse_integer(std::string_view text, NodeId node, std::int64_t& out) {
  std::string s(trim(text));
  std::int64_t add = 0;
  const std::string l = lower(s);
  const auto at = l.find("$nodeid");
  if (at != std::string::npos) {
    add = node;
    std::string rest = s.substr(0, at) + s.substr(at + 7);
    rest = std::string(trim(rest));
    if (!rest.empty() && rest.front() == '+') rest.erase(0, 1);
    if (!rest.empty() && rest.back() == '+') rest.pop_back();
    rest = std::string(trim(rest));
    if (rest.empty()) {
      out = add;
      return true;
    }
    s = rest;
  }
  std::int64_t v = 0;
  if (!parse_plain(s, v)) return false;
  out = v + add;
  return true;
}

const Object* Eds::object(std::uint16_t index) const {
  auto it = objects_.find(index);
  return it == objects_.end() ? nullptr : &it->second;
}

const SubObject* Eds::find(ObjectAddress a) const {
  const Object* o = object(a.index);
  if (o == nullptr) return nullptr;
  for (const SubObject& s : o->subs) {
    if (s.address.sub == a.sub) return &s;
  }
  return nullptr;
}

std::string Eds::device_info(std::string_view key) const {
  const std::string k = lower(key);
  for (const auto& [name, value] : device_info_) {
    if (lower(name) == k) return value;
  }
  return "";
}

std::string Eds::where(const SubObject& s) const {
  char b[64];
  std::snprintf(b, sizeof b, ":%d: 0x%04X:%02X", s.line, unsigned{s.address.index},
                unsigned{s.address.sub});
  return source_ + b + " (" + s.name + ")";
}

Result<std::int64_t> Eds::value(const SubObject& s, NodeId node, bool configured) const {
  const std::string& text = configured && s.parameter_value ? *s.parameter_value : s.default_value;
  if (trim(text).empty()) return std::int64_t{0};
  std::int64_t v = 0;
  if (!parse_integer(text, node, v)) {
    return Status::error(ErrorCode::kParseError, "%s: value '%s' is not an integer",
                         where(s).c_str(), text.c_str());
  }
  return v;
}

void Eds::put(Object o) {
  objects_[o.index] = std::move(o);
}

namespace {

class Reader {
 public:
  explicit Reader(std::string source) : source_(std::move(source)) {}

  Status error(int line, const std::string& section, const std::string& what) const {
    if (section.empty()) {
      return Status::error(ErrorCode::kParseError, "%s:%d: %s", source_.c_str(), line,
                           what.c_str());
    }
    return Status::error(ErrorCode::kParseError, "%s:%d: [%s]: %s", source_.c_str(), line,
                         section.c_str(), what.c_str());
  }

  Status split(std::string_view text) {
    int n = 0;
    std::size_t pos = 0;
    while (pos <= text.size()) {
      const std::size_t nl = text.find('\n', pos);
      std::string_view raw =
          text.substr(pos, nl == std::string_view::npos ? std::string_view::npos : nl - pos);
      pos = nl == std::string_view::npos ? text.size() + 1 : nl + 1;
      ++n;
      std::string_view l = trim(raw);
      if (l.empty() || l.front() == ';' || l.front() == '#') continue;
      if (l.front() == '[') {
        const auto close = l.find(']');
        if (close == std::string_view::npos) return error(n, "", "section header without ']'");
        RawSection s;
        s.name = std::string(trim(l.substr(1, close - 1)));
        s.line = n;
        if (s.name.empty()) return error(n, "", "empty section name");
        const std::string key = lower(s.name);
        if (!seen_.insert(key).second) return error(n, s.name, "section appears twice");
        sections_.push_back(std::move(s));
        continue;
      }
      const auto eq = l.find('=');
      if (eq == std::string_view::npos) {
        return error(n, sections_.empty() ? "" : sections_.back().name,
                     "expected key=value, got '" + std::string(l) + "'");
      }
      if (sections_.empty()) return error(n, "", "key=value before the first [section]");
      RawSection& s = sections_.back();
      const std::string key = lower(trim(l.substr(0, eq)));
      if (key.empty()) return error(n, s.name, "empty key");
      if (s.get(key) != nullptr) return error(n, s.name, "key '" + key + "' appears twice");
      s.keys.push_back({key, Line{std::string(trim(l.substr(eq + 1))), n}});
    }
    return Status::success();
  }

  const RawSection* section(std::string_view name) const {
    const std::string l = lower(name);
    for (const auto& s : sections_) {
      if (lower(s.name) == l) return &s;
    }
    return nullptr;
  }

  // `key` as CiA 306 spells it ("PDOMapping"); looked up without case.
  Status number(const RawSection& s, const char* key, bool required, std::int64_t lo,
                std::int64_t hi, std::int64_t& out, bool& present) const {
    const Line* v = s.get(lower(key));
    present = v != nullptr;
    if (v == nullptr) {
      return required ? error(s.line, s.name, std::string(key) + " is missing") : Status::success();
    }
    std::int64_t x = 0;
    if (!parse_integer(v->value, 1, x) || lower(v->value).find("$nodeid") != std::string::npos) {
      return error(v->line, s.name, std::string(key) + " '" + v->value + "' is not a number");
    }
    if (x < lo || x > hi) {
      return error(v->line, s.name,
                   std::string(key) + " " + v->value + " is outside " + std::to_string(lo) + ".." +
                       std::to_string(hi));
    }
    out = x;
    return Status::success();
  }

  // Fills the value fields of a sub-object from a section (VAR object or [XXXXsubN]).
  Status entry(const RawSection& s, SubObject& e) const {
    bool present = false;
    std::int64_t v = 0;
    if (const Line* n = s.get("parametername")) e.name = n->value;
    if (e.name.empty()) return error(s.line, s.name, "ParameterName is missing");
    CDPR_RETURN_IF_ERROR(number(s, "DataType", true, 0, 0xFFFF, v, present));
    e.data_type = static_cast<std::uint16_t>(v);
    if (type_size(e.data_type) < 0) {
      char b[96];
      std::snprintf(b, sizeof b, "DataType 0x%04X is not a CiA 301 data type",
                    unsigned{e.data_type});
      return error(s.get("datatype")->line, s.name, b);
    }
    const Line* acc = s.get("accesstype");
    if (acc == nullptr) return error(s.line, s.name, "AccessType is missing");
    const std::string a = lower(acc->value);
    if (a == "ro") {
      e.access = Access::kRo;
    } else if (a == "wo") {
      e.access = Access::kWo;
    } else if (a == "rw") {
      e.access = Access::kRw;
    } else if (a == "rwr") {
      e.access = Access::kRwr;
    } else if (a == "rww") {
      e.access = Access::kRww;
    } else if (a == "const") {
      e.access = Access::kConst;
    } else {
      return error(acc->line, s.name,
                   "AccessType '" + acc->value + "' is not ro, wo, rw, rwr, rww or const");
    }
    CDPR_RETURN_IF_ERROR(number(s, "PDOMapping", false, 0, 1, v, present));
    e.pdo_mapping = present && v != 0;
    if (const Line* d = s.get("defaultvalue")) {
      e.default_value = d->value;
      CDPR_RETURN_IF_ERROR(check_value(s, d->line, "DefaultValue", e, d->value));
    }
    if (const Line* p = s.get("parametervalue")) {
      e.parameter_value = p->value;
      CDPR_RETURN_IF_ERROR(check_value(s, p->line, "ParameterValue", e, p->value));
    }
    if (const Line* l = s.get("lowlimit")) e.low_limit = l->value;
    if (const Line* h = s.get("highlimit")) e.high_limit = h->value;
    e.line = s.line;
    return Status::success();
  }

  // A numeric value must parse and fit its type for every node id.
  Status check_value(const RawSection& s, int line, const char* key, const SubObject& e,
                     const std::string& text) const {
    const int size = type_size(e.data_type);
    if (size == 0 || trim(text).empty()) return Status::success();  // strings, domains, empty
    if (e.data_type == type::kReal32 || e.data_type == type::kReal64) {
      char* end = nullptr;
      const std::string t(trim(text));
      std::strtod(t.c_str(), &end);
      if (end == t.c_str() || *end != '\0') {
        return error(line, s.name, std::string(key) + " '" + t + "' is not a number");
      }
      return Status::success();
    }
    for (NodeId node : {NodeId{1}, kMaxNodeId}) {
      std::int64_t v = 0;
      if (!parse_integer(text, node, v)) {
        return error(line, s.name, std::string(key) + " '" + text + "' is not an integer");
      }
      if (size >= 8) continue;
      const int bits = 8 * size;
      // Signed types: their negative range, and the unsigned pattern (0xFFFF for INTEGER16 -1)
      // that many files use.
      const std::int64_t lo = type_is_signed(e.data_type) ? -(std::int64_t{1} << (bits - 1)) : 0;
      const std::int64_t hi = (std::int64_t{1} << bits) - 1;
      if (v < lo || v > hi) {
        return error(
            line, s.name,
            std::string(key) + " " + text + " does not fit " + std::string(type_name(e.data_type)));
      }
    }
    return Status::success();
  }

  Status object(const RawSection& s, std::uint16_t index, Object& o) const {
    o.index = index;
    o.line = s.line;
    bool present = false;
    std::int64_t v = 0;
    CDPR_RETURN_IF_ERROR(number(s, "ObjectType", false, 0, 0xFF, v, present));
    const std::int64_t code = present ? v : 0x7;
    switch (code) {
      case 0x0:
      case 0x2:
      case 0x5:
      case 0x6:
      case 0x7:
      case 0x8:
      case 0x9:
        o.code = static_cast<ObjectCode>(code);
        break;
      default:
        return error(s.get("objecttype")->line, s.name,
                     "ObjectType " + s.get("objecttype")->value +
                         " is not NULL, DOMAIN, DEFTYPE, DEFSTRUCT, VAR, ARRAY or RECORD");
    }
    if (const Line* n = s.get("parametername")) o.name = n->value;
    if (o.name.empty()) return error(s.line, s.name, "ParameterName is missing");
    if (o.code == ObjectCode::kNull) return Status::success();
    if (o.code == ObjectCode::kVar || o.code == ObjectCode::kDomain ||
        o.code == ObjectCode::kDefType) {
      RawSection copy = s;
      if (o.code == ObjectCode::kDomain && s.get("datatype") == nullptr) {
        copy.keys.push_back({"datatype", Line{"0x000F", s.line}});
      }
      if (o.code == ObjectCode::kDomain && s.get("accesstype") == nullptr) {
        copy.keys.push_back({"accesstype", Line{"rw", s.line}});
      }
      SubObject e;
      e.address = {index, 0};
      CDPR_RETURN_IF_ERROR(entry(copy, e));
      o.subs.push_back(std::move(e));
      return Status::success();
    }
    // ARRAY, RECORD, DEFSTRUCT: sub-objects.
    std::int64_t compact = 0;
    CDPR_RETURN_IF_ERROR(number(s, "CompactSubObj", false, 0, 254, compact, present));
    if (compact > 0) return compact_subs(s, index, static_cast<int>(compact), o);
    std::int64_t sub_number = 0;
    CDPR_RETURN_IF_ERROR(number(s, "SubNumber", true, 0, 255, sub_number, present));
    char prefix[8];
    std::snprintf(prefix, sizeof prefix, "%04x", unsigned{index});
    for (const RawSection& r : sections_) {
      const std::string n = lower(r.name);
      if (n.size() < 8 || n.compare(0, 4, prefix) != 0 || n.compare(4, 3, "sub") != 0) continue;
      const std::string sub_s = n.substr(7);
      if (!is_hex(sub_s) || sub_s.size() > 2) return error(r.line, r.name, "bad sub-index");
      SubObject e;
      e.address = {index, static_cast<std::uint8_t>(std::strtoul(sub_s.c_str(), nullptr, 16))};
      CDPR_RETURN_IF_ERROR(entry(r, e));
      o.subs.push_back(std::move(e));
    }
    std::sort(o.subs.begin(), o.subs.end(),
              [](const SubObject& a, const SubObject& b) { return a.address.sub < b.address.sub; });
    if (static_cast<std::int64_t>(o.subs.size()) != sub_number) {
      return error(s.get("subnumber")->line, s.name,
                   "SubNumber is " + std::to_string(sub_number) + " but " +
                       std::to_string(o.subs.size()) + " [" + s.name + "subN] sections follow");
    }
    if (o.subs.empty() || o.subs.front().address.sub != 0) {
      return error(s.line, s.name, "no sub-index 0 ([" + s.name + "sub0])");
    }
    return Status::success();
  }

  // CompactSubObj=N: sub 0 holds N, subs 1..N share the object's type and access; names and
  // defaults may be given in [XXXXName] / [XXXXValue] (keys are the sub-index in decimal).
  Status compact_subs(const RawSection& s, std::uint16_t index, int n, Object& o) const {
    SubObject proto;
    proto.address = {index, 1};
    CDPR_RETURN_IF_ERROR(entry(s, proto));
    SubObject count;
    count.address = {index, 0};
    count.name = "NrOfObjects";
    count.data_type = type::kUnsigned8;
    count.access = Access::kRo;
    count.default_value = std::to_string(n);
    count.line = s.line;
    o.subs.push_back(count);
    char names[16], values[16];
    std::snprintf(names, sizeof names, "%04XName", unsigned{index});
    std::snprintf(values, sizeof values, "%04XValue", unsigned{index});
    const RawSection* ns = section(names);
    const RawSection* vs = section(values);
    for (int k = 1; k <= n; ++k) {
      SubObject e = proto;
      e.address.sub = static_cast<std::uint8_t>(k);
      e.name = o.name + std::to_string(k);
      if (ns != nullptr) {
        if (const Line* l = ns->get(std::to_string(k))) e.name = l->value;
      }
      if (vs != nullptr) {
        if (const Line* l = vs->get(std::to_string(k))) {
          e.default_value = l->value;
          CDPR_RETURN_IF_ERROR(check_value(*vs, l->line, "DefaultValue", e, l->value));
        }
      }
      o.subs.push_back(std::move(e));
    }
    return Status::success();
  }

  // [MandatoryObjects] etc.: SupportedObjects=N and 1..N=index; every listed object has a section.
  Status object_list(const char* name, std::set<std::uint16_t>& listed) const {
    const RawSection* s = section(name);
    if (s == nullptr) return Status::success();
    std::int64_t n = 0;
    bool present = false;
    CDPR_RETURN_IF_ERROR(number(*s, "SupportedObjects", true, 0, 0xFFFF, n, present));
    for (std::int64_t k = 1; k <= n; ++k) {
      const Line* l = s->get(std::to_string(k));
      if (l == nullptr) {
        return error(s->line, s->name,
                     "SupportedObjects is " + std::to_string(n) + " but entry " +
                         std::to_string(k) + " is missing");
      }
      std::int64_t index = 0;
      if (!parse_plain(l->value, index) || index < 1 || index > 0xFFFF) {
        return error(l->line, s->name, "'" + l->value + "' is not an object index");
      }
      char sec[8];
      std::snprintf(sec, sizeof sec, "%04X", static_cast<unsigned>(index));
      if (section(sec) == nullptr) {
        return error(l->line, s->name,
                     "lists object " + std::string(sec) + " but there is no [" + sec + "] section");
      }
      listed.insert(static_cast<std::uint16_t>(index));
    }
    return Status::success();
  }

  Status build(Eds& eds, std::map<std::uint16_t, Object>& objects, Section& file_info,
               Section& device_info, Section& commissioning) const {
    (void)eds;
    auto copy = [](const RawSection* s, Section& out) {
      if (s == nullptr) return;
      for (const auto& [k, v] : s->keys) out.emplace_back(k, v.value);
    };
    copy(section("FileInfo"), file_info);
    copy(section("DeviceInfo"), device_info);
    copy(section("DeviceComissioning"), commissioning);
    std::set<std::uint16_t> listed;
    for (const char* list : {"MandatoryObjects", "OptionalObjects", "ManufacturerObjects"}) {
      CDPR_RETURN_IF_ERROR(object_list(list, listed));
    }
    for (const RawSection& s : sections_) {
      const std::string n = lower(s.name);
      if (n.size() == 4 && is_hex(n)) {
        const auto index = static_cast<std::uint16_t>(std::strtoul(n.c_str(), nullptr, 16));
        Object o;
        CDPR_RETURN_IF_ERROR(object(s, index, o));
        if (!listed.empty() && listed.count(index) == 0 && index >= 0x1000) {
          return error(s.line, s.name,
                       "object is not listed in [MandatoryObjects], [OptionalObjects] or "
                       "[ManufacturerObjects]");
        }
        objects[index] = std::move(o);
      } else if (n.size() > 7 && is_hex(n.substr(0, 4)) && n.compare(4, 3, "sub") == 0) {
        char parent[8];
        std::snprintf(parent, sizeof parent, "%s", n.substr(0, 4).c_str());
        if (section(parent) == nullptr) {
          return error(s.line, s.name,
                       "sub-object without its object [" + std::string(s.name.substr(0, 4)) + "]");
        }
      }
    }
    if (objects.empty()) return error(1, "", "no object sections ([1000], ...)");
    return Status::success();
  }

 private:
  std::string source_;
  std::vector<RawSection> sections_;
  std::set<std::string> seen_;
};

}  // namespace

Result<Eds> Eds::parse(std::string_view text, std::string_view source) {
  Eds eds;
  eds.source_ = std::string(source);
  Reader r(eds.source_);
  CDPR_RETURN_IF_ERROR(r.split(text));
  CDPR_RETURN_IF_ERROR(
      r.build(eds, eds.objects_, eds.file_info_, eds.device_info_, eds.commissioning_));
  return eds;
}

Result<Eds> Eds::load(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::error(ErrorCode::kNotFound, "%s: cannot open the EDS/DCF file: %s", path.c_str(),
                         std::strerror(errno));
  }
  std::stringstream ss;
  ss << in.rdbuf();
  return parse(ss.str(), path);
}

namespace {

std::string format_value(std::uint16_t data_type, std::int64_t v) {
  char b[32];
  if (type_is_signed(data_type)) {
    // Values may come as the raw bytes of the object (0xFD for INTEGER8 -3): sign-extend.
    const int size = type_size(data_type);
    if (size > 0 && size < 8) {
      const int bits = 8 * size;
      const std::uint64_t mask = (std::uint64_t{1} << bits) - 1;
      std::uint64_t u = static_cast<std::uint64_t>(v) & mask;
      if (u & (std::uint64_t{1} << (bits - 1))) u |= ~mask;
      v = static_cast<std::int64_t>(u);
    }
    std::snprintf(b, sizeof b, "%lld", static_cast<long long>(v));
  } else {
    const int size = type_size(data_type);
    std::uint64_t u = static_cast<std::uint64_t>(v);
    if (size > 0 && size < 8) u &= (std::uint64_t{1} << (8 * size)) - 1;
    std::snprintf(b, sizeof b, "0x%llX", static_cast<unsigned long long>(u));
  }
  return b;
}

void write_entry(std::ostringstream& out, const SubObject& e, const std::optional<std::int64_t>& v,
                 ObjectCode code) {
  out << "ParameterName=" << e.name << "\n";
  out << "ObjectType=0x" << std::hex << std::uppercase << static_cast<unsigned>(code) << std::dec
      << "\n";
  char dt[16];
  std::snprintf(dt, sizeof dt, "0x%04X", unsigned{e.data_type});
  out << "DataType=" << dt << "\n";
  out << "AccessType=" << to_string(e.access) << "\n";
  if (!e.default_value.empty()) out << "DefaultValue=" << e.default_value << "\n";
  if (!e.low_limit.empty()) out << "LowLimit=" << e.low_limit << "\n";
  if (!e.high_limit.empty()) out << "HighLimit=" << e.high_limit << "\n";
  out << "PDOMapping=" << (e.pdo_mapping ? 1 : 0) << "\n";
  if (v) {
    out << "ParameterValue=" << format_value(e.data_type, *v) << "\n";
  } else if (e.parameter_value) {
    out << "ParameterValue=" << *e.parameter_value << "\n";
  }
}

}  // namespace

std::string to_dcf(const Eds& eds, const Commissioning& c,
                   const std::map<std::uint32_t, std::int64_t>& values) {
  std::ostringstream out;
  out << "; Device configuration file (CiA 306) written by the cdpr CANopen master: the\n"
         "; description of "
      << eds.source() << "\n; with ParameterValue = what the master wrote at boot.\n\n";
  out << "[FileInfo]\n";
  char name[64];
  std::snprintf(name, sizeof name, "node%u", unsigned{c.node_id});
  out << "FileName=" << (c.node_name.empty() ? std::string(name) : c.node_name) << ".dcf"
      << "\nFileVersion=1\nFileRevision=0\nEDSVersion=4.0\n";
  out << "Description=configuration of node " << unsigned{c.node_id} << " (" << c.node_name
      << ")\nCreatedBy=cdpr canopen master\n\n";
  out << "[DeviceInfo]\n";
  for (const auto& [k, v] : eds.device_info()) out << k << "=" << v << "\n";
  out << "\n[DeviceComissioning]\n";
  out << "NodeID=" << unsigned{c.node_id} << "\nNodeName=" << c.node_name
      << "\nBaudrate=" << std::lround(c.bitrate / 1000.0)
      << "\nNetNumber=0\nNetworkName=" << c.network_name
      << "\nCANopenManager=0\nLSS_SerialNumber=0\n\n";
  std::vector<std::uint16_t> mandatory, optional, manufacturer;
  for (const auto& [index, o] : eds.objects()) {
    if (index < 0x1000) continue;  // data type definitions are not listed
    if (index == 0x1000 || index == 0x1001 || index == 0x1018) {
      mandatory.push_back(index);
    } else if (index >= 0x2000 && index < 0x6000) {
      manufacturer.push_back(index);
    } else {
      optional.push_back(index);
    }
  }
  auto list = [&](const char* section, const std::vector<std::uint16_t>& v) {
    out << "[" << section << "]\nSupportedObjects=" << v.size() << "\n";
    for (std::size_t i = 0; i < v.size(); ++i) {
      char b[16];
      std::snprintf(b, sizeof b, "0x%04X", unsigned{v[i]});
      out << i + 1 << "=" << b << "\n";
    }
    out << "\n";
  };
  list("MandatoryObjects", mandatory);
  list("OptionalObjects", optional);
  list("ManufacturerObjects", manufacturer);
  for (const auto& [index, o] : eds.objects()) {
    auto value_of = [&](const SubObject& e) -> std::optional<std::int64_t> {
      auto it = values.find(e.address.key());
      if (it == values.end()) return std::nullopt;
      return it->second;
    };
    char sec[16];
    std::snprintf(sec, sizeof sec, "%04X", unsigned{index});
    out << "[" << sec << "]\n";
    const bool single = o.code == ObjectCode::kVar || o.code == ObjectCode::kDomain ||
                        o.code == ObjectCode::kDefType;
    if (single && o.subs.size() == 1) {
      SubObject e = o.subs.front();
      e.name = o.name;
      write_entry(out, e, value_of(e), o.code);
      out << "\n";
      continue;
    }
    char code[8];
    std::snprintf(code, sizeof code, "0x%X", static_cast<unsigned>(o.code));
    out << "ParameterName=" << o.name << "\nObjectType=" << code << "\nSubNumber=" << o.subs.size()
        << "\n\n";
    for (const SubObject& e : o.subs) {
      out << "[" << sec << "sub" << std::hex << std::uppercase << unsigned{e.address.sub}
          << std::dec << "]\n";
      write_entry(out, e, value_of(e), ObjectCode::kVar);
      out << "\n";
    }
  }
  return out.str();
}

}  // namespace cdpr::canopen::eds
