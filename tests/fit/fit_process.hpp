// The cdpr-fit process fixture shared by the tests in tests/fit: a fresh directory per test (kept
// when the test fails, for reading its files) and the real cdpr-fit binary (CDPR_FIT_BIN, set by
// tests/fit/CMakeLists.txt) run in a shell with stdout and stderr captured separately; the shipped
// MINI configs the tests run it on (CDPR_SOURCE_DIR/config).
#pragma once

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace cdpr::fit_test {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;

// The project's root; the nominal MINI and the measured one (the truth of the recordings).
inline const std::string kSource = CDPR_SOURCE_DIR;
inline const std::string kNominal = kSource + "/config/mini.yaml";
inline const std::string kTruth = kSource + "/config/mini-measured.yaml";

struct ProcessResult {
  int status = -1;  // exit status, -1 when killed by a signal
  std::string out;
  std::string err;
};

inline std::string slurp(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// `s` as one single-quoted shell word.
inline std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) {
    if (c == '\'') {
      q += "'\\''";
    } else {
      q += c;
    }
  }
  return q + "'";
}

class FitProcessTest : public ::testing::Test {
 protected:
  explicit FitProcessTest(std::string prefix) : prefix_(std::move(prefix)) {}

  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           (prefix_ + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    if (!HasFailure()) fs::remove_all(dir_);
  }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  // Runs cdpr-fit with `args`; with `in_dir` in the test's directory (relative paths then name
  // files there, as in the documented sessions).
  ProcessResult fit(const std::vector<std::string>& args, bool in_dir = false) const {
    std::string cmd =
        (in_dir ? "cd " + quote(dir_.string()) + " && " : std::string()) + quote(CDPR_FIT_BIN);
    for (const std::string& a : args) cmd += " " + quote(a);
    const fs::path out = dir_ / "stdout.txt", err = dir_ / "stderr.txt";
    cmd += " >" + quote(out.string()) + " 2>" + quote(err.string());
    ProcessResult r;
    const int raw = std::system(cmd.c_str());
    r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
    r.out = slurp(out);
    r.err = slurp(err);
    return r;
  }

  // The measured MINI (or `truth`) commanded through the nominal model with elastic cables,
  // `poses` designed poses, default noise (encoder 0.1 mm, laser 1 mm, force 1 N), written to
  // `name` in the test's directory; its path.
  std::string simulate_elastic(int poses, const std::string& name, int seed = 3,
                               const std::string& truth = kTruth) const {
    const std::string rec = path(name);
    const ProcessResult r =
        fit({"simulate", "--config", truth, "--nominal", kNominal, "--physics", "elastic",
             "--design", std::to_string(poses), "--seed", std::to_string(seed), "--out", rec});
    EXPECT_EQ(r.status, 0) << r.err;
    return rec;
  }

  fs::path dir_;

 private:
  std::string prefix_;
};

}  // namespace cdpr::fit_test
