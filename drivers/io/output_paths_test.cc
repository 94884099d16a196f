#include "cdpr/io/output_paths.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace cdpr::io {
namespace {

namespace fs = std::filesystem;

class OutputPaths : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("cdpr_output_paths_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "sub");
    std::ofstream(dir_ / "rec.csv") << "x\n";
    std::ofstream(dir_ / "mini.yaml") << "y\n";
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string p(const std::string& name) const { return (dir_ / name).string(); }
  fs::path dir_;
};

TEST_F(OutputPaths, AnOutputNamingAnInputIsRefusedNamingBoth) {
  const Status s = check_output_paths({{"--config", p("mini.yaml")}, {"--recording", p("rec.csv")}},
                                      {{"--out", p("sub/../rec.csv")}});
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(s.message().find("--out " + p("sub/../rec.csv")), std::string_view::npos)
      << s.message();
  EXPECT_NE(s.message().find("--recording " + p("rec.csv")), std::string_view::npos) << s.message();
}

TEST_F(OutputPaths, LinksToAnInputAreTheSameFile) {
  fs::create_hard_link(dir_ / "rec.csv", dir_ / "hard.csv");
  fs::create_symlink(dir_ / "mini.yaml", dir_ / "soft.yaml");
  EXPECT_TRUE(same_file(p("hard.csv"), p("rec.csv")));
  EXPECT_TRUE(same_file(p("soft.yaml"), p("mini.yaml")));
  EXPECT_FALSE(
      check_output_paths({{"--config", p("mini.yaml")}}, {{"--out", p("soft.yaml")}}).ok());
}

TEST_F(OutputPaths, TwoOutputsNamingOneNewFileAreRefused) {
  const Status s =
      check_output_paths({{"--config", p("mini.yaml")}},
                         {{"--out", p("new.yaml")}, {"--report", p("./sub/../new.yaml")}});
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("--report"), std::string_view::npos) << s.message();
  EXPECT_NE(s.message().find("--out"), std::string_view::npos) << s.message();
}

TEST_F(OutputPaths, DistinctAndAbsentPathsPass) {
  EXPECT_TRUE(
      check_output_paths(
          {{"--config", p("mini.yaml")}, {"--truth", ""}},
          {{"--out", p("calibrated.yaml")}, {"--report", ""}, {"--html", p("sub/report.html")}})
          .ok());
  EXPECT_FALSE(same_file(p("rec.csv"), p("mini.yaml")));
}

}  // namespace
}  // namespace cdpr::io
