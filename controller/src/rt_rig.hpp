// The RT controller on the fake robot, time driven by the test (one SYNC period per cycle):
// the fixture of the RtRig and RtMotion tests (rt_controller_test.cc,
// rt_controller_motion_test.cc).
#pragma once

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <memory>
#include <set>
#include <vector>

#include "alloc_counter.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/calibration/winch.hpp"
#include "cdpr/controller/rt_controller.hpp"
#include "fake_robot_io.hpp"
#include "testing/test_robots.hpp"

namespace cdpr::controller::rig {

using testing::FakeRobotIO;
using namespace std::chrono_literals;

inline Geometry make_geometry(int version, RobotModel model) {
  Geometry g;
  g.version = version;
  g.reference_tension = default_reference_tension(model);
  g.model = std::move(model);
  return g;
}

// The controller on the fake robot, time driven by the test (one SYNC period per cycle).
class RtRig : public ::testing::Test {
 protected:
  void SetUp() override { make(RtControllerOptions{}); }

  void make(const RtControllerOptions& options) {
    options_ = options;
    auto rt = RtController::create(io_, geometry_, options_);
    ASSERT_TRUE(rt.ok()) << rt.status().to_string();
    rt_ = std::move(*rt);
    // The drives stand at the home pose's targets, the tensions at its plan.
    const std::array<double, kMaxAxes> targets = ik_counts(geometry_, geometry_.model.home);
    for (int i = 0; i < m_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      io_.position[k] = targets[k];
      io_.tension[k] = planned_[k];
    }
  }

  // Encoder targets of `pose` under `g` (offsets 0), and its planned tensions in planned_.
  std::array<double, kMaxAxes> ik_counts(const Geometry& g, const Pose& pose) {
    CommandData data(g.model);
    EXPECT_TRUE(command_counts(g.model, pose, g.reference_tension, data).ok());
    std::array<double, kMaxAxes> counts{};
    for (int i = 0; i < m_; ++i) {
      counts[static_cast<std::size_t>(i)] = data.cable.counts(i);
      planned_[static_cast<std::size_t>(i)] = data.plan.tensions(i);
    }
    return counts;
  }

  void cycle(int n = 1) {
    for (int c = 0; c < n; ++c) {
      rt_->cycle(now_);
      now_ += kPeriod;
    }
  }
  bool run_until(const std::function<bool(const RtSnapshot&)>& done, int max_cycles) {
    for (int c = 0; c < max_cycles; ++c) {
      if (done(rt_->snapshot())) return true;
      cycle();
    }
    return done(rt_->snapshot());
  }

  // Commands live in the rig (the loop keeps a pointer to the active one).
  MotionCommand& make_command(MotionCommand::Type type) {
    MotionCommand& c = commands_.emplace_back();
    c.type = type;
    return c;
  }
  std::uint64_t post(MotionCommand& c) {
    c.seq = ++seq_;
    rt_->post(&c);
    return seq_;
  }
  std::uint64_t post_reference(const Pose& pose, bool from_actual,
                               const Geometry* geometry = nullptr) {
    MotionCommand& c = make_command(MotionCommand::Type::kReference);
    c.pose = pose;
    c.from_actual = from_actual;
    c.geometry = geometry;
    return post(c);
  }
  std::uint64_t post_move(const Pose& to) {
    auto traj = PoseTrajectory::plan(rt_->snapshot().pose(), to, MotionLimits{});
    EXPECT_TRUE(traj.ok());
    MotionCommand& c = make_command(MotionCommand::Type::kMove);
    c.trajectory = std::move(*traj);
    return post(c);
  }
  // From disabled to holding still at home.
  void hold_home() {
    const std::uint64_t seq = post_reference(geometry_.model.home, true);
    ASSERT_TRUE(
        run_until([&](const RtSnapshot& s) { return s.command_done == seq && s.settled; }, 2000));
  }
  // Kinematic cable lengths at `pose` (m).
  Eigen::VectorXd lengths_at(const Pose& pose) {
    CommandData data(geometry_.model);
    EXPECT_TRUE(command_counts(geometry_.model, pose, geometry_.reference_tension, data).ok());
    return data.kinematics.lengths;
  }
  double counts_per_metre() const {
    return 1.0 / winch_metres_per_count(geometry_.model.winches[0]);
  }

  static constexpr canopen::Timestamp kPeriod = 4ms;
  Geometry geometry_ = make_geometry(1, cdpr::testing::mini_robot());
  int m_ = geometry_.model.num_cables();
  FakeRobotIO io_{geometry_.model.num_cables()};
  RtControllerOptions options_;
  std::unique_ptr<RtController> rt_;
  std::array<double, kMaxAxes> planned_{};
  std::deque<MotionCommand> commands_;
  std::uint64_t seq_ = 0;
  canopen::Timestamp now_{1s};
};

}  // namespace cdpr::controller::rig
