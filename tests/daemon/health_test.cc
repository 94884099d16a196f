// In-service monitoring through the daemon (controller/src/daemon_health.cc), against the
// in-process virtual cell (virtual_cell.hpp): the virtual MINI's true frame anchors are those of
// config/mini-measured.yaml while the daemon holds config/mini.yaml's (about 14.5 mm apart), so a
// monitor of the nominal geometry must see its readings leave the model. Robot time is the
// cell's manual clock.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "cell_fixture.hpp"

namespace cdpr::controller {
namespace {

using json = nlohmann::json;

class DaemonHealth : public testing::CellTest {
 protected:
  DaemonHealth() : CellTest("cdprd-health-") {}
  // `monitoring` (when enabled): the monitoring settings' keys, with their leading comma.
  void start(bool enabled, const std::string& monitoring =
                               ", assess_period_s: 2, reference_s: 4, move_speed_m_s: 1.0") {
    testing::VirtualCell::Settings s;
    if (enabled) s.extra = "monitoring: {enabled: true, period_s: 0.2" + monitoring + "}\n";
    start_daemon(s);
    ASSERT_TRUE(holds_settled(10.0));
    home_ = daemon().rt().snapshot().pose();
  }
  // Moves to home + (dx, dy, dz) and waits until it holds settled again.
  void visit(double dx, double dy, double dz) {
    const Pose& h = home_;
    const Reply r = request(
        "move",
        {{"pose", {h.position.x() + dx, h.position.y() + dy, h.position.z() + dz, 0.0, 0.0, 0.0}}});
    ASSERT_TRUE(r.ok) << r.message;
    ASSERT_TRUE(run_until([&] { return daemon().rt().snapshot().mode == RtMode::kMoving; }, 5.0));
    ASSERT_TRUE(holds_settled(20.0));
    // Held there for a few samples.
    const std::int64_t t0 = daemon().rt().snapshot().now_ns;
    ASSERT_TRUE(
        run_until([&] { return daemon().rt().snapshot().now_ns - t0 > 2'000'000'000; }, 5.0));
  }
  // The health reply's result.
  json health() {
    const Reply r = request("health");
    EXPECT_TRUE(r.ok) << r.message;
    return r.result;
  }
  Pose home_;
};

// The monitor of a geometry takes its model uncertainty and acceptance figure from the metadata
// the accept wrote (calibration_report.hpp monitoring_figures), else from the config.
class DaemonHealthFigures : public DaemonHealth {
 protected:
  static constexpr double kConfigLength = 3e-4, kConfigForce = 1.5, kConfigAcceptance = 5e-5;
  // Starts the daemon on a state directory whose active version 2 is the nominal robot with
  // `meta` (none: version 1, the nominal geometry, is the active one) and returns the health
  // reply's figures once the monitor has a sample.
  json figures(const json* meta, const std::string& settings = "") {
    if (meta != nullptr) {
      auto store = StateStore::open((dir_ / "state").string());
      EXPECT_TRUE(store.ok());
      EXPECT_TRUE(store->add_geometry(cell_->nominal, {{"source", "nominal"}}).ok());
      EXPECT_EQ(*store->add_geometry(cell_->nominal, *meta), 2);
      EXPECT_TRUE(store->activate(2, {{"why", "test"}}).ok());
    }
    testing::VirtualCell::Settings s;
    s.extra = "monitoring: {enabled: true, period_s: 0.2, reference_s: 0, model_length_m: " +
              std::to_string(kConfigLength) + ", model_force_n: " + std::to_string(kConfigForce) +
              ", acceptance_position_m: " + std::to_string(kConfigAcceptance) + settings + "}\n";
    start_daemon(s);
    EXPECT_TRUE(holds_settled(10.0));
    EXPECT_EQ(daemon().status()["geometry_version"], meta != nullptr ? 2 : 1);
    json h;
    EXPECT_TRUE(run_until(
        [&] {
          const Reply r = request("health");
          h = r.result;
          return r.ok && h.value("samples", 0) > 0;
        },
        5.0))
        << h.dump(2);
    EXPECT_DOUBLE_EQ(h["position_rms_acceptance_m"].get<double>(),
                     h["figures"]["acceptance_position_m"]["value"].get<double>());
    return h["figures"];
  }
  void expect_config(const json& f, const std::string& source = "config") {
    EXPECT_EQ(f["model_length_m"]["source"], source) << f.dump(2);
    EXPECT_DOUBLE_EQ(f["model_length_m"]["value"].get<double>(), kConfigLength);
    EXPECT_EQ(f["model_force_n"]["source"], source);
    EXPECT_DOUBLE_EQ(f["model_force_n"]["value"].get<double>(), kConfigForce);
    EXPECT_EQ(f["acceptance_position_m"]["source"], source);
    EXPECT_DOUBLE_EQ(f["acceptance_position_m"]["value"].get<double>(), kConfigAcceptance);
  }
  const json calibrated_ = {{"source", "calibration"},
                            {"calibration", 4},
                            {"parent", 1},
                            {"monitoring",
                             {{"predicted_position_rms_m", 2.9e-5},
                              {"model_length_m", 2.2e-4},
                              {"model_force_n", 0.07}}}};
};

TEST_F(DaemonHealthFigures, AnAcceptedCalibrationsGeometryIsMonitoredWithItsOwnFigures) {
  const json f = figures(&calibrated_);
  const json& stated = calibrated_["monitoring"];
  EXPECT_EQ(f["model_length_m"]["source"], "calibration 4") << f.dump(2);
  EXPECT_DOUBLE_EQ(f["model_length_m"]["value"].get<double>(), stated["model_length_m"]);
  EXPECT_EQ(f["model_force_n"]["source"], "calibration 4");
  EXPECT_DOUBLE_EQ(f["model_force_n"]["value"].get<double>(), stated["model_force_n"]);
  EXPECT_EQ(f["acceptance_position_m"]["source"], "calibration 4");
  EXPECT_DOUBLE_EQ(f["acceptance_position_m"]["value"].get<double>(),
                   stated["predicted_position_rms_m"]);
}

TEST_F(DaemonHealthFigures, AnOlderStateFileWithoutTheFiguresLoadsWithTheConfigs) {
  json older = calibrated_;
  older.erase("monitoring");
  expect_config(figures(&older));
}

TEST_F(DaemonHealthFigures, TheNominalGeometryIsMonitoredWithTheConfigs) {
  expect_config(figures(nullptr));
}

TEST_F(DaemonHealthFigures, TheConfigOverridesTheCalibrationWhenItSaysSo) {
  expect_config(figures(&calibrated_, ", override_calibration: true"),
                "config (monitoring.override_calibration)");
}

TEST_F(DaemonHealth, IsOffUnlessTheConfigTurnsItOn) {
  start(false);
  const Reply r = request("health");
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_EQ(r.result["enabled"], false);
  EXPECT_NE(r.result["message"].get<std::string>().find("monitoring.enabled"), std::string::npos);
}

TEST_F(DaemonHealth, SamplesWhileHoldingAndSeesAWrongGeometryWithoutMovingTheRobot) {
  start(true);
  const double d = 0.06;
  for (int round = 0; round < 2; ++round) {
    visit(d, 0, 0);
    visit(0, d, 0);
    visit(-d, 0, d);
    visit(0, -d, -d);
    visit(0, 0, 0);
  }
  const Pose before = daemon().rt().snapshot().pose();
  const Reply r = request("health");
  ASSERT_TRUE(r.ok) << r.message;
  const json& h = r.result;
  EXPECT_EQ(h["enabled"], true);
  EXPECT_GT(h["samples"].get<int>(), 50) << h.dump(2);
  // Moves slower than move_speed_m_s are sampled too (the virtual robot is quasi-static).
  EXPECT_GT(h["samples_moving"].get<int>(), 0) << h.dump(2);
  EXPECT_LT(h["samples_moving"].get<int>(), h["samples"].get<int>());
  EXPECT_FALSE(h["rows"].empty());
  // The nominal anchors are about 14.5 mm off, the stated model uncertainty 0.1 mm: the reference
  // phase finds the model's own error beyond it and judges the model as it is.
  EXPECT_TRUE(h["referenced"].get<bool>());
  EXPECT_FALSE(h["reference_consistent"].get<bool>());
  // The detectors fire and an event says so.
  EXPECT_GT(h["alarms"].get<int>(), 0) << h["text"].get<std::string>();
  EXPECT_EQ(cell_->count_events("health", "alarm", ""), 1);  // once per geometry
  // The assessment names a moved pulley (the nominal anchors are all off; one candidate at a
  // time) and the predicted position error grew past the alert: the change event carries it.
  EXPECT_TRUE(h["changed"].get<bool>());
  EXPECT_EQ(h["effects"][0]["id"], "frame_anchor");
  EXPECT_GT(h["position_rms_now_m"].get<double>(), 1e-3);
  EXPECT_EQ(cell_->count_events("health", "text", "looks like"), 1);
  EXPECT_FALSE(h["text"].get<std::string>().empty());
  std::printf("[health] %s\n", h["text"].get<std::string>().c_str());
  // Asking moves nothing.
  EXPECT_EQ(daemon().rt().snapshot().pose().vector(), before.vector());
  EXPECT_EQ(daemon().state(), DaemonState::kHolding);
}

// The virtual MINI carries a laser (config/mini.yaml `lasers`, read over Modbus by the driver's
// poll thread): the samples at settled holds carry its reading, a row of their own.
// (A generous age bound: the laser's poll thread runs in wall time, and a loaded machine may
// leave it unscheduled for longer than the shipped 0.25 s.)
TEST_F(DaemonHealth, SamplesTheLaserAtSettledHolds) {
  start(true, ", reference_s: 0, laser_max_age_s: 30");
  visit(0.05, 0, 0);
  visit(0, 0, 0);
  const json h = health();
  EXPECT_GT(h["laser_samples"].get<int>(), 0) << h.dump(2);
  // Only a sample right after a hold settled can precede the first reading after it.
  EXPECT_LT(h["laser_skipped"].get<int>(), h["laser_samples"].get<int>()) << h.dump(2);
  bool laser_row = false;
  for (const json& r : h["rows"]) laser_row = laser_row || r["name"] == "laser 1";
  EXPECT_TRUE(laser_row) << h["rows"].dump(2);
}

// A reading from before the hold settled (the poll thread stopped) or one that failed (no
// target) is not the platform's distance now: the sample goes without it, counted.
TEST_F(DaemonHealth, SkipsAStaleOrFailedLaserReading) {
  start(true, ", reference_s: 0, laser_max_age_s: 30");
  visit(0, 0, 0.03);
  const json before = health();
  cell_->laser_status = sim::LaserStatus::kNoTarget;
  visit(0, 0, 0);
  const json failed = health();
  EXPECT_EQ(failed["laser_samples"], before["laser_samples"]) << failed.dump(2);
  const int skipped = failed["laser_skipped"].get<int>() - before["laser_skipped"].get<int>();
  EXPECT_GE(skipped, 5) << failed.dump(2);  // the visit holds 2 s at 0.2 s per sample
  cell_->laser_status.reset();
  cell_->laser->stop();
  visit(0, 0, 0.03);  // the newest reading is from before this hold
  const json stale = health();
  EXPECT_EQ(stale["laser_samples"], before["laser_samples"]) << stale.dump(2);
  EXPECT_GE(stale["laser_skipped"].get<int>() - failed["laser_skipped"].get<int>(), 5);
  EXPECT_GT(stale["samples"].get<int>(), failed["samples"].get<int>());  // sampled without it
}

// A sample during a move is used only while the drives follow their targets within
// max_following_m: the virtual drives follow a cycle late, a following error of the cable speed
// times the delay.
TEST_F(DaemonHealth, SamplesMovesOnlyBelowTheFollowingErrorBound) {
  start(true, ", reference_s: 0, move_speed_m_s: 1.0, max_following_m: 1e-9");
  visit(0.06, 0, 0);
  visit(0, 0, 0);
  const json tight = health();
  EXPECT_EQ(tight["samples_moving"], 0) << tight.dump(2);
  EXPECT_GT(tight["moving_skipped_following"].get<int>(), 0) << tight.dump(2);
  EXPECT_GT(tight["samples"].get<int>(), 0);  // the holds are sampled

  start(true, ", reference_s: 0, move_speed_m_s: 1.0, max_following_m: 0.05");
  visit(0.06, 0, 0);
  visit(0, 0, 0);
  const json loose = health();
  EXPECT_GT(loose["samples_moving"].get<int>(), 0) << loose.dump(2);
  EXPECT_EQ(loose["moving_skipped_following"], 0) << loose.dump(2);
}

}  // namespace
}  // namespace cdpr::controller
