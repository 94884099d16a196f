// A restart never moves the robot (issue 39, findings 1-3): cdprd killed (destroyed without an
// orderly stop, the virtual robot and the bus staying) at each designed pose and during moves,
// then started again on the same state directory; homing refusals; the homing methods; the
// operator's enable and disable. In-process: the daemon and the virtual robot on the virtual bus
// with a manual clock (virtual_cell.hpp).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "cdpr/controller/state_store.hpp"
#include "cell_fixture.hpp"

namespace cdpr::controller {
namespace {

using json = nlohmann::json;

class Restart : public testing::CellTest {
 protected:
  Restart() : CellTest("cdprd-restart-") {}

  Pose true_pose() const { return cell_->physics->state().pose; }
  // The true pose did not change: under 0.05 mm and 0.005 degrees.
  static void expect_same(const Pose& a, const Pose& b, const std::string& where) {
    EXPECT_LT((a.position - b.position).norm(), 0.05e-3) << where;
    EXPECT_LT((a.rpy - b.rpy).cwiseAbs().maxCoeff(), 0.005 * M_PI / 180.0) << where;
  }
  // After a restart: holding, with a trusted pose or a reason motion is refused.
  void expect_holding_or_refusing(const std::string& where) {
    const json st = daemon().status();
    EXPECT_EQ(st["state"], "holding") << where << ": " << st.dump();
    if (!st["pose"]["trusted"].get<bool>()) {
      EXPECT_FALSE(st["pose"]["reason"].get<std::string>().empty()) << where;
      const Reply mv = request("move", {{"pose", {0, 0, 0, 0, 0, 0}}});
      EXPECT_FALSE(mv.ok) << where;
      EXPECT_NE(mv.message.find("cdprctl home"), std::string::npos) << where << ": " << mv.message;
    }
  }
  // Kill, let the robot stand, start again and hold a while: the true pose must not change.
  void kill_and_restart(const std::string& where) {
    cell_->kill_daemon();
    for (int i = 0; i < 40; ++i) cell_->idle();  // the robot alone for 10 ms
    const Pose before = true_pose();
    ASSERT_TRUE(cell_->start_daemon().ok()) << where;
    run_until([] { return false; }, 0.3);
    expect_same(before, true_pose(), where);
    expect_holding_or_refusing(where);
  }
  std::vector<std::array<double, 6>> designed_poses() {
    const Reply dry = request("calibrate", {{"dry_run", true}});
    EXPECT_TRUE(dry.ok) << dry.message;
    std::vector<std::array<double, 6>> out;
    for (const auto& p : dry.result["poses"]) {
      std::array<double, 6> a{};
      for (int i = 0; i < 6; ++i)
        a[static_cast<size_t>(i)] = p[static_cast<size_t>(i)].get<double>();
      out.push_back(a);
    }
    return out;
  }
};

TEST_F(Restart, AKillAtEachDesignedPoseAndDuringAMoveNeverMovesThePlatform) {
  start_daemon();
  const auto poses = designed_poses();
  ASSERT_EQ(poses.size(), 25u);
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const std::string where = "designed pose " + std::to_string(i + 1);
    const Reply mv = request("move", {{"pose", poses[i]}});
    ASSERT_TRUE(mv.ok) << where << ": " << mv.message;
    ASSERT_TRUE(holds_settled(20.0)) << where;
    for (int k = 0; k < 10; ++k) cell_->cycle();  // the supervisor persists the held state
    kill_and_restart(where);
    // Held still, the persisted state makes the pose trusted at the restart.
    EXPECT_TRUE(daemon().status()["pose"]["trusted"].get<bool>())
        << where << ": " << daemon().status()["pose"].dump();
    ASSERT_TRUE(holds_settled(5.0)) << where;
  }
  // Killed in the middle of moves: holding where the drives are, or refusing with the reason.
  for (std::size_t i : {0u, 6u}) {
    if (!daemon().status()["pose"]["trusted"].get<bool>()) break;
    ASSERT_TRUE(request("move", {{"pose", poses[i]}}).ok);
    run_until([] { return false; }, 0.2);
    ASSERT_EQ(daemon().rt().snapshot().mode, RtMode::kMoving);
    kill_and_restart("in the move to designed pose " + std::to_string(i + 1));
  }
}

TEST_F(Restart, WithoutAHomingRecordMotionIsRefusedUntilHome) {
  testing::VirtualCell::Settings s;
  s.start = "{enable: at-start}";
  start_daemon(s);
  json st = daemon().status();
  EXPECT_FALSE(st["pose"]["trusted"].get<bool>());
  EXPECT_NE(st["pose"]["reason"].get<std::string>().find("no homing.json"), std::string::npos);
  EXPECT_EQ(daemon().rt().snapshot().mode, RtMode::kHoldingCounts);
  EXPECT_EQ(request("move", {{"pose", {0.01, 0, 0, 0, 0, 0}}}).code, "invalid_state");
  EXPECT_EQ(request("calibrate").code, "invalid_state");
  const Reply h = request("home", {{"method", "reference"}});
  ASSERT_TRUE(h.ok) << h.message;
  ASSERT_TRUE(holds_settled(5.0));
  EXPECT_TRUE(daemon().status()["pose"]["trusted"].get<bool>());
  EXPECT_TRUE(request("move", {{"pose", {0.01, 0, 0, 0, 0, 0}}}).ok);
}

TEST_F(Restart, AMismatchedRecordRefusesMotionNamingWhatDiffers) {
  start_daemon();
  ASSERT_TRUE(holds_settled(5.0));
  auto store = StateStore::open((dir_ / "state").string());
  ASSERT_TRUE(store.ok());
  auto rec = store->load_homing();
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  const HomingRecord good = *rec;

  rec->drives[0].serial ^= 1;  // another drive on node 1
  ASSERT_TRUE(store->save_homing(*rec).ok());
  ASSERT_TRUE(cell_->start_daemon().ok());
  EXPECT_NE(daemon().status()["pose"]["reason"].get<std::string>().find("drives"),
            std::string::npos);
  EXPECT_FALSE(request("move", {{"pose", {0.01, 0, 0, 0, 0, 0}}}).ok);

  HomingRecord other = good;
  other.geometry_version = 7;
  ASSERT_TRUE(store->save_homing(other).ok());
  ASSERT_TRUE(cell_->start_daemon().ok());
  EXPECT_NE(daemon().status()["pose"]["reason"].get<std::string>().find("geometry version"),
            std::string::npos);

  std::ofstream(dir_ / "state" / "homing.json")
      << R"({"offsets_counts": [0, 0, 0, 0, 0, 0, 0, 0], "how": "old", "time": "t"})";
  ASSERT_TRUE(cell_->start_daemon().ok());
  EXPECT_NE(daemon().status()["pose"]["reason"].get<std::string>().find("old format"),
            std::string::npos);
  EXPECT_EQ(daemon().status()["state"], "holding");
}

TEST_F(Restart, HomeWithAbsoluteEncodersKeepsTheOffsetsAfterThePoseCheck) {
  start_daemon();
  ASSERT_TRUE(request("move", {{"pose", {0.03, 0, 0, 0, 0, 0}}}).ok);
  ASSERT_TRUE(holds_settled(10.0));
  auto store = StateStore::open((dir_ / "state").string());
  ASSERT_TRUE(store.ok());
  const std::vector<double> offsets = store->load_homing()->offsets_counts;
  cell_->kill_daemon();
  std::filesystem::remove(dir_ / "state" / "homing.json");
  std::ofstream(dir_ / "state" / "homing.json")
      << json{{"offsets_counts", offsets}, {"how", "old"}, {"time", "t"}}.dump();
  testing::VirtualCell::Settings s;
  s.start = "{enable: at-start}";
  const Pose before = true_pose();
  ASSERT_TRUE(cell_->start_daemon(s).ok());
  const Reply h = request("home", {{"method", "absolute"}});
  ASSERT_TRUE(h.ok) << h.message;
  EXPECT_NEAR(h.result["pose"][0].get<double>(), 0.03, 1e-3);
  ASSERT_TRUE(holds_settled(5.0));
  expect_same(before, true_pose(), "after home --method absolute");
  // Finding 3: back to 0 0 0 lands at home, not 30 mm off.
  ASSERT_TRUE(request("move", {{"pose", {0, 0, 0, 0, 0, 0}}}).ok);
  ASSERT_TRUE(holds_settled(10.0));
  EXPECT_LT((true_pose().position - cell_->physics->truth().home.position).norm(), 1e-3);
}

TEST_F(Restart, HomeWithTheDrivesOwnHomingMakesThemReadTheModelAndMovesNothing) {
  start_daemon();  // on the reference platform at home
  ASSERT_TRUE(holds_settled(5.0));
  const int m = cell_->robot->num_cables();
  std::vector<std::uint32_t> homings;
  for (int i = 0; i < m; ++i) homings.push_back(cell_->robot->drive(i).homings());
  const Pose before = true_pose();
  const Reply h = request("home", {{"method", "drive"}});
  ASSERT_TRUE(h.ok) << h.message;
  run_until([] { return false; }, 0.3);  // the RT loop holds the new counts
  ASSERT_TRUE(holds_settled(5.0)) << daemon().status().dump();
  expect_same(before, true_pose(), "after home --method drive");
  for (int i = 0; i < m; ++i) {
    EXPECT_EQ(cell_->robot->drive(i).homings(), homings[static_cast<size_t>(i)] + 1) << i;
  }
  // The drives read the model's counts at home: the record's offsets are under a count.
  auto store = StateStore::open((dir_ / "state").string());
  ASSERT_TRUE(store.ok());
  auto rec = store->load_homing();
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  EXPECT_EQ(rec->method, "drive");
  for (double o : rec->offsets_counts) EXPECT_LE(std::abs(o), 0.5);
  // Out and back lands at home.
  ASSERT_TRUE(request("move", {{"pose", {0.03, 0, 0, 0, 0, 0}}}).ok);
  ASSERT_TRUE(holds_settled(10.0));
  ASSERT_TRUE(request("move", {{"pose", {0, 0, 0, 0, 0, 0}}}).ok);
  ASSERT_TRUE(holds_settled(10.0));
  EXPECT_LT((true_pose().position - before.position).norm(), 0.05e-3);
}

TEST_F(Restart, ADriveThatFailsItsHomingLeavesThePoseUntrustedAndNothingMoves) {
  start_daemon();
  ASSERT_TRUE(holds_settled(5.0));
  cell_->robot->drive(2).set_ignore_mode_switch(true);  // node 3 never enters homing mode
  const Pose before = true_pose();
  const Reply h = request("home", {{"method", "drive"}});
  ASSERT_FALSE(h.ok);
  EXPECT_EQ(h.code, "fault");
  EXPECT_NE(h.message.find("node 3"), std::string::npos) << h.message;
  run_until([] { return false; }, 0.5);
  expect_same(before, true_pose(), "after a failed drive homing");
  EXPECT_EQ(daemon().status()["state"], "holding");
  expect_holding_or_refusing("after a failed drive homing");
  EXPECT_FALSE(daemon().status()["pose"]["trusted"].get<bool>());
  // Disabled, the drives cannot home: enable first.
  cell_->robot->drive(2).set_ignore_mode_switch(false);
  ASSERT_TRUE(request("disable").ok);
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kDisabled; }, 2.0));
  const Reply d = request("home", {{"method", "drive"}});
  EXPECT_EQ(d.code, "invalid_state");
  EXPECT_NE(d.message.find("enable first"), std::string::npos) << d.message;
}

