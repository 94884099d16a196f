#!/usr/bin/env python3
"""SIGKILL of the real cdpr-sim process under a running cdprd, on a kernel CAN bus (issue 17).

Run through tests/vcan/vcan-run (native vcan, or user-mode-linux with a relaxed 20 ms SYNC):

    sim_kill_vcan_test.py CDPRD CDPRCTL CDPR_SIM SOURCE_DIR WORK_DIR

cdpr-sim (every drive, the force node and the laser) is killed with SIGKILL twice, once while
cdprd holds and once while it measures (pose 2 of a calibration). Each time, through cdprctl:
the named fault in `cdprctl status` and in cdprd's log, the robot stopped, the geometry version 1
still active and its file unchanged, the partial recording readable (every row whole, the
columns of its header); then cdpr-sim restarts, `fault-reset` is refused with its reason (its
nodes booted and lost their configuration), cdprd restarts, and it holds again with version 1.
"""
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

CDPRD, CDPRCTL, SIM, SRC, WORK = sys.argv[1:6]
UML = os.environ.get("CDPR_VCAN_PATH", "").startswith("user-mode-linux")
PERIOD_MS = 20 if UML else 4
NETWORK = f"{SRC}/tests/sim/sim-master-network.yaml" if UML else f"{SRC}/config/canopen-mini.yaml"
SOCK = f"{WORK}/cdprd.sock"
PORT = 17020 + os.getpid() % 1000
GEOMETRY = f"{WORK}/state/geometry/000001.yaml"
failures = []
T0 = time.time()


def check(ok, what):
    print(f"{time.time() - T0:6.1f} s  " + ("ok    " if ok else "FAIL  ") + what, flush=True)
    if not ok:
        failures.append(what)
    return ok


def ctl(*args, timeout=60):
    r = subprocess.run([CDPRCTL, "--socket", SOCK, *args], capture_output=True, text=True,
                       timeout=timeout)
    return r.returncode, r.stdout, r.stderr


def ctl_json(*args):
    rc, out, err = ctl("--json", *args)
    if rc != 0:
        raise RuntimeError(f"cdprctl {' '.join(args)} exited {rc}: {err}{out}")
    return json.loads(out)


def wait_for(pred, timeout, what):
    end = time.time() + timeout
    while time.time() < end:
        try:
            if pred():
                return True
        except (RuntimeError, json.JSONDecodeError, KeyError, TypeError):
            pass
        time.sleep(0.2)
    return check(False, f"{what} within {timeout} s")


def holding(version=1):
    s = ctl_json("status")
    return s["state"] == "holding" and s["rt"]["settled"] and s["geometry_version"] == version


