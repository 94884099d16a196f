// The tension-control stage of the RT cycle on the fake robot, whose force sensors read a
// stiffness model of the cables: the platform yields to the trims (quasi-static, at the home pose)
// so that only what the cables' stiffness puts into the kernel of A^T stays as tension.
#include "cdpr/controller/tension_control.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <limits>
#include <memory>

#include "alloc_counter.hpp"
#include "cdpr/calibration/elongation.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/rt_controller.hpp"
#include "fake_robot_io.hpp"
#include "testing/test_robots.hpp"

namespace cdpr::controller {
namespace {

using testing::FakeRobotIO;
using namespace std::chrono_literals;

// The controller on the fake robot with tension control on; the sensors read the plant below.
class TensionRig : public ::testing::Test {
 protected:
  void SetUp() override {
    geometry_.version = 1;
    geometry_.model = cdpr::testing::mini_robot();
    geometry_.reference_tension = default_reference_tension(geometry_.model);
    m_ = geometry_.model.num_cables();
    options_.tension_control.gain = 5.0;
    options_.tension_control.margin = 10.0;
    // The kernel step alone: the plan on the band's margin, every taut cable weighing 1 (the
    // guard is measured on the virtual MINI: daemon_tension_band_test).
    options_.tension_control.guard = 0.0;
    make();
  }
  void make() {
    auto rt = RtController::create(io_, geometry_, options_);
    ASSERT_TRUE(rt.ok()) << rt.status().to_string();
    rt_ = std::move(*rt);
    CommandData data(geometry_.model);
    ASSERT_TRUE(
        command_counts(geometry_.model, geometry_.model.home, geometry_.reference_tension, data)
            .ok());
    // The plant at home: tension change df = -K (I - A (A^T K A)^-1 A^T K) dl for cable length
    // changes dl (the platform moves to stay in equilibrium); A = structure_matrix^T.
    a_ = data.kinematics.structure_matrix.transpose();
    const Eigen::MatrixXd& a = a_;
    k_ = Eigen::MatrixXd::Zero(m_, m_);
    Eigen::MatrixXd& k = k_;
    for (int i = 0; i < m_; ++i) {
      const double c =
          cable_elongation_derivatives(geometry_.model.cables[static_cast<size_t>(i)],
                                       data.cable.loaded_lengths(i), data.plan.tensions(i))
              .d_tension;
      k(i, i) = 1.0 / c;
      home_counts_[static_cast<size_t>(i)] = data.cable.counts(i);
      planned_[static_cast<size_t>(i)] = data.plan.tensions(i);
    }
    response_ = -k * (Eigen::MatrixXd::Identity(m_, m_) -
                      a * (a.transpose() * k * a).ldlt().solve(a.transpose() * k));
    // A basis of the kernel of A^T, for disturbances of the internal forces.
    Eigen::FullPivLU<Eigen::MatrixXd> lu(a.transpose());
    kernel_ = lu.kernel();
    for (int i = 0; i < m_; ++i) {
      io_.position[static_cast<size_t>(i)] = home_counts_[static_cast<size_t>(i)];
    }
    internal_ = Eigen::VectorXd::Zero(m_);
    sense();
  }

