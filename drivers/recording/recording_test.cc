#include "cdpr/recording/recording.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>
#include <string>

namespace cdpr::recording {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Bitwise equality (so -0.0 != 0.0 and NaN == NaN): "round-trips exactly".
bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

bool same_bits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  if (a.size() != b.size()) return false;
  for (Eigen::Index i = 0; i < a.size(); ++i) {
    if (std::isnan(a(i)) != std::isnan(b(i))) return false;
    if (!std::isnan(a(i)) && !same_bits(a(i), b(i))) return false;
  }
  return true;
}

Recording random_recording(int m, int k, int n, bool reference, bool temperature,
                           std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  std::uniform_int_distribution<int> exponent(-300, 300);
  Recording rec;
  rec.metadata.set(key::kFormat, "cdpr-recording 1");
  rec.metadata.set(key::kUnits, "SI");
  rec.metadata.set(key::kRobot, "MINI");
  rec.metadata.set(key::kConfigHash, "fnv1a64:0123456789abcdef");
  rec.metadata.set_number(key::kNoiseLaser, 1e-3);
  rec.num_cables = m;
  rec.num_lasers = k;
  rec.has_reference = reference;
  rec.has_temperature = temperature;
  std::int64_t index = 3;
  for (int j = 0; j < n; ++j) {
    RecordedPose p;
    index += 1 + j % 3;
    p.index = index;
    p.time_s = 0.1 * j + u(rng) * 1e-3;
    p.commanded.position = Eigen::Vector3d(u(rng), u(rng), u(rng));
    p.commanded.rpy = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.1;
    p.lengths = Eigen::VectorXd::NullaryExpr(m, [&] { return std::abs(u(rng)) + 0.5; });
    p.tensions = Eigen::VectorXd::NullaryExpr(m, [&] { return 100.0 * std::abs(u(rng)); });
    p.lasers = Eigen::VectorXd::NullaryExpr(k, [&] { return std::abs(u(rng)); });
    // Awkward numbers: extreme exponents, subnormal, negative zero, 0.1, not measured.
    p.tensions(j % m) = std::ldexp(u(rng), exponent(rng));
    if (j == 1) p.lengths(0) = kNaN;
    if (j == 2) p.tensions(m - 1) = 4.9406564584124654e-324;
    if (j == 3) p.commanded.rpy(2) = -0.0;
    if (j == 4 && k > 0) p.lasers(0) = 0.1;
    p.reference.position.setConstant(kNaN);
    p.reference.rpy.setConstant(kNaN);
    if (reference && j % 2 == 0) p.reference = p.commanded;
    if (temperature && j != 0) p.temperature_c = 20.0 + u(rng);
    rec.poses.push_back(p);
  }
  return rec;
}

void expect_same(const Recording& a, const Recording& b) {
  EXPECT_EQ(a.metadata, b.metadata);
  EXPECT_EQ(a.num_cables, b.num_cables);
  EXPECT_EQ(a.num_lasers, b.num_lasers);
  EXPECT_EQ(a.has_reference, b.has_reference);
  EXPECT_EQ(a.has_temperature, b.has_temperature);
  ASSERT_EQ(a.poses.size(), b.poses.size());
  for (std::size_t j = 0; j < a.poses.size(); ++j) {
    const RecordedPose& p = a.poses[j];
    const RecordedPose& q = b.poses[j];
    SCOPED_TRACE("pose " + std::to_string(j));
    EXPECT_EQ(p.index, q.index);
    EXPECT_TRUE(same_bits(p.time_s, q.time_s));
    EXPECT_TRUE(same_bits(p.commanded.vector(), q.commanded.vector()));
    EXPECT_TRUE(same_bits(p.lengths, q.lengths));
    EXPECT_TRUE(same_bits(p.tensions, q.tensions));
    EXPECT_TRUE(same_bits(p.lasers, q.lasers));
    EXPECT_TRUE(same_bits(p.reference.vector(), q.reference.vector()));
    EXPECT_TRUE(same_bits(Eigen::VectorXd::Constant(1, p.temperature_c),
                          Eigen::VectorXd::Constant(1, q.temperature_c)));
  }
}

TEST(Recording, RoundTripIsBitExact) {
  for (const bool reference : {false, true}) {
    for (const bool temperature : {false, true}) {
      const Recording rec = random_recording(8, 2, 30, reference, temperature, 7);
      auto text = format_recording(rec);
      ASSERT_TRUE(text.ok()) << text.status().to_string();
      auto back = parse_recording(*text, "mem.csv");
      ASSERT_TRUE(back.ok()) << back.status().to_string();
      expect_same(rec, *back);
      // Writing what was read gives the same bytes.
      auto again = format_recording(*back);
      ASSERT_TRUE(again.ok());
      EXPECT_EQ(*text, *again);
    }
  }
}

