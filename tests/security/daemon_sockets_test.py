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

sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from vcan_harness import Cell  # noqa: E402

cell = Cell(port_base=17020)
check, CDPRCTL, SOCK, PORT = cell.check, cell.cdprctl, cell.sock, cell.port


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


def scenario():
    cell.start_sim("mini-none.yaml")
    cell.start_daemon(timeout=120)
    check(cell.poll(lambda: cell.ctl_json("status")["state"] == "holding", 120),
          "cdprd comes up and holds")
    # A client stays connected while the sockets are listed (the accepted connection is counted).
    watcher = subprocess.Popen([CDPRCTL, "--socket", SOCK, "watch"], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    cell.others.append(watcher)
    time.sleep(2.0)
    pid = cell.daemon.pid
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


cell.write_configs(priority=0)
cell.run(scenario, daemon_tail=30, sim_tail=15)
