#!/usr/bin/env python3
"""cdprd opens no network listener: its only sockets are the Unix control socket (and the
connections accepted on it), CAN, and the Modbus TCP connection to the configured laser address.

Run through tests/vcan/vcan-run (native vcan, or user-mode-linux with a relaxed 20 ms SYNC):

    daemon_sockets_test.py CDPRD CDPRCTL CDPR_SIM SOURCE_DIR WORK_DIR

The virtual robot (cdpr-sim) serves the drives on vcan0 and the laser over Modbus TCP on
127.0.0.1:PORT; cdprd starts, homes and holds. While a cdprctl client is connected, every socket
of cdprd (/proc/PID/fd) is looked up in the kernel's tables of its network namespace
(/proc/PID/net/{tcp,tcp6,udp,udp6,raw,raw6,packet,unix,netlink}) and `ss`:
  - TCP: only connections to 127.0.0.1:PORT (the configured laser), never LISTEN;
  - UDP, raw IP and packet sockets: none;
  - Unix: the control socket (bound as <path>.tmp<pid>, then renamed to <path>; listening and
    accepted), or unnamed (socketpair); no abstract name (reachable without file permissions), no
    other path, and exactly one listening socket;
  - netlink: allowed (kernel only, not reachable from the network);
  - a socket in none of these tables is CAN (AF_CAN has no such table): at least one expected.
"""
import os
import subprocess
import sys
import time

CDPRD, CDPRCTL, SIM, SRC, WORK = sys.argv[1:6]
UML = os.environ.get("CDPR_VCAN_PATH", "").startswith("user-mode-linux")
PERIOD_MS = 20 if UML else 4
NETWORK = f"{SRC}/tests/sim/sim-master-network.yaml" if UML else f"{SRC}/config/canopen-mini.yaml"
SOCK = f"{WORK}/cdprd.sock"
PORT = 17020 + os.getpid() % 1000
failures = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what, flush=True)
    if not ok:
        failures.append(what)
    return ok


def ctl(*args, timeout=60):
    return subprocess.run([CDPRCTL, "--socket", SOCK, *args], capture_output=True, text=True,
                          timeout=timeout)


def write_configs():
    os.makedirs(WORK, exist_ok=True)
    with open(f"{WORK}/laser.yaml", "w") as f:
        f.write(f"name: sim-laser\ntransport: tcp\nhost: 127.0.0.1\nport: {PORT}\nslave_id: 1\n"
                f"response_timeout: 0.2\npoll_rate: 50\n"
                f"register_map: {SRC}/config/lasers/baumer-om20-om30.yaml\n")
    with open(f"{WORK}/cdprd.yaml", "w") as f:
        f.write(f"robot: {SRC}/config/mini.yaml\ncanopen: {NETWORK}\nlaser: {WORK}/laser.yaml\n"
                f"can_interface: vcan0\nstate_directory: {WORK}/state\n"
                f"realtime: {{priority: 0, sync_period_ms: {PERIOD_MS}}}\n"
                "identity: {vendor_id: 0x00CD9001, drive_product_code: 0x402, "
                "force_product_code: 0x404}\n"
                f"control: {{socket: {SOCK}}}\n")


def hex_addr(text):
    """'0100007F:1F90' -> ('127.0.0.1', 8080) for IPv4; IPv6 returned as hex."""
    host, port = text.split(":")
    if len(host) == 8:
        b = bytes.fromhex(host)[::-1]
        return ".".join(str(x) for x in b), int(port, 16)
    return host, int(port, 16)


def tables(pid):
    """inode -> (kind, details) from the kernel tables of the process's network namespace."""
    found = {}
    for kind in ("tcp", "tcp6", "udp", "udp6", "raw", "raw6"):
        try:
            lines = open(f"/proc/{pid}/net/{kind}").read().splitlines()[1:]
        except FileNotFoundError:
            continue
        for line in lines:
            f = line.split()
            found[f[9]] = (kind, {"local": hex_addr(f[1]), "remote": hex_addr(f[2]), "state": f[3]})
    for line in open(f"/proc/{pid}/net/unix").read().splitlines()[1:]:
        f = line.split()
        found[f[6]] = ("unix", {"path": f[7] if len(f) > 7 else "", "state": f[5],
                                "listening": int(f[3], 16) & 0x10000 != 0})
    for kind, col in (("packet", 8), ("netlink", 9)):
        try:
            for line in open(f"/proc/{pid}/net/{kind}").read().splitlines()[1:]:
                f = line.split()
                found[f[col]] = (kind, {})
        except FileNotFoundError:
            pass
    return found