def sha(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def write_configs():
    shutil.rmtree(WORK, ignore_errors=True)
    os.makedirs(WORK)
    with open(f"{WORK}/laser.yaml", "w") as f:
        f.write(f"name: sim-laser\ntransport: tcp\nhost: 127.0.0.1\nport: {PORT}\nslave_id: 1\n"
                f"response_timeout: 0.2\npoll_rate: 50\n"
                f"register_map: {SRC}/config/lasers/baumer-om20-om30.yaml\n")
    with open(f"{WORK}/cdprd.yaml", "w") as f:
        f.write(f"robot: {SRC}/config/mini.yaml\ncanopen: {NETWORK}\nlaser: {WORK}/laser.yaml\n"
                f"can_interface: vcan0\nstate_directory: {WORK}/state\n"
                f"realtime: {{priority: {0 if UML else 80}, sync_period_ms: {PERIOD_MS}}}\n"
                "identity: {vendor_id: 0x00CD9001, drive_product_code: 0x402, "
                "force_product_code: 0x404}\n"
                "motion: {max_linear_velocity: 0.2, max_linear_acceleration: 0.6, "
                "max_linear_jerk: 6, max_angular_velocity: 0.6, max_angular_acceleration: 2, "
                "max_angular_jerk: 20}\n"
                "measuring: {poses: 12, laser_samples: 5, average_cycles: 10, "
                "noise_length_m: 4e-7, noise_force_n: 0.1, noise_laser_m: 1e-4}\n"
                "identification: {diagnose: false}\n"
                f"control: {{socket: {SOCK}}}\n")


def start_sim(log):
    p = subprocess.Popen([SIM, "--config", f"{SRC}/config/mini.yaml", "--scenario",
                          f"{SRC}/config/scenarios/mini-calibration.yaml", "--can", "vcan0",
                          "--canopen", NETWORK, "--modbus", f"tcp:{PORT}", "--home", "reference",
                          "--seed", "3"], stdout=log, stderr=log)
    start = log.tell() if hasattr(log, "tell") else 0
    for _ in range(600):
        with open(log.name) as f:
            f.seek(start)
            if "CANopen on vcan0" in f.read():
                return p
        time.sleep(0.1)
    raise RuntimeError("cdpr-sim did not come up; see " + log.name)


def start_daemon(log):
    if os.path.exists(SOCK):
        os.unlink(SOCK)
    p = subprocess.Popen([CDPRD, "--config", f"{WORK}/cdprd.yaml"], stdout=log, stderr=log)
    for _ in range(600):
        if os.path.exists(SOCK):
            try:
                ctl_json("status")
                return p
            except RuntimeError:
                pass
        if p.poll() is not None:
            break
        time.sleep(0.1)
    raise RuntimeError("cdprd did not come up; see " + log.name)


def stop_daemon(p):
    p.send_signal(signal.SIGTERM)
    try:
        p.wait(timeout=30)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


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
    global sim, daemon
    sim = start_sim(sim_log)
    refused = []

    def reset_refused():
        rc, out, err = ctl("fault-reset")
        refused[:] = [rc, (out + err).strip()]
        return rc != 0 and "restart cdprd" in refused[1]

    wait_for(reset_refused, 30, f"{what}: fault-reset refused once cdpr-sim is back ({refused})")
    if refused and refused[0] != 0:
        check(True, f"{what}: fault-reset refused with its reason ({refused[1][:120]})")
    stop_daemon(daemon)
    daemon = start_daemon(daemon_log)
    wait_for(holding, 60, f"{what}: cdpr-sim, then cdprd restarted: holding with version 1")


def after_kill(what, log_path, before_sha, sequence=False):
    """The checks after cdpr-sim was killed."""
    wait_for(lambda: ctl_json("status")["state"] == "fault", 30, f"{what}: cdprd in fault")
    s = ctl_json("status")
    fault = (s.get("fault") or {}).get("fault")
    check(fault == "node_lost",
          f"{what}: named fault in `cdprctl status`: {fault} ({(s.get('fault') or {}).get('message')})")
    check(f"fault: {fault}" in open(log_path).read(), f"{what}: the fault is in cdprd's log")
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


write_configs()
sim_log = open(f"{WORK}/cdpr-sim.log", "w")
daemon_log = open(f"{WORK}/cdprd.log", "w")
sim = daemon = None
try:
    sim = start_sim(sim_log)
    daemon = start_daemon(daemon_log)
    wait_for(holding, 60, "cdprd holds with geometry version 1")
    geometry_sha = sha(GEOMETRY)

    # 1. cdpr-sim killed while cdprd holds.
    sim.send_signal(signal.SIGKILL)
    sim.wait()
    after_kill("killed while holding", daemon_log.name, geometry_sha)
    restart_sim_then_daemon("killed while holding")

    # 2. cdpr-sim killed while cdprd measures.
    rc, out, err = ctl("calibrate")
    check(rc == 0, f"calibrate starts ({(out + err).strip()[:80]})")
    wait_for(lambda: ctl_json("status")["calibration"]["pose"] >= 2, 120, "two poses measured")
    sim.send_signal(signal.SIGKILL)
    sim.wait()
    after_kill("killed while measuring", daemon_log.name, geometry_sha, sequence=True)
    restart_sim_then_daemon("killed while measuring")
    rc, out, err = ctl("calibrate")
    check(rc == 0, "a new calibration starts")
    ctl("abort")
    wait_for(holding, 60, "holding after its abort")
except Exception as e:  # noqa: BLE001 - report any failure with the logs
    check(False, f"exception: {e}")
finally:
    if daemon is not None and daemon.poll() is None:
        stop_daemon(daemon)
    if sim is not None and sim.poll() is None:
        sim.send_signal(signal.SIGTERM)
        try:
            sim.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()

print(f"wall time {time.time() - T0:.0f} s")
if failures:
    print("\n--- cdprd.log (tail) ---")
    print("".join(open(f"{WORK}/cdprd.log").readlines()[-40:]))
    print("--- cdpr-sim.log (tail) ---")
    print("".join(open(f"{WORK}/cdpr-sim.log").readlines()[-20:]))
    print(f"{len(failures)} check(s) failed")
    sys.exit(1)
print("every check passed")
