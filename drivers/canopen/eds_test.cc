// EDS/DCF files (CiA 306): reading the shipped simulator EDS and a hand-written vendor-style EDS,
// errors that name file, line and object, DCF writing read back, and network configurations
// checked against EDS files (objects that are missing, read-only, not mappable or of another type).
#include "cdpr/canopen/eds.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>

#include "cdpr/canopen/config.hpp"
#include "cdpr/canopen/eds_check.hpp"
#include "cdpr/io/atomic_file.hpp"

namespace cdpr::canopen::eds {
namespace {

const std::string kEdsDir = CDPR_SOURCE_DIR "/config/eds";

TEST(Eds, IntegerExpressionsWithNodeId) {
  std::int64_t v = 0;
  EXPECT_TRUE(parse_integer("$NODEID+0x180", 5, v));
  EXPECT_EQ(v, 0x185);
  EXPECT_TRUE(parse_integer("0x200+$NODEID", 5, v));
  EXPECT_EQ(v, 0x205);
  EXPECT_TRUE(parse_integer("$nodeid", 9, v));
  EXPECT_EQ(v, 9);
  EXPECT_TRUE(parse_integer("017", 1, v));  // octal
  EXPECT_EQ(v, 15);
  EXPECT_TRUE(parse_integer("-3", 1, v));
  EXPECT_EQ(v, -3);
  EXPECT_FALSE(parse_integer("12abc", 1, v));
  EXPECT_FALSE(parse_integer("", 1, v));
}

TEST(Eds, ReadsTheSimulatorDriveEds) {
  auto e = Eds::load(kEdsDir + "/cdpr-sim-drive.eds");
  ASSERT_TRUE(e.ok()) << e.status().to_string();
  EXPECT_EQ(e->device_info("ProductNumber"), "0x00000402");
  const SubObject* sw = e->find({0x6041, 0});
  ASSERT_NE(sw, nullptr);
  EXPECT_EQ(sw->data_type, type::kUnsigned16);
  EXPECT_EQ(sw->access, Access::kRo);
  EXPECT_TRUE(sw->pdo_mapping);
  const SubObject* tpdo3 = e->find({0x1802, 1});
  ASSERT_NE(tpdo3, nullptr);
  auto cob = e->value(*tpdo3, 7);
  ASSERT_TRUE(cob.ok());
  EXPECT_EQ(*cob, 0x387);  // $NODEID+0x380: enabled by default
  ASSERT_NE(e->object(0x1A00), nullptr);
  EXPECT_EQ(e->object(0x1A00)->subs.size(), 9u);
  EXPECT_EQ(e->object(0x1800)->subs.back().address.sub, 5);
  auto f = Eds::load(kEdsDir + "/cdpr-sim-force.eds");
  ASSERT_TRUE(f.ok()) << f.status().to_string();
  EXPECT_EQ(f->find({0x6401, 8})->data_type, type::kInteger16);
}

TEST(Eds, ReadsAHandWrittenVendorStyleEds) {
  auto e = Eds::load(kEdsDir + "/vendor-style/festo-cmmp-as-m3-style.eds");
  ASSERT_TRUE(e.ok()) << e.status().to_string();
  EXPECT_EQ(e->device_info("vendornumber"), "0x1D");
  auto vendor = e->value(*e->find({0x1018, 1}), 1);
  ASSERT_TRUE(vendor.ok());
  EXPECT_EQ(*vendor, 0x1D);
  // CompactSubObj: sub 0 holds the count, subs 1..N share the type, names from [1003Name].
  const Object* errors = e->object(0x1003);
  ASSERT_NE(errors, nullptr);
  ASSERT_EQ(errors->subs.size(), 9u);
  EXPECT_EQ(errors->subs[0].data_type, type::kUnsigned8);
  EXPECT_EQ(errors->subs[3].data_type, type::kUnsigned32);
  EXPECT_EQ(errors->subs[3].name, "Pre-defined Error Field 3");
  // rww (written by RPDO), 0x60C1 in a record, TPDO sub-index 4 (compatibility entry).
  EXPECT_EQ(e->find({0x6040, 0})->access, Access::kRww);
  EXPECT_TRUE(writable(e->find({0x607A, 0})->access));
  EXPECT_TRUE(e->find({0x60C1, 1})->pdo_mapping);
  EXPECT_NE(e->find({0x1800, 4}), nullptr);
  auto homing = e->value(*e->find({0x6098, 0}), 1);
  ASSERT_TRUE(homing.ok());
  EXPECT_EQ(*homing, -17);
}

Status parse_error(const std::string& text) {
  auto e = Eds::parse(text, "bad.eds");
  return e.ok() ? Status::success() : e.status();
}

TEST(Eds, ErrorsNameFileLineAndObject) {
  const std::string head = "[MandatoryObjects]\nSupportedObjects=1\n1=0x6041\n";
  auto msg = [&](const std::string& body) {
    return std::string(parse_error(head + body).message());
  };
  EXPECT_EQ(msg("[6041]\nParameterName=Statusword\nDataType=0x0099\nAccessType=ro\n"),
            "bad.eds:6: [6041]: DataType 0x0099 is not a CiA 301 data type");
  EXPECT_EQ(msg("[6041]\nParameterName=Statusword\nDataType=0x0006\n"),
            "bad.eds:4: [6041]: AccessType is missing");
  EXPECT_EQ(msg("[6041]\nParameterName=Statusword\nDataType=0x0006\nAccessType=read\n"),
            "bad.eds:7: [6041]: AccessType 'read' is not ro, wo, rw, rwr, rww or const");
  EXPECT_EQ(msg("[6041]\nParameterName=S\nDataType=0x0005\nAccessType=ro\nDefaultValue=300\n"),
            "bad.eds:8: [6041]: DefaultValue 300 does not fit UNSIGNED8");
  EXPECT_EQ(msg("[6041]\nParameterName=S\nDataType=0x0006\nAccessType=ro\nPDOMapping=2\n"),
            "bad.eds:8: [6041]: PDOMapping 2 is outside 0..1");
  EXPECT_EQ(msg("[6041]\nParameterName=S\nObjectType=0x9\nSubNumber=2\n[6041sub0]\n"
                "ParameterName=n\nDataType=0x0005\nAccessType=ro\n"),
            "bad.eds:7: [6041]: SubNumber is 2 but 1 [6041subN] sections follow");
  EXPECT_EQ(msg("[6041]\nParameterName=S\nDataType=0x0006\nAccessType=ro\nAccessType=rw\n"),
            "bad.eds:8: [6041]: key 'accesstype' appears twice");
  EXPECT_EQ(
      std::string(parse_error("[MandatoryObjects]\nSupportedObjects=1\n1=0x1000\n").message()),
      "bad.eds:3: [MandatoryObjects]: lists object 1000 but there is no [1000] section");
  EXPECT_EQ(std::string(parse_error("DataType=7\n").message()),
            "bad.eds:1: key=value before the first [section]");
  EXPECT_EQ(msg("[6041]\nParameterName=S\nDataType=0x0006\nAccessType=ro\n[6042]\n"
                "ParameterName=T\nDataType=0x0006\nAccessType=ro\n"),
            "bad.eds:8: [6042]: object is not listed in [MandatoryObjects], [OptionalObjects] or "
            "[ManufacturerObjects]");
  auto missing = Eds::load("/nonexistent/drive.eds");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), ErrorCode::kNotFound);
}

