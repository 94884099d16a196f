#include "cdpr/controller/state_store.hpp"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "cdpr/config/robot_config.hpp"
#include "cdpr/io/append_only_file.hpp"
#include "cdpr/io/atomic_file.hpp"

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

TEST_F(StateStoreTest, HomingRecordRoundTripsAndAnAbsentOneIsNotFound) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->load_homing().status().code(), ErrorCode::kNotFound);
  HomingRecord r;
  r.method = "reference";
  r.time = "2026-01-01T00:00:00Z";
  r.geometry_version = 3;
  r.offsets_counts = {1.5, -2.25, 1e6};
  r.drives = {{1, 0xCD9001, 0x402, 0x51000001}, {2, 0xCD9001, 0x402, 0x51000002}};
  r.counts = {10, 20, 30};
  r.pose = {0.1, 0.2, 0.3, 0.01, 0.02, 0.03};
  r.clean_stop = true;
  ASSERT_TRUE(s->save_homing(r).ok());
  auto o = s->load_homing();
  ASSERT_TRUE(o.ok()) << o.status().to_string();
  EXPECT_EQ(o->format, HomingRecord::kFormat);
  EXPECT_EQ(o->offsets_counts, r.offsets_counts);
  EXPECT_EQ(o->drives, r.drives);
  EXPECT_EQ(o->geometry_version, 3);
  EXPECT_EQ(o->counts, r.counts);
  EXPECT_EQ(o->pose, r.pose);
  EXPECT_TRUE(o->clean_stop);
}

TEST_F(StateStoreTest, TheOldHomingFormatReadsAsFormatOneWithoutWhatItBelongsTo) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok());
  std::ofstream(dir_ / "homing.json")
      << R"({"offsets_counts": [1, 2], "how": "reference platform at home", "time": "t"})";
  auto o = s->load_homing();
  ASSERT_TRUE(o.ok()) << o.status().to_string();
  EXPECT_EQ(o->format, 1);
  EXPECT_EQ(o->offsets_counts, (std::vector<double>{1, 2}));
  EXPECT_TRUE(o->drives.empty());
  EXPECT_TRUE(o->counts.empty());
}

TEST_F(StateStoreTest, ABrokenHomingRecordIsAParseErrorNamingTheField) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok());
  std::ofstream(dir_ / "homing.json") << R"({"format": 2, "offsets_counts": [1], "drives": 3})";
  auto o = s->load_homing();
  ASSERT_FALSE(o.ok());
  EXPECT_EQ(o.status().code(), ErrorCode::kParseError);
  EXPECT_NE(o.status().message().find("geometry_version"), std::string::npos);
}

TEST_F(StateStoreTest, AppendedRecordsSurviveAndATornLastHistoryLineIsSkipped) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok());
  ASSERT_TRUE(s->add_geometry(robot_, {}).ok());
  ASSERT_TRUE(s->activate(1, {{"why", "a"}}).ok());
  io::AppendOnlyFile f;
  ASSERT_TRUE(f.open((dir_ / "history.jsonl").string(), false).ok());
  ASSERT_TRUE(f.append("{\"version\": 1, \"why\": \"torn").ok());  // a crash mid-line
  auto h = s->history();
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->size(), 1u);
}

// A writer killed between the write and the rename of cdpr/io/atomic_file.hpp (its temporary
// stays behind); returns its (now dead) pid.
pid_t kill_writer_before_rename(const std::string& target) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    io::AtomicFileSet set;
    if (set.stage(target, "new content\n").ok()) ::raise(SIGKILL);
    ::_exit(1);
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  EXPECT_TRUE(WIFSIGNALED(status));
  return pid;
}

std::size_t temporaries_under(const fs::path& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    n += io::is_temporary_name(e.path().filename().string()) ? 1 : 0;
  }
  return n;
}

TEST_F(StateStoreTest, RemovesOnlyTheLeftoverTemporariesOfKilledWritersInsideTheStateDirectory) {
  auto s = StateStore::open(dir_.string());
  ASSERT_TRUE(s.ok()) << s.status().to_string();
  auto v1 = s->add_geometry(robot_, {{"source", "nominal"}});
  ASSERT_TRUE(v1.ok());
  ASSERT_TRUE(s->activate(*v1, {{"why", "test"}}).ok());
  fs::create_directories(dir_ / "calibrations" / "000001");
  kill_writer_before_rename((dir_ / "active").string());
  kill_writer_before_rename((dir_ / "calibrations" / "000001" / "report.json").string());
  ASSERT_EQ(temporaries_under(dir_), 2u);

  // Not removed: a temporary that a running process is writing, files that only look similar,
  // a symbolic link with a temporary's name, and anything behind a linked folder.
  const pid_t writer = ::fork();
  if (writer == 0) {
    ::pause();
    ::_exit(0);
  }
  const std::string live = ".homing.json.tmp-" + std::to_string(writer) + "-0";
  const fs::path outside = dir_.string() + "-outside";
  fs::remove_all(outside);
  fs::create_directories(outside);
  const std::string outside_temp = ".x.yaml.tmp-1-0";
  for (const fs::path& p : {dir_ / live, dir_ / "notes.tmp", dir_ / "geometry" / ".a.tmp.XYZ",
                            outside / outside_temp, outside / "target"}) {
    std::ofstream(p) << "keep\n";
  }
  fs::create_directory_symlink(outside, dir_ / "calibrations" / "linked");
  fs::create_symlink(outside / "target", dir_ / ".link.tmp-1-0");

  auto removed = s->remove_leftover_temporaries();
  ::kill(writer, SIGKILL);
  ::waitpid(writer, nullptr, 0);
  ASSERT_TRUE(removed.ok()) << removed.status().to_string();
  ASSERT_EQ(removed->size(), 2u);
  EXPECT_EQ((*removed)[0].rfind(".active.tmp-", 0), 0u) << (*removed)[0];
  EXPECT_EQ((*removed)[1].rfind("calibrations/000001/.report.json.tmp-", 0), 0u) << (*removed)[1];
  EXPECT_TRUE(fs::exists(dir_ / live));
  EXPECT_TRUE(fs::exists(dir_ / "notes.tmp"));
  EXPECT_TRUE(fs::exists(dir_ / "geometry" / ".a.tmp.XYZ"));
  EXPECT_TRUE(fs::is_symlink(dir_ / ".link.tmp-1-0"));
  EXPECT_TRUE(fs::exists(outside / outside_temp));
  EXPECT_TRUE(fs::exists(outside / "target"));
  auto active = s->active_version();
  ASSERT_TRUE(active.ok());
  EXPECT_EQ(*active, 1);  // the killed writer's content never replaced it
  // Once its writer is gone, the other temporary goes too (and nothing else).
  auto again = s->remove_leftover_temporaries();
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(*again, std::vector<std::string>{live});
  EXPECT_TRUE(fs::exists(dir_ / "notes.tmp"));
  fs::remove_all(outside);
}

}  // namespace
}  // namespace cdpr::controller
