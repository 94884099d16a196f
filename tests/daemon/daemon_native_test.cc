// cdprd's supervisor and RT cycle composed with the virtual robot in ONE process, over the
// in-process virtual CAN bus with a manual clock and the laser over Modbus TCP on loopback: the
// daemon's logic tested in seconds (the same scenarios run across processes on vcan in
// tests/daemon/daemon_vcan_test.cc). The composition lives here, not in the daemon: the
// controller and the virtual robot only meet on the bus and the Modbus link, as on the robot.
//
// Truth: config/mini-measured.yaml with config/scenarios/mini-calibration.yaml's hidden effects
// (softer cables, encoder zero offsets, noise); the daemon starts from config/mini.yaml. The drives
// power on with the true platform at home (the reference platform).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <thread>

#include "alloc_counter.hpp"
#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/pose_design.hpp"
#include "cdpr/calibration/simulate.hpp"
#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/config.hpp"
#include "cdpr/config/robot_config.hpp"
#include "cdpr/controller/calibration_report.hpp"
#include "cdpr/controller/daemon.hpp"
#include "cdpr/controller/state_store.hpp"
#include "cdpr/modbus/laser_sensor.hpp"
#include "cdpr/modbus/register_map.hpp"
#include "cdpr/sim/can_robot.hpp"
#include "cdpr/sim/laser_slave.hpp"
#include "cdpr/sim/physics.hpp"
#include "cdpr/sim/scenario.hpp"
#include "cell_fixture.hpp"
#include "virtual_cell.hpp"

namespace cdpr::controller {
namespace {

using namespace std::chrono_literals;
using json = nlohmann::json;

class DaemonNative : public testing::CellTest {
 protected:
  explicit DaemonNative(
      testing::VirtualCell::HomeTensions home = testing::VirtualCell::HomeTensions::kPlanner)
      : CellTest("cdprd-native-", home) {}

