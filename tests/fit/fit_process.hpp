// The cdpr-fit process fixture shared by the tests in tests/fit: a fresh directory per test (kept
// when the test fails, for reading its files) and the real cdpr-fit binary (CDPR_FIT_BIN, set by
// tests/fit/CMakeLists.txt) run in a shell with stdout and stderr captured separately.
#pragma once

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

  fs::path dir_;

 private:
  std::string prefix_;
};

}  // namespace cdpr::fit_test
