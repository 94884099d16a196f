// Speed and allocation figures of the statics: the elasto-static equilibrium (solve_elastostatics,
// the virtual robot's physics) and the force distribution (closed form vs the exact QP). Run:
//   build/<dir>/bench/statics_bench --benchmark_counter_tabular=true
// Counters: allocs/call = global operator new calls per call (cdpr_test_support's counting
// operator new; must stay 0), iters/call = solver iterations per call, feasible = share of the
// poses where a distribution was found.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "alloc_counter.hpp"
#include "cdpr/calibration/elastostatics.hpp"
#include "cdpr/calibration/force_distribution.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "testing/test_robots.hpp"

namespace {

using cdpr::Pose;
using cdpr::RobotModel;

RobotModel robot(int which) {
  // 0: MINI with pulleys, 1: MINI point anchors, 2: LARGE with pulleys.
  return which == 2 ? cdpr::testing::large_robot(true) : cdpr::testing::mini_robot(which == 0);
}
cdpr::testing::WorkspaceBox box(int which) {
  cdpr::testing::WorkspaceBox b =
      which == 2 ? cdpr::testing::large_workspace() : cdpr::testing::mini_workspace();
  b.half_extent *= 0.6;
  b.max_angle *= 0.5;
  return b;
}
std::string label(const RobotModel& model) {
  return model.name + (model.pulleys[0].enabled() ? ", pulleys" : ", point anchors");
}

void report(benchmark::State& state, std::uint64_t allocations, double iterations) {
  state.counters["allocs/call"] =
      benchmark::Counter(static_cast<double>(allocations), benchmark::Counter::kAvgIterations);
  state.counters["iters/call"] = benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
}

// Poses with their planned tensions (QP) and the length commands that hold the platform there.
struct Case {
  Pose pose;
  Eigen::VectorXd commands;
};
std::vector<Case> cases(const RobotModel& model, int which, int n) {
  std::mt19937_64 rng(321);
  cdpr::ForceDistributionData fd(model);
  cdpr::CableCommandData cmd(model);
  std::vector<Case> out;
  while (static_cast<int>(out.size()) < n) {
    const Pose p = cdpr::testing::random_pose(box(which), rng);
    const cdpr::ForceDistributionResult f = cdpr::distribute_forces(model, p, {}, fd);
    if (!f.feasible()) continue;
    const Eigen::VectorXd tensions = f.tensions;
    if (!cdpr::inverse_kinematics_compensated(model, p, tensions, cmd)) continue;
    out.push_back({p, cmd.length_commands});
  }
  return out;
}

// Equilibrium from the commanded pose (the simulator's warm start is even closer).
void BM_ElastostaticsFromCommandedPose(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const RobotModel model = robot(which);
  const std::vector<Case> cs = cases(model, which, 64);
  cdpr::ElastostaticData data(model);
  cdpr::ElastostaticOptions options;
  // Start 1 mm / 1 mrad away so that the solver has work to do.
  std::vector<Pose> starts;
  for (const Case& c : cs) {
    Pose s = c.pose;
    s.position.array() += which == 2 ? 0.01 : 0.001;
    s.rpy.array() += 0.001;
    starts.push_back(s);
  }
  std::size_t k = 0;
  double iterations = 0.0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const std::size_t j = k++ & 63;
    options.initial_pose = starts[j];
    const cdpr::ElastostaticSummary s =
        cdpr::solve_elastostatics(model, cs[j].commands, options, data);
    iterations += s.iterations;
    benchmark::DoNotOptimize(s.pose.position.data());
    if (!s.success()) state.SkipWithError(s.status.to_string().c_str());
  }
  report(state, count.allocations(), iterations);
  state.SetLabel(label(model));
}
BENCHMARK(BM_ElastostaticsFromCommandedPose)->Arg(0)->Arg(1)->Arg(2);

// Cold start: the rigid forward kinematics of the commands first, then the equilibrium.
void BM_ElastostaticsColdStart(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const RobotModel model = robot(which);
  const std::vector<Case> cs = cases(model, which, 64);
  cdpr::ElastostaticData data(model);
  const cdpr::ElastostaticOptions options;
  std::size_t k = 0;
  double iterations = 0.0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const cdpr::ElastostaticSummary s =
        cdpr::solve_elastostatics(model, cs[k++ & 63].commands, options, data);
    iterations += s.iterations;
    benchmark::DoNotOptimize(s.pose.position.data());
    if (!s.success()) state.SkipWithError(s.status.to_string().c_str());
  }
  report(state, count.allocations(), iterations);
  state.SetLabel(label(model));
}
BENCHMARK(BM_ElastostaticsColdStart)->Arg(0)->Arg(2);

// With the uniqueness check (12 restarts): the price of the extra assurance.
void BM_ElastostaticsWithUniquenessCheck(benchmark::State& state) {
  const RobotModel model = robot(0);
  const std::vector<Case> cs = cases(model, 0, 16);
  cdpr::ElastostaticData data(model);
  cdpr::ElastostaticOptions options;
  options.uniqueness_starts = 12;
  std::size_t k = 0;
  double iterations = 0.0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const std::size_t j = k++ & 15;
    options.initial_pose = cs[j].pose;
    const cdpr::ElastostaticSummary s =
        cdpr::solve_elastostatics(model, cs[j].commands, options, data);
    iterations += s.iterations;
    benchmark::DoNotOptimize(s.stability_margin);
  }
  report(state, count.allocations(), iterations);
  state.SetLabel(label(model));
}
BENCHMARK(BM_ElastostaticsWithUniquenessCheck);

// Force distribution at random poses; tight limits (f_max = 60 N on MINI) make clipping common.
void BM_ForceDistribution(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const auto method = state.range(1) == 0 ? cdpr::ForceDistributionMethod::kClosedForm
                                          : cdpr::ForceDistributionMethod::kQuadraticProgram;
  RobotModel model = robot(which);
  if (which != 2) {
    for (cdpr::CableModel& c : model.cables) c.f_max = 60.0;
  }
  std::mt19937_64 rng(99);
  std::vector<Pose> ps;
  for (int k = 0; k < 256; ++k) ps.push_back(cdpr::testing::random_pose(box(which), rng));
  cdpr::ForceDistributionData data(model);
  cdpr::ForceDistributionOptions options;
  options.method = method;
  std::size_t k = 0;
  double iterations = 0.0, feasible = 0.0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const cdpr::ForceDistributionResult r =
        cdpr::distribute_forces(model, ps[k++ & 255], options, data);
    iterations += r.iterations;
    feasible += r.feasible() ? 1.0 : 0.0;
    benchmark::DoNotOptimize(r.tensions.data());
  }
  report(state, count.allocations(), iterations);
  state.counters["feasible"] = benchmark::Counter(feasible, benchmark::Counter::kAvgIterations);
  state.SetLabel(label(model) +
                 (state.range(1) == 0 ? ", closed form" : ", exact QP (Goldfarb-Idnani)"));
}
BENCHMARK(BM_ForceDistribution)
    ->Args({0, 0})
    ->Args({0, 1})
    ->Args({1, 0})
    ->Args({1, 1})
    ->Args({2, 0})
    ->Args({2, 1});

}  // namespace

BENCHMARK_MAIN();