def socket_inodes(pid):
    out = []
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except FileNotFoundError:
            continue
        if target.startswith("socket:["):
            out.append((int(fd), target[8:-1]))
    return sorted(out)


write_configs()
sim_log = open(f"{WORK}/cdpr-sim.log", "w")
sim = subprocess.Popen([SIM, "--config", f"{SRC}/config/mini.yaml", "--scenario",
                        f"{SRC}/config/scenarios/mini-none.yaml", "--can", "vcan0",
                        "--canopen", NETWORK, "--modbus", f"tcp:{PORT}", "--home", "reference",
                        "--seed", "3"], stdout=sim_log, stderr=sim_log)
daemon_log = open(f"{WORK}/cdprd.log", "w")
daemon = None
watcher = None
try:
    for _ in range(600):
        if "CANopen on vcan0" in open(f"{WORK}/cdpr-sim.log").read():
            break
        time.sleep(0.1)
    daemon = subprocess.Popen([CDPRD, "--config", f"{WORK}/cdprd.yaml"], stdout=daemon_log,
                              stderr=daemon_log)
    up = False
    for _ in range(1200):
        if daemon.poll() is not None:
            break
        if os.path.exists(SOCK) and '"holding"' in ctl("--json", "status").stdout:
            up = True
            break
        time.sleep(0.1)
    check(up, "cdprd comes up and holds")
    # A client stays connected while the sockets are listed (the accepted connection is counted).
    watcher = subprocess.Popen([CDPRCTL, "--socket", SOCK, "watch"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    time.sleep(2.0)
    pid = daemon.pid
    known = tables(pid)
    inodes = socket_inodes(pid)
    can_sockets = 0
    print(f"cdprd (pid {pid}) holds {len(inodes)} socket(s):")
    for fd, inode in inodes:
        kind, d = known.get(inode, ("can?", {}))
        print(f"  fd {fd:3d} inode {inode:>8s} {kind:8s} {d}")
        if kind in ("tcp", "tcp6"):
            check(d["state"] != "0A", f"fd {fd}: TCP socket is not listening ({d})")
            check(d["remote"] == ("127.0.0.1", PORT),
                  f"fd {fd}: TCP only to the configured laser 127.0.0.1:{PORT} (got {d['remote']})")
        elif kind in ("udp", "udp6", "raw", "raw6", "packet"):
            check(False, f"fd {fd}: no {kind} socket ({d})")
        elif kind == "unix":
            path = d["path"]
            check(not path.startswith("@"), f"fd {fd}: no abstract Unix socket ({path})")
            # The server binds under a temporary name beside the socket and renames it into
            # place (docs/control-protocol.md); the kernel keeps the name it was bound to.
            check(path in ("", SOCK, f"{SOCK}.tmp{pid}"),
                  f"fd {fd}: Unix socket is the control socket or unnamed (got '{path}')")
        elif kind == "can?":
            can_sockets += 1
    check(can_sockets >= 1, f"{can_sockets} CAN socket(s) (sockets in no IP/Unix/packet table)")
    listening_unix = [i for _, i in inodes if known.get(i, ("", {}))[0] == "unix"
                      and known[i][1]["listening"]]
    check(len(listening_unix) == 1, f"one listening control socket ({len(listening_unix)})")
    # The same through ss: nothing of cdprd's listens on TCP or UDP.
    ss = subprocess.run(["ss", "-H", "-ltunp"], capture_output=True, text=True)
    mine = [l for l in ss.stdout.splitlines() if f"pid={pid}," in l]
    check(ss.returncode == 0 and not mine, f"ss -ltunp lists no listener of cdprd ({mine})")
except Exception as e:  # noqa: BLE001 - report any failure with the logs
    check(False, f"exception: {e}")
finally:
    for p in (watcher, daemon, sim):
        if p is not None and p.poll() is None:
            p.terminate()
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()

if failures:
    print("\n--- cdprd.log (tail) ---")
    print("".join(open(f"{WORK}/cdprd.log").readlines()[-30:]))
    print("--- cdpr-sim.log (tail) ---")
    print("".join(open(f"{WORK}/cdpr-sim.log").readlines()[-15:]))
    print(f"{len(failures)} check(s) failed")
    sys.exit(1)
print("every check passed")