  int calibrate() {
    auto id = cell_->calibrate();
    EXPECT_TRUE(id.ok()) << id.status().to_string();
    return id.ok() ? *id : 0;
  }
  // A short calibration: 12 poses, no mismatch locator.
  static testing::VirtualCell::Settings quick(const std::string& acceptance = "{mode: manual}") {
    testing::VirtualCell::Settings s;
    s.measuring =
        "{poses: 12, laser_samples: 3, laser_interval_s: 0.002, average_cycles: 25, "
        "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4}";
    s.identification = "{diagnose: false}";
    s.acceptance = acceptance;
    return s;
  }
  // One cycle's normal motion: the largest target change per cycle at the configured cable speed.
  double one_cycle_counts() {
    return daemon().status()["rt"]["one_cycle_motion_counts"].get<double>();
  }
};

// The shipped configuration's tension control (config/sim/cdprd.yaml), the virtual robot homed
// with the tensions it holds at home.
class DaemonNativeTensionControl : public DaemonNative {
 protected:
  DaemonNativeTensionControl() : DaemonNative(testing::VirtualCell::HomeTensions::kHeld) {}
};

// The full calibration of the virtual MINI with the shipped configuration's tension control on
// (config/sim/cdprd.yaml: the tension control in the null space, the poses designed 30 N inside
// the limits): it passes its gates, the acceptance is bumpless and the next move lands on target.
// The tension band at every cycle is asserted by daemon_tension_band_test; here its smallest
// clearance over the 25-pose sequence is printed. The scenario's softer cables are estimated
// (stiffness-per-cable) instead of found by the mismatch locator (76 s of the test's 81 on a
// loaded machine): the locator's rounds in the daemon are AGrossLaserReadingIsMeasuredAgain...'s.
TEST_F(DaemonNativeTensionControl, CalibratesMiniAcceptsBumplesslyAndTheNextMoveLandsOnTarget) {
  testing::VirtualCell::Settings shipped;
  shipped.measuring =
      "{poses: 25, laser_samples: 5, laser_interval_s: 0.002, average_cycles: 25, "
      "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4, tension_band: 3, "
      "design_tension_margin: 30}";
  shipped.identification =
      "{estimate: [anchors, offsets, laser-plane, stiffness-per-cable], diagnose: false}";
  shipped.extra = "tension_control: {gain: 20, max_rate: 0.02}\n";
  start_daemon(shipped);
  const double t0 = cell_->seconds();
  const auto wall0 = std::chrono::steady_clock::now();
  const Reply cal = request("calibrate");
  ASSERT_TRUE(cal.ok) << cal.message;
  const int id = cal.result["calibration"].get<int>();
  ASSERT_GT(id, 0);
  ASSERT_TRUE(run_until([&] { return daemon().state() != DaemonState::kHolding; }, 5.0));
  // The smallest distance of a measured tension to the band [f_min + margin, f_max - margin] at
  // any cycle of the measuring sequence (moves included).
  const double margin = cell_->config.motion.tension_margin;
  double clearance = std::numeric_limits<double>::infinity();
  const bool done = run_until(
      [&] {
        const DaemonState st = daemon().state();
        if (st == DaemonState::kMeasuring) {
          const RtSnapshot r = daemon().rt().snapshot();
          for (int i = 0; r.have_tensions && i < r.num_cables; ++i) {
            const CableModel& c = cell_->nominal.cables[static_cast<std::size_t>(i)];
            const double f = r.tensions[static_cast<std::size_t>(i)];
            clearance = std::min({clearance, f - (c.f_min + margin), (c.f_max - margin) - f});
          }
        }
        return st == DaemonState::kAwaitingAcceptance || st == DaemonState::kFault ||
               (st == DaemonState::kHolding &&
                daemon().status()["calibration"]["outcome"] != "measuring" &&
                daemon().status()["calibration"]["outcome"] != "identifying");
      },
      900.0);
  ASSERT_TRUE(done) << daemon().status().dump(2);
  std::printf("[daemon-native] calibration %d: %.1f s of robot time, %.1f s wall\n", id,
              cell_->seconds() - t0,
              std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count());
  std::printf("[daemon-native] smallest clearance to [f_min + %.0f, f_max - %.0f] N: %.1f N\n",
              margin, margin, clearance);
  const json st = daemon().status();
  ASSERT_EQ(st["calibration"]["outcome"], "awaiting_acceptance") << st.dump(2);
  // The report proposes anchors close to the truth.
  auto report = request("report");
  ASSERT_TRUE(report.ok) << report.message;
  const json& rep = report.result["report"];
  std::printf("[daemon-native] verdict: %s; gates passed: %d\n",
              rep["verdict"].get<std::string>().c_str(), rep["gates_passed"].get<bool>());
  std::printf("[daemon-native] fit: %s\n", rep["fit"].dump().c_str());
  EXPECT_TRUE(rep["gates_passed"].get<bool>()) << rep["gates"].dump(2);
  // The page: the daemon's decision first, then the calibration report's summary (verdict,
  // effects, key figures with the ISO box accuracy) before the first plot; files named
  // relative to the calibration's folder.
  auto page = request("report", {{"html", true}});
  ASSERT_TRUE(page.ok) << page.message;
  const std::string html = page.result["html"].get<std::string>();
  const std::size_t decision = html.find("<section id=\"cdprd-decision\">");
  const std::size_t verdict = html.find("id=\"verdict\"");
  const std::size_t figures = html.find("id=\"key-figures\"");
  const std::size_t first_plot = html.find("<svg");
  ASSERT_NE(decision, std::string::npos);
  EXPECT_LT(decision, verdict);
  EXPECT_LT(verdict, figures);
  EXPECT_LT(figures, first_plot);
  EXPECT_NE(html.find("over the ISO 9283 box"), std::string::npos);
  EXPECT_NE(html.find("recording <code>recording.csv</code> ("), std::string::npos);
  // The ISO 9283 section: an AP-like figure predicted at the five points, the bench's command.
  const json& iso = rep["iso9283"];
  std::printf("[daemon-native] ISO 9283 predicted: %s\n", iso["predicted"].dump().c_str());
  EXPECT_EQ(iso["predicted"]["points"], 5) << iso.dump(2);
  const std::size_t iso_section = html.find("<section id=\"iso9283\">");
  ASSERT_NE(iso_section, std::string::npos);
  EXPECT_GT(iso_section, decision);
  EXPECT_NE(html.find(kIso9283Command), std::string::npos);
  auto after =
      config::load_robot_config(daemon().store().calibration_dir(id) + "/model_after.yaml");
  ASSERT_TRUE(after.ok()) << after.status().to_string();
  const double before_rms =
      testing::VirtualCell::anchor_rms(cell_->nominal, cell_->physics->truth());
  const double after_rms = testing::VirtualCell::anchor_rms(*after, cell_->physics->truth());
  std::printf("[daemon-native] anchors RMS vs truth: %.3f mm before, %.3f mm after\n",
              before_rms * 1e3, after_rms * 1e3);
  EXPECT_LT(after_rms, 1e-3);
  EXPECT_LT(after_rms, before_rms);
  // Homed at the tensions it is held at home, the home-pose gauge holds (0.12 to 0.16 mm; homed
  // at the planner's 1x and held at 2x, the platform turned 1.3 mrad and the anchors 0.8 mm).
  EXPECT_LT(after_rms, 0.3e-3);
  // The nominal geometry is mm off the robot's, so at the tilted designed poses some cables hang
  // mm slack until the tension regulation takes it up: every measured row has each cable inside
  // the regulation's band [f_min - band, f_max + band] (up to the force noise).
  auto rec = recording::read_recording(daemon().store().calibration_dir(id) + "/recording.csv");
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  const double band = cell_->config.measuring.tension_band;
  for (const auto& row : rec->poses) {
    for (int i = 0; i < row.tensions.size(); ++i) {
      const CableModel& c = cell_->nominal.cables[static_cast<std::size_t>(i)];
      EXPECT_GT(row.tensions(i), c.f_min - band - 0.5)
          << "pose " << row.index << ", cable " << i + 1;
      EXPECT_LT(row.tensions(i), c.f_max + band + 0.5)
          << "pose " << row.index << ", cable " << i + 1;
    }
  }

  // Accept: the hot swap does not jump.
  const Reply acc = request("accept");
  ASSERT_TRUE(acc.ok) << acc.message;
  const int version = acc.result["version"].get<int>();
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kHolding; }, 30.0))
      << daemon().status().dump(2);
  EXPECT_EQ(daemon().status()["geometry_version"], version);
  const RtSnapshot snap = daemon().rt().snapshot();
  std::printf(
      "[daemon-native] hot swap: largest target step %.1f counts (one cycle of normal "
      "motion: %.1f counts)\n",
      snap.largest_reference_step, one_cycle_counts());
  EXPECT_LE(snap.largest_reference_step, one_cycle_counts());
  EXPECT_TRUE(cell_->saw_event("calibration", "outcome", "applied"));

  // A test move with the new geometry lands within 0.5 mm of its target in the sim.
  Pose target = cell_->nominal.home;
  target.position += Eigen::Vector3d(0.05, -0.04, 0.03);
  const Reply mv = request(
      "move",
      {{"pose", {target.position.x(), target.position.y(), target.position.z(), 0.0, 0.0, 0.0}}});
  ASSERT_TRUE(mv.ok) << mv.message;
  ASSERT_TRUE(run_until(
      [&] {
        const RtSnapshot s = daemon().rt().snapshot();
        return daemon().state() == DaemonState::kHolding && s.settled &&
               (s.pose().position - target.position).norm() < 1e-9;
      },
      30.0));
  const double error = (cell_->physics->state().pose.position - target.position).norm();
  std::printf("[daemon-native] test move: true position error %.3f mm\n", error * 1e3);
  EXPECT_LT(error, 0.5e-3);
}

