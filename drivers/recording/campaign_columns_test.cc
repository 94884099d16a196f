// The optional campaign columns of a recording (docs/recording-format.md): planned tensions, the
// pose's scatter, the supported flag, a start pose.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "cdpr/recording/recording.hpp"

namespace cdpr::recording {
namespace {

using ::testing::HasSubstr;

std::string small_file(const std::string& header, const std::string& rows) {
  return "# format: cdpr-recording 1\n# units: SI\n# robot: TWO\n" + header + "\n" + rows;
}

const char* const kCampaignHeader =
    "pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,tension_1,"
    "tension_2,planned_tension_1,planned_tension_2,scatter_length_m,scatter_force_n,supported,"
    "start_x,start_y,start_z,start_roll,start_pitch,start_yaw";

TEST(Recording, CampaignColumnsAreReadWrittenBackAndCarriedIntoTheMeasurements) {
  const std::string rows =
      "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,55,56,2e-5,0.4,1,0.1,0.2,0.25,0,0,0.01\n"
      "1,0.5,0.1,0.2,0.4,0,0,0.01,1.4,1.7,52,53,,,,,0,,,,,,\n";
  auto r = parse_recording(small_file(kCampaignHeader, rows), "campaign.csv");
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_TRUE(r->has_planned_tensions && r->has_scatter_length && r->has_scatter_force &&
              r->has_supported && r->has_start);
  const RecordedPose& p0 = r->poses[0];
  EXPECT_DOUBLE_EQ(p0.planned_tensions(1), 56.0);
  EXPECT_DOUBLE_EQ(p0.scatter_length_m, 2e-5);
  EXPECT_DOUBLE_EQ(p0.scatter_force_n, 0.4);
  EXPECT_TRUE(p0.supported);
  EXPECT_DOUBLE_EQ(p0.start.position.z(), 0.25);
  EXPECT_FALSE(r->poses[1].supported);
  EXPECT_TRUE(std::isnan(r->poses[1].scatter_length_m));

  auto text = format_recording(*r);
  ASSERT_TRUE(text.ok()) << text.status().to_string();
  auto back = parse_recording(*text, "again.csv");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(*format_recording(*back), *text);

  auto set = to_measurement_set(*r);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  const PoseMeasurement& m0 = set->poses[0];
  EXPECT_TRUE(m0.supported);
  EXPECT_DOUBLE_EQ(m0.scatter_force, 0.4);
  ASSERT_TRUE(m0.start.has_value());
  EXPECT_DOUBLE_EQ(m0.start->rpy.z(), 0.01);
  EXPECT_DOUBLE_EQ(m0.planned_tensions(0), 55.0);
  EXPECT_FALSE(set->poses[1].start.has_value());
  // And back into a recording with the same columns.
  auto rec2 = from_measurement_set(*set, r->metadata);
  ASSERT_TRUE(rec2.ok()) << rec2.status().to_string();
  EXPECT_TRUE(rec2->has_planned_tensions && rec2->has_scatter_length && rec2->has_supported &&
              rec2->has_start);
  EXPECT_TRUE(rec2->poses[0].supported);
}

TEST(Recording, BadCampaignCellsAreRefusedNamingTheCell) {
  const std::string good =
      "0,0,0.1,0.2,0.3,0,0,0,1.5,1.6,50,51,55,56,2e-5,0.4,1,0.1,0.2,0.25,0,0,0";
  auto with = [&](int cell, const std::string& value) {
    std::vector<std::string> cells;
    std::stringstream in(good);
    for (std::string c; std::getline(in, c, ',');) cells.push_back(c);
    cells[static_cast<std::size_t>(cell)] = value;
    std::string row;
    for (const std::string& c : cells) row += (row.empty() ? "" : ",") + c;
    return parse_recording(small_file(kCampaignHeader, row + "\n"), "bad.csv");
  };
  auto supported = with(16, "2");
  ASSERT_FALSE(supported.ok());
  EXPECT_THAT(std::string(supported.status().message()), HasSubstr("supported"));
  EXPECT_THAT(std::string(supported.status().message()), HasSubstr("expected 1"));
  auto scatter = with(14, "-1e-3");
  ASSERT_FALSE(scatter.ok());
  EXPECT_THAT(std::string(scatter.status().message()), HasSubstr("scatter_length_m"));
  // Five of the six start cells: read, but refused as a measurement.
  auto partial = with(20, "");
  ASSERT_TRUE(partial.ok()) << partial.status().to_string();
  auto set = to_measurement_set(*partial);
  ASSERT_FALSE(set.ok());
  EXPECT_THAT(std::string(set.status().message()), HasSubstr("5 of its 6 start_ cells"));
}

TEST(Recording, CampaignColumnGroupsComeWholeOrNotAtAll) {
  const std::string no_start_yaw =
      "pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,tension_1,"
      "tension_2,start_x,start_y,start_z,start_roll,start_pitch";
  auto a =
      parse_recording(small_file(no_start_yaw, "0,0,0,0,0,0,0,0,1,1,5,5,0,0,0,0,0\n"), "a.csv");
  ASSERT_FALSE(a.ok());
  EXPECT_THAT(std::string(a.status().message()), HasSubstr("missing column 'start_yaw'"));
  const std::string one_planned =
      "pose,time_s,cmd_x,cmd_y,cmd_z,cmd_roll,cmd_pitch,cmd_yaw,length_1,length_2,tension_1,"
      "tension_2,planned_tension_1";
  auto b = parse_recording(small_file(one_planned, "0,0,0,0,0,0,0,0,1,1,5,5,5\n"), "b.csv");
  ASSERT_FALSE(b.ok());
  EXPECT_THAT(std::string(b.status().message()), HasSubstr("1 planned_tension_ columns but 2"));
}

}  // namespace
}  // namespace cdpr::recording