  // The sensors: plan + internal-force disturbance + the response to the cable lengths' change
  // from home (a cable cannot push: at least 0 N).
  void sense() {
    Eigen::VectorXd dl(m_);
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<size_t>(i);
      dl(i) = winch_length_change<double>(geometry_.model.winches[k],
                                          io_.position[k] - home_counts_[k]);
    }
    const Eigen::VectorXd df = response_ * dl;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<size_t>(i);
      if (!stuck_[k]) io_.tension[k] = std::max(0.0, planned_[k] + internal_(i) + df(i));
    }
  }
  void cycle(int n = 1) {
    for (int c = 0; c < n; ++c) {
      rt_->cycle(now_);
      now_ += kPeriod;
      sense();
    }
  }
  bool run_until(const std::function<bool(const RtSnapshot&)>& done, int max_cycles) {
    for (int c = 0; c < max_cycles; ++c) {
      if (done(rt_->snapshot())) return true;
      cycle();
    }
    return done(rt_->snapshot());
  }
  void hold_home() {
    MotionCommand& c = commands_.emplace_back();
    c.type = MotionCommand::Type::kReference;
    c.pose = geometry_.model.home;
    c.from_actual = true;
    c.seq = ++seq_;
    rt_->post(&c);
    ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.command_done == c.seq; }, 2000));
  }
  // A 20 mm move along y from home.
  void move_from_home() {
    Pose to = geometry_.model.home;
    to.position.y() += 0.02;
    auto traj = PoseTrajectory::plan(geometry_.model.home, to, MotionLimits{});
    ASSERT_TRUE(traj.ok());
    MotionCommand& c = commands_.emplace_back();
    c.type = MotionCommand::Type::kMove;
    c.trajectory = std::move(*traj);
    c.seq = ++seq_;
    rt_->post(&c);
  }
  // A disturbance of the internal forces that puts cable `slack` at `below` N under its plan.
  void disturb(int slack, double below) {
    const Eigen::VectorXd d = kernel_.col(0) / kernel_(slack, 0);
    internal_ = -below * d;
  }
  double lo(int i) const { return geometry_.model.cables[static_cast<size_t>(i)].f_min + 10.0; }
  double hi(int i) const { return geometry_.model.cables[static_cast<size_t>(i)].f_max - 10.0; }
  double counts_per_metre() const {
    return 1.0 / winch_metres_per_count(geometry_.model.winches[0]);
  }
  bool all_in_band() const {
    for (int i = 0; i < m_; ++i) {
      const double f = io_.tension[static_cast<size_t>(i)];
      if (f < lo(i) || f > hi(i)) return false;
    }
    return true;
  }

  static constexpr canopen::Timestamp kPeriod = 4ms;
  Geometry geometry_;
  int m_ = 0;
  FakeRobotIO io_{8};
  RtControllerOptions options_;
  std::unique_ptr<RtController> rt_;
  std::array<double, kMaxAxes> home_counts_{}, planned_{};
  std::array<bool, kMaxAxes> stuck_{};
  Eigen::MatrixXd a_, k_, response_, kernel_;
  Eigen::VectorXd internal_;
  std::deque<MotionCommand> commands_;
  std::uint64_t seq_ = 0;
  canopen::Timestamp now_{1s};
};

TEST_F(TensionRig, ASlackCableIsTakenUpIntoTheBandAndStaysThere) {
  hold_home();
  disturb(0, planned_[0]);  // cable 1 at 0 N, the others off by the same internal force
  sense();
  ASSERT_LT(io_.tension[0], 1.0);
  const bool reached =
      run_until([&](const RtSnapshot& s) { return s.tension_control.in_band; }, 2000);
  ASSERT_TRUE(reached);
  cycle(250);  // and stays there
  EXPECT_TRUE(all_in_band());
  const RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.tension_control.state, TensionControlState::kActive);
  EXPECT_LE(s.tension_control.largest_error, 2.0 * options_.tension_control.deadband + 0.5);
  // The cable below the band was taken up on its own (shortened); the platform yielded to the
  // part of that change outside the kernel.
  EXPECT_LT(s.tension_control.trim_counts[0], 0.0);
}