// A laser reading 100 mm short at one pose (the beam on an object in front of the target: 2200
// sigmas of an averaged reading, 10 x the laser's other residuals) beside the scenario's softer
// cables: the locator names it a gross reading, the
// daemon measures that pose again, leaves the first row out and the calibration passes; the
// recording keeps both rows and the report names them.
TEST_F(DaemonNative, AGrossLaserReadingIsMeasuredAgainAndLeftOut) {
  start_daemon();
  constexpr int kPose = 7;  // 0-based row of the recording
  ASSERT_TRUE(request("calibrate").ok);
  auto done = [&] { return daemon().status()["calibration"]["pose"].get<int>(); };
  ASSERT_TRUE(run_until([&] { return done() >= kPose; }, 300.0)) << daemon().status().dump(2);
  cell_->laser_offset_m = -0.1;
  ASSERT_TRUE(run_until([&] { return done() >= kPose + 1; }, 60.0)) << daemon().status().dump(2);
  cell_->laser_offset_m = 0.0;
  ASSERT_TRUE(run_until(
      [&] {
        const DaemonState s = daemon().state();
        return s == DaemonState::kAwaitingAcceptance || s == DaemonState::kFault ||
               (s == DaemonState::kHolding &&
                daemon().status()["calibration"]["outcome"] != "measuring" &&
                daemon().status()["calibration"]["outcome"] != "identifying");
      },
      900.0));
  ASSERT_EQ(daemon().state(), DaemonState::kAwaitingAcceptance) << daemon().status().dump(2);
  const auto rep = request("report");
  ASSERT_TRUE(rep.ok) << rep.message;
  const json& r = rep.result["report"];
  ASSERT_EQ(r["poses_measured_again"].size(), 1u) << r["verdict"];
  const json& again = r["poses_measured_again"][0];
  EXPECT_EQ(again["pose"], kPose + 1);
  const std::string reading = again["reading"].get<std::string>();
  const std::string where = "laser distance 1 of the 8th pose: off by ";
  ASSERT_EQ(reading.rfind(where, 0), 0u) << reading;
  EXPECT_NEAR(std::stod(reading.substr(where.size())), 100.0, 5.0) << reading;  // mm
  EXPECT_TRUE(r["gates_passed"].get<bool>()) << r["gates"].dump(2);
  // The recording keeps the first row (one row more than the poses identified).
  const int id = daemon().status()["calibration"]["id"].get<int>();
  auto rec = recording::read_recording(daemon().store().calibration_dir(id) + "/recording.csv");
  ASSERT_TRUE(rec.ok()) << rec.status().to_string();
  const int rows = static_cast<int>(rec->poses.size());
  EXPECT_EQ(again["measured_again_as"], rows);
  EXPECT_EQ(r["poses"], rows - 1);
  EXPECT_NEAR(
      rec->poses[kPose].lasers(0) - rec->poses[static_cast<std::size_t>(rows - 1)].lasers(0), -0.1,
      1e-3);
  auto page = request("report", {{"html", true}});
  ASSERT_TRUE(page.ok) << page.message;
  EXPECT_NE(page.result["html"].get<std::string>().find("Pose 8 was measured again as pose " +
                                                        std::to_string(rows)),
            std::string::npos);
  auto after =
      config::load_robot_config(daemon().store().calibration_dir(id) + "/model_after.yaml");
  ASSERT_TRUE(after.ok()) << after.status().to_string();
  EXPECT_LT(testing::VirtualCell::anchor_rms(*after, cell_->physics->truth()), 1e-3);
}

