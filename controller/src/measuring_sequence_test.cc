#include "cdpr/controller/measuring_sequence.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace cdpr::controller {
namespace {

// A robot that is wherever it is sent at once; it logs each call and can fail one.
class FakeRobot final : public MeasuringRobot {
 public:
  Status move(const Pose& pose, double pretension) override {
    calls.push_back("move " + std::to_string(pose.position.x()) +
                    (std::isnan(pretension) ? "" : " at " + std::to_string(pretension)));
    return maybe_fail("move");
  }
  Status settle() override {
    calls.push_back("settle");
    return maybe_fail("settle");
  }
  Status regulate(int pose_index) override {
    calls.push_back("regulate " + std::to_string(pose_index));
    return maybe_fail("regulate");
  }
  Status sample(recording::RecordedPose& row) override {
    calls.push_back("sample");
    t += 2.0;  // averaging and the laser take robot time
    row.lengths = Eigen::VectorXd::Constant(2, 1.0 + 0.1 * static_cast<double>(row.index));
    row.tensions = Eigen::VectorXd::Constant(2, 50.0);
    row.lasers = Eigen::VectorXd::Constant(1, 0.5);
    return maybe_fail("sample");
  }
  double now_s() const override { return t; }
  void measured(const recording::RecordedPose& row, int done, int total, double elapsed_s,
                double remaining_s) override {
    calls.push_back("measured " + std::to_string(row.index) + " " + std::to_string(done) + "/" +
                    std::to_string(total));
    last_elapsed = elapsed_s;
    last_remaining = remaining_s;
  }

  Status maybe_fail(const std::string& what) {
    if (what == fail_at && --fail_after < 0) return Status(ErrorCode::kAborted, what + " failed");
    return Status::success();
  }

  std::vector<std::string> calls;
  double t = 100.0;
  double last_elapsed = 0.0, last_remaining = 0.0;
  std::string fail_at;
  int fail_after = 0;
};

Pose at(double x) {
  Pose p;
  p.position = Eigen::Vector3d(x, 0.0, 0.0);
  p.rpy.setZero();
  return p;
}

class MeasuringSequenceTest : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = (std::filesystem::temp_directory_path() /
             ("cdpr_measuring_" + std::to_string(::getpid()) + "_" +
              ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".csv"))
                .string();
    std::filesystem::remove(path_);
    header_.metadata.set(recording::key::kFormat, "cdpr-recording 1");
    header_.metadata.set(recording::key::kUnits, "SI");
    header_.num_cables = 2;
    header_.num_lasers = 1;
  }
  void TearDown() override { std::filesystem::remove(path_); }

  std::string path_;
  recording::Recording header_;
  FakeRobot robot_;
};

TEST_F(MeasuringSequenceTest, StepsThroughEachPoseThenReturnsToTheFirst) {
  MeasuringSequence seq(robot_, recording::RecordingAppender(path_, header_));
  seq.add_round({at(1.0), at(2.0)}, {});
  const std::vector<MeasuringStep> expected = {
      MeasuringStep::kMove,   MeasuringStep::kSettle, MeasuringStep::kRegulate,
      MeasuringStep::kSample, MeasuringStep::kAppend, MeasuringStep::kNext,
      MeasuringStep::kMove,   MeasuringStep::kSettle, MeasuringStep::kRegulate,
      MeasuringStep::kSample, MeasuringStep::kAppend, MeasuringStep::kNext,
      MeasuringStep::kReturn};
  for (MeasuringStep want : expected) {
    ASSERT_EQ(seq.next(), want) << to_string(seq.next());
    ASSERT_TRUE(seq.step().ok());
  }
  EXPECT_EQ(seq.next(), MeasuringStep::kDone);
  const std::vector<std::string> calls = {"move 1.000000",  "settle",         "regulate 0",
                                          "sample",         "measured 0 1/2", "move 2.000000",
                                          "settle",         "regulate 1",     "sample",
                                          "measured 1 2/2", "move 1.000000"};
  EXPECT_EQ(robot_.calls, calls);
  ASSERT_EQ(seq.recording().poses.size(), 2u);
  EXPECT_DOUBLE_EQ(seq.recording().poses[0].time_s, 2.0);  // after its sampling
  EXPECT_DOUBLE_EQ(seq.recording().poses[1].time_s, 4.0);
  EXPECT_EQ(seq.recording().poses[1].commanded.position.x(), 2.0);
  EXPECT_DOUBLE_EQ(robot_.last_elapsed, 4.0);
  EXPECT_DOUBLE_EQ(robot_.last_remaining, 0.0);
}

