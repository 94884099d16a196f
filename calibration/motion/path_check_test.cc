#include "cdpr/calibration/path_check.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <string>

#include "alloc_counter.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "testing/test_robots.hpp"

namespace cdpr {
namespace {

constexpr double kDeg = std::numbers::pi / 180.0;

bool contains(const Status& s, const std::string& text) {
  return s.message().find(text) != std::string_view::npos;
}

Pose pose_at(double x, double y, double z, double roll = 0, double pitch = 0, double yaw = 0) {
  Pose p;
  p.position << x, y, z;
  p.rpy << roll, pitch, yaw;
  return p;
}

PoseTrajectory plan_move(const Pose& a, const Pose& b) {
  auto t = PoseTrajectory::plan(a, b, MotionLimits{});
  EXPECT_TRUE(t.ok()) << t.status().to_string();
  return *t;
}

TEST(PlanTensions, MatchesTheVirtualRobotsPlanner) {
  const RobotModel mini = testing::mini_robot();
  const double reference = default_reference_tension(mini);
  std::mt19937_64 rng(5);
  testing::WorkspaceBox box = testing::mini_workspace();
  box.half_extent *= 1.8;  // also poses outside the workspace
  KinematicsData kinematics(mini);
  TensionPlan plan;
  int feasible = 0, infeasible = 0;
  for (int k = 0; k < 300; ++k) {
    const Pose pose = testing::random_pose(box, rng);
    ASSERT_TRUE(inverse_kinematics(mini, pose, kinematics));
    const Status s = plan_tensions(mini, kinematics, reference, 0.0, plan);
    const Result<Eigen::VectorXd> expected = simple_tension_distribution(mini, pose, reference);
    ASSERT_EQ(s.ok(), expected.ok()) << s.to_string() << " / " << expected.status().to_string();
    if (!s.ok()) {
      EXPECT_EQ(s.code(), expected.status().code());
      ++infeasible;
      continue;
    }
    ++feasible;
    EXPECT_LT((Eigen::VectorXd(plan.tensions) - *expected).cwiseAbs().maxCoeff(), 1e-9);
  }
  // Both kinds of pose were seen.
  EXPECT_GT(feasible, 50);
  EXPECT_GT(infeasible, 20);
}

TEST(PlanTensions, KeepsTensionsInsideTheMarginBand) {
  const RobotModel mini = testing::mini_robot();
  KinematicsData kinematics(mini);
  TensionPlan plan;
  const double margin = 20.0;
  const Pose pose = pose_at(0.1, -0.05, 0.08, 5 * kDeg, 0, -5 * kDeg);
  ASSERT_TRUE(inverse_kinematics(mini, pose, kinematics));
  ASSERT_TRUE(plan_tensions(mini, kinematics, default_reference_tension(mini), margin, plan).ok());
  for (int i = 0; i < mini.num_cables(); ++i) {
    EXPECT_GE(plan.tensions(i), mini.cables[0].f_min + margin - 1e-9);
    EXPECT_LE(plan.tensions(i), mini.cables[0].f_max - margin + 1e-9);
  }
  // The tensions balance the platform's weight.
  const Wrench6 w = gravity_wrench(mini, kinematics.rotation);
  EXPECT_LT((kinematics.structure_matrix * Eigen::VectorXd(plan.tensions) + w).norm(), 1e-9);
  // An empty band is bad input, named by cable.
  const Status s = plan_tensions(mini, kinematics, 20.0, 100.0, plan);
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(contains(s, "cable 1")) << s.to_string();
}

// Along a line where the planner's choice switches between 1x and 2x the reference (a cable
// meets the band's edge), its plan steps; the plan at one reference in between changes little
// from one point to the next, and a plan at the band's edge is accepted as it is.
TEST(PlanTensions, AtOneReferenceTheyChangeSmoothlyWhereThePlannersChoiceSteps) {
  const RobotModel mini = testing::mini_robot();
  const double reference = default_reference_tension(mini);
  const double margin = 10.0;
  KinematicsData kinematics(mini);
  TensionPlan chosen, at;
  double chosen_step = 0.0, at_step = 0.0, previous_ref = 0.0;
  Eigen::VectorXd last_chosen, last_at;
  int switches = 0, at_edge = 0;
  for (int k = 0; k <= 400; ++k) {  // 0.5 mm apart
    const Pose pose = pose_at(-0.1 + 0.0005 * k, 0.08, 0.06, 0, 0, 0);
    ASSERT_TRUE(inverse_kinematics(mini, pose, kinematics));
    ASSERT_TRUE(plan_tensions(mini, kinematics, reference, margin, chosen).ok());
    ASSERT_TRUE(plan_tensions_at(mini, kinematics, reference, margin, at).ok());
    EXPECT_EQ(at.reference, reference);
    if (at.cables_at_limits > 0) ++at_edge;
    const Eigen::VectorXd c = chosen.tensions, a = at.tensions;
    if (k > 0) {
      chosen_step = std::max(chosen_step, (c - last_chosen).cwiseAbs().maxCoeff());
      at_step = std::max(at_step, (a - last_at).cwiseAbs().maxCoeff());
      if (chosen.reference != previous_ref) ++switches;
    }
    last_chosen = c;
    last_at = a;
    previous_ref = chosen.reference;
  }
  ASSERT_GT(switches, 0) << "the line no longer crosses a switch of the planner's choice";
  EXPECT_GT(at_edge, 0);
  EXPECT_GT(chosen_step, 10.0);
  EXPECT_LT(at_step, 0.2 * chosen_step);
}

TEST(CheckPose, AcceptsHomeAndRefusesAHeavyPlatformNamingTheOverloadedCable) {
  RobotModel mini = testing::mini_robot();
  PathCheckSummary summary;
  EXPECT_TRUE(check_pose(mini, mini.home, {}, &summary).ok());
  EXPECT_EQ(summary.points, 1);
  EXPECT_GT(summary.min_tension_slack, 0.0);
  mini.platform.mass = 60.0;  // more than the top cables can carry within f_max
  const Status s = check_pose(mini, mini.home);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(s,
                       "pose (0.000, 0.000, 0.000) m, (0.0, 0.0, 0.0) deg is outside the "
                       "wrench-feasible workspace: cable "))
      << s.to_string();
  EXPECT_TRUE(contains(s, "N > f_max 200 N")) << s.to_string();
  // The named cable is a top cable (5 to 8) and really would exceed f_max: with f_max raised the
  // least-tension plan puts it above 200 N.
  int cable = 0;
  double needed = 0.0;
  ASSERT_EQ(std::sscanf(std::string(s.message()).c_str(),
                        "pose (%*[^)]) m, (%*[^)]) deg is outside the wrench-feasible workspace: "
                        "cable %d would need %lf",
                        &cable, &needed),
            2)
      << s.to_string();
  EXPECT_GE(cable, 5);
  EXPECT_LE(cable, 8);
  EXPECT_GT(needed, 200.0);
  for (CableModel& c : mini.cables) c.f_max = 1000.0;
  Result<Eigen::VectorXd> f = simple_tension_distribution(mini, mini.home, 5.0);
  ASSERT_TRUE(f.ok());
  EXPECT_GT(f->maxCoeff(), 200.0);
}

TEST(CheckPose, NamesTheSlackCableAndTheMargin) {
  const RobotModel mini = testing::mini_robot();
  const Pose far = pose_at(0.45, 0.0, 0.0);
  Status s = check_pose(mini, far);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(s, "N < f_min 5 N")) << s.to_string();
  // A pose feasible without a margin but not with one; the margin is named.
  const Pose edge = pose_at(0.0, 0.0, 0.0, 0, 0, 12 * kDeg);
  ASSERT_TRUE(check_pose(mini, edge).ok());
  PathCheckOptions options;
  options.tension_margin = 30.0;
  s = check_pose(mini, edge, options);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange) << s.to_string();
  EXPECT_TRUE(contains(s, "margin 30 N")) << s.to_string();
}