TEST_F(DaemonNative, RtCycleDoesNotAllocateWhileHoldingOrMoving) {
  start_daemon();
  Pose target = cell_->nominal.home;
  target.position.z() += 0.02;
  ASSERT_TRUE(request("move", {{"pose", {0.0, 0.0, target.position.z(), 0.0, 0.0, 0.0}}}).ok);
  // The robot's steps allocate (it stands in for devices); count only the daemon's cycle.
  std::uint64_t allocations = 0;
  for (int c = 0; c < 300; ++c) {
    {
      test::AllocationCounter count;
      daemon().cycle(cell_->clock.now());
      allocations += count.allocations();
    }
    const can::Timestamp next = cell_->clock.now() + cell_->network.sync_period;
    while (cell_->clock.now() < next) cell_->idle();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_GT(daemon().rt().snapshot().largest_move_step, 0.0) << "the platform did not move";
}

// Issue 39 (6): 10 s without the bus (every transmission fails) is one "transmit failed" line
// when it starts and one with the count when it is over, not one per frame (16,136 lines in 45 s).
TEST_F(DaemonNative, TransmitFailuresWhileTheBusIsGoneAreTwoLogLinesWithACount) {
  start_daemon();
  cell_->master_endpoint().set_transmit_failing(true);
  (void)run_until([] { return false; }, 10.0);
  cell_->master_endpoint().set_transmit_failing(false);
  (void)run_until([] { return false; }, 3.0);
  EXPECT_EQ(cell_->count_events("log", "message", "transmit failed"), 2);
  EXPECT_EQ(cell_->count_events("log", "message", "transmit failed ended: "), 1);
  EXPECT_GT(daemon().master().stats().tx_failures, 1000u);
}

TEST_F(DaemonNative, AbortHoldsTheRobotAndKeepsTheGeometry) {
  start_daemon();
  const int before = daemon().status()["geometry_version"].get<int>();
  ASSERT_TRUE(request("calibrate").ok);
  ASSERT_TRUE(
      run_until([&] { return daemon().status()["calibration"]["pose"].get<int>() >= 3; }, 120.0));
  const Reply ab = request("abort");
  ASSERT_TRUE(ab.ok) << ab.message;
  ASSERT_TRUE(run_until(
      [&] { return daemon().state() == DaemonState::kHolding && daemon().rt().snapshot().settled; },
      30.0))
      << daemon().status().dump(2);
  const json st = daemon().status();
  EXPECT_EQ(st["calibration"]["outcome"], "aborted");
  EXPECT_EQ(st["geometry_version"], before);
  EXPECT_TRUE(st["fault"].is_null());
  // The partial recording is kept and readable.
  const std::string rec =
      daemon().store().calibration_dir(st["calibration"]["id"].get<int>()) + "/recording.csv";
  auto r = recording::read_recording(rec);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_GE(r->poses.size(), 3u);
}

TEST_F(DaemonNative, RejectKeepsTheGeometryRestartKeepsTheAcceptedOneAndRollbackIsBumpless) {
  start_daemon(quick());
  const int v1 = daemon().status()["geometry_version"].get<int>();
  ASSERT_GT(calibrate(), 0);
  // The result awaits the operator with the platform back at the first (home) pose, not at the
  // last designed one near the tension limits, where a hot swap might find no feasible tensions.
  EXPECT_LT((daemon().rt().snapshot().pose().position - cell_->nominal.home.position).norm(), 1e-9);
  ASSERT_TRUE(request("reject").ok);
  run_until([&] { return daemon().state() == DaemonState::kHolding; }, 5.0);
  EXPECT_EQ(daemon().status()["geometry_version"], v1);
  EXPECT_TRUE(cell_->saw_event("calibration", "outcome", "rejected"));

  ASSERT_GT(calibrate(), 0);
  const Reply acc = request("accept");
  ASSERT_TRUE(acc.ok) << acc.message;
  const int v2 = acc.result["version"].get<int>();
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kHolding; }, 30.0));
  ASSERT_EQ(daemon().status()["geometry_version"], v2);
  // The new version's metadata carries what the calibration reported for the in-service monitor
  // (its report's figures): the predicted position error and the model's uncertainty.
  const Reply show = request("geometry_show", {{"version", v2}});
  ASSERT_TRUE(show.ok) << show.message;
  const json& figures = show.result["meta"]["monitoring"];
  const Reply report = request("report");
  ASSERT_TRUE(report.ok) << report.message;
  EXPECT_EQ(figures, report.result["report"]["monitoring"]);
  for (const char* key : {"predicted_position_rms_m", "model_length_m", "model_force_n"}) {
    ASSERT_TRUE(figures[key].is_number()) << key << ": " << figures.dump();
    EXPECT_GT(figures[key].get<double>(), 0.0) << key;
  }
  EXPECT_EQ(figures["predicted_position_rms_m"],
            report.result["report"]["predicted_position_rms_m"]);
  std::printf("[daemon-native] accepted geometry's monitoring figures: %s\n",
              figures.dump().c_str());

  // Restart: a new daemon on the same state directory comes back with version v2, where the
  // platform is, without a jump.
  const RtSnapshot old = daemon().rt().snapshot();
  start_daemon(quick());
  EXPECT_EQ(daemon().status()["geometry_version"], v2);
  const RtSnapshot now = daemon().rt().snapshot();
  EXPECT_LT((now.pose().position - old.pose().position).norm(), 0.2e-3);
  EXPECT_LE(now.largest_reference_step, one_cycle_counts());

  // Rollback to v1: bumpless too, and recorded in the history.
  const Reply rb = request("geometry_rollback", {{"version", v1}});
  ASSERT_TRUE(rb.ok) << rb.message;
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kHolding; }, 30.0));
  EXPECT_EQ(daemon().status()["geometry_version"], v1);
  EXPECT_LE(daemon().rt().snapshot().largest_reference_step, one_cycle_counts());
  const Reply h = request("geometry_history");
  ASSERT_TRUE(h.ok);
  EXPECT_EQ(h.result["activations"].back()["version"], v1);
  const Reply diff = request("geometry_diff", {{"from", v1}, {"to", v2}});
  ASSERT_TRUE(diff.ok) << diff.message;
  EXPECT_GT(diff.result["largest_change_m"].get<double>(), 0.0);
}