TEST(Recording, RoundTripThroughAFile) {
  const Recording rec = random_recording(4, 1, 10, true, true, 11);
  const std::string path =
      (std::filesystem::temp_directory_path() / "cdpr_recording_test_rt.csv").string();
  ASSERT_TRUE(write_recording(rec, path).ok());
  auto back = read_recording(path);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  expect_same(rec, *back);
  std::filesystem::remove(path);
}

TEST(Recording, MissingFileIsNotFound) {
  auto r = read_recording("/nonexistent/dir/rec.csv");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kNotFound);
  EXPECT_THAT(std::string(r.status().message()), HasSubstr("/nonexistent/dir/rec.csv"));
}

// A valid 2-cable, 1-laser recording; lines 1..3 are metadata, 4 the header, 5.. the rows.
const char* const kHeader =
    "pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,tension_1,"
    "tension_2,laser_1";

std::string small_file(const std::string& header, const std::string& rows) {
  return "# format: cdpr-recording 1\n# units: SI\n# robot: TWO\n" + header + "\n" + rows;
}

const char* const kRow0 = "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7\n";
const char* const kRow1 = "1,0.5,0.1,0.2,0.4,0,0,0.01,1.4,1.7,52,53,0.6\n";

TEST(Recording, ParsesTheDocumentedLayout) {
  auto r = parse_recording(small_file(kHeader, std::string(kRow0) + kRow1), "two.csv");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(r->num_cables, 2);
  EXPECT_EQ(r->num_lasers, 1);
  EXPECT_FALSE(r->has_reference);
  ASSERT_EQ(r->poses.size(), 2u);
  EXPECT_EQ(r->poses[1].index, 1);
  EXPECT_DOUBLE_EQ(r->poses[1].commanded.position.z(), 0.4);
  EXPECT_DOUBLE_EQ(r->poses[1].commanded.rpy.z(), 0.01);
  EXPECT_DOUBLE_EQ(r->poses[1].lengths(1), 1.7);
  EXPECT_DOUBLE_EQ(r->poses[1].tensions(0), 52.0);
  EXPECT_DOUBLE_EQ(r->poses[0].lasers(0), 0.7);
  EXPECT_EQ(r->metadata.get(key::kRobot), "TWO");
}

TEST(Recording, ColumnsMayComeInAnyOrderWithBlanksAndCRLF) {
  const std::string header =
      "laser_1, tension_2, tension_1, length_2, length_1, cmd_yaw, cmd_pitch, cmd_roll, cmd_z, "
      "cmd_y, cmd_x, time_s, pose\r";
  auto r = parse_recording(small_file(header,
                                      "0.7, 51, 50, 1.6, 1.5, 0, 0, 0, 0.3, 0.2, 0.1, 0, "
                                      "0\r\n\n"),
                           "reordered.csv");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_DOUBLE_EQ(r->poses[0].lengths(0), 1.5);
  EXPECT_DOUBLE_EQ(r->poses[0].tensions(1), 51.0);
  EXPECT_DOUBLE_EQ(r->poses[0].commanded.position.x(), 0.1);
}

TEST(Recording, EmptyCellMeansNotMeasured) {
  auto r = parse_recording(small_file(kHeader, "0,0,0.1,0.2,0.3,0,0,0,,1.6,50,,0.7\n"), "e.csv");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_TRUE(std::isnan(r->poses[0].lengths(0)));
  EXPECT_TRUE(std::isnan(r->poses[0].tensions(1)));
  EXPECT_DOUBLE_EQ(r->poses[0].lengths(1), 1.6);
}

struct BadCase {
  const char* what;
  std::string text;
  std::string expected;  // the location and the reason, as the message must show them
};

