#include "cdpr/io/atomic_file.hpp"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace cdpr::io {
namespace {

namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

class AtomicFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("cdpr_atomic_file_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  // Names in the directory other than `keep`.
  std::vector<std::string> others(const std::vector<std::string>& keep) const {
    std::vector<std::string> out;
    for (const auto& e : fs::directory_iterator(dir_)) {
      const std::string n = e.path().filename().string();
      bool kept = false;
      for (const std::string& k : keep) kept = kept || k == n;
      if (!kept) out.push_back(n);
    }
    return out;
  }
  // Runs `child` in a forked process that is killed with SIGKILL by `child` itself or, after
  // `kill_after`, by the test. Returns true when the child died of SIGKILL.
  template <typename F>
  bool run_killed(F child, std::chrono::microseconds kill_after = std::chrono::hours(1)) {
    const pid_t pid = ::fork();
    if (pid == 0) {
      child();
      ::_exit(0);
    }
    if (kill_after < std::chrono::hours(1)) {
      std::this_thread::sleep_for(kill_after);
      ::kill(pid, SIGKILL);
    }
    int status = 0;
    ::waitpid(pid, &status, 0);
    return WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
  }

  fs::path dir_;
};

TEST_F(AtomicFile, ReplacesTheFileAndLeavesNoTemporary) {
  ASSERT_TRUE(write_file_atomically(path("a.yaml"), "old\n").ok());
  ASSERT_TRUE(write_file_atomically(path("a.yaml"), "new contents\n").ok());
  EXPECT_EQ(slurp(path("a.yaml")), "new contents\n");
  EXPECT_TRUE(others({"a.yaml"}).empty());
}

TEST_F(AtomicFile, NewFilesGetTheUmaskPermissionsLikeOfstream) {
  const mode_t mask = ::umask(0);
  ::umask(mask);
  ASSERT_TRUE(write_file_atomically(path("p.txt"), "x").ok());
  struct stat st {};
  ASSERT_EQ(::stat(path("p.txt").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0666 & ~mask);
}

TEST_F(AtomicFile, AMissingDirectoryIsNotFoundAndNamesThePath) {
  const std::string bad = path("no/such/dir/report.json");
  const Status s = write_file_atomically(bad, "{}");
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::kNotFound);
  EXPECT_NE(s.message().find(bad), std::string_view::npos) << s.message();
}

TEST_F(AtomicFile, KilledBetweenWriteAndRenameLeavesTheOldFileIntact) {
  ASSERT_TRUE(write_file_atomically(path("rec.csv"), "old recording\n").ok());
  const std::string fresh(1 << 20, 'n');
  const bool killed = run_killed([&] {
    AtomicFileSet set;
    if (set.stage(path("rec.csv"), fresh).ok()) ::raise(SIGKILL);  // written, not renamed
  });
  ASSERT_TRUE(killed);
  EXPECT_EQ(slurp(path("rec.csv")), "old recording\n");
  // The new content was written in full to the temporary the kill left behind.
  const std::vector<std::string> left = others({"rec.csv"});
  ASSERT_EQ(left.size(), 1u);
  EXPECT_EQ(left[0].rfind(".rec.csv.tmp-", 0), 0u) << left[0];
  EXPECT_EQ(slurp(dir_ / left[0]), fresh);
  // ... and is recognised as one, with the writer's pid.
  int pid = 0;
  EXPECT_TRUE(is_temporary_name(left[0], &pid)) << left[0];
  EXPECT_GT(pid, 0);
  EXPECT_NE(pid, ::getpid());
}

TEST_F(AtomicFile, RecognisesOnlyItsOwnTemporaryNames) {
  int pid = 0;
  EXPECT_TRUE(is_temporary_name(".active.tmp-4242-7", &pid));
  EXPECT_EQ(pid, 4242);
  EXPECT_TRUE(is_temporary_name(".000001.yaml.tmp-1-0"));
  for (const char* other : {"active", "000001.yaml", ".tmp-1-2", "..tmp-1-2", ".a.tmp-1",
                            ".a.tmp--2", ".a.tmp-1-", ".a.tmp-x-2", ".a.tmp-1-2x", "a.tmp-1-2",
                            ".a.tmp-1-2/b", ".a.tmp.XXXXXX", ".a.tmp-12345678901-1", ""}) {
    EXPECT_FALSE(is_temporary_name(other)) << other;
  }
}

TEST_F(AtomicFile, KilledAtAnyMomentLeavesTheOldOrTheNewFileWhole) {
  const std::string a(1 << 20, 'a'), b(1 << 20, 'b');
  ASSERT_TRUE(write_file_atomically(path("f"), a).ok());
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> delay_us(0, 20000);
  for (int round = 0; round < 20; ++round) {
    const bool killed = run_killed(
        [&] {
          for (int k = 0;; ++k) (void)write_file_atomically(path("f"), k % 2 == 0 ? b : a);
        },
        std::chrono::microseconds(delay_us(rng)));
    ASSERT_TRUE(killed);
    const std::string now = slurp(path("f"));
    ASSERT_TRUE(now == a || now == b) << "round " << round << ": " << now.size() << " bytes";
  }
}

TEST_F(AtomicFile, ASetWritesAllItsFilesTogether) {
  ASSERT_TRUE(write_file_atomically(path("report.json"), "old json").ok());
  AtomicFileSet set;
  ASSERT_TRUE(set.stage(path("report.json"), "new json").ok());
  ASSERT_TRUE(set.stage(path("report.html"), "new html").ok());
  EXPECT_EQ(slurp(path("report.json")), "old json");  // nothing renamed before commit()
  EXPECT_FALSE(fs::exists(path("report.html")));
  ASSERT_TRUE(set.commit().ok());
  EXPECT_EQ(slurp(path("report.json")), "new json");
  EXPECT_EQ(slurp(path("report.html")), "new html");
  EXPECT_TRUE(others({"report.json", "report.html"}).empty());
}

TEST_F(AtomicFile, ASetWithAFailedFileChangesNoTarget) {
  ASSERT_TRUE(write_file_atomically(path("calibrated.yaml"), "old yaml").ok());
  AtomicFileSet set;
  ASSERT_TRUE(set.stage(path("calibrated.yaml"), "new yaml").ok());
  EXPECT_FALSE(set.stage(path("missing/report.json"), "json").ok());
  EXPECT_EQ(set.staged(), 0u);
  EXPECT_TRUE(set.commit().ok());  // nothing left to commit
  EXPECT_EQ(slurp(path("calibrated.yaml")), "old yaml");
  EXPECT_TRUE(others({"calibrated.yaml"}).empty());
}

TEST_F(AtomicFile, AnAbandonedSetRemovesItsTemporaries) {
  {
    AtomicFileSet set;
    ASSERT_TRUE(set.stage(path("x.csv"), "x").ok());
  }
  EXPECT_FALSE(fs::exists(path("x.csv")));
  EXPECT_TRUE(others({}).empty());
}

}  // namespace
}  // namespace cdpr::io