// The trims change the internal forces only: the stiffness-mapped length change K dl is in the
// kernel of A^T (no wrench on the platform, so no pose change to first order), and the plant's
// tension change equals K dl (the platform's yield takes nothing away).
TEST_F(TensionRig, TrimsChangeOnlyTheInternalForcesNotThePose) {
  hold_home();
  // Every cable taut but off its plan along the kernel: no slack take-up, only the kernel step.
  disturb(0, 0.5 * (planned_[0] - lo(0)));
  internal_ += kernel_.col(1) * (20.0 / kernel_.col(1).cwiseAbs().maxCoeff());
  sense();
  for (int i = 0; i < m_; ++i) ASSERT_GT(io_.tension[static_cast<size_t>(i)], 1.0);
  cycle(500);
  Eigen::VectorXd dl(m_);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<size_t>(i);
    dl(i) = winch_length_change<double>(geometry_.model.winches[k],
                                        rt_->snapshot().tension_control.trim_counts[k]);
  }
  const Eigen::VectorXd kdl = k_ * dl;
  ASSERT_GT(kdl.norm(), 5.0) << "the disturbance was corrected by trims";
  EXPECT_LT((a_.transpose() * kdl).norm(), 1e-6 * kdl.norm() * a_.norm());
  EXPECT_LT((response_ * dl + kdl).norm(), 1e-6 * kdl.norm());
  // And the correction undid the disturbance as far as internal forces can: every cable in the
  // band, and what is left of the error to the targets (the plan clamped into the band shrunk by
  // the deadband) along the kernel is inside the dead zone (half the deadband, plus the readings'
  // half-unit dither).
  EXPECT_TRUE(all_in_band());
  const double deadband = options_.tension_control.deadband;
  Eigen::VectorXd rest(m_);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<size_t>(i);
    rest(i) = std::clamp(planned_[k], lo(i) + deadband, hi(i) - deadband) - io_.tension[k];
  }
  const Eigen::VectorXd along =
      rest - a_ * (a_.transpose() * a_).ldlt().solve(a_.transpose() * rest);
  EXPECT_LE(along.cwiseAbs().maxCoeff(), 0.5 * deadband + 0.1) << "left: " << rest.transpose();
}

TEST_F(TensionRig, TrimsMoveNoFasterThanTheRateLimit) {
  hold_home();
  disturb(0, planned_[0]);
  sense();
  const double dmax = options_.tension_control.max_rate * 0.004 * counts_per_metre();
  std::array<double, kMaxAxes> prev = rt_->snapshot().tension_control.trim_counts;
  double largest = 0.0;
  for (int c = 0; c < 300; ++c) {
    cycle();
    const auto& t = rt_->snapshot().tension_control.trim_counts;
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<size_t>(i);
      largest = std::max(largest, std::abs(t[k] - prev[k]));
    }
    prev = t;
  }
  EXPECT_LE(largest, dmax * (1.0 + 1e-9));
  EXPECT_GT(largest, 0.9 * dmax) << "a 0 N cable drives the trims at their limit";
}

TEST_F(TensionRig, ACableThatNeverTightensWindsTheTrimsUpOnlyToTheirBound) {
  options_.tension_control.max_trim = 0.003;
  make();
  hold_home();
  stuck_[0] = true;
  io_.tension[0] = 0.0;  // e.g. a cable off its pulley: no trim brings it back
  cycle(3000);           // 12 s: far longer than the bound takes at the rate limit
  RtSnapshot s = rt_->snapshot();
  const double bound = options_.tension_control.max_trim * counts_per_metre();
  EXPECT_TRUE(s.tension_control.saturated);
  for (int i = 0; i < m_; ++i) {
    EXPECT_LE(std::abs(s.tension_control.trim_counts[static_cast<size_t>(i)]), bound + 1e-6);
  }
  // The cable is back: the trims leave the bound at once and the band is reached again.
  stuck_[0] = false;
  sense();
  ASSERT_TRUE(run_until([&](const RtSnapshot& r) { return r.tension_control.in_band; }, 3000));
  cycle(250);  // and stays there (a trim inside the band is left where it is)
  EXPECT_TRUE(all_in_band());
}