TEST(Recording, EveryBadCellIsNamedByLineAndColumn) {
  const std::string h = kHeader;
  const std::vector<BadCase> cases = {
      {"non-number",
       small_file(h, std::string(kRow0) + "1,0.5,0.1,0.2,0.4,0,0,0.01,1.4,abc,52,53,0.6\n"),
       "bad.csv:6: column 10 (length_2): 'abc' is not a number"},
      {"nan literal",
       small_file(h, std::string(kRow0) + "1,0.5,0.1,0.2,0.4,0,0,0.01,1.4,1.7,nan,53,0.6\n"),
       "bad.csv:6: column 11 (tension_1): 'nan' is not allowed"},
      {"inf literal", small_file(h, "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,-inf\n"),
       "bad.csv:5: column 13 (laser_1): '-inf' is not a finite number"},
      {"overflow", small_file(h, "0,0,0.1,0.2,1e999,0,0,0,1.5,1.6,50,51,0.7\n"),
       "bad.csv:5: column 5 (cmd_z): '1e999' is out of the range"},
      {"missing cell", small_file(h, "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51\n"),
       "bad.csv:5: column 13 (laser_1): missing cell"},
      {"extra cell",
       small_file(h, std::string(kRow0) + "1,0.5,0.1,0.2,0.4,0,0,0.01,1.4,1.7,52,53,0.6,9\n"),
       "bad.csv:6: column 14: extra cell '9'"},
      {"empty required cell", small_file(h, "0,0,0.1,,0.3,0,0,0,1.5,1.6,50,51,0.7\n"),
       "bad.csv:5: column 4 (cmd_y): empty cell"},
      {"pose not increasing", small_file(h, std::string(kRow0) + kRow0),
       "bad.csv:6: column 1 (pose): pose index 0 does not increase (line 5 has 0)"},
      {"pose not an integer", small_file(h, "1.5,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7\n"),
       "bad.csv:5: column 1 (pose): '1.5' is not an integer"},
      {"duplicated column", small_file(h + ",length_2", std::string(kRow0)),
       "bad.csv:4: column 14 (length_2): duplicates column 10"},
      {"missing required column",
       small_file("pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,length_1,tension_1,laser_1",
                  "0,0,0,0,0,0,0,1,1,1\n"),
       "bad.csv:4: missing required column 'cmd_yaw'"},
      {"gap in cable numbering",
       small_file("pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_3,"
                  "tension_1,tension_2,tension_3,laser_1",
                  "0,0,0,0,0,0,0,0,1,1,1,1,1,1\n"),
       "bad.csv:4: missing required column 'length_2'"},
      {"fewer tensions than lengths",
       small_file("pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,"
                  "tension_1,laser_1",
                  "0,0,0,0,0,0,0,0,1,1,1,1\n"),
       "bad.csv:4: 2 length_ columns but 1 tension_ columns"},
      {"swivel columns for some cables only",
       small_file(h + ",swivel_1", "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7,0.1\n"),
       "bad.csv:4: 1 swivel_ columns but 2 cables"},
      {"inclinometer roll without pitch",
       small_file(h + ",incl_roll", "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7,0.1\n"),
       "bad.csv:4: missing column 'incl_pitch'"},
      {"inclinometer pitch missing in a row",
       small_file(h + ",incl_roll,incl_pitch", "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7,0.1,\n"),
       "bad.csv:5: column 15 (incl_pitch): empty cell, but incl_roll and incl_pitch"},
      {"unknown column", small_file(h + ",colour", "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7,1\n"),
       "bad.csv:4: column 14 (colour): unknown column"},
      {"partial reference",
       small_file(h + ",ref_x,ref_y", "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,0.7,1,1\n"),
       "bad.csv:4: missing column 'ref_z'"},
      {"no rows", small_file(h, ""), "bad.csv:4: no data rows"},
      {"no header", "# units: SI\n", "bad.csv: no header row"},
      {"duplicate metadata", "# units: SI\n# robot: A\n# robot: B\n" + h + "\n" + kRow0,
       "bad.csv:3: metadata key 'robot' appears twice (first on line 2)"},
      {"wrong file kind",
       "# format: cdpr-cable-experiment 1\n# units: SI\nlength_m,tension_n,elongation_m\n1,2,3\n",
       "bad.csv: format 'cdpr-cable-experiment 1' is not 'cdpr-recording 1'"},
  };
  for (const BadCase& c : cases) {
    SCOPED_TRACE(c.what);
    auto r = parse_recording(c.text, "bad.csv");
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.status().code(), ErrorCode::kParseError);
    EXPECT_THAT(std::string(r.status().message()), HasSubstr(c.expected));
  }
}

TEST(Recording, UnitsMustBeStatedAsSI) {
  const std::string body = std::string(kHeader) + "\n" + kRow0;
  auto none = parse_recording("# robot: X\n" + body, "nounits.csv");
  ASSERT_FALSE(none.ok());
  EXPECT_THAT(std::string(none.status().message()),
              HasSubstr("nounits.csv: no '# units: SI' line before the header"));
  auto mm = parse_recording("# robot: X\n# units: mm\n" + body, "mm.csv");
  ASSERT_FALSE(mm.ok());
  EXPECT_THAT(std::string(mm.status().message()),
              HasSubstr("mm.csv:2: units 'mm' are not supported"));
  auto si = parse_recording("# units: SI\n" + body, "si.csv");
  EXPECT_TRUE(si.ok()) << si.status().to_string();
  // The writer refuses to claim anything but SI.
  Recording rec = random_recording(2, 1, 2, false, false, 1);
  rec.metadata.set(key::kUnits, "mm");
  EXPECT_FALSE(format_recording(rec).ok());
}