TEST(CheckPose, NamesADegenerateCable) {
  const RobotModel mini = testing::mini_robot(/*with_pulleys=*/false);
  // Platform anchor 5 on frame anchor 5.
  Pose p;
  p.position = mini.frame_anchors.col(4) - mini.platform_anchors.col(4);
  const Status s = check_pose(mini, p);
  EXPECT_EQ(s.code(), ErrorCode::kNumericalFailure);
  EXPECT_TRUE(contains(s, "is not reachable: cable 5 is degenerate")) << s.to_string();
}

TEST(CheckPath, RefusesAMoveOutOfTheWorkspaceNamingCableAndPoint) {
  const RobotModel mini = testing::mini_robot();
  const Pose target = pose_at(0.45, 0.0, 0.02, 0, 0, 4 * kDeg);
  const PoseTrajectory move = plan_move(mini.home, target);
  const Status s = check_path(mini, move);
  ASSERT_EQ(s.code(), ErrorCode::kOutOfRange) << s.to_string();
  // The first failing point of the same grid (steps of at most 5 mm and 0.5 deg), found here
  // pose by pose.
  const PathCheckOptions defaults;
  const int n = static_cast<int>(std::max(std::ceil(move.linear_distance() / 0.005),
                                          std::ceil(move.angular_distance() / (0.5 * kDeg))));
  int first_bad = -1;
  Status at_point;
  for (int k = 0; k <= n && first_bad < 0; ++k) {
    Pose p;
    Eigen::Matrix3d R;
    move.path_point(static_cast<double>(k) / n, p.position, R);
    p.rpy = rpy_from_rotation(R);
    at_point = check_pose(mini, p, defaults);
    if (!at_point.ok()) first_bad = k;
  }
  ASSERT_GT(first_bad, 0);
  char expected[200];
  const double s_bad = static_cast<double>(first_bad) / n;
  std::snprintf(expected, sizeof expected,
                "move to (0.450, 0.000, 0.020) m, (0.0, 0.0, 4.0) deg leaves the wrench-feasible "
                "workspace at s = %.3f (%.3f, 0.000, %.3f) m: cable ",
                s_bad, 0.45 * s_bad, 0.02 * s_bad);
  EXPECT_TRUE(contains(s, expected)) << s.to_string() << "\nexpected: " << expected;
  // Same cable and tension as the single-pose check at that point.
  const std::string_view reason = at_point.message().substr(at_point.message().find("cable "));
  EXPECT_TRUE(contains(s, std::string(reason))) << s.to_string() << "\n" << reason;
}