TEST_F(DaemonNative, ACalibrationStartsAtOnceAfterThePreviousOneWasRejected) {
  // The worker thread publishes its events through the sink: a slow sink holds the worker just
  // after it announced the outcome, as a preempted thread would on a loaded PC. A script that
  // rejects and calibrates again at once must not be told a calibration still runs.
  start_daemon(quick());
  std::atomic<int> slowed{0};
  daemon().set_event_sink([&slowed](const json& e) {
    if (e["event"] == "calibration" && e["data"].value("outcome", "") == "awaiting_acceptance") {
      ++slowed;
      std::this_thread::sleep_for(200ms);
    }
  });
  ASSERT_GT(calibrate(), 0);
  ASSERT_TRUE(request("reject").ok);
  EXPECT_EQ(daemon().state(), DaemonState::kHolding);
  const Reply again = request("calibrate");
  EXPECT_TRUE(again.ok) << again.code << ": " << again.message;
  EXPECT_EQ(slowed.load(), 1);
}

TEST_F(DaemonNative, AutoAcceptanceAppliesACalibrationWhoseGatesPassAndWaitsOtherwise) {
  // Gates an honest 12-pose calibration passes: applied without an operator.
  start_daemon(quick("{mode: auto, min_fit_p_value: 0, max_predicted_position_error_m: 1}"));
  ASSERT_TRUE(request("calibrate").ok);
  ASSERT_TRUE(run_until(
      [&] {
        return daemon().state() == DaemonState::kHolding &&
               daemon().status()["geometry_version"] == 2;
      },
      600.0))
      << daemon().status().dump(2);
  EXPECT_TRUE(cell_->saw_event("calibration", "outcome", "applied"));
  EXPECT_LE(daemon().rt().snapshot().largest_reference_step, one_cycle_counts());

  // A gate that fails (the anchors move by centimetres, the limit is 1 mm): it waits.
  start_daemon(quick("{mode: auto, min_fit_p_value: 0, max_anchor_change_m: 0.000001}"));
  ASSERT_GT(calibrate(), 0);
  const json st = daemon().status();
  EXPECT_EQ(st["state"], "awaiting_acceptance");
  EXPECT_FALSE(st["calibration"]["gates_passed"].get<bool>());
  EXPECT_EQ(st["geometry_version"], 2);
}