RobotModel model_with(int cables, int lasers) {
  RobotModel model;
  model.name = "MINI";
  model.frame_anchors = Eigen::Matrix3Xd::Zero(3, cables);
  model.platform_anchors = Eigen::Matrix3Xd::Zero(3, cables);
  model.lasers.resize(static_cast<std::size_t>(lasers));
  return model;
}

TEST(Recording, CableAndLaserCountsAreCheckedAgainstTheConfig) {
  const Recording rec = random_recording(4, 1, 3, false, false, 3);
  EXPECT_TRUE(check_against_model(rec, model_with(4, 1)).ok());
  const Status cables = check_against_model(rec, model_with(8, 1));
  EXPECT_EQ(cables.code(), ErrorCode::kFailedPrecondition);
  EXPECT_THAT(std::string(cables.message()),
              HasSubstr("the recording has 4 cables (length_1..length_4) but config 'MINI' has 8"));
  const Status lasers = check_against_model(rec, model_with(4, 2));
  EXPECT_EQ(lasers.code(), ErrorCode::kFailedPrecondition);
  EXPECT_THAT(std::string(lasers.message()), HasSubstr("1 laser columns but config 'MINI' has 2"));
}

// A 4-cable robot in the cube [-1, 1]^3 (frame size 2 sqrt(3) m, centre 0), and a recording of
// it: three poses near the centre, every length 1.7 m (line 4 is the first data row).
RobotModel cube_robot() {
  RobotModel model = model_with(4, 1);
  model.pulleys.resize(4);              // point anchors
  model.frame_anchors << 1, -1, 1, -1,  //
      1, 1, -1, -1,                     //
      1, 1, 1, -1;
  return model;
}

std::string cube_recording(const std::string& row1_change = "") {
  std::string text =
      "# units: SI\n# noise_length_m: 1e-4\n"
      "pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,length_3,"
      "length_4,tension_1,tension_2,tension_3,tension_4,laser_1\n";
  for (int j = 0; j < 3; ++j) {
    text += std::to_string(j) + ",0,0.0" + std::to_string(j) +
            ",0,0,0,0,0,1.7,1.7,1.7,1.7,10,10,10,10,0.5\n";
  }
  if (!row1_change.empty()) {
    const std::size_t at = text.find("\n1,");
    text.replace(at + 1, text.find('\n', at + 1) - at - 1, row1_change);
  }
  return text;
}

Status plausibility_of(const std::string& text) {
  const Result<Recording> rec = parse_recording(text, "rec.csv");
  EXPECT_TRUE(rec.ok()) << rec.status().to_string();
  return rec.ok() ? check_plausible(*rec, cube_robot(), "rec.csv") : rec.status();
}

// Issue 16 items 4 and 5: what a recording of the robot in SI units cannot hold, named by line
// and column with readable numbers.
TEST(Plausibility, APlausibleRecordingPasses) {
  EXPECT_TRUE(plausibility_of(cube_recording()).ok())
      << plausibility_of(cube_recording()).message();
}

TEST(Plausibility, CellsOutOfRangeAreNamedByLineAndColumn) {
  const double size = 2.0 * std::sqrt(3.0);
  char bound[32], frame[32];
  std::snprintf(bound, sizeof bound, "%.6g", 10 * size);
  std::snprintf(frame, sizeof frame, "%.6g", size);
  const Status x =
      plausibility_of(cube_recording("1,0,1e300,0,0,0,0,0,1.7,1.7,1.7,1.7,10,10,10,10,0.5"));
  EXPECT_EQ(x.code(), ErrorCode::kInvalidArgument);
  EXPECT_EQ(std::string(x.message()),
            std::string("rec.csv:5: column 3 (cmd_x): 1e+300 m is outside the plausible range [-") +
                bound + ", " + bound + "] m (10 frame sizes of " + frame +
                " m around the frame centre)");
  const Status length =
      plausibility_of(cube_recording("1,0,0,0,0,0,0,0,1.7,-1e308,1.7,1.7,10,10,10,10,0.5"));
  EXPECT_THAT(
      std::string(length.message()),
      HasSubstr("rec.csv:5: column 10 (length_2): -1e+308 m is outside the plausible range (0, "));
  const Status zero =
      plausibility_of(cube_recording("1,0,0,0,0,0,0,0,1.7,1.7,0,1.7,10,10,10,10,0.5"));
  EXPECT_THAT(std::string(zero.message()), HasSubstr("column 11 (length_3): 0 m is outside"));
  const Status laser =
      plausibility_of(cube_recording("1,0,0,0,0,0,0,0,1.7,1.7,1.7,1.7,10,10,10,10,500"));
  EXPECT_THAT(std::string(laser.message()), HasSubstr("column 17 (laser_1): 500 m"));
  EXPECT_THAT(std::string(laser.message()), HasSubstr("looks like mm, expected m"));
  const Status angle =
      plausibility_of(cube_recording("1,0,0,0,0,0,0,40,1.7,1.7,1.7,1.7,10,10,10,10,0.5"));
  EXPECT_THAT(std::string(angle.message()), HasSubstr("column 8 (cmd_yaw): 40 rad is outside"));
}

