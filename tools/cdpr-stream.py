#!/usr/bin/env python3
"""Streams a circle to cdprd's setpoint stream (docs/motion.md "Setpoint stream") and prints the
daemon's latency figures. Start the stream first (cdprctl stream start); the circle starts at
the commanded pose (cdprctl status --json) and runs at the cycle rate."""
import argparse, json, math, socket, struct, subprocess, time

RECORD = struct.Struct("<IHHQq6d")  # magic, version, flags, seq, sent_ns, pose


def status(ctl):
    return json.loads(subprocess.run([ctl, "status", "--json"], check=True,
                                     capture_output=True, text=True).stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--circle", type=float, default=0.01, help="radius, m")
    ap.add_argument("--period", type=float, default=4.0, help="s per turn")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--cycle", type=float, default=0.004, help="send period, s (the SYNC period)")
    ap.add_argument("--cdprctl", default="cdprctl")
    a = ap.parse_args()
    st = status(a.cdprctl)
    path = st["stream"]["socket"]
    p0 = st["rt"]["commanded_pose"]
    x0, y0 = p0[0], p0[1]
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    # The circle's time is the setpoint's slot (seq * cycle): the first setpoint is the
    # commanded pose itself (a stream starts from rest there, else cdprd ends it:
    # resume_refused).
    seq, t0 = 0, time.monotonic()
    while (t := seq * a.cycle) < a.seconds:
        w = 2 * math.pi * t / a.period
        pose = [x0 + a.circle * (math.cos(w) - 1), y0 + a.circle * math.sin(w)] + list(p0[2:6])
        seq += 1
        s.sendto(RECORD.pack(0x53504443, 1, 0, seq, time.monotonic_ns(), *pose), path)
        time.sleep(max(0.0, t0 + seq * a.cycle - time.monotonic()))
    print(json.dumps(status(a.cdprctl)["stream"], indent=2))


if __name__ == "__main__":
    main()