TEST_F(MeasuringSequenceTest, AppendsEachRowToTheFileAsTheWriterWouldWriteIt) {
  MeasuringSequence seq(robot_, recording::RecordingAppender(path_, header_));
  seq.add_round({at(1.0), at(2.0)}, {});
  ASSERT_TRUE(seq.run_round().ok());
  auto text = recording::format_recording(seq.recording());
  ASSERT_TRUE(text.ok());
  std::ifstream in(path_, std::ios::binary);
  std::stringstream file;
  file << in.rdbuf();
  EXPECT_EQ(file.str(), *text);
  EXPECT_EQ(seq.path(), path_);
}

TEST_F(MeasuringSequenceTest, LaterRoundsContinueTheRowsAtTheirPretensions) {
  MeasuringSequence seq(robot_, recording::RecordingAppender(path_, header_));
  seq.add_round({at(1.0)}, {});
  ASSERT_TRUE(seq.run_round().ok());
  robot_.calls.clear();
  seq.add_round({at(3.0), at(4.0)}, {120.0});
  ASSERT_TRUE(seq.run_round().ok());
  ASSERT_EQ(seq.recording().poses.size(), 3u);
  EXPECT_EQ(seq.recording().poses[2].index, 2);
  EXPECT_EQ(seq.poses().size(), 3u);
  EXPECT_DOUBLE_EQ(seq.pretension(1), 120.0);
  EXPECT_TRUE(std::isnan(seq.pretension(2)));
  EXPECT_EQ(robot_.calls.front(), "move 3.000000 at 120.000000");
  EXPECT_EQ(robot_.calls[4], "measured 1 2/3");
  EXPECT_EQ(robot_.calls.back(), "move 1.000000");  // the calibration's first pose
}

TEST_F(MeasuringSequenceTest, AFailedStepNamesThePoseAndKeepsTheRowsBefore) {
  robot_.fail_at = "settle";
  robot_.fail_after = 1;  // the second pose's
  MeasuringSequence seq(robot_, recording::RecordingAppender(path_, header_));
  seq.add_round({at(1.0), at(2.0), at(3.0)}, {});
  const Status s = seq.run_round();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.to_string().find("pose 1: settle failed"), std::string::npos) << s.to_string();
  EXPECT_EQ(seq.next(), MeasuringStep::kSettle);
  EXPECT_EQ(seq.recording().poses.size(), 1u);
  auto back = recording::read_recording(path_);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->poses.size(), 1u);
}

TEST_F(MeasuringSequenceTest, AFailedReturnIsNamedAndNoFileIsMadeWithoutARow) {
  robot_.fail_at = "move";
  MeasuringSequence seq(robot_, recording::RecordingAppender(path_, header_));
  seq.add_round({at(1.0)}, {});
  EXPECT_FALSE(seq.run_round().ok());
  EXPECT_FALSE(std::filesystem::exists(path_));
  robot_.fail_after = 1;  // the next move (pose 0) passes, the return fails
  MeasuringSequence again(robot_, recording::RecordingAppender(path_, header_));
  again.add_round({at(1.0)}, {});
  const Status s = again.run_round();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.to_string().find("back to the first pose: "), std::string::npos) << s.to_string();
  EXPECT_EQ(again.recording().poses.size(), 1u);
}

}  // namespace
}  // namespace cdpr::controller