TEST_F(DaemonNative, AnOperatorQuickStopFaultsAndFaultResetHoldsWhereThePlatformStopped) {
  start_daemon();
  ASSERT_TRUE(request("stop").ok);
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kFault; }, 2.0));
  const json st = daemon().status();
  EXPECT_EQ(st["fault"]["fault"], "quick_stop");
  EXPECT_EQ(request("calibrate").code, "fault");
  ASSERT_TRUE(request("fault_reset").ok);
  ASSERT_TRUE(run_until([&] { return daemon().state() == DaemonState::kHolding; }, 10.0))
      << daemon().status().dump(2);
  EXPECT_LE(daemon().rt().snapshot().largest_reference_step, one_cycle_counts());
}

TEST_F(DaemonNative, AFirstStartKilledBeforeItActivatedTheNominalGeometryIsCompletedAtTheNext) {
  // What a first start leaves when it is killed between writing version 1 and activating it.
  {
    auto store = StateStore::open((dir_ / "state").string());
    ASSERT_TRUE(store.ok());
    ASSERT_TRUE(store->add_geometry(cell_->nominal, {{"source", "nominal"}}).ok());
    ASSERT_EQ(store->active_version().status().code(), ErrorCode::kNotFound);
  }
  start_daemon();
  EXPECT_EQ(daemon().status()["geometry_version"], 1);
  auto active = daemon().store().active_version();
  ASSERT_TRUE(active.ok());
  EXPECT_EQ(*active, 1);
}