TEST(CheckPath, AcceptsAMoveInsideTheWorkspaceCheckingEveryStep) {
  const RobotModel mini = testing::mini_robot();
  const Pose from = pose_at(-0.05, 0.02, -0.03);
  const Pose to = pose_at(0.12, -0.10, 0.08, 5 * kDeg, -4 * kDeg, 8 * kDeg);
  const PoseTrajectory move = plan_move(from, to);
  PathCheckSummary summary;
  const Status s = check_path(mini, move, {}, &summary);
  EXPECT_TRUE(s.ok()) << s.to_string();
  const double steps = std::max(std::ceil(move.linear_distance() / 0.005),
                                std::ceil(move.angular_distance() / (0.5 * kDeg)));
  EXPECT_EQ(summary.points, static_cast<int>(steps) + 1);
  // The planner may put a cable on f_min (when even 4x the reference leaves one there).
  EXPECT_GE(summary.min_tension_slack, 0.0);
  EXPECT_LT(summary.min_tension_slack, 195.0);
  EXPECT_GE(summary.min_slack_cable, 1);
  // A finer grid and a larger margin still pass here.
  PathCheckOptions options;
  options.max_linear_step = 0.001;
  options.tension_margin = 2.0;
  EXPECT_TRUE(check_path(mini, move, options).ok());
  // A pure rotation is sampled by angle.
  const PoseTrajectory turn = plan_move(from, pose_at(-0.05, 0.02, -0.03, 0, 0, 10 * kDeg));
  summary = {};
  EXPECT_TRUE(check_path(mini, turn, {}, &summary).ok());
  EXPECT_EQ(summary.points, 21);  // 10 deg in 0.5 deg steps
}

TEST(CheckPath, RefusesAMoveLeavingTheWorkspaceBox) {
  const RobotModel mini = testing::mini_robot();
  PathCheckOptions options;
  options.workspace_box =
      Eigen::AlignedBox3d(Eigen::Vector3d::Constant(-0.156), Eigen::Vector3d::Constant(0.156));
  const PoseTrajectory move = plan_move(mini.home, pose_at(0.2, 0.0, 0.0));
  const Status s = check_path(mini, move, options);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  // 40 steps of 5 mm: the first point beyond 0.156 m is step 32 (x = 0.160 m).
  EXPECT_TRUE(contains(s,
                       "leaves the workspace box at s = 0.800 (0.160, 0.000, 0.000) m: x = "
                       "0.1600 m > 0.1560 m"))
      << s.to_string();
  EXPECT_TRUE(check_path(mini, plan_move(mini.home, pose_at(0.15, -0.1, 0.1)), options).ok());
}

