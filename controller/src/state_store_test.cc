#include "cdpr/controller/state_store.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>

#include "cdpr/config/robot_config.hpp"

namespace cdpr::controller {
namespace {
namespace fs = std::filesystem;

class StateStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("cdpr-store-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    auto robot = config::load_robot_config(CDPR_SOURCE_DIR "/config/mini.yaml");
    ASSERT_TRUE(robot.ok());
    robot_ = *robot;
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
  RobotModel robot_;
};

TEST_F(StateStoreTest, VersionsAreNumberedActivatedAndReadBackExactly) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  EXPECT_EQ(s->active_version().status().code(), ErrorCode::kNotFound);
  auto v1 = s->add_geometry(robot_, {{"source", "nominal"}});
  ASSERT_TRUE(v1.ok());
  RobotModel moved = robot_;
  moved.frame_anchors(0, 2) += 0.00123;
  auto v2 = s->add_geometry(moved, {{"source", "calibration"}});
  ASSERT_TRUE(v2.ok());
  EXPECT_EQ(*v1, 1);
  EXPECT_EQ(*v2, 2);
  ASSERT_TRUE(s->activate(*v2, {{"why", "test"}}).ok());
  EXPECT_EQ(*s->active_version(), 2);
  auto back = s->load_geometry(2);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->frame_anchors.col(2), moved.frame_anchors.col(2));
  EXPECT_EQ((*s->geometry_meta(2))["source"], "calibration");
  auto h = s->history();
  ASSERT_TRUE(h.ok());
  ASSERT_EQ(h->size(), 1u);
  EXPECT_EQ((*h)[0]["version"], 2);
  EXPECT_EQ(s->load_geometry(7).status().code(), ErrorCode::kNotFound);
  EXPECT_FALSE(s->activate(7, {}).ok());
}

TEST_F(StateStoreTest, OffsetsRoundTripAndAbsentOffsetsAreNotFound) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->load_offsets().status().code(), ErrorCode::kNotFound);
  ASSERT_TRUE(s->save_offsets({1.5, -2.25, 1e6}, "test").ok());
  auto o = s->load_offsets();
  ASSERT_TRUE(o.ok());
  EXPECT_EQ(*o, (std::vector<double>{1.5, -2.25, 1e6}));
}

TEST_F(StateStoreTest, AKillBetweenWriteAndRenameLeavesTheOldFileIntact) {
  fs::create_directories(dir_);
  const std::string path = (dir_ / "active").string();
  ASSERT_TRUE(write_file_atomically(path, "1\n").ok());
  // A child writes a large new version and is killed while writing (before the rename).
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    std::string big(64 << 20, 'x');
    (void)write_file_atomically(path, big);
    _exit(0);
  }
  ::usleep(2000);
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  auto text = read_text_file(path);
  ASSERT_TRUE(text.ok());
  // Either the old content or (if the child finished) the new one, never a mixture.
  EXPECT_TRUE(*text == "1\n" || text->size() == (64u << 20)) << text->size();
}

TEST_F(StateStoreTest, AppendedRecordsSurviveAndATornLastHistoryLineIsSkipped) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s->add_geometry(robot_, {}).ok());
  ASSERT_TRUE(s->activate(1, {{"why", "a"}}).ok());
  AppendOnlyFile f;
  ASSERT_TRUE(f.open((dir_ / "history.jsonl").string(), false).ok());
  ASSERT_TRUE(f.append("{\"version\": 1, \"why\": \"torn").ok());  // a crash mid-line
  auto h = s->history();
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->size(), 1u);
}

}  // namespace
}  // namespace cdpr::controller
