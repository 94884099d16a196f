"""The cell of the tests that run cdpr-sim, cdprd and cdprctl as separate processes on vcan0.

Shared by tests/daemon/daemon_vcan_test.py, tests/daemon/sim_kill_vcan_test.py and
tests/security/daemon_sockets_test.py (each keeps only its scenario). They run through
tests/vcan/vcan-run (native vcan, or user-mode-linux with a relaxed 20 ms SYNC) as

    TEST.py CDPRD CDPRCTL CDPR_SIM SOURCE_DIR WORK_DIR

A test makes a Cell, writes its configs, then hands its scenario to Cell.run: every exception is a
failed check, the processes are always ended, and the exit status is 1 (with the logs' tails) when
any check failed, 0 otherwise.

The virtual robot (cdpr-sim) serves its drives and force node on vcan0 and its laser over Modbus
TCP on 127.0.0.1:PORT (a port per process: port_base + pid % 1000); cdprd starts from
config/mini.yaml with its state directory and control socket in WORK_DIR.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import time


class Cell:
    def __init__(self, port_base, timestamps=False):
        self.cdprd, self.cdprctl, self.sim_bin, self.src, self.work = sys.argv[1:6]
        self.uml = os.environ.get("CDPR_VCAN_PATH", "").startswith("user-mode-linux")
        self.period_ms = 20 if self.uml else 4
        self.network = (f"{self.src}/config/sim/canopen.yaml" if self.uml else
                        f"{self.src}/config/canopen-mini.yaml")
        self.sock = f"{self.work}/cdprd.sock"
        self.port = port_base + os.getpid() % 1000
        self.timestamps = timestamps  # each check line starts with the seconds since the start
        self.t0 = time.time()
        self.failures = []
        self.sim = self.daemon = None
        self.others = []  # more processes the scenario starts, ended first
        self.sim_log = self.daemon_log = None

    # --- checks and cdprctl -------------------------------------------------------------------

    def check(self, ok, what):
        stamp = f"{time.time() - self.t0:6.1f} s  " if self.timestamps else ""
        print(stamp + ("ok    " if ok else "FAIL  ") + what, flush=True)
        if not ok:
            self.failures.append(what)
        return ok

    def ctl(self, *args, timeout=60):
        """cdprctl on the cell's socket: (exit status, stdout, stderr)."""
        r = subprocess.run([self.cdprctl, "--socket", self.sock, *args], capture_output=True,
                           text=True, timeout=timeout)
        return r.returncode, r.stdout, r.stderr

    def calibrate(self, *args):
        """`cdprctl calibrate` without --wait. cdprd designs the poses before it answers: seconds
        under user-mode-linux, more than cdprctl's default 10 s at a load of 10 (seen)."""
        return self.ctl("--timeout", "120", "calibrate", *args, timeout=180)

    def ctl_json(self, *args):
        rc, out, err = self.ctl("--json", *args)
        if rc != 0:
            raise RuntimeError(f"cdprctl {' '.join(args)} exited {rc}: {err}{out}")
        return json.loads(out)

    @staticmethod
    def poll(pred, timeout):
        """True as soon as `pred` holds (cdprctl failing or its answer lacking counts as not yet),
        False after `timeout` s."""
        end = time.time() + timeout
        while time.time() < end:
            try:
                if pred():
                    return True
            except (RuntimeError, json.JSONDecodeError, KeyError, TypeError):
                pass
            time.sleep(0.2)
        return False

    def wait_for(self, pred, timeout, what):
        """poll, a failed check when `pred` does not hold within `timeout` s."""
        return self.poll(pred, timeout) or self.check(False, f"{what} within {timeout} s")

    def true_pose(self):
        """The sim's true platform pose: the line it prints on SIGUSR1 (waited for, not timed)."""
        def poses():
            return [l for l in open(self.sim_log.name) if "true platform pose" in l]
        before = len(poses())
        self.sim.send_signal(signal.SIGUSR1)
        self.wait_for(lambda: len(poses()) > before, 60, "the sim's true platform pose")
        return [float(x) for x in poses()[-1].split("pose")[1].split()]

    def holding(self, version=None):
        """cdprd holds, settled (with geometry `version` when given)."""
        s = self.ctl_json("status")
        return s["state"] == "holding" and s["rt"]["settled"] and (
            version is None or s["geometry_version"] == version)

    # --- configs and processes ----------------------------------------------------------------

    def write_configs(self, daemon_groups="", priority=None):
        """A fresh WORK_DIR with laser.yaml and cdprd.yaml, and the two logs opened.
        `daemon_groups`: more top-level groups of cdprd.yaml (YAML lines); `priority`: the RT
        priority (default: 0 under user-mode-linux, 80 otherwise)."""
        if priority is None:
            priority = 0 if self.uml else 80
        if self.uml and "tension_watch" not in daemon_groups:
            # Under user-mode-linux a starved cdpr-sim keeps sending its last readings for longer
            # than the 0.2 s a stuck force sensor is confirmed in (seen at load ~20 amid SYNC
            # overruns: a false force_stuck on cable 1). The watch itself is tested on the
            # in-process bus (tests/daemon/force_stuck_test.cc); here it only must not trip on
            # the emulator's pauses.
            daemon_groups += ("tension_watch: {slack_below: 1, overload_above: 0, cycles: 5, "
                              "stuck_raw_units: 12, stuck_confirm_s: 2}\n")
        shutil.rmtree(self.work, ignore_errors=True)
        os.makedirs(self.work)
        # The laser's answer timeout is generous (2 s): a starved cdpr-sim under user-mode-linux
        # answers late, not never; the driver's timeouts are tested on their own (tests/modbus).
        with open(f"{self.work}/laser.yaml", "w") as f:
            f.write(f"name: sim-laser\ntransport: tcp\nhost: 127.0.0.1\nport: {self.port}\n"
                    f"slave_id: 1\nresponse_timeout: 2\npoll_rate: 50\n"
                    f"register_map: {self.src}/config/lasers/baumer-om20-om30.yaml\n")
        with open(f"{self.work}/cdprd.yaml", "w") as f:
            f.write(f"robot: {self.src}/config/mini.yaml\ncanopen: {self.network}\n"
                    f"laser: {self.work}/laser.yaml\n"
                    f"can_interface: vcan0\nstate_directory: {self.work}/state\n"
                    f"realtime: {{priority: {priority}, sync_period_ms: {self.period_ms}}}\n"
                    "identity: {vendor_id: 0x00CD9001, drive_product_code: 0x402, "
                    "force_product_code: 0x404}\n" + daemon_groups +
                    "start: {enable: at-start, home_without_record: reference}\n" +
                    f"control: {{socket: {self.sock}}}\n")
        self.sim_log = open(f"{self.work}/cdpr-sim.log", "w")
        self.daemon_log = open(f"{self.work}/cdprd.log", "w")

    def sim_args(self, scenario="mini-calibration.yaml"):
        """cdpr-sim's arguments for `scenario` (config/scenarios/), without the program."""
        return ["--config", f"{self.src}/config/mini.yaml", "--scenario",
                f"{self.src}/config/scenarios/{scenario}"]

    def start_sim(self, scenario="mini-calibration.yaml"):
        """cdpr-sim on vcan0 and tcp:PORT, homed at the reference platform; returns once it says
        CANopen is up (raises after 60 s)."""
        self.sim = subprocess.Popen(
            [self.sim_bin, *self.sim_args(scenario), "--can", "vcan0", "--canopen", self.network,
             "--modbus", f"tcp:{self.port}", "--home", "reference", "--seed", "3"],
            stdout=self.sim_log, stderr=self.sim_log)
        start = self.sim_log.tell()  # a restart reads only what the new process writes
        for _ in range(600):
            with open(self.sim_log.name) as f:
                f.seek(start)
                if "CANopen on vcan0" in f.read():
                    return self.sim
            time.sleep(0.1)
        raise RuntimeError("cdpr-sim did not come up; see " + self.sim_log.name)

    def start_daemon(self, timeout=60):
        """cdprd (a stale socket removed first); returns once `cdprctl status` answers (raises
        when it exits or after `timeout` s)."""
        if os.path.exists(self.sock):
            os.unlink(self.sock)
        p = subprocess.Popen([self.cdprd, "--config", f"{self.work}/cdprd.yaml"],
                             stdout=self.daemon_log, stderr=self.daemon_log)
        self.daemon = p
        for _ in range(int(timeout * 10)):
            if os.path.exists(self.sock):
                try:
                    self.ctl_json("status")
                    return p
                except RuntimeError:
                    pass
            if p.poll() is not None:
                break
            time.sleep(0.1)
        raise RuntimeError("cdprd did not come up; see " + self.daemon_log.name)

    @staticmethod
    def stop(p, timeout=30):
        """SIGTERM, then SIGKILL after `timeout` s; reaped either way."""
        if p is None or p.poll() is not None:
            return
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()

    def stop_daemon(self):
        self.stop(self.daemon)

    # --- the run ------------------------------------------------------------------------------

    def run(self, scenario, daemon_tail=40, sim_tail=20):
        """Runs `scenario()`, ends every process, reports; exits 1 when a check failed."""
        try:
            scenario()
        except Exception as e:  # noqa: BLE001 - report any failure with the logs
            self.check(False, f"exception: {e}")
        finally:
            for p in self.others:
                self.stop(p)
            self.stop(self.daemon)
            self.stop(self.sim, timeout=10)
        if self.timestamps:
            print(f"wall time {time.time() - self.t0:.0f} s")
        if self.failures:
            print("\n--- cdprd.log (tail) ---")
            print("".join(open(f"{self.work}/cdprd.log").readlines()[-daemon_tail:]))
            print("--- cdpr-sim.log (tail) ---")
            print("".join(open(f"{self.work}/cdpr-sim.log").readlines()[-sim_tail:]))
            print(f"{len(self.failures)} check(s) failed")
            sys.exit(1)
        print("every check passed")