TEST_F(Restart, DrivesStayDisabledUntilEnableAndDisableHoldsNothing) {
  start_daemon();  // homed on the reference platform, record written
  ASSERT_TRUE(holds_settled(5.0));
  testing::VirtualCell::Settings s;
  s.start = "{enable: operator}";
  ASSERT_TRUE(cell_->start_daemon(s).ok());
  run_until([] { return false; }, 0.3);
  json st = daemon().status();
  EXPECT_EQ(st["state"], "disabled");
  EXPECT_FALSE(st["drives"]["enabled"].get<bool>());
  EXPECT_EQ(request("move", {{"pose", {0.01, 0, 0, 0, 0, 0}}}).code, "invalid_state");
  const Pose before = true_pose();
  ASSERT_TRUE(request("enable").ok);
  ASSERT_TRUE(holds_settled(5.0)) << daemon().status().dump();
  expect_same(before, true_pose(), "after enable");
  EXPECT_TRUE(daemon().status()["drives"]["enabled"].get<bool>());
  ASSERT_TRUE(request("disable").ok);
  ASSERT_TRUE(run_until([&] { return !daemon().status()["drives"]["enabled"].get<bool>(); }, 2.0));
  EXPECT_EQ(daemon().status()["state"], "disabled");
}

TEST_F(Restart, AFaultResetAtATiltedPoseHoldsWhereThePlatformStopped) {
  start_daemon();
  const auto poses = designed_poses();
  ASSERT_GE(poses.size(), 7u);
  ASSERT_TRUE(request("move", {{"pose", poses[6]}}).ok);
  ASSERT_TRUE(holds_settled(20.0));
  ASSERT_TRUE(request("stop").ok);
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kFault; }, 2.0));
  EXPECT_EQ(request("move", {{"pose", poses[0]}}).code, "fault");
  run_until([] { return false; }, 0.2);
  const Pose before = true_pose();
  ASSERT_TRUE(request("fault_reset").ok);
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kHolding; }, 5.0))
      << daemon().status().dump();
  run_until([] { return false; }, 0.3);
  expect_same(before, true_pose(), "after the fault reset");
  expect_holding_or_refusing("after the fault reset");
}

}  // namespace
}  // namespace cdpr::controller
