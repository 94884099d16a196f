// cdpr-sim physics: CPU cost of one step (SYNC) for MINI's 8 cables, ns per step.
//
// Each benchmark alternates between two nearby motor positions (the platform moves ~1 mm per
// step, as at 100 Hz and 0.1 m/s), so every step solves a new equilibrium from the previous one.
// Baseline in the same run: the library solver solve_elastostatics (elastostatics.hpp) started
// cold from the rigid forward kinematics of the commands, which the physics falls back to.
#include <benchmark/benchmark.h>

#include <string>

#include "cdpr/calibration/elastostatics.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"

namespace {

struct Setup {
  cdpr::RobotModel nominal;
  cdpr::sim::Scenario scenario;
  Eigen::VectorXd a, b;  // counts at two nearby poses
};

Setup make_setup(const std::string& scenario_name) {
  Setup s;
  auto nominal =
      cdpr::config::load_robot_config(std::string(CDPR_SOURCE_DIR) + "/config/mini.yaml");
  auto scenario =
      cdpr::sim::load_scenario(std::string(CDPR_SOURCE_DIR) + "/config/scenarios/" + scenario_name);
  if (!nominal.ok() || !scenario.ok()) std::abort();
  s.nominal = *nominal;
  s.scenario = *scenario;
  cdpr::Pose p;
  auto a = cdpr::sim::nominal_counts(s.nominal, p);
  p.position.x() += 0.001;
  auto b = cdpr::sim::nominal_counts(s.nominal, p);
  if (!a.ok() || !b.ok()) std::abort();
  s.a = a->array().round().matrix();
  s.b = b->array().round().matrix();
  return s;
}

void run_physics(benchmark::State& state, const std::string& scenario_name) {
  const Setup s = make_setup(scenario_name);
  auto truth = cdpr::sim::resolve_truth(s.scenario, s.nominal);
  if (!truth.ok()) std::abort();
  auto physics = cdpr::sim::Physics::create(*truth, s.scenario, 1);
  if (!physics.ok()) std::abort();
  double t = 0.0;
  bool flip = false;
  if (!physics->step(s.a, t).ok()) std::abort();
  for (auto _ : state) {
    t += 0.01;
    flip = !flip;
    const cdpr::Status st = physics->step(flip ? s.b : s.a, t);
    if (!st.ok()) {
      state.SkipWithError(st.to_string().c_str());
      break;
    }
    benchmark::DoNotOptimize(physics->state().pose);
  }
  state.counters["newton_iterations"] = physics->state().iterations;
}

void BM_SimStep_Hooke(benchmark::State& state) {
  run_physics(state, "mini-none.yaml");
}
BENCHMARK(BM_SimStep_Hooke);

void BM_SimStep_HookeNoise(benchmark::State& state) {
  run_physics(state, "mini-hooke.yaml");
}
BENCHMARK(BM_SimStep_HookeNoise);

// With sag: a catenary per cable and a finite-difference Jacobian per Newton step.
void BM_SimStep_Everything_WithSag(benchmark::State& state) {
  run_physics(state, "mini-everything.yaml");
}
BENCHMARK(BM_SimStep_Everything_WithSag);

// Baseline: the library solver from a cold start, on the same true robot and commands.
void BM_Baseline_SolveElastostaticsCold(benchmark::State& state) {
  const Setup s = make_setup("mini-none.yaml");
  auto truth = cdpr::sim::resolve_truth(s.scenario, s.nominal);
  if (!truth.ok()) std::abort();
  auto physics = cdpr::sim::Physics::create(*truth, s.scenario, 1);
  if (!physics.ok()) std::abort();
  Eigen::VectorXd la(8), lb(8);
  for (int i = 0; i < 8; ++i) {
    la(i) = physics->unstretched_length(i, s.a(i), 0.0);
    lb(i) = physics->unstretched_length(i, s.b(i), 0.0);
  }
  cdpr::ElastostaticData data(*truth);
  cdpr::ElastostaticOptions o;
  o.wrench_tolerance = 1e-7;
  bool flip = false;
  for (auto _ : state) {
    flip = !flip;
    const cdpr::ElastostaticSummary r = cdpr::solve_elastostatics(*truth, flip ? lb : la, o, data);
    if (!r.success()) {
      state.SkipWithError(r.status.to_string().c_str());
      break;
    }
    benchmark::DoNotOptimize(r.pose);
  }
}
BENCHMARK(BM_Baseline_SolveElastostaticsCold);

}  // namespace

BENCHMARK_MAIN();
