// Speed and allocation figures of the robot model: IK with swivel pulleys, IK with elongation
// compensation (the RT-loop path), forward kinematics. Run:
//   build/<dir>/bench/model_bench --benchmark_counter_tabular=true
// Counter allocs/call: global operator new calls per call (cdpr_test_support's counting
// operator new), which must stay 0 on the IK path.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "alloc_counter.hpp"
#include "cdpr/calibration/forward_kinematics.hpp"
#include "cdpr/calibration/ik_compensation.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "testing/test_robots.hpp"

namespace {

using cdpr::Pose;
using cdpr::RobotModel;

std::vector<Pose> poses(const cdpr::testing::WorkspaceBox& box, int n) {
  std::mt19937_64 rng(123);
  std::vector<Pose> out;
  for (int k = 0; k < n; ++k) out.push_back(cdpr::testing::random_pose(box, rng));
  return out;
}

void report_allocations(benchmark::State& state, std::uint64_t allocations) {
  state.counters["allocs/call"] =
      benchmark::Counter(static_cast<double>(allocations), benchmark::Counter::kAvgIterations);
}

RobotModel robot(int which) {
  // 0: MINI with pulleys, 1: MINI point anchors, 2: LARGE with pulleys.
  return which == 2 ? cdpr::testing::large_robot(true) : cdpr::testing::mini_robot(which == 0);
}
cdpr::testing::WorkspaceBox box(int which) {
  return which == 2 ? cdpr::testing::large_workspace() : cdpr::testing::mini_workspace();
}

void BM_InverseKinematics(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const RobotModel model = robot(which);
  const std::vector<Pose> ps = poses(box(which), 256);
  cdpr::KinematicsData data(model);
  std::size_t k = 0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const bool ok = cdpr::inverse_kinematics(model, ps[k++ & 255], data);
    benchmark::DoNotOptimize(ok);
    benchmark::DoNotOptimize(data.lengths.data());
    benchmark::DoNotOptimize(data.structure_matrix.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
  state.SetLabel(model.name + (model.pulleys[0].enabled() ? ", pulleys" : ", point anchors"));
}
BENCHMARK(BM_InverseKinematics)->Arg(0)->Arg(1)->Arg(2);

void BM_InverseKinematicsCompensated(benchmark::State& state) {
  RobotModel model = cdpr::testing::mini_robot(true);
  const auto kind = static_cast<cdpr::ElongationKind>(state.range(0));
  for (cdpr::CableModel& c : model.cables) {
    c.elongation = kind;
    c.polynomial.order = 5;  // the paper's order
    c.polynomial.coefficients.assign(21, 1e-4);
  }
  const std::vector<Pose> ps = poses(cdpr::testing::mini_workspace(), 256);
  const Eigen::VectorXd tensions = Eigen::VectorXd::LinSpaced(8, 20.0, 150.0);
  cdpr::CableCommandData data(model);
  std::size_t k = 0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const bool ok = cdpr::inverse_kinematics_compensated(model, ps[k++ & 255], tensions, data);
    benchmark::DoNotOptimize(ok);
    benchmark::DoNotOptimize(data.counts_rounded.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
  static const char* kNames[] = {"rigid", "Hooke", "polynomial order 5"};
  state.SetLabel(std::string("MINI, pulleys, ") + kNames[state.range(0)]);
}
BENCHMARK(BM_InverseKinematicsCompensated)->Arg(0)->Arg(1)->Arg(2);

// FK from the home pose (the worst case: a cold start anywhere in the workspace).
void BM_ForwardKinematicsFromHome(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const RobotModel model = robot(which);
  const std::vector<Pose> ps = poses(box(which), 256);
  std::vector<Eigen::VectorXd> lengths;
  cdpr::KinematicsData ik(model);
  for (const Pose& p : ps) {
    cdpr::inverse_kinematics(model, p, ik);
    lengths.push_back(ik.lengths);
  }
  cdpr::ForwardKinematicsData data(model);
  const cdpr::ForwardKinematicsOptions options;
  std::size_t k = 0;
  double iterations = 0;
  double failures = 0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const cdpr::ForwardKinematicsSummary s =
        cdpr::forward_kinematics(model, lengths[k++ & 255], options, data);
    iterations += s.iterations;
    failures += s.success() ? 0 : 1;
    benchmark::DoNotOptimize(s.pose.position.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
  state.counters["iterations"] = benchmark::Counter(iterations, benchmark::Counter::kAvgIterations);
  state.counters["failures"] = failures;
  state.SetLabel(model.name + (model.pulleys[0].enabled() ? ", pulleys" : ", point anchors"));
}
BENCHMARK(BM_ForwardKinematicsFromHome)->Arg(0)->Arg(1)->Arg(2);

// FK warm-started from a pose 1 mm / 0.5 degree away (tracking in a control loop).
void BM_ForwardKinematicsWarmStart(benchmark::State& state) {
  const RobotModel model = cdpr::testing::mini_robot(true);
  const std::vector<Pose> ps = poses(cdpr::testing::mini_workspace(), 256);
  std::vector<Eigen::VectorXd> lengths;
  std::vector<cdpr::ForwardKinematicsOptions> options;
  cdpr::KinematicsData ik(model);
  for (const Pose& p : ps) {
    cdpr::inverse_kinematics(model, p, ik);
    lengths.push_back(ik.lengths);
    cdpr::ForwardKinematicsOptions o;
    o.initial_pose =
        Pose{p.position + Eigen::Vector3d(1e-3, 0, 0), p.rpy + Eigen::Vector3d(0, 0.0087, 0)};
    options.push_back(o);
  }
  cdpr::ForwardKinematicsData data(model);
  std::size_t k = 0;
  const cdpr::test::AllocationCounter count;
  for (auto _ : state) {
    const std::size_t j = k++ & 255;
    const cdpr::ForwardKinematicsSummary s =
        cdpr::forward_kinematics(model, lengths[j], options[j], data);
    benchmark::DoNotOptimize(s.pose.position.data());
    benchmark::ClobberMemory();
  }
  report_allocations(state, count.allocations());
  state.SetLabel("MINI, pulleys");
}
BENCHMARK(BM_ForwardKinematicsWarmStart);

}  // namespace

BENCHMARK_MAIN();