// The poses cdprd designs keep measuring.design_tension_margin, and at least
// motion.tension_margin, from the cable limits (the design narrows the limits, so none is dropped
// afterwards). Tilted up to 25 degrees without a margin, the design takes poses at the workspace
// edge, within the margin of a limit.
TEST_F(DaemonNative, DesignedPosesKeepTheDesignAndTheMotionTensionMargin) {
  const Result<RobotModel> narrowed = narrow_tension_limits(cell_->nominal, 30.0);
  ASSERT_TRUE(narrowed.ok()) << narrowed.status().to_string();
  const double f_ref = default_reference_tension(cell_->nominal);
  // Poses of a dry run whose tensions keep the margin, of how many.
  auto keeping_margin = [&](const std::string& design_margin, const std::string& motion) {
    testing::VirtualCell::Settings s;
    s.measuring = "{poses: 25, max_angle: 0.4363, design_tension_margin: " + design_margin + "}";
    s.motion = motion;
    start_daemon(s);
    const Reply dry = request("calibrate", {{"dry_run", true}});
    EXPECT_TRUE(dry.ok) << dry.message;
    std::pair<int, int> n{0, 0};
    if (!dry.ok) return n;
    for (const auto& p : dry.result["poses"]) {
      Pose pose;
      pose.position = Eigen::Vector3d(p[0].get<double>(), p[1].get<double>(), p[2].get<double>());
      pose.rpy = Eigen::Vector3d(p[3].get<double>(), p[4].get<double>(), p[5].get<double>());
      n.first += simple_tension_distribution(*narrowed, pose, f_ref).ok() ? 1 : 0;
      ++n.second;
    }
    return n;
  };
  const auto plain = keeping_margin("0", "{tension_margin: 0}");
  EXPECT_LT(plain.first, plain.second);
  const auto kept_for_motion = keeping_margin("0", "{tension_margin: 30}");
  EXPECT_EQ(kept_for_motion.second, 25);
  EXPECT_EQ(kept_for_motion.first, kept_for_motion.second);
  const auto kept_for_design = keeping_margin("30", "{tension_margin: 0}");
  EXPECT_EQ(kept_for_design.second, 25);
  EXPECT_EQ(kept_for_design.first, kept_for_design.second);
}

