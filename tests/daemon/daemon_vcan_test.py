#!/usr/bin/env python3
"""cdprd end to end on a kernel CAN bus: cdpr-sim, cdprd and cdprctl as separate processes.

Run through tests/vcan/vcan-run (native vcan, or user-mode-linux with a relaxed 20 ms SYNC):

    daemon_vcan_test.py CDPRD CDPRCTL CDPR_SIM SOURCE_DIR WORK_DIR

The virtual robot (truth: config/mini-measured.yaml with config/scenarios/mini-calibration.yaml's
hidden effects) serves its drives and force node on vcan0 and its laser over Modbus TCP on
loopback; cdprd starts from config/mini.yaml. Checked, in this order, all through cdprctl:
  1. abort mid-sequence holds the robot and keeps the geometry; the partial recording is readable;
  2. a full calibration (`calibrate --wait`), accepted: anchors within 1 mm RMS of the truth
     (cdpr-sim --evaluate), the hot swap's largest target step within one cycle of normal motion;
  3. a test move after the swap lands within 0.5 mm of its target on the true robot (SIGUSR1);
  4. a restart of cdprd comes back with the accepted geometry, holding;
  5. a second calibration, rejected, keeps the accepted geometry;
  6. rollback to version 1 makes it active again (bumpless) and is in the history.
"""
import os
import subprocess
import sys
import time

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from vcan_harness import Cell  # noqa: E402

cell = Cell(port_base=16020)
ctl, ctl_json, check, wait_for = cell.ctl, cell.ctl_json, cell.check, cell.wait_for
holding, WORK = cell.holding, cell.work


def scenario():
    cell.start_sim()
    cell.start_daemon()
    s = ctl_json("status")
    check(s["state"] == "holding" and s["geometry_version"] == 1,
          f"cdprd holds with the nominal geometry (state {s['state']}, version {s['geometry_version']})")

    # 1. Abort mid-sequence.
    rc, out, err = cell.calibrate()
    check(rc == 0, f"calibrate starts ({out.strip()}{err.strip()})")
    wait_for(lambda: ctl_json("status")["calibration"]["pose"] >= 2, 180, "two poses measured")
    rc, out, err = ctl("abort")
    check(rc == 0, "abort accepted")
    wait_for(lambda: holding(1), 60, "holding after the abort")
    s = ctl_json("status")
    check(s["calibration"]["outcome"] == "aborted" and s["geometry_version"] == 1 and s["fault"] is None,
          f"abort: outcome {s['calibration']['outcome']}, geometry {s['geometry_version']}, no fault")
    rec = f"{WORK}/state/calibrations/{s['calibration']['id']:06d}/recording.csv"
    rows = [l for l in open(rec) if l[:1].isdigit()]
    check(len(rows) >= 2, f"the partial recording keeps {len(rows)} measured poses")

    # 2. A full calibration, accepted.
    t0 = time.time()
    rc, out, err = ctl("--timeout", "1500", "calibrate", "--wait", timeout=1600)
    print(out, err)
    check(rc == 0, f"calibrate --wait exits 0 (got {rc}) in {time.time() - t0:.0f} s")
    accepted = ctl_json("accept")
    v2 = accepted["version"]
    check(v2 == 2, f"accept: the calibration becomes geometry version {v2}")
    wait_for(lambda: holding(v2), 60, f"holding with geometry version {v2}")
    s = ctl_json("status")
    cal = ctl_json("report")["calibration"]
    ev = subprocess.run([cell.sim_bin, *cell.sim_args(), "--evaluate",
                         f"{WORK}/state/calibrations/{cal:06d}/model_after.yaml"],
                        capture_output=True, text=True)
    print(ev.stdout)
    anchor_rms_mm = float(ev.stdout.splitlines()[1].split()[1])
    check(anchor_rms_mm <= 1.0, f"identified anchors {anchor_rms_mm:.3f} mm RMS from the truth (<= 1 mm)")
    step, bound = s["rt"]["largest_reference_step_counts"], s["rt"]["one_cycle_motion_counts"]
    check(step <= bound, f"hot swap: largest target step {step:.0f} counts <= one cycle of normal motion {bound:.0f}")

    # 3. A test move lands on its target on the true robot.
    target = [0.05, -0.04, 0.03]
    rc, out, err = ctl("move", *map(str, target))
    check(rc == 0, f"move accepted ({err.strip()})")
    wait_for(lambda: holding(v2) and abs(ctl_json("status")["rt"]["commanded_pose"][0] - target[0]) < 1e-9,
             60, "holding at the move's target")
    p = cell.true_pose()
    err_mm = 1e3 * sum((a - b) ** 2 for a, b in zip(p[:3], target)) ** 0.5
    check(err_mm <= 0.5, f"test move: the true platform is {err_mm:.3f} mm from the target (<= 0.5 mm)")

    # 4. Restart: back with the accepted geometry.
    cell.stop_daemon()
    cell.start_daemon()
    wait_for(lambda: holding(v2), 60, f"holding with version {v2} after the restart")
    s = ctl_json("status")
    check(s["geometry_version"] == v2, f"restart: geometry version {s['geometry_version']} active")

    # 5. A second calibration, rejected.
    rc, out, err = ctl("--timeout", "900", "calibrate", "--poses", f"{WORK}/few-poses.csv", "--wait",
                       timeout=1000)
    check(rc in (0, 5), f"a short calibration ends awaiting acceptance (exit {rc}: {err.strip()[:200]})")
    rc, out, err = ctl("reject")
    check(rc == 0, f"reject ({err.strip()})")
    wait_for(lambda: holding(v2), 60, f"holding with version {v2} after the reject")

    # 6. Rollback to the nominal geometry.
    rc, out, err = ctl("geometry", "rollback", "1")
    check(rc == 0, f"rollback to version 1 ({err.strip()})")
    wait_for(lambda: holding(1), 60, "holding with version 1 after the rollback")
    s = ctl_json("status")
    check(s["rt"]["largest_reference_step_counts"] <= s["rt"]["one_cycle_motion_counts"],
          f"rollback is bumpless ({s['rt']['largest_reference_step_counts']:.0f} counts)")
    h = ctl_json("geometry", "history")
    check(h["activations"][-1]["version"] == 1, "the history ends with the rollback")