TEST(Eds, WritesADcfThatReadsBack) {
  auto e = Eds::load(kEdsDir + "/cdpr-sim-drive.eds");
  ASSERT_TRUE(e.ok()) << e.status().to_string();
  Commissioning c;
  c.node_id = 3;
  c.node_name = "winch3";
  c.bitrate = 500e3;
  c.network_name = "mini";
  const std::map<std::uint32_t, std::int64_t> values{
      {ObjectAddress{0x1017, 0}.key(), 50},
      {ObjectAddress{0x1801, 1}.key(), 0x80000283},
      {ObjectAddress{0x60C2, 2}.key(), -3},
  };
  const std::string text = to_dcf(*e, c, values);
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("cdpr-eds-test-" + std::to_string(::getpid()) + ".dcf"))
                               .string();
  ASSERT_TRUE(io::write_file_atomically(path, text).ok());
  auto d = Eds::load(path);
  std::remove(path.c_str());
  ASSERT_TRUE(d.ok()) << d.status().to_string();
  auto hb = d->value(*d->find({0x1017, 0}), 3, true);
  ASSERT_TRUE(hb.ok());
  EXPECT_EQ(*hb, 50);
  auto cob = d->value(*d->find({0x1801, 1}), 3, true);
  ASSERT_TRUE(cob.ok());
  EXPECT_EQ(*cob, 0x80000283);
  auto index = d->value(*d->find({0x60C2, 2}), 3, true);
  ASSERT_TRUE(index.ok());
  EXPECT_EQ(*index, -3);
  EXPECT_FALSE(d->find({0x6040, 0})->parameter_value.has_value());
  // The description itself is unchanged.
  EXPECT_EQ(d->objects().size(), e->objects().size());
  EXPECT_TRUE(d->find({0x6041, 0})->pdo_mapping);
  EXPECT_EQ(d->find({0x1801, 1})->default_value, "$NODEID+0x280");
  bool node_id = false;
  for (const auto& [k, v] : d->commissioning()) node_id = node_id || (k == "nodeid" && v == "3");
  EXPECT_TRUE(node_id);
}

