#include "cdpr/calibration/path_program.hpp"

#include <gtest/gtest.h>

#include <string>

namespace cdpr {
namespace {

bool contains(const Status& s, const std::string& text) {
  return s.message().find(text) != std::string_view::npos;
}

Pose origin() {
  return Pose{};
}

TEST(PathProgram, ReadsLinesArcsSplinesAndDwellsWithModalWords) {
  const std::string text =
      "; a demo (SI units)\n"
      "G1 X0.10 Y0.00 Z0.05 F0.05   ; a line\n"
      "\n"
      "Y0.02 (modal G1) C0.1\n"
      "G3 X0.00 Y0.12 I-0.10 J0.0\n"
      "g2 x0.10 y0.02 i0 j-0.1 f0.02\n"
      "G4 P0.5\n"
      "G18 G5 X0.05 Y0.05\n"
      "N10 X0.0 Y0.0 Z1e-2\n"
      "G0 X0 Y0 Z0 A0 B0 C0\n";
  auto segs = parse_path_program(text, "demo.path", origin());
  ASSERT_TRUE(segs.ok()) << segs.status().to_string();
  ASSERT_EQ(segs->size(), 8u);
  const auto& s = *segs;
  EXPECT_EQ(s[0].kind, PathSegment::Kind::kLine);
  EXPECT_EQ(s[0].line, 2);
  EXPECT_DOUBLE_EQ(s[0].feed, 0.05);
  EXPECT_EQ(s[1].kind, PathSegment::Kind::kLine);  // modal
  EXPECT_TRUE(s[1].target.position.isApprox(Eigen::Vector3d(0.10, 0.02, 0.05)));
  EXPECT_DOUBLE_EQ(s[1].target.rpy.z(), 0.1);
  EXPECT_EQ(s[2].kind, PathSegment::Kind::kArc);
  EXPECT_TRUE(s[2].center.isApprox(Eigen::Vector3d(0.0, 0.02, 0.05)));  // start + (I, J, K)
  EXPECT_TRUE(s[2].axis.isApprox(Eigen::Vector3d::UnitZ()));            // G3: counter-clockwise
  EXPECT_TRUE(s[3].axis.isApprox(-Eigen::Vector3d::UnitZ()));           // G2: clockwise
  EXPECT_DOUBLE_EQ(s[3].feed, 0.02);
  EXPECT_EQ(s[4].kind, PathSegment::Kind::kDwell);
  EXPECT_DOUBLE_EQ(s[4].dwell, 0.5);
  EXPECT_EQ(s[5].kind, PathSegment::Kind::kSpline);
  EXPECT_EQ(s[6].kind, PathSegment::Kind::kSpline);  // modal G5
  EXPECT_DOUBLE_EQ(s[6].target.position.z(), 0.01);
  EXPECT_DOUBLE_EQ(s[6].feed, 0.02);  // F is modal
  EXPECT_EQ(s[7].kind, PathSegment::Kind::kLine);
  EXPECT_TRUE(std::isnan(s[7].feed));  // G0: the limits only
  EXPECT_EQ(s[7].line, 10);
  // The program plans into a path (the arcs close on their circles).
  EXPECT_TRUE(Path::plan(origin(), *segs, PathLimits{}, nullptr, "demo.path").ok());
}

TEST(PathProgram, RefusesBadLinesNamingFileLineAndWord) {
  const struct {
    const char* text;
    const char* message;
  } cases[] = {
      {"G1 X0.1\nG1 X0.2 Y\n", "p.path:2: Y: expected a finite number after Y"},
      {"G1 X1.2.3\n", "p.path:1: X1.2.3: expected a finite number"},
      {"G1 X1e999\n", "p.path:1: X1e999: expected a finite number"},
      {"G1 X2e6\n", "p.path:1: X2e6: beyond"},
      {"G1 M3\n", "p.path:1: M3: unknown word"},
      {"G1 X0.1 X0.2\n", "p.path:1: X0.2: X given twice on one line"},
      {"G21\n", "p.path:1: G21: millimetres are not supported"},
      {"G91\n", "p.path:1: G91: relative coordinates are not supported"},
      {"G2 X0.1 R0.05\n", "p.path:1: R: radius arcs are not supported"},
      {"G2 X0.1\n", "p.path:1: G2: an arc needs I J K"},
      {"G1 X0 I0.1\n", "p.path:1: I: I J K (arc centre) belong to G2 and G3"},
      {"X0.1\n", "p.path:1: X: coordinates without a motion word"},
      {"G4\n", "p.path:1: G4: a dwell needs P"},
      {"G4 P-1\n", "p.path:1: P: the dwell must be >= 0 s"},
      {"G1 X0 F0\n", "p.path:1: F: the feed must be > 0 m/s"},
      {"G1 G2 X0\n", "p.path:1: G: two motion words"},
      {"G1 (unclosed X0\n", "p.path:1: (: comment without ')'"},
      {"G1 X0 %\n", "p.path:1: %: expected a word"},
      {"G7\n", "p.path:1: G: G7 is not supported"},
  };
  for (const auto& c : cases) {
    auto r = parse_path_program(c.text, "p.path", origin());
    ASSERT_FALSE(r.ok()) << c.text;
    EXPECT_EQ(r.status().code(), ErrorCode::kParseError);
    EXPECT_TRUE(contains(r.status(), c.message))
        << r.status().to_string() << "\nexpected " << c.message;
  }
}

TEST(PathProgram, BoundsTheInputSize) {
  const std::string long_line = "G1 X0 ; " + std::string(kMaxPathLineBytes, 'x') + "\n";
  auto r = parse_path_program("G1 X0\n" + long_line, "p.path", origin());
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(contains(r.status(), "p.path:2: the line is longer than 256 bytes"));
  const std::string huge(kMaxPathFileBytes + 1, '\n');
  auto h = parse_path_program(huge, "p.path", origin());
  ASSERT_FALSE(h.ok());
  EXPECT_TRUE(contains(h.status(), "larger than"));
  std::string many;
  for (std::size_t i = 0; i <= kMaxPathSegments; ++i) many += "G4 P0\n";
  if (many.size() <= kMaxPathFileBytes) {
    auto m = parse_path_program(many, "p.path", origin());
    ASSERT_FALSE(m.ok());
    EXPECT_TRUE(contains(m.status(), "more than 100000 instructions")) << m.status().to_string();
  }
}

}  // namespace
}  // namespace cdpr