# 15 designed poses, not cdprd's 25: the checks need an accepted calibration within 1 mm, and 15
# give 0.27 mm RMS (25 gave 0.11), in 70 s of measuring instead of 121. The scenario's softer
# cables are estimated (stiffness-per-cable) instead of found by the mismatch locator: the checks
# are the processes' (calibrate, accept, hot swap, restart, reject, rollback over vcan), and the
# locator took 44 to 115 s of the run under user-mode-linux; the daemon's locator rounds are
# tested in-process (tests/daemon/daemon_native_test.cc).
cell.write_configs(
    "motion: {max_linear_velocity: 0.2, max_linear_acceleration: 0.6, "
    "max_linear_jerk: 6, max_angular_velocity: 0.6, max_angular_acceleration: 2, "
    "max_angular_jerk: 20}\n"
    "measuring: {poses: 15, laser_samples: 10, average_cycles: 10, "
    "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4}\n"
    "identification: {estimate: [anchors, offsets, laser-plane, stiffness-per-cable], "
    "diagnose: false}\n")
# Eight poses from the designed set for the quick calibration that gets rejected.
with open(f"{WORK}/few-poses.csv", "w") as f:
    f.write("# units: SI\npose,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n"
            "1,0.05,0.05,0.05,0,0,0\n2,-0.05,0.05,-0.05,0,0,0\n3,0.05,-0.05,-0.05,0,0,0\n"
            "4,-0.05,-0.05,0.05,0,0,0\n5,0.08,0,0,0.1,0,0\n6,0,0.08,0,0,0.1,0\n"
            "7,0,0,0.08,0,0,0.1\n")
cell.run(scenario)