// --- the network configuration against EDS files ------------------------------------------------

std::string network(const std::string& eds, const std::string& tpdo_map,
                    const std::string& extra = "") {
  return "profiles:\n"
         "  winch:\n"
         "    kind: cia402\n"
         "    eds: " +
         eds +
         "\n"
         "    rpdo:\n"
         "      - {number: 1, transmission: 1, map: [\"0x6040:00 u16\", \"0x607A:00 i32\"]}\n"
         "    tpdo:\n"
         "      - {number: 1, transmission: 1, map: [" +
         tpdo_map + "]}\n" + extra +
         "nodes:\n"
         "  - {id: 3, name: winch3, profile: winch}\n";
}

TEST(EdsCheck, AcceptsTheMiniNetworkAndTheVendorStyleDrive) {
  auto mini = load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
  ASSERT_TRUE(mini.ok()) << mini.status().to_string();
  ASSERT_NE(mini->nodes[0].eds_data, nullptr);
  EXPECT_EQ(mini->nodes[0].eds_data.get(), mini->nodes[7].eds_data.get());  // loaded once
  auto vendor = parse_config(network(kEdsDir + "/vendor-style/festo-cmmp-as-m3-style.eds",
                                     "\"0x6041:00 u16\", \"0x6064:00 i32\""),
                             "net.yaml");
  ASSERT_TRUE(vendor.ok()) << vendor.status().to_string();
}

TEST(EdsCheck, RefusesAMappingOfAnObjectTheEdsSaysIsNotMappable) {
  // 0x607C (home offset) is PDOMapping=0 in the drive's EDS.
  auto c =
      parse_config(network(kEdsDir + "/cdpr-sim-drive.eds", "\"0x6041:00 u16\", \"0x6064:00 i32\"",
                           "      - {number: 2, transmission: 1, map: [\"0x607C:00 i32\"]}\n"),
                   "net.yaml");
  ASSERT_FALSE(c.ok());
  auto e = Eds::load(kEdsDir + "/cdpr-sim-drive.eds");
  ASSERT_TRUE(e.ok());
  EXPECT_EQ(std::string(c.status().message()),
            "net.yaml: node 3 (winch3): the master maps 0x607C:00 as i32 in TPDO2, but " + kEdsDir +
                "/cdpr-sim-drive.eds:" + std::to_string(e->find({0x607C, 0})->line) +
                ": 0x607C:00 (Home offset) is not mappable (PDOMapping=0)");
}

