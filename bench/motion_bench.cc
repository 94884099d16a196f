// Speed and allocation figures of the motion code: what the RT cycle calls (trajectory sample,
// command_counts = tension plan + compensated IK, slew step) and what the supervisor calls
// before a move (plan, check_path). Run:
//   build/<dir>/bench/motion_bench --benchmark_counters_tabular=true
// Counter allocs/call: global operator new calls per call, which must stay 0 on the RT calls.
#include <benchmark/benchmark.h>

#include <cmath>
#include <numbers>
#include <random>
#include <vector>

#include "alloc_counter.hpp"
#include "bench_util.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/path.hpp"
#include "cdpr/calibration/path_check.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/slew.hpp"
#include "cdpr/calibration/trajectory.hpp"
#include "testing/test_robots.hpp"

namespace {

using cdpr::Pose;
using cdpr::RobotModel;
constexpr double kDeg = std::numbers::pi / 180.0;

void report_allocations(benchmark::State& state, std::uint64_t allocations) {
  state.counters["allocs/call"] =
      benchmark::Counter(static_cast<double>(allocations), benchmark::Counter::kAvgIterations);
}

RobotModel robot(int which) {
  return which == 1 ? cdpr::testing::large_robot(true) : cdpr::testing::mini_robot(true);
}

// A move inside each robot's test workspace with translation and rotation.
cdpr::PoseTrajectory move(int which) {
  Pose to;
  const double scale = which == 1 ? 10.0 : 1.0;
  to.position << 0.12 * scale, -0.1 * scale, 0.08 * scale;
  to.rpy << 2 * kDeg, -2 * kDeg, 3 * kDeg;
  cdpr::MotionLimits limits;
  limits.max_linear_velocity *= scale;
  limits.max_linear_acceleration *= scale;
  limits.max_linear_jerk *= scale;
  return cdpr::bench::must(cdpr::PoseTrajectory::plan(Pose{}, to, limits), "plan");
}

// Samples `traj` (a PoseTrajectory or a Path) every 4 ms of it, over and over.
template <typename Trajectory>
void sample_every_cycle(benchmark::State& state, const Trajectory& traj) {
  Pose pose;
  cdpr::TaskVelocity v;
  double t = 0.0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    traj.sample(t, pose, &v);
    t += 0.004;
    if (t > traj.duration()) t = 0.0;
    benchmark::DoNotOptimize(pose.rpy.data());
    benchmark::DoNotOptimize(v.angular.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
}

void BM_TrajectorySample(benchmark::State& state) {
  sample_every_cycle(state, move(0));
}
BENCHMARK(BM_TrajectorySample);

// The RT cycle's planned tensions and encoder targets along a move (every 4 ms of it).
void BM_CommandCounts(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const RobotModel model = robot(which);
  const cdpr::PoseTrajectory traj = move(which);
  std::vector<Pose> poses;
  for (double t = 0.0; t <= traj.duration(); t += 0.004) {
    traj.sample(t, poses.emplace_back());
  }
  const double reference = cdpr::default_reference_tension(model);
  cdpr::CommandData data(model);
  std::size_t k = 0;
  int failures = 0;
  double attempts = 0.0;  // QP solves per call: 1, 2 or 3 (reference 1x, 2x, 4x)
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    failures += !cdpr::command_counts(model, poses[k], reference, data).ok();
    attempts += 1.0 + std::log2(data.plan.reference / reference);
    k = k + 1 == poses.size() ? 0 : k + 1;
    benchmark::DoNotOptimize(data.cable.counts.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
  state.counters["failures"] = failures;
  state.counters["QPs/call"] = benchmark::Counter(attempts, benchmark::Counter::kAvgIterations);
  state.SetLabel(model.name + ", pulleys, " + std::to_string(poses.size()) + " poses");
}
BENCHMARK(BM_CommandCounts)->Arg(0)->Arg(1);

// Baseline for BM_CommandCounts: the compensated IK alone with fixed tensions.
void BM_CompensatedIkOnly(benchmark::State& state) {
  const RobotModel model = robot(static_cast<int>(state.range(0)));
  const cdpr::PoseTrajectory traj = move(static_cast<int>(state.range(0)));
  Pose pose;
  traj.sample(0.5 * traj.duration(), pose);
  const Eigen::VectorXd tensions = Eigen::VectorXd::Constant(model.num_cables(), 20.0);
  cdpr::CableCommandData data(model);
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    benchmark::DoNotOptimize(cdpr::inverse_kinematics_compensated(model, pose, tensions, data));
    benchmark::DoNotOptimize(data.counts.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
}
BENCHMARK(BM_CompensatedIkOnly)->Arg(0)->Arg(1);

void BM_SlewStep8Axes(benchmark::State& state) {
  cdpr::SlewLimiter slew;
  if (!slew.configure(8, 0.004, 2.0e5, 1.0e6).ok()) state.SkipWithError("configure");
  const std::vector<double> zero(8, 0.0);
  std::vector<double> target(8);
  for (int i = 0; i < 8; ++i) target[static_cast<std::size_t>(i)] = 3.0e4 * (i - 4);
  (void)slew.reset(zero);
  (void)slew.set_target(target);
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    slew.step();
    if (slew.done()) (void)slew.reset(zero), (void)slew.set_target(target);
    benchmark::DoNotOptimize(slew.command().data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
}
BENCHMARK(BM_SlewStep8Axes);

void BM_PlanTrajectory(benchmark::State& state) {
  Pose to;
  to.position << 0.12, -0.1, 0.08;
  to.rpy << 5 * kDeg, -4 * kDeg, 8 * kDeg;
  for (auto _ : state) {
    auto t = cdpr::PoseTrajectory::plan(Pose{}, to, cdpr::MotionLimits{});
    benchmark::DoNotOptimize(t);
  }
}
BENCHMARK(BM_PlanTrajectory);

// The feasibility check of the whole move before it is accepted (default steps 5 mm, 0.5 deg).
void BM_CheckPath(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const RobotModel model = robot(which);
  const cdpr::PoseTrajectory traj = move(which);
  cdpr::PathCheckSummary summary;
  for (auto _ : state) {
    summary = {};
    const cdpr::Status s = cdpr::check_path(model, traj, {}, &summary);
    if (!s.ok()) state.SkipWithError(s.to_string().c_str());
    benchmark::DoNotOptimize(summary);
  }
  state.counters["points"] = summary.points;
  state.SetLabel(model.name + ", " + std::to_string(traj.linear_distance()) + " m");
}
BENCHMARK(BM_CheckPath)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// A MINI path with every piece kind: a full circle of 0.1 m radius, a turning spline through two
// waypoints, a line back.
cdpr::Path mixed_path() {
  Pose start;
  start.position << 0.1, 0.0, 0.0;
  std::vector<cdpr::PathSegment> segs(4);
  segs[0].kind = cdpr::PathSegment::Kind::kArc;
  segs[0].target = start;
  segs[1].kind = segs[2].kind = cdpr::PathSegment::Kind::kSpline;
  segs[1].target.position << 0.05, 0.05, 0.02;
  segs[1].target.rpy << 3 * kDeg, 0.0, 5 * kDeg;
  segs[2].target.position << 0.0, 0.0, 0.0;
  segs[3].target = start;
  return cdpr::bench::must(cdpr::Path::plan(start, segs, {}), "path");
}

void BM_PathSample(benchmark::State& state) {
  sample_every_cycle(state, mixed_path());
}
BENCHMARK(BM_PathSample);

void BM_PlanPath(benchmark::State& state) {
  for (auto _ : state) {
    const cdpr::Path path = mixed_path();
    benchmark::DoNotOptimize(path.duration());
  }
}
BENCHMARK(BM_PlanPath)->Unit(benchmark::kMicrosecond);

void BM_CheckMixedPath(benchmark::State& state) {
  const RobotModel model = robot(0);
  const cdpr::Path path = mixed_path();
  cdpr::PathCheckSummary summary;
  for (auto _ : state) {
    const cdpr::Status s = cdpr::check_path(model, path, {}, &summary);
    if (!s.ok()) state.SkipWithError(s.to_string().c_str());
    benchmark::DoNotOptimize(summary);
  }
  state.counters["points"] = summary.points;
}
BENCHMARK(BM_CheckMixedPath)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
