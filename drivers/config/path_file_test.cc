#include "cdpr/config/path_file.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/path_program.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

bool contains(const Status& s, const std::string& text) {
  return s.message().find(text) != std::string_view::npos;
}

Pose origin() {
  return Pose{};
}

TEST(PathFile, LoadsAFileAndNamesAMissingOne) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("cdpr_path_file_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string file = (dir / "square.path").string();
  std::ofstream(file) << "G1 X0.1 F0.05\nG1 Y0.1\nG1 X0\nG1 Y0\n";
  auto segs = load_path_file(file, origin());
  ASSERT_TRUE(segs.ok()) << segs.status().to_string();
  EXPECT_EQ(segs->size(), 4u);
  std::ofstream(file) << "G1 X0.1\nG1 Q1\n";
  auto bad = load_path_file(file, origin());
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(contains(bad.status(), file + ":2: Q1: unknown word")) << bad.status().to_string();
  auto missing = load_path_file((dir / "none.path").string(), origin());
  EXPECT_EQ(missing.status().code(), ErrorCode::kNotFound);
  std::filesystem::remove_all(dir);
}

TEST(PathFile, TheShippedDemoPlansAndPassesTheMiniCheck) {
  const std::string file = std::string(CDPR_SOURCE_DIR) + "/config/examples/mini-demo.path";
  const RobotModel mini = testing::mini_robot();
  auto segs = load_path_file(file, mini.home);
  ASSERT_TRUE(segs.ok()) << segs.status().to_string();
  auto path = Path::plan(mini.home, *segs, PathLimits{}, nullptr, file);
  ASSERT_TRUE(path.ok()) << path.status().to_string();
  // Stops: line, circle (after it the dwell), spline, helix, line home.
  EXPECT_EQ(path->motions().size(), 5u);
  PathCheckOptions options;
  options.tension_margin = 5.0;
  options.workspace_box =
      Eigen::AlignedBox3d(Eigen::Vector3d::Constant(-0.156), Eigen::Vector3d::Constant(0.156));
  PathCheckSummary summary;
  const Status s = check_path(mini, *path, options, &summary);
  EXPECT_TRUE(s.ok()) << s.to_string();
  EXPECT_GT(summary.points, 200);
  Pose end;
  path->sample(path->duration(), end);
  EXPECT_LT(end.position.norm(), 1e-12);
}

TEST(PathFile, RefusesAFileLargerThanTheBoundAndAFifo) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("cdpr_path_bound_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string file = (dir / "huge.path").string();
  std::ofstream(file) << std::string(kMaxPathFileBytes + 1, '\n');
  auto huge = load_path_file(file, origin());
  EXPECT_EQ(huge.status().code(), ErrorCode::kOutOfRange) << huge.status().to_string();
  EXPECT_TRUE(contains(huge.status(), file)) << huge.status().to_string();
  const std::string fifo = (dir / "fifo.path").string();
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  auto f = load_path_file(fifo, origin());  // never waits for a writer
  EXPECT_EQ(f.status().code(), ErrorCode::kInvalidArgument) << f.status().to_string();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace cdpr