// Issue 39: a start-up write's type is the EDS's when the YAML gives none, and a given type that is
// not the EDS's is named at its file, line and field.
TEST(EdsCheck, AStartUpWriteTakesItsTypeFromTheEdsOrMustMatchIt) {
  const std::string drive = kEdsDir + "/cdpr-sim-drive.eds";
  const std::string tpdo = "\"0x6041:00 u16\", \"0x6064:00 i32\"";
  auto taken = parse_config(
      network(drive, tpdo, "    sdo:\n      - {object: \"0x6083:00\", value: 100000}\n"),
      "net.yaml");
  ASSERT_TRUE(taken.ok()) << taken.status().to_string();
  ASSERT_EQ(taken->nodes[0].sdo_writes.size(), 1u);
  EXPECT_EQ(taken->nodes[0].sdo_writes[0].type, DataType::kU32);  // UNSIGNED32 in the EDS
  EXPECT_EQ(taken->nodes[0].sdo_writes[0].value, 100000);
  // The EDS's type bounds the value: -1 does not fit UNSIGNED32.
  auto negative = parse_config(
      network(drive, tpdo, "    sdo:\n      - {object: \"0x6083:00\", value: -1}\n"), "net.yaml");
  ASSERT_FALSE(negative.ok());
  EXPECT_NE(negative.status().message().find("net.yaml:10: profiles.winch.sdo[0].value"),
            std::string::npos)
      << negative.status().message();
  // A size that is not the EDS's.
  auto wrong = parse_config(
      network(drive, tpdo, "    sdo:\n      - {object: \"0x6083:00\", type: u16, value: 1}\n"),
      "net.yaml");
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.status().message().rfind("net.yaml:10: profiles.winch.sdo[0]: node 3 (winch3): "
                                           "the master writes 0x6083:00 (sdo write) as u16, but ",
                                           0),
            0u)
      << wrong.status().message();
  EXPECT_NE(wrong.status().message().find("is UNSIGNED32"), std::string::npos);
  // Without a type, an object the EDS does not have cannot be written.
  auto unknown = parse_config(
      network(drive, tpdo, "    sdo:\n      - {object: \"0x2100:00\", value: 1}\n"), "net.yaml");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.status().message().find("has no object 0x2100:00: give its type"),
            std::string::npos)
      << unknown.status().message();
}

TEST(EdsCheck, RefusesWrongTypesReadOnlyObjectsAndMissingObjects) {
  const std::string drive = kEdsDir + "/cdpr-sim-drive.eds";
  const std::string tpdo = "\"0x6041:00 u16\", \"0x6064:00 i32\"";
  // The statusword mapped as a 32-bit value.
  auto type = parse_config(network(drive, "\"0x6041:00 u32\", \"0x6064:00 i32\""), "net.yaml");
  ASSERT_FALSE(type.ok());
  EXPECT_NE(type.status().message().find("maps 0x6041:00 as u32 in TPDO1, but "),
            std::string::npos);
  EXPECT_NE(type.status().message().find("is UNSIGNED16"), std::string::npos);
  // A start-up write to a read-only object.
  auto ro = parse_config(
      network(drive, tpdo, "    sdo:\n      - {object: \"0x6041:00\", type: u16, value: 1}\n"),
      "net.yaml");
  ASSERT_FALSE(ro.ok());
  EXPECT_NE(ro.status().message().find("the master writes 0x6041:00 (sdo write) as u16, but "),
            std::string::npos)
      << ro.status().message();
  EXPECT_NE(ro.status().message().find("(Statusword) is ro"), std::string::npos);
  // An object the device does not have.
  auto missing = parse_config(
      network(drive, tpdo, "    sdo:\n      - {object: \"0x2100:00\", type: u8, value: 1}\n"),
      "net.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(std::string(missing.status().message()),
            "net.yaml:10: profiles.winch.sdo[0]: node 3 (winch3): the master writes 0x2100:00 "
            "(sdo write) as u8, but " +
                drive + " has no object 0x2100:00");
  // A TPDO inhibit time on a drive whose EDS has no such sub-index: the vendor-style one has.
  auto inhibit = parse_config(network(kEdsDir + "/cdpr-sim-force.eds", tpdo), "net.yaml");
  ASSERT_FALSE(inhibit.ok());
  // An EDS that cannot be read is named at its YAML line.
  auto unreadable = parse_config(network("no-such.eds", tpdo), "dir/net.yaml");
  ASSERT_FALSE(unreadable.ok());
  EXPECT_EQ(unreadable.status().message().rfind(
                "dir/net.yaml:4: profiles.winch.eds: dir/no-such.eds: cannot open", 0),
            0u)
      << unreadable.status().message();
}