TEST_F(DaemonNative, RequestsWithBadArgumentsAreNamedErrors) {
  start_daemon();
  EXPECT_EQ(request("nonsense").code, "unknown_command");
  EXPECT_EQ(request("accept").code, "invalid_state");
  EXPECT_EQ(request("geometry_rollback", {{"version", "x"}}).code, "bad_request");
  EXPECT_EQ(request("geometry_rollback", {{"version", 99}}).code, "not_found");
  EXPECT_EQ(request("calibrate",
                    {{"poses_csv", "# units: SI\npose,x,y,z,roll,pitch,yaw\n0,5,0,0,0,0,0\n"}})
                .code,
            "bad_request");
  const Reply dry = request("calibrate", {{"dry_run", true}});
  ASSERT_TRUE(dry.ok) << dry.message;
  EXPECT_EQ(dry.result["poses"].size(), 25u);
  EXPECT_EQ(daemon().state(), DaemonState::kHolding);
}

// Issue 39 (8): the laser over serial Modbus RTU through cdprd: the virtual robot serves RTU on a
// pseudo-terminal, cdprd's configuration names a laser file (transport rtu, the pty as device),
// and the driver built from it (as cdprd's main builds it) reads the true distance into the
// daemon, at home and after a move.
TEST(DaemonLaserRtu, TheDaemonReadsTheLaserOverModbusRtuFromItsConfiguration) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("cdprd-rtu-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  {
    auto c = testing::VirtualCell::create(CDPR_SOURCE_DIR, dir, 7,
                                          testing::VirtualCell::LaserLink::kRtuThroughConfig);
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    testing::VirtualCell& cell = **c;
    EXPECT_NE(cell.slave->describe().find("RTU"), std::string::npos) << cell.slave->describe();
    ASSERT_TRUE(cell.start_daemon().ok());
    EXPECT_EQ(cell.config.laser, (dir / "laser.yaml").string());
    // The daemon's reading follows the true distance (noise 0.1 mm) within a few polls.
    const auto reads_truth = [&] {
      const double truth = cell.physics->state().lasers.front().true_distance;
      for (int i = 0; i < 500; ++i) {  // up to 5 s of wall time
        const json l = cell.daemon->status()["laser_m"];
        if (l.is_number() && std::abs(l.get<double>() - truth) < 1e-3) return true;
        std::this_thread::sleep_for(10ms);
      }
      return false;
    };
    ASSERT_TRUE(reads_truth()) << cell.daemon->status()["laser_m"].dump();
    const double at_home = cell.physics->state().lasers.front().true_distance;
    Pose target = cell.nominal.home;
    target.position.z() += 0.03;
    ASSERT_TRUE(cell.request("move", {{"pose",
                                       {target.position.x(), target.position.y(),
                                        target.position.z(), 0.0, 0.0, 0.0}}})
                    .ok);
    ASSERT_TRUE(cell.run_until(
        [&] {
          const RtSnapshot s = cell.daemon->rt().snapshot();
          return cell.daemon->state() == DaemonState::kHolding && s.settled &&
                 (s.pose().position - target.position).norm() < 1e-9;
        },
        30.0));
    EXPECT_GT(std::abs(cell.physics->state().lasers.front().true_distance - at_home), 5e-3);
    EXPECT_TRUE(reads_truth()) << cell.daemon->status()["laser_m"].dump();
    EXPECT_GT(cell.slave->answered(), 0u);
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace cdpr::controller