TEST(CheckPath, RefusesAMoveBeyondOneWinchsOwnLengthLimitNamingTheCable) {
  const RobotModel mini = testing::mini_robot();
  const PoseTrajectory move = plan_move(mini.home, pose_at(0.1, 0.0, 0.0));
  KinematicsData k(mini.num_cables());
  ASSERT_TRUE(inverse_kinematics(mini, mini.home, k));
  PathCheckOptions options;
  options.min_cable_lengths.assign(static_cast<std::size_t>(mini.num_cables()), 0.0);
  options.max_cable_lengths.assign(static_cast<std::size_t>(mini.num_cables()), 10.0);
  EXPECT_TRUE(check_path(mini, move, options).ok());
  // Every cable whose length the move changes by more than 1 cm, limited to 5 mm from home: the
  // first one is named.
  KinematicsData end(mini.num_cables());
  ASSERT_TRUE(inverse_kinematics(mini, pose_at(0.1, 0.0, 0.0), end));
  int limited = -1;
  for (int i = 0; i < mini.num_cables() && limited < 0; ++i) {
    if (end.lengths(i) - k.lengths(i) > 0.01) limited = i;
  }
  ASSERT_GE(limited, 0);
  options.max_cable_lengths[static_cast<std::size_t>(limited)] = k.lengths(limited) + 0.005;
  const Status s = check_path(mini, move, options);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(s, "cable " + std::to_string(limited + 1) + " is")) << s.to_string();
  options.max_cable_lengths.pop_back();
  EXPECT_EQ(check_path(mini, move, options).code(), ErrorCode::kInvalidArgument);
}

TEST(CheckPath, RejectsBadOptionsNamingTheField) {
  const RobotModel mini = testing::mini_robot();
  const PoseTrajectory move = plan_move(mini.home, pose_at(0.1, 0, 0));
  PathCheckOptions options;
  options.max_linear_step = 0.0;
  Status s = check_path(mini, move, options);
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(contains(s, "max_linear_step")) << s.to_string();
  options = {};
  options.max_angular_step = -1.0;
  EXPECT_TRUE(contains(check_path(mini, move, options), "max_angular_step"));
  options = {};
  options.tension_margin = std::nan("");
  EXPECT_TRUE(contains(check_path(mini, move, options), "tension_margin"));
  options = {};
  options.reference_tension = -3.0;
  EXPECT_TRUE(contains(check_pose(mini, mini.home, options), "reference_tension"));
  options = {};
  options.tension_margin = 150.0;
  s = check_pose(mini, mini.home, options);
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  EXPECT_TRUE(contains(s, "cable 1: f_min 5 N + margin 150 N exceeds f_max 200 N")) << s.message();
  options = {};
  options.max_linear_step = 1e-12;
  EXPECT_EQ(check_path(mini, move, options).code(), ErrorCode::kInvalidArgument);
}

// A full circle of radius r about the origin in the plane z = z0, then a line to `end`.
Path circle_then_line(double r, double z0, const Pose& end, int first_line = 1) {
  std::vector<PathSegment> segs(2);
  segs[0].kind = PathSegment::Kind::kArc;
  segs[0].target = pose_at(r, 0, z0);
  segs[0].center = Eigen::Vector3d(0, 0, z0);
  segs[0].line = first_line;
  segs[1].target = end;
  segs[1].line = first_line + 1;
  auto p = Path::plan(pose_at(r, 0, z0), segs, PathLimits{});
  EXPECT_TRUE(p.ok()) << p.status().to_string();
  return *p;
}

TEST(CheckMultiSegmentPath, AcceptsACircleCheckingItAtTheStepDensity) {
  const RobotModel mini = testing::mini_robot();
  const Path path = circle_then_line(0.1, 0.02, pose_at(0.1, 0.0, 0.1));
  PathCheckSummary summary;
  const Status s = check_path(mini, path, {}, &summary);
  EXPECT_TRUE(s.ok()) << s.to_string();
  // 2 pi 0.1 m in steps of at most 5 mm: 126 steps; 0.08 m of line: 16; both ends of each.
  EXPECT_EQ(summary.points, 127 + 17);
  PathCheckOptions fine;
  fine.max_linear_step = 0.001;
  EXPECT_TRUE(check_path(mini, path, fine, &summary).ok());
  EXPECT_EQ(summary.points, 630 + 81);
}