TEST(Plausibility, LengthsInMillimetresAreRefusedAsAWhole) {
  std::string text = cube_recording();
  for (std::size_t at = text.find("1.7"); at != std::string::npos; at = text.find("1.7", at + 4)) {
    text.replace(at, 3, "1700");
  }
  const Status s = plausibility_of(text);
  EXPECT_THAT(std::string(s.message()),
              HasSubstr("rec.csv: length_1..length_4: looks like mm, expected m"));
}

TEST(Plausibility, NoiseMetadataOutsideItsRangeIsRefused) {
  std::string text = cube_recording();
  text.replace(text.find("1e-4"), 4, "1e300");
  EXPECT_THAT(std::string(plausibility_of(text).message()),
              HasSubstr("rec.csv: metadata noise_length_m: 1e+300 m is outside the plausible "
                        "range (0, 1] m"));
}

TEST(Plausibility, PoseListsAreCheckedWithTheirLines) {
  const Result<PoseList> list = parse_pose_list(
      "# units: SI\npose,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n1,0,-99,0,0,0,0\n", "p.csv");
  ASSERT_TRUE(list.ok()) << list.status().to_string();
  EXPECT_THAT(std::string(check_plausible(*list, cube_robot(), "p.csv").message()),
              HasSubstr("p.csv:4: column 3 (y): -99 m is outside the plausible range"));
}

TEST(Recording, AByteOrderMarkIsIgnored) {
  const Result<Recording> rec = parse_recording("\xEF\xBB\xBF" + cube_recording(), "bom.csv");
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  EXPECT_EQ(rec->poses.size(), 3u);
  EXPECT_EQ(rec->poses[0].line, 4);
}

TEST(Recording, WriterRefusesInconsistentData) {
  Recording rec = random_recording(3, 1, 3, false, false, 5);
  Recording bad = rec;
  bad.poses[1].lengths.resize(2);
  EXPECT_THAT(std::string(format_recording(bad).status().message()), HasSubstr("2 length values"));
  bad = rec;
  bad.poses[2].index = bad.poses[1].index;
  EXPECT_FALSE(format_recording(bad).ok());
  bad = rec;
  bad.poses[0].lasers(0) = std::numeric_limits<double>::infinity();
  EXPECT_THAT(std::string(format_recording(bad).status().message()), HasSubstr("infinite"));
}

TEST(Recording, MeasurementSetTakesNoiseAndReferenceFromTheRecording) {
  Recording rec = random_recording(3, 2, 4, true, true, 9);
  rec.metadata.set_number(key::kNoiseLength, 2e-4);
  rec.metadata.set_number(key::kNoiseForce, 0.5);
  auto set = to_measurement_set(rec);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  EXPECT_EQ(set->noise.sigma_length, 2e-4);
  EXPECT_EQ(set->noise.sigma_force, 0.5);
  EXPECT_EQ(set->noise.sigma_laser, 1e-3);
  ASSERT_EQ(set->num_poses(), 4);
  EXPECT_TRUE(set->poses[0].reference.has_value());   // filled on even rows
  EXPECT_FALSE(set->poses[1].reference.has_value());  // empty on odd rows
  EXPECT_TRUE(same_bits(set->poses[2].cable_lengths, rec.poses[2].lengths));
  EXPECT_TRUE(validate(*set, model_with(3, 2)).ok());
  // Back to a recording and to a set again: the same numbers.
  auto again = from_measurement_set(*set);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  auto set2 = to_measurement_set(*again);
  ASSERT_TRUE(set2.ok());
  EXPECT_EQ(set2->noise.sigma_length, 2e-4);
  EXPECT_TRUE(same_bits(set2->poses[3].tensions, set->poses[3].tensions));
  // A half-filled reference pose is refused; a sigma that is not positive too.
  rec.poses[1].reference.position.x() = 0.5;
  EXPECT_THAT(std::string(to_measurement_set(rec).status().message()),
              HasSubstr("1 of its 6 ref_ cells"));
  rec = random_recording(3, 2, 4, false, false, 9);
  rec.metadata.set(key::kNoiseLaser, "-1");
  EXPECT_FALSE(to_measurement_set(rec).ok());
}