TEST(EdsCheck, PlannedAccessesFollowTheBootOrder) {
  auto mini = load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
  ASSERT_TRUE(mini.ok()) << mini.status().to_string();
  const auto plan = planned_accesses(*mini, mini->nodes[0]);
  ASSERT_GE(plan.size(), 10u);
  EXPECT_EQ(plan.front().object, (ObjectAddress{0x1017, 0}));
  EXPECT_EQ(plan[1].object, (ObjectAddress{0x1016, 1}));
  EXPECT_EQ(plan[2].object, (ObjectAddress{0x6007, 0}));
  EXPECT_EQ(plan[3].object, (ObjectAddress{0x1400, 1}));
  EXPECT_EQ(pdo_numbers(mini->nodes[0], PdoDirection::kTpdo), (std::vector<int>{1, 2, 3, 4}));
}

// The shipped drive EDS without some objects, as a file in the test's temp dir (the object
// lists are rebuilt by to_dcf).
std::string drive_eds_without(std::initializer_list<std::uint16_t> drop, const std::string& name) {
  auto e = Eds::load(kEdsDir + "/cdpr-sim-drive.eds");
  EXPECT_TRUE(e.ok()) << e.status().to_string();
  Eds out;
  for (const auto& [index, o] : e->objects()) {
    if (std::find(drop.begin(), drop.end(), index) == drop.end()) out.put(o);
  }
  out.set_device_info(e->device_info());
  const std::string path = ::testing::TempDir() + "/" + name + ".eds";
  EXPECT_TRUE(io::write_file_atomically(path, to_dcf(out, Commissioning{}, {})).ok());
  return path;
}

// Issue 39 (7): a CSP-only drive needs no homing objects; configured homing does.
TEST(EdsCheck, ACspDriveWithoutHomingObjectsIsAcceptedUnlessHomingIsConfigured) {
  const std::string eds = drive_eds_without({0x607C, 0x6098}, "no-homing");
  const std::string tpdo = "\"0x6041:00 u16\", \"0x6064:00 i32\"";
  auto csp = parse_config(network(eds, tpdo), "net.yaml");
  EXPECT_TRUE(csp.ok()) << csp.status().to_string();
  auto homing = parse_config(network(eds, tpdo, "    homing_method: 35\n"), "net.yaml");
  ASSERT_FALSE(homing.ok());
  EXPECT_NE(homing.status().message().find("writes 0x6098:00 (homing method)"), std::string::npos)
      << homing.status().message();
  auto mode = parse_config(network(eds, tpdo, "    mode: homing\n"), "net.yaml");
  EXPECT_FALSE(mode.ok());
}

// Drives by configuration: a quirk changes what the master needs of the EDS; unknown quirks
// are named at their YAML line.
TEST(EdsCheck, QuirksChangeThePlannedAccessesAndUnknownOnesAreNamed) {
  const std::string eds = drive_eds_without({0x60C2}, "no-60c2");
  const std::string tpdo = "\"0x6041:00 u16\", \"0x6064:00 i32\"";
  auto plain = parse_config(network(eds, tpdo), "net.yaml");
  ASSERT_FALSE(plain.ok());
  EXPECT_NE(plain.status().message().find("0x60C2:01"), std::string::npos);
  auto quirk =
      parse_config(network(eds, tpdo, "    quirks: [no_interpolation_period]\n"), "net.yaml");
  EXPECT_TRUE(quirk.ok()) << quirk.status().to_string();
  auto display = parse_config(
      network(kEdsDir + "/cdpr-sim-drive.eds", tpdo, "    quirks: [no_mode_display]\n"),
      "net.yaml");
  ASSERT_TRUE(display.ok()) << display.status().to_string();
  bool reads_6061 = false;
  for (const PlannedAccess& a : planned_accesses(*display, display->nodes[0])) {
    reads_6061 = reads_6061 || a.object == ObjectAddress{0x6061, 0};
  }
  EXPECT_FALSE(reads_6061);
  auto unknown = parse_config(network(eds, tpdo, "    quirks: [no_such_thing]\n"), "net.yaml");
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(std::string(unknown.status().message()),
            "net.yaml:9: profiles.winch.quirks[0]: 'no_such_thing' is not a quirk "
            "(no_mode_display, no_interpolation_period)");
}

}  // namespace
}  // namespace cdpr::canopen::eds
