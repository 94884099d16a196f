// Electronic data sheets (CiA 306): EDS files describe a device's object dictionary (what exists,
// its data type, access, default value and whether it can be mapped into a PDO); a DCF (device
// configuration file) is an EDS with the values actually configured (ParameterValue) and the
// node's commissioning data. Both are INI files:
//
//   [6041]
//   ParameterName=Statusword
//   ObjectType=0x7
//   DataType=0x0006
//   AccessType=ro
//   PDOMapping=1
//
// is object 0x6041, a VAR of type UNSIGNED16, read-only and mappable; an ARRAY or RECORD such as
// [1018] has SubNumber= sub-objects in sections [1018sub0], [1018sub1], ... (or CompactSubObj=).
// Lines starting with ';' are comments; keys are case-insensitive.
//
// Reading checks what the master relies on and names file, line and object in every error
// ("drive.eds:212: [1A00sub3]: DataType 0x0099 is not a CiA 301 data type"). Writing produces a
// DCF from an Eds and the values the master applied. Start-up code only (allocates).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/canopen/pdo.hpp"
#include "cdpr/canopen/types.hpp"
#include "cdpr/status.hpp"

namespace cdpr::canopen::eds {

// CiA 301 object codes (ObjectType=).
enum class ObjectCode : std::uint8_t {
  kNull = 0x0,
  kDomain = 0x2,
  kDefType = 0x5,
  kDefStruct = 0x6,
  kVar = 0x7,
  kArray = 0x8,
  kRecord = 0x9,
};

// CiA 301 static data types (DataType=), the index of their definition object.
namespace type {
inline constexpr std::uint16_t kBoolean = 0x0001;
inline constexpr std::uint16_t kInteger8 = 0x0002;
inline constexpr std::uint16_t kInteger16 = 0x0003;
inline constexpr std::uint16_t kInteger32 = 0x0004;
inline constexpr std::uint16_t kUnsigned8 = 0x0005;
inline constexpr std::uint16_t kUnsigned16 = 0x0006;
inline constexpr std::uint16_t kUnsigned32 = 0x0007;
inline constexpr std::uint16_t kReal32 = 0x0008;
inline constexpr std::uint16_t kVisibleString = 0x0009;
inline constexpr std::uint16_t kOctetString = 0x000A;
inline constexpr std::uint16_t kUnicodeString = 0x000B;
inline constexpr std::uint16_t kTimeOfDay = 0x000C;
inline constexpr std::uint16_t kTimeDifference = 0x000D;
inline constexpr std::uint16_t kDomain = 0x000F;
inline constexpr std::uint16_t kInteger24 = 0x0010;
inline constexpr std::uint16_t kReal64 = 0x0011;
inline constexpr std::uint16_t kInteger64 = 0x0015;
inline constexpr std::uint16_t kUnsigned24 = 0x0016;
inline constexpr std::uint16_t kUnsigned64 = 0x001B;
}  // namespace type

// "UNSIGNED16", ...; "unknown" for a type this reader does not know.
std::string_view type_name(std::uint16_t data_type);
// Size in bytes of a fixed-size type; 0 for strings and domains (variable size), -1 if unknown.
int type_size(std::uint16_t data_type);
bool type_is_signed(std::uint16_t data_type);
// The DataType of one of our PDO/SDO value types (kU16 -> UNSIGNED16).
std::uint16_t data_type_of(DataType t);
// Whether an EDS type is the same as one of ours (same size and signedness; BOOLEAN is not u8).
bool same_type(std::uint16_t data_type, DataType t);

enum class Access : std::uint8_t { kRo, kWo, kRw, kRwr, kRww, kConst };
std::string_view to_string(Access a);
constexpr bool readable(Access a) {
  return a != Access::kWo;
}
constexpr bool writable(Access a) {
  return a == Access::kWo || a == Access::kRw || a == Access::kRwr || a == Access::kRww;
}

// One value entry: a VAR object (sub 0), or one sub-index of an ARRAY or RECORD.
struct SubObject {
  ObjectAddress address;
  std::string name;
  std::uint16_t data_type = 0;
  Access access = Access::kRo;
  std::string default_value;                   // as written, e.g. "$NODEID+0x180"; may be empty
  std::optional<std::string> parameter_value;  // DCF: the configured value
  bool pdo_mapping = false;
  std::string low_limit, high_limit;
  int line = 0;  // line of the section header in the file
};

struct Object {
  std::uint16_t index = 0;
  std::string name;
  ObjectCode code = ObjectCode::kVar;
  int line = 0;
  std::vector<SubObject> subs;  // a VAR has exactly one, sub-index 0
};

// Values of [FileInfo], [DeviceInfo] and (DCF) [DeviceComissioning], keys as written.
using Section = std::vector<std::pair<std::string, std::string>>;

class Eds {
 public:
  // Parses EDS/DCF text; `source` names it in errors ("config/eds/drive.eds:12: [6041]: ...").
  static Result<Eds> parse(std::string_view text, std::string_view source);
  static Result<Eds> load(const std::string& path);

  const std::string& source() const { return source_; }
  const std::map<std::uint16_t, Object>& objects() const { return objects_; }
  const Object* object(std::uint16_t index) const;
  const SubObject* find(ObjectAddress a) const;
  const Section& file_info() const { return file_info_; }
  const Section& device_info() const { return device_info_; }
  const Section& commissioning() const { return commissioning_; }
  // A value of [DeviceInfo] (keys compared without case), or "".
  std::string device_info(std::string_view key) const;

  // "drive.eds:212: 0x6041:00 (Statusword)" for messages.
  std::string where(const SubObject& s) const;

  // The default value of a numeric entry for node `node` ($NODEID resolved), or the DCF's
  // ParameterValue when `configured` and present. Errors name file, line and object.
  Result<std::int64_t> value(const SubObject& s, NodeId node, bool configured = false) const;

  // Adds or replaces an object (to build descriptions in code, e.g. a DCF of a node without EDS).
  void put(Object o);
  // To build descriptions in code: the [DeviceInfo] values and the name used in messages.
  void set_device_info(Section s) { device_info_ = std::move(s); }
  void set_source(std::string s) { source_ = std::move(s); }

 private:
  std::string source_;
  std::map<std::uint16_t, Object> objects_;
  Section file_info_, device_info_, commissioning_;
};

// Evaluates an EDS integer expression: decimal, 0x hex, leading-0 octal, optionally with
// "$NODEID+" / "+$NODEID" (CiA 306). False if it is not one.
bool parse_integer(std::string_view text, NodeId node, std::int64_t& out);

// What goes into a DCF's [DeviceComissioning] section.
struct Commissioning {
  NodeId node_id = 0;
  std::string node_name;
  double bitrate = 1e6;  // bit/s (written in kbit/s)
  std::string network_name;
};

// A DCF: the EDS's objects, each with ParameterValue from `values` (keyed by
// ObjectAddress::key(), the value as the master wrote it) or, for the others, as the EDS had it;
// [DeviceComissioning] from `c`; [FileInfo] names the tool.
std::string to_dcf(const Eds& eds, const Commissioning& c,
                   const std::map<std::uint32_t, std::int64_t>& values);

}  // namespace cdpr::canopen::eds