TEST(Recording, AllEmptyTensionsMeanNoForceSensors) {
  Recording rec = random_recording(2, 1, 3, false, false, 2);
  for (RecordedPose& p : rec.poses) p.tensions.setConstant(kNaN);
  auto set = to_measurement_set(rec);
  ASSERT_TRUE(set.ok());
  EXPECT_EQ(set->poses[0].tensions.size(), 0);
}

TEST(CableExperiment, RoundTripAndErrors) {
  CableExperiment e;
  e.metadata.set(key::kSource, "hand-made");
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0.1, 3.0);
  for (int i = 0; i < 20; ++i) e.samples.push_back({u(rng), 100.0 * u(rng), 1e-3 * u(rng)});
  auto text = format_cable_experiment(e);
  ASSERT_TRUE(text.ok());
  auto back = parse_cable_experiment(*text, "cable.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->samples.size(), e.samples.size());
  for (std::size_t i = 0; i < e.samples.size(); ++i) {
    EXPECT_TRUE(same_bits(back->samples[i].length_m, e.samples[i].length_m));
    EXPECT_TRUE(same_bits(back->samples[i].tension_n, e.samples[i].tension_n));
    EXPECT_TRUE(same_bits(back->samples[i].elongation_m, e.samples[i].elongation_m));
  }
  EXPECT_EQ(back->metadata.get(key::kSource), "hand-made");
  const std::string head = "# units: SI\nlength_m,tension_n,elongation_m\n";
  auto empty = parse_cable_experiment(head + "1,2,\n", "c.csv");
  EXPECT_THAT(std::string(empty.status().message()), HasSubstr("c.csv:3: column 3 (elongation_m)"));
  auto negative = parse_cable_experiment(head + "1,2,3\n-1,2,3\n", "c.csv");
  EXPECT_THAT(std::string(negative.status().message()),
              HasSubstr("c.csv:4: column 1 (length_m): a length must be > 0 m"));
  auto missing = parse_cable_experiment("# units: SI\nlength_m,tension_n\n1,2\n", "c.csv");
  EXPECT_THAT(std::string(missing.status().message()),
              HasSubstr("c.csv:2: missing required column 'elongation_m'"));
}