TEST_F(TensionRig, StaleReadingsFreezeTheTrimsThenTheyDecayAndAFreshReadingResumes) {
  hold_home();
  disturb(0, planned_[0]);
  sense();
  ASSERT_TRUE(run_until([&](const RtSnapshot& s) { return s.tension_control.in_band; }, 2000));
  io_.tensions_arrive = false;
  const int stale = static_cast<int>(options_.tension_control.stale_s / 0.004) + 2;
  cycle(stale);  // until then the last reading is used
  const std::array<double, kMaxAxes> held = rt_->snapshot().tension_control.trim_counts;
  const int hold = static_cast<int>(options_.tension_control.hold_s / 0.004);
  cycle(hold - 2);
  RtSnapshot s = rt_->snapshot();
  EXPECT_EQ(s.tension_control.state, TensionControlState::kFrozen);
  EXPECT_EQ(s.tension_control.trim_counts, held);
  cycle(static_cast<int>(options_.tension_control.decay_s / 0.004));  // one time constant more
  s = rt_->snapshot();
  EXPECT_EQ(s.tension_control.state, TensionControlState::kDecaying);
  for (int i = 0; i < m_; ++i) {
    const auto k = static_cast<size_t>(i);
    EXPECT_LT(std::abs(s.tension_control.trim_counts[k]), 0.5 * std::abs(held[k]) + 1.0);
  }
  io_.tensions_arrive = true;
  cycle();
  EXPECT_EQ(rt_->snapshot().tension_control.state, TensionControlState::kActive);
  EXPECT_TRUE(run_until([&](const RtSnapshot& r) { return r.tension_control.in_band; }, 2000));
}

TEST_F(TensionRig, ActiveWhileMovingAndOffWhileDisabled) {
  hold_home();
  move_from_home();
  cycle(20);
  RtSnapshot s = rt_->snapshot();
  ASSERT_EQ(s.mode, RtMode::kMoving);
  EXPECT_EQ(s.tension_control.state, TensionControlState::kActive);
  rt_->request_quick_stop();
  cycle(2);
  s = rt_->snapshot();
  EXPECT_EQ(s.mode, RtMode::kDisabled);
  EXPECT_EQ(s.tension_control.state, TensionControlState::kOff);
  for (int i = 0; i < m_; ++i) EXPECT_EQ(s.tension_control.trim_counts[static_cast<size_t>(i)], 0);
}

TEST_F(TensionRig, CycleWithTensionControlAllocatesNothing) {
  hold_home();
  disturb(0, planned_[0]);
  move_from_home();
  std::uint64_t allocations = 0;
  std::array<int, 5> seen{};  // cycles in each state (off, active, held, frozen, decaying)
  for (int n = 0; n < 600; ++n) {
    rt_->hold_tension_trims(n >= 150 && n < 200);  // a pose being sampled: the trims held
    if (n == 300) io_.tensions_arrive = false;     // frozen, then decaying
    {
      test::AllocationCounter count;
      rt_->cycle(now_);
      allocations += count.allocations();
    }
    now_ += kPeriod;
    sense();  // the plant allocates: outside the count
    ++seen[static_cast<std::size_t>(rt_->snapshot().tension_control.state)];
  }
  EXPECT_EQ(allocations, 0u);
  for (const TensionControlState st :
       {TensionControlState::kActive, TensionControlState::kHeld, TensionControlState::kFrozen,
        TensionControlState::kDecaying}) {
    EXPECT_GT(seen[static_cast<std::size_t>(st)], 0) << "never " << to_string(st);
  }
  EXPECT_GT(rt_->snapshot().largest_move_step, 0.0) << "the platform moved";
  EXPECT_NE(rt_->snapshot().tension_control.state, TensionControlState::kOff);
}

TEST(TensionControl, RefusesNegativeOrNonFiniteOptions) {
  TensionControlOptions o;
  EXPECT_TRUE(TensionControl::validate(o, 0.004).ok());
  o.gain = -1.0;
  EXPECT_FALSE(TensionControl::validate(o, 0.004).ok());
  o = TensionControlOptions{};
  o.decay_s = 0.0;
  EXPECT_FALSE(TensionControl::validate(o, 0.004).ok());
  o = TensionControlOptions{};
  o.guard = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(TensionControl::validate(o, 0.004).ok());
  EXPECT_FALSE(TensionControl::validate(TensionControlOptions{}, 0.0).ok());
}

}  // namespace
}  // namespace cdpr::controller
