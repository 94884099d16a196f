#!/usr/bin/env python3
"""SIGKILL of the real cdpr-sim process under a running cdprd, on a kernel CAN bus (issue 17).

Run through tests/vcan/vcan-run (native vcan, or user-mode-linux with a relaxed 20 ms SYNC):

    sim_kill_vcan_test.py CDPRD CDPRCTL CDPR_SIM SOURCE_DIR WORK_DIR

cdpr-sim (every drive, the force node and the laser) is killed with SIGKILL twice, once while
cdprd holds and once while it measures (pose 2 of a calibration, one pose recorded). Each time,
through cdprctl: the named fault in `cdprctl status` and in cdprd's log, the robot stopped, the
geometry version 1 still active and its file unchanged, the partial recording readable (every row
whole, the columns of its header); then cdpr-sim restarts, `fault-reset` is refused with its
reason (its nodes booted and lost their configuration), cdprd restarts, and it holds again with
version 1.
"""
import hashlib
import os
import signal
import sys

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from vcan_harness import Cell  # noqa: E402

cell = Cell(port_base=17020, timestamps=True)
ctl, ctl_json, check, wait_for = cell.ctl, cell.ctl_json, cell.check, cell.wait_for
WORK = cell.work
GEOMETRY = f"{WORK}/state/geometry/000001.yaml"


def holding():
    return cell.holding(1)


def sha(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def recording_readable(path):
    """Every row whole: as many fields as the header's columns, all numbers."""
    lines = open(path).read().split("\n")
    if lines[-1] != "":
        return False, "the last row has no newline"
    header = next(l for l in lines if l and not l.startswith("#"))
    rows = [l for l in lines if l[:1].isdigit()]
    n = len(header.split(","))
    for r in rows:
        fields = r.split(",")
        if len(fields) != n:
            return False, f"a row with {len(fields)} fields, header {n}"
        try:
            [float(x) for x in fields]
        except ValueError:
            return False, f"a row that is not numbers: {r[:60]}"
    return True, f"{len(rows)} rows of {n} columns"


def restart_sim_then_daemon(what):
    """cdpr-sim restarts (its nodes boot, unconfigured): fault-reset is refused with its reason,
    then cdprd restarts and holds again."""
    cell.start_sim()
    refused = []

    def reset_refused():
        rc, out, err = ctl("fault-reset")
        refused[:] = [rc, (out + err).strip()]
        return rc != 0 and "restart cdprd" in refused[1]

    wait_for(reset_refused, 30, f"{what}: fault-reset refused once cdpr-sim is back ({refused})")
    if refused and refused[0] != 0:
        check(True, f"{what}: fault-reset refused with its reason ({refused[1][:120]})")
    cell.stop_daemon()
    cell.start_daemon()
    wait_for(holding, 60, f"{what}: cdpr-sim, then cdprd restarted: holding with version 1")


def after_kill(what, before_sha, sequence=False):
    """The checks after cdpr-sim was killed."""
    wait_for(lambda: ctl_json("status")["state"] == "fault", 30, f"{what}: cdprd in fault")
    s = ctl_json("status")
    fault = (s.get("fault") or {}).get("fault")
    check(fault == "node_lost",
          f"{what}: named fault in `cdprctl status`: {fault} ({(s.get('fault') or {}).get('message')})")
    check(f"fault: {fault}" in open(cell.daemon_log.name).read(),
          f"{what}: the fault is in cdprd's log")
    check(s["geometry_version"] == 1 and sha(GEOMETRY) == before_sha,
          f"{what}: geometry version {s['geometry_version']} active, its file unchanged")
    if sequence:
        wait_for(lambda: ctl_json("status")["calibration"]["outcome"] not in
                 ("measuring", "identifying"), 60, f"{what}: the calibration ends")
        s = ctl_json("status")
        cal = s["calibration"]
        check(cal["outcome"] in ("failed", "aborted"),
              f"{what}: calibration {cal['outcome']}: {cal.get('message', '')[:120]}")
        ok, how = recording_readable(
            f"{WORK}/state/calibrations/{cal['id']:06d}/recording.csv")
        check(ok, f"{what}: the partial recording is readable ({how})")


def kill_sim():
    cell.sim.send_signal(signal.SIGKILL)
    cell.sim.wait()


def scenario():
    cell.start_sim()
    cell.start_daemon()
    wait_for(holding, 60, "cdprd holds with geometry version 1")
    geometry_sha = sha(GEOMETRY)

    # 1. cdpr-sim killed while cdprd holds.
    kill_sim()
    after_kill("killed while holding", geometry_sha)
    restart_sim_then_daemon("killed while holding")

    # 2. cdpr-sim killed while cdprd measures.
    rc, out, err = cell.calibrate()
    check(rc == 0, f"calibrate starts ({(out + err).strip()[:80]})")
    wait_for(lambda: ctl_json("status")["calibration"]["pose"] >= 1, 120, "one pose measured")
    kill_sim()
    after_kill("killed while measuring", geometry_sha, sequence=True)
    restart_sim_then_daemon("killed while measuring")
    rc, out, err = cell.calibrate()
    check(rc == 0, "a new calibration starts")
    ctl("abort")
    wait_for(holding, 60, "holding after its abort")


cell.write_configs(
    "motion: {max_linear_velocity: 0.2, max_linear_acceleration: 0.6, "
    "max_linear_jerk: 6, max_angular_velocity: 0.6, max_angular_acceleration: 2, "
    "max_angular_jerk: 20}\n"
    "measuring: {poses: 12, laser_samples: 5, average_cycles: 10, "
    "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4}\n"
    "identification: {diagnose: false}\n")
cell.run(scenario)