TEST(ForceExperiment, RoundTripAndErrors) {
  ForceSensorExperiment e;
  for (int c = 1; c <= 3; ++c) {
    for (double mass : {0.0, 1.0, 2.5, 5.0}) e.samples.push_back({c, mass, 2.0 * mass * 9.81 + c});
  }
  auto text = format_force_experiment(e);
  ASSERT_TRUE(text.ok());
  auto back = parse_force_experiment(*text, "f.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->samples.size(), e.samples.size());
  for (std::size_t i = 0; i < e.samples.size(); ++i) {
    EXPECT_EQ(back->samples[i].channel, e.samples[i].channel);
    EXPECT_TRUE(same_bits(back->samples[i].raw, e.samples[i].raw));
  }
  const std::string head = "# units: SI\nchannel,mass_kg,raw\n";
  EXPECT_THAT(std::string(parse_force_experiment(head + "0,1,2\n", "f.csv").status().message()),
              HasSubstr("f.csv:3: column 1 (channel): channel 0 is not in 1..1000"));
  EXPECT_THAT(std::string(parse_force_experiment(head + "1,1,x\n", "f.csv").status().message()),
              HasSubstr("f.csv:3: column 3 (raw): 'x' is not a number"));
  EXPECT_THAT(std::string(parse_force_experiment(head + "1,-1,2\n", "f.csv").status().message()),
              HasSubstr("f.csv:3: column 2 (mass_kg): a mass must be >= 0 kg"));
}

TEST(PoseList, RoundTripAndErrors) {
  PoseList list;
  list.metadata.set(key::kRobot, "MINI");
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-0.2, 0.2);
  for (int j = 0; j < 12; ++j) {
    list.poses.push_back(
        Pose{Eigen::Vector3d(u(rng), u(rng), u(rng)), Eigen::Vector3d(u(rng), u(rng), u(rng))});
  }
  auto text = format_pose_list(list);
  ASSERT_TRUE(text.ok());
  auto back = parse_pose_list(*text, "poses.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->poses.size(), list.poses.size());
  for (std::size_t j = 0; j < list.poses.size(); ++j) {
    EXPECT_TRUE(same_bits(back->poses[j].vector(), list.poses[j].vector()));
  }
  const std::string head = "# units: SI\npose,x,y,z,roll,pitch,yaw\n";
  EXPECT_THAT(
      std::string(
          parse_pose_list(head + "0,0,0,0,0,0,0\n0,0,0,0,0,0,0\n", "p.csv").status().message()),
      HasSubstr("p.csv:4: column 1 (pose): pose index 0 does not increase"));
  EXPECT_THAT(std::string(parse_pose_list(head + "0,0,0,,0,0,0\n", "p.csv").status().message()),
              HasSubstr("p.csv:3: column 4 (z): empty cell"));
}

TEST(Helpers, HashAndNumbers) {
  // Published FNV-1a 64 test vectors.
  EXPECT_EQ(fnv1a64(""), 0xcbf29ce484222325ULL);
  EXPECT_EQ(fnv1a64("a"), 0xaf63dc4c8601ec8cULL);
  EXPECT_EQ(fnv1a64("foobar"), 0x85944171f73967e8ULL);
  EXPECT_EQ(format_number(0.1), "0.1");
  EXPECT_EQ(format_number(kNaN), "");
  EXPECT_EQ(std::stod(format_number(1.0 / 3.0)), 1.0 / 3.0);
  const std::string path =
      (std::filesystem::temp_directory_path() / "cdpr_recording_test_hash.txt").string();
  {
    std::FILE* f = std::fopen(path.c_str(), "wb");
    ASSERT_NE(f, nullptr);
    std::fputs("foobar", f);
    std::fclose(f);
  }
  auto h = file_hash(path);
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(*h, "fnv1a64:85944171f73967e8");
  std::filesystem::remove(path);
}

// Issue 18: the laser columns are optional (k = 0).
TEST(Recording, RecordingWithoutLaserColumnsIsRead) {
  const std::string text =
      "# units: SI\n"
      "pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,tension_1,"
      "tension_2\n"
      "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51\n";
  auto r = parse_recording(text, "nolaser.csv");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(r->num_lasers, 0);
  EXPECT_EQ(r->poses[0].lasers.size(), 0);
  // It fits a config with lasers too (the laser was simply not used) ...
  EXPECT_TRUE(check_against_model(*r, model_with(2, 1)).ok());
  // ... and gives poses without laser distances.
  auto set = to_measurement_set(*r);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  EXPECT_EQ(set->poses[0].laser_distances.size(), 0);
  // Written back, it has no laser column and no laser noise key.
  auto back = format_recording(*r);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_THAT(*back, Not(HasSubstr("laser")));
}

TEST(Recording, SwivelInclinometerAndImuColumnsRoundTrip) {
  Recording rec = random_recording(4, 0, 12, false, false, 21);
  rec.has_swivel = true;
  rec.has_inclinometer = true;
  rec.has_imu_yaw = true;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (std::size_t j = 0; j < rec.poses.size(); ++j) {
    RecordedPose& p = rec.poses[j];
    p.swivels = Eigen::VectorXd::NullaryExpr(4, [&] { return u(rng); });
    p.inclination = Eigen::Vector2d(0.1 * u(rng), 0.1 * u(rng));
    p.imu_yaw = u(rng);
    if (j == 2) p.swivels(1) = kNaN;              // one encoder not read
    if (j == 3) p.inclination.setConstant(kNaN);  // inclinometer not read
    if (j == 4) p.imu_yaw = kNaN;                 // no heading
  }
  rec.metadata.set_number(key::kNoiseSwivel, 2e-3);
  auto text = format_recording(rec);
  ASSERT_TRUE(text.ok()) << text.status().to_string();
  EXPECT_THAT(*text, HasSubstr("swivel_1,swivel_2,swivel_3,swivel_4,incl_roll,incl_pitch,imu_yaw"));
  auto back = parse_recording(*text, "mem.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  expect_same(rec, *back);
  ASSERT_TRUE(back->has_swivel && back->has_inclinometer && back->has_imu_yaw);
  for (std::size_t j = 0; j < rec.poses.size(); ++j) {
    EXPECT_TRUE(same_bits(rec.poses[j].swivels, back->poses[j].swivels));
    EXPECT_TRUE(same_bits(Eigen::VectorXd(rec.poses[j].inclination),
                          Eigen::VectorXd(back->poses[j].inclination)));
    EXPECT_TRUE(same_bits(Eigen::VectorXd::Constant(1, rec.poses[j].imu_yaw),
                          Eigen::VectorXd::Constant(1, back->poses[j].imu_yaw)));
  }
  // Into the identification's view: readings, NaN where empty, and the stated noise.
  auto set = to_measurement_set(*back);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  EXPECT_EQ(set->noise.sigma_swivel, 2e-3);
  EXPECT_EQ(set->noise.sigma_inclination, SensorNoise{}.sigma_inclination);
  EXPECT_TRUE(std::isnan(set->poses[2].swivel_angles(1)));
  EXPECT_TRUE(std::isnan(set->poses[3].inclination(0)));
  EXPECT_TRUE(std::isnan(set->poses[4].imu_yaw));
  EXPECT_EQ(set->poses[5].swivel_angles(0), rec.poses[5].swivels(0));
  // And back into a recording with the same columns and the noise keys.
  auto again = from_measurement_set(*set, back->metadata);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_TRUE(again->has_swivel && again->has_inclinometer && again->has_imu_yaw);
  EXPECT_EQ(again->metadata.get(key::kNoiseSwivel), "0.002");
  EXPECT_TRUE(again->metadata.has(key::kNoiseInclination));
}

TEST(Recording, SwivelColumnsNeedSwivelPulleys) {
  Recording rec = random_recording(2, 0, 2, false, false, 3);
  rec.has_swivel = true;
  for (RecordedPose& p : rec.poses) p.swivels = Eigen::VectorXd::Zero(2);
  RobotModel model = model_with(2, 0);
  model.pulleys.resize(2);
  const Status s = check_against_model(rec, model);
  EXPECT_EQ(s.code(), ErrorCode::kFailedPrecondition);
  EXPECT_THAT(std::string(s.message()), HasSubstr("swivel_1: cable 1 has no swivel pulley"));
  for (PulleyModel& p : model.pulleys) p.radius = 0.02;
  EXPECT_TRUE(check_against_model(rec, model).ok());
}

// ---- RecordingAppender ------------------------------------------------------------------------

std::string read_all(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (f == nullptr) return {};
  std::string text;
  char buf[4096];
  for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) text.append(buf, n);
  std::fclose(f);
  return text;
}

std::string scratch_file(const char* name) {
  const std::string path = (std::filesystem::temp_directory_path() /
                            (std::string(name) + "-" + std::to_string(::getpid()) + ".csv"))
                               .string();
  std::filesystem::remove(path);
  return path;
}

TEST(RecordingAppender, FileEqualsTheWritersOutputAfterEveryRow) {
  const Recording all = random_recording(4, 1, 6, true, true, 11);
  const std::string path = scratch_file("cdpr_appender_rows");
  RecordingAppender out(path, all);
  EXPECT_TRUE(out.recording().poses.empty());
  EXPECT_FALSE(std::filesystem::exists(path));  // created with the first row
  Recording so_far = all;
  so_far.poses.clear();
  for (const RecordedPose& p : all.poses) {
    ASSERT_TRUE(out.append(p).ok());
    so_far.poses.push_back(p);
    auto text = format_recording(so_far);
    ASSERT_TRUE(text.ok());
    EXPECT_EQ(read_all(path), *text);
  }
  // What stays in memory is what the file reads back as, bit for bit.
  auto back = read_recording(path);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  expect_same(out.recording(), *back);
  std::filesystem::remove(path);
}

TEST(RecordingAppender, RefusesARowThatDoesNotFitAndWritesNothing) {
  const Recording all = random_recording(3, 1, 2, false, false, 5);
  const std::string path = scratch_file("cdpr_appender_refuse");
  RecordingAppender out(path, all);
  ASSERT_TRUE(out.append(all.poses[1]).ok());
  const std::string before = read_all(path);
  EXPECT_THAT(out.append(all.poses[0]).to_string(), HasSubstr("does not increase"));
  RecordedPose short_row = all.poses[1];
  short_row.index += 10;
  short_row.lengths.resize(2);
  EXPECT_FALSE(out.append(short_row).ok());
  EXPECT_EQ(read_all(path), before);
  EXPECT_EQ(out.recording().poses.size(), 1u);
  std::filesystem::remove(path);
}

TEST(RecordingAppender, ATornLastRowIsCutAndEveryWholeRowReadsBack) {
  const Recording all = random_recording(4, 1, 3, false, false, 7);
  const std::string path = scratch_file("cdpr_appender_torn");
  {
    RecordingAppender out(path, all);
    for (const RecordedPose& p : all.poses) ASSERT_TRUE(out.append(p).ok());
  }
  const std::string whole = read_all(path);
  auto intact = RecordingAppender::cut_torn_row(path);
  ASSERT_TRUE(intact.ok());
  EXPECT_EQ(*intact, 0u);
  // A power loss in the middle of the next row's write: part of it, without its newline.
  {
    io::AppendOnlyFile f;
    ASSERT_TRUE(f.open(path, false).ok());
    ASSERT_TRUE(f.append("9,1.5,0.1,0.2").ok());
  }
  EXPECT_FALSE(read_recording(path).ok());
  auto cut = RecordingAppender::cut_torn_row(path);
  ASSERT_TRUE(cut.ok()) << cut.status().to_string();
  EXPECT_EQ(*cut, std::string("9,1.5,0.1,0.2").size());
  EXPECT_EQ(read_all(path), whole);
  auto back = read_recording(path);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  expect_same(*back, all);
  auto missing = RecordingAppender::cut_torn_row(path + ".absent");
  ASSERT_TRUE(missing.ok());
  EXPECT_EQ(*missing, 0u);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace cdpr::recording
