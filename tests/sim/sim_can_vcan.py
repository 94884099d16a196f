#!/usr/bin/python3
"""cdpr-sim's CANopen slaves on a kernel CAN bus, read by an independent peer (python3-can).

Usage (through tests/vcan/vcan-run, which provides vcan0):
    sim_can_vcan.py CDPR_SIM_EXE SOURCE_DIR

Starts cdpr-sim as a separate process on vcan0 with the MINI network (8 drives, force node 9) and
checks, with hand-made CANopen frames: the nodes' heartbeats (0x1017 preset, PRE-OPERATIONAL),
the identity object 0x1018 over expedited SDO uploads, the device name 0x1008 over a segmented
upload, and a boot-up after NMT reset communication. Exit status 0 only if everything matched.
"""
import os
import select
import signal
import subprocess
import sys
import time

import can

TIMEOUT = 30.0  # s per answer: user-mode-linux on a loaded host is slow; only a hang fails


def fail(msg):
    print("FAIL: " + msg, flush=True)
    sys.exit(1)


def wait_frame(bus, match, what, timeout=TIMEOUT):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = bus.recv(timeout=max(0.0, end - time.monotonic()))
        if msg is not None and not msg.is_error_frame and match(msg):
            return msg
    fail("no " + what + " within %.1f s" % timeout)


def sdo_request(bus, node, data):
    bus.send(can.Message(arbitration_id=0x600 + node, data=bytes(data), is_extended_id=False))


def sdo_answer(bus, node, what):
    return wait_frame(bus, lambda m: m.arbitration_id == 0x580 + node and len(m.data) == 8, what)


def upload_uint(bus, node, index, sub):
    what = "SDO answer from node %d for 0x%04X:%02X" % (node, index, sub)
    sdo_request(bus, node, [0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])
    m = sdo_answer(bus, node, what)
    d = m.data
    if d[0] == 0x80:
        fail("%s: abort 0x%08X" % (what, int.from_bytes(d[4:8], "little")))
    # Expedited with the size indicated (0x43/0x47/0x4B/0x4F: 4/3/2/1 bytes).
    if d[0] & 0xF3 != 0x43 or int.from_bytes(d[1:3], "little") != index or d[3] != sub:
        fail("%s: unexpected answer %s" % (what, d.hex()))
    n = 4 - ((d[0] >> 2) & 3)
    return int.from_bytes(d[4:4 + n], "little")


def upload_string(bus, node, index, sub):
    what = "SDO answer from node %d for 0x%04X:%02X" % (node, index, sub)
    sdo_request(bus, node, [0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])
    d = sdo_answer(bus, node, what).data
    if d[0] & 0xE0 != 0x40:
        fail("%s: unexpected initiate answer %s" % (what, d.hex()))
    if d[0] & 0x02:  # expedited
        n = 4 - ((d[0] >> 2) & 3) if d[0] & 1 else 4
        return bytes(d[4:4 + n]).decode()
    size = int.from_bytes(d[4:8], "little")
    out = b""
    toggle = 0
    while True:
        sdo_request(bus, node, [0x60 | toggle, 0, 0, 0, 0, 0, 0, 0])
        s = sdo_answer(bus, node, what + " (segment)").data
        if s[0] & 0xE0 != 0x00 or (s[0] & 0x10) != toggle:
            fail("%s: unexpected segment %s" % (what, s.hex()))
        n = 7 - ((s[0] >> 1) & 7)
        out += bytes(s[1:1 + n])
        toggle ^= 0x10
        if s[0] & 1:
            break
    if len(out) != size:
        fail("%s: %d bytes announced, %d received" % (what, size, len(out)))
    return out.decode()


def main():
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    exe, src = sys.argv[1], sys.argv[2]
    bus = can.Bus(interface="socketcan", channel="vcan0", receive_own_messages=False)
    sim = subprocess.Popen(
        [exe, "--config", os.path.join(src, "config/mini.yaml"),
         "--scenario", os.path.join(src, "config/scenarios/mini-none.yaml"),
         "--can", "vcan0", "--canopen", os.path.join(src, "config/canopen-mini.yaml"),
         "--duration", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Wait for the sim to say it is on the bus.
        line, end = "", time.monotonic() + 60
        while "CANopen on vcan0" not in line:
            left = end - time.monotonic()
            if left <= 0 or not select.select([sim.stdout], [], [], left)[0]:
                fail("cdpr-sim did not report its CANopen nodes")
            line = sim.stdout.readline()
            if not line:
                fail("cdpr-sim exited early (status %s)" % sim.poll())
            print("sim: " + line.rstrip(), flush=True)

        # Heartbeats (0x1017 = 50 ms preset from the network description), PRE-OPERATIONAL.
        for node in (1, 8, 9):
            hb = wait_frame(bus, lambda m, n=node: m.arbitration_id == 0x700 + n and
                            len(m.data) == 1 and m.data[0] != 0x00, "heartbeat of node %d" % node)
            if hb.data[0] != 0x7F:
                fail("node %d heartbeat state 0x%02X, want 0x7F (pre-operational)" %
                     (node, hb.data[0]))
            print("node %d: heartbeat 0x%02X" % (node, hb.data[0]), flush=True)

        # Identity object.
        for node, product in ((1, 0x402), (5, 0x402), (9, 0x404)):
            count = upload_uint(bus, node, 0x1018, 0)
            values = [upload_uint(bus, node, 0x1018, s) for s in (1, 2, 3, 4)]
            print("node %d: 0x1018 = %d entries %s" % (node, count,
                                                       [hex(v) for v in values]), flush=True)
            if count != 4:
                fail("node %d: 0x1018:00 = %d, want 4" % (node, count))
            if values[0] != 0x00CD9001 or values[1] != product or values[3] != 0x51000000 + node:
                fail("node %d: identity %s" % (node, [hex(v) for v in values]))

        name = upload_string(bus, 1, 0x1008, 0)
        print("node 1: 0x1008 = '%s'" % name, flush=True)
        if name != "cdpr-sim winch1":
            fail("node 1: device name '%s'" % name)

        # NMT reset communication of node 3: boot-up.
        bus.send(can.Message(arbitration_id=0x000, data=bytes([0x82, 3]), is_extended_id=False))
        wait_frame(bus, lambda m: m.arbitration_id == 0x703 and list(m.data) == [0x00],
                   "boot-up of node 3 after NMT reset communication")
        print("node 3: boot-up after reset communication", flush=True)
    finally:
        if sim.poll() is None:
            sim.send_signal(signal.SIGTERM)
        try:
            rest, _ = sim.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            sim.kill()
            rest, _ = sim.communicate()
        for line in rest.splitlines():
            print("sim: " + line, flush=True)
        bus.shutdown()
    if sim.returncode != 0:
        fail("cdpr-sim exit status %d" % sim.returncode)
    print("PASS", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