TEST(CheckMultiSegmentPath, NamesTheLineAndPointWherePathLeavesTheWorkspace) {
  const RobotModel mini = testing::mini_robot();
  PathCheckOptions options;
  options.workspace_box =
      Eigen::AlignedBox3d(Eigen::Vector3d::Constant(-0.156), Eigen::Vector3d::Constant(0.156));
  const Path path = circle_then_line(0.1, 0.0, pose_at(0.1, 0.0, 0.2), 7);
  const Status s = check_path(mini, path, options);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  // The line starts at sigma = 2 pi 0.1; its 40 steps of 5 mm pass z = 0.156 at step 32.
  char expected[200];
  std::snprintf(expected, sizeof expected,
                "path line 8 leaves the workspace box at sigma = %.3f m (0.100, ",
                2 * std::numbers::pi * 0.1 + 0.16);
  EXPECT_TRUE(contains(s, expected)) << s.to_string() << "\nexpected: " << expected;
  EXPECT_TRUE(contains(s, "0.000, 0.160) m: z = 0.1600 m > 0.1560 m")) << s.to_string();
}

TEST(CheckMultiSegmentPath, ChecksCableLengthsAndCableInterference) {
  const RobotModel mini = testing::mini_robot();
  const Path path = circle_then_line(0.1, 0.0, pose_at(0.1, 0.0, 0.05));
  KinematicsData k(mini);
  ASSERT_TRUE(inverse_kinematics(mini, mini.home, k));
  PathCheckOptions options;
  options.max_cable_length = k.lengths.maxCoeff() + 0.01;  // the circle reaches further
  const Status s = check_path(mini, path, options);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(s, "leaves the cable length limits at sigma = ")) << s.to_string();
  EXPECT_TRUE(contains(s, " m long > ")) << s.to_string();
  // MINI's spans do not cross: at home the closest spans are those whose platform anchors are
  // 0.06 m apart, a pair that a thinner cable cannot make touch.
  PathCheckOptions thin;
  thin.cable_diameter = 0.05;
  EXPECT_TRUE(check_pose(mini, mini.home, thin).ok());
  EXPECT_TRUE(check_path(mini, path, thin).ok());
  // Cables 1 and 2 with their frame anchors swapped cross between frame and platform.
  RobotModel crossed = mini;
  crossed.frame_anchors.col(0).swap(crossed.frame_anchors.col(1));
  std::swap(crossed.pulleys[0], crossed.pulleys[1]);
  KinematicsData kc(crossed);
  ASSERT_TRUE(inverse_kinematics(crossed, crossed.home, kc));
  const double d = segment_distance(crossed.frame_anchors.col(0), kc.platform_points.col(0),
                                    crossed.frame_anchors.col(1), kc.platform_points.col(1));
  ASSERT_LT(d, 0.04);
  PathCheckOptions thick;
  thick.cable_diameter = d + 0.002;
  const Status t = check_pose(crossed, crossed.home, thick);
  EXPECT_EQ(t.code(), ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(t, "has touching cables: cables 1 and 2 pass ")) << t.to_string();
}

TEST(SegmentDistance, IsTheClosestDistanceOfTwoSegments) {
  const Eigen::Vector3d o = Eigen::Vector3d::Zero(), x = Eigen::Vector3d::UnitX();
  // Crossing at right angles, 0.3 apart.
  EXPECT_NEAR(segment_distance(-x, x, Eigen::Vector3d(0, -1, 0.3), Eigen::Vector3d(0, 1, 0.3)), 0.3,
              1e-15);
  // Parallel, overlapping.
  EXPECT_NEAR(segment_distance(o, x, Eigen::Vector3d(0.5, 0.2, 0), Eigen::Vector3d(2, 0.2, 0)), 0.2,
              1e-15);
  // The closest points are ends (clamped).
  EXPECT_NEAR(segment_distance(o, x, Eigen::Vector3d(2, 1, 0), Eigen::Vector3d(3, 5, 0)),
              std::sqrt(2.0), 1e-15);
  // Degenerate segments are points.
  EXPECT_NEAR(segment_distance(o, o, Eigen::Vector3d(0, 3, 0), Eigen::Vector3d(0, 3, 0)), 3.0,
              1e-15);
  EXPECT_NEAR(segment_distance(o, o, Eigen::Vector3d(-1, 1, 0), Eigen::Vector3d(1, 1, 0)), 1.0,
              1e-15);
}

TEST(CommandCounts, MatchesCompensatedInverseKinematicsWithThePlannedTensions) {
  const RobotModel mini = testing::mini_robot();
  const double reference = default_reference_tension(mini);
  CommandData data(mini);
  CableCommandData expected(mini);
  std::mt19937_64 rng(9);
  for (int k = 0; k < 50; ++k) {
    const Pose pose = testing::random_pose(testing::mini_workspace(), rng);
    const Result<Eigen::VectorXd> f = simple_tension_distribution(mini, pose, reference);
    const Status s = command_counts(mini, pose, reference, data);
    ASSERT_EQ(s.ok(), f.ok()) << s.to_string();
    if (!s.ok()) continue;
    ASSERT_TRUE(inverse_kinematics_compensated(mini, pose, *f, expected));
    EXPECT_LT((data.cable.counts - expected.counts).cwiseAbs().maxCoeff(), 1e-6);
    EXPECT_EQ(data.cable.counts_rounded, expected.counts_rounded);
    EXPECT_LT((Eigen::VectorXd(data.plan.tensions) - *f).cwiseAbs().maxCoeff(), 1e-9);
  }
}

TEST(CommandCounts, FailureKeepsThePreviousCountsAndNamesTheReason) {
  const RobotModel mini = testing::mini_robot();
  CommandData data(mini);
  ASSERT_TRUE(command_counts(mini, mini.home, 20.0, data).ok());
  const Eigen::VectorXd before = data.cable.counts;
  const Status s = command_counts(mini, pose_at(0.45, 0, 0), 20.0, data);
  EXPECT_EQ(s.code(), ErrorCode::kOutOfRange);
  EXPECT_TRUE(contains(s, "wrench-feasible workspace")) << s.to_string();
  EXPECT_EQ(data.cable.counts, before);
  EXPECT_EQ(command_counts(mini, mini.home, -1.0, data).code(), ErrorCode::kInvalidArgument);
  Pose nan_pose;
  nan_pose.position.x() = std::nan("");
  EXPECT_FALSE(command_counts(mini, nan_pose, 20.0, data).ok());
  EXPECT_EQ(data.cable.counts, before);
  CommandData wrong_size(4);
  EXPECT_EQ(command_counts(mini, mini.home, 20.0, wrong_size).code(), ErrorCode::kInvalidArgument);
}

TEST(CommandCounts, TriesTheMarginsInOrderAndUsesTheFirstFeasibleOne) {
  const RobotModel mini = testing::mini_robot();
  const double reference = default_reference_tension(mini);
  const Pose far = pose_at(0.2, 0.15, 0.1);
  // The widest margin that is still feasible at `far`, found one margin at a time.
  CommandData one(mini);
  double feasible = -1.0, infeasible = -1.0;
  for (double margin = 0.0; margin < 200.0 && infeasible < 0.0; margin += 5.0) {
    if (command_counts(mini, far, reference, one, margin).ok()) {
      feasible = margin;
    } else if (feasible >= 0.0) {
      infeasible = margin;
    }
  }
  ASSERT_GE(feasible, 0.0);
  ASSERT_GT(infeasible, feasible);
  ASSERT_TRUE(command_counts(mini, far, reference, one, feasible).ok());
  CommandData data(mini);
  const std::array<double, 3> margins{infeasible, feasible, 0.0};
  int chosen = -2;
  test::AllocationCounter count;
  ASSERT_TRUE(command_counts(mini, far, reference, data, margins, &chosen).ok());
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(chosen, 1);
  EXPECT_EQ(data.cable.counts, one.cable.counts);
  EXPECT_EQ(data.plan.tensions, one.plan.tensions);
  // None feasible: the last margin's reason, no index.
  const std::array<double, 1> too_wide{infeasible};
  EXPECT_FALSE(command_counts(mini, far, reference, data, too_wide, &chosen).ok());
  EXPECT_EQ(chosen, -1);
}

TEST(CommandCounts, AllocatesNothingAlongAMoveNorOnFailure) {
  const RobotModel mini = testing::mini_robot();
  const double reference = default_reference_tension(mini);
  const PoseTrajectory move =
      plan_move(mini.home, pose_at(0.12, -0.1, 0.08, 5 * kDeg, -4 * kDeg, 8 * kDeg));
  CommandData data(mini);
  Pose pose;
  int ok = 0;
  test::AllocationCounter count;
  for (int k = 0; k <= 500; ++k) {
    move.sample(move.duration() * k / 500.0, pose);
    ok += command_counts(mini, pose, reference, data).ok();
  }
  const Status failed = command_counts(mini, pose_at(0.45, 0, 0), reference, data);
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(ok, 501);
  EXPECT_FALSE(failed.ok());
}

}  // namespace
}  // namespace cdpr
