#!/usr/bin/env python3
"""Mutation run of cdpr-fit's calibrate, diagnose and simulate as a user would meet them (issue 16).

Starts from a valid MINI session (designed poses, an elastic recording) plus the inputs of the
issue (a 0xFF cell, cmd_x = 1e300, a -1e308 cell, noise 1e300, a BOM, millimetres, an output
naming an input), mutates the recording, the robot config and the pose list (byte flips and
insertions of any byte, 0xFF and NUL included; extreme numbers in cells; duplicated, dropped,
swapped and truncated lines) and runs the three commands, with and without --json and --report.

Every run must end by itself (no signal, within --per-run seconds) with a documented exit status
(0, 1, 2; calibrate and diagnose also 3, 4); with --json, stdout must be one JSON document. The run stops after
--runs mutations or --seconds, whichever comes first, and fails when fewer than --min-runs ran.
The random generator is seeded (--seed): the same seed gives the same mutations.

  fuzz_cli.py --fit build/ci/tools/cdpr-fit --source . [--seconds 150] [--runs 4000]
"""
import argparse
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

EXTREMES = ["1e300", "-1e308", "1e-320", "nan", "inf", "-inf", "", "0", "-0", "1e", "0x10",
            "99999999999999999999", "+-1", "1,2", "\xff", "\x00", "1e308", "-1e300"]
# calibrate: 3 fit test failed, 4 not trustworthy (docs/cdpr-fit.md); diagnose: 3 mismatch, 4 inconclusive.
ALLOWED = {"calibrate": {0, 1, 2, 3, 4}, "simulate": {0, 1, 2}, "diagnose": {0, 1, 2, 3, 4}}


def mutate(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        kind = rng.randrange(8)
        if not b:
            b += b"\xff"
            continue
        if kind == 0:  # flip a byte to any value
            b[rng.randrange(len(b))] = rng.randrange(256)
        elif kind == 1:  # insert a byte
            b.insert(rng.randrange(len(b) + 1), rng.choice([0xFF, 0x00, 0xC3, 0x0A, 0x2C, 0x23,
                                                             rng.randrange(256)]))
        elif kind == 2:  # delete a byte range
            i = rng.randrange(len(b))
            del b[i:i + rng.randrange(1, 8)]
        elif kind in (3, 4):  # an extreme value in a cell or after a colon
            lines = bytes(b).split(b"\n")
            i = rng.randrange(len(lines))
            sep = b"," if b"," in lines[i] else b":"
            cells = lines[i].split(sep)
            j = rng.randrange(len(cells))
            cells[j] = (b" " if sep == b":" and j > 0 else b"") + \
                rng.choice(EXTREMES).encode("latin-1")
            lines[i] = sep.join(cells)
            b = bytearray(b"\n".join(lines))
        elif kind == 5:  # duplicate or drop a line
            lines = bytes(b).split(b"\n")
            i = rng.randrange(len(lines))
            if rng.random() < 0.5:
                lines.insert(i, lines[i])
            else:
                del lines[i]
            b = bytearray(b"\n".join(lines))
        elif kind == 6:  # swap two lines
            lines = bytes(b).split(b"\n")
            i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
            b = bytearray(b"\n".join(lines))
        else:  # truncate, or put a BOM in front
            if rng.random() < 0.5:
                del b[rng.randrange(len(b)):]
            else:
                b[0:0] = b"\xef\xbb\xbf"
    return bytes(b)


def run(fit, args, per_run, cwd):
    start = time.monotonic()
    try:
        p = subprocess.run([fit] + args, cwd=cwd, capture_output=True, timeout=per_run)
    except subprocess.TimeoutExpired:
        return None, b"", b"timeout", time.monotonic() - start
    return p.returncode, p.stdout, p.stderr, time.monotonic() - start


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fit", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--seconds", type=float, default=150.0)
    ap.add_argument("--runs", type=int, default=4000)
    ap.add_argument("--min-runs", type=int, default=0)
    ap.add_argument("--per-run", type=float, default=120.0)
    ap.add_argument("--seed", type=int, default=16)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--keep", help="directory to copy failing inputs to")
    a = ap.parse_args()
    nominal = os.path.join(a.source, "config", "mini.yaml")
    truth = os.path.join(a.source, "config", "mini-measured.yaml")
    work = tempfile.mkdtemp(prefix="cdpr_fit_fuzz_")
    try:
        for cmd in (["design-poses", "--config", nominal, "--count", "12", "--out", "poses.csv"],
                    ["simulate", "--config", truth, "--nominal", nominal, "--physics", "elastic",
                     "--poses", "poses.csv", "--seed", "3", "--out", "rec.csv"]):
            code, _, err, _ = run(a.fit, cmd, 120, work)
            if code != 0:
                print("fuzz_cli: setting up failed:", err.decode(errors="replace"))
                return 1
        seeds = {
            "rec": open(os.path.join(work, "rec.csv"), "rb").read(),
            "poses": open(os.path.join(work, "poses.csv"), "rb").read(),
            "config": open(nominal, "rb").read(),
        }
        # The inputs of the issue, run first.
        fixed = [("poses", b"# units: SI\npose,x,y,z,roll,pitch,yaw\n0,\xff,0,0,0,0,0\n"),
                 ("rec", b"\xef\xbb\xbf" + seeds["rec"]),
                 ("config", seeds["config"].replace(b"name: MINI", b"name: MINI\xff"))]
        lines = seeds["rec"].split(b"\n")
        header = next(i for i, l in enumerate(lines) if l.startswith(b"pose,"))
        names = lines[header].split(b",")
        for column, value in ((b"cmd_x", b"1e300"), (b"length_2", b"-1e308"),
                              (b"laser_1", b"512.3")):
            row = lines[header + 3].split(b",")
            row[names.index(column)] = value
            fixed.append(("rec", b"\n".join(lines[:header + 3] + [b",".join(row)] +
                                           lines[header + 4:])))
        fixed.append(("rec", b"\n".join(l if not l.startswith(b"# noise_length_m")
                                        else b"# noise_length_m: 1e300" for l in lines)))

        rng = random.Random(a.seed)
        deadline = time.monotonic() + a.seconds
        failures = []
        counts = {}

        def one(n, target, data, command, json_flag, report):
            d = os.path.join(work, "run%d" % n)
            os.makedirs(d)
            files = {"rec": "rec.csv", "poses": "poses.csv", "config": "config.yaml"}
            for key, name in files.items():
                with open(os.path.join(d, name), "wb") as f:
                    f.write(data if key == target else seeds[key])
            args = (["--json"] if json_flag else [])
            if command == "calibrate":
                args += ["calibrate", "--config", "config.yaml", "--recording", "rec.csv",
                         "--out", "out.yaml"] + (["--report", "report.json"] if report else [])
            elif command == "diagnose":
                args += ["diagnose", "--config", "config.yaml", "--recording", "rec.csv",
                         "--bootstrap", "2", "--folds", "2", "--out", "out.yaml"] + \
                    (["--json", "report.json", "--html", "report.html"] if report else [])
            else:
                args += ["simulate", "--config", "config.yaml", "--poses", "poses.csv",
                         "--out", "out.csv"] + (["--nominal", "config.yaml", "--physics",
                                                 "elastic"] if report else [])
            # A run still going when the whole budget ends is cut, not counted; only a run that
            # overran its own limit (--per-run) is a failure.
            limit = min(a.per_run, max(1.0, deadline + 5.0 - time.monotonic()))
            code, out, err, secs = run(a.fit, args, limit, d)
            problem = None
            if code is None and limit < a.per_run:
                shutil.rmtree(d, ignore_errors=True)
                return n, command, "cut", None, err, d, args
            if code is None:
                problem = "no end within %.0f s" % a.per_run
            elif code < 0:
                problem = "killed by signal %d" % -code
            elif code not in ALLOWED[command]:
                problem = "exit status %d" % code
            elif json_flag:
                try:
                    json.loads(out.decode("utf-8"))
                except (ValueError, UnicodeDecodeError) as e:
                    problem = "stdout is not one JSON document (%s)" % e
            if problem is None:
                shutil.rmtree(d, ignore_errors=True)
            return n, command, code, problem, err, d, args

        n = 0
        outcomes = []
        with ThreadPoolExecutor(max_workers=a.jobs) as pool:
            pending = []
            while n < a.runs and time.monotonic() < deadline:
                if n < len(fixed) * 3:
                    target, data = fixed[n // 3]
                    command = ["calibrate", "diagnose", "simulate"][n % 3]
                else:
                    target = rng.choice(["rec", "rec", "config", "poses"])
                    data = mutate(seeds[target], rng)
                    command = {"rec": rng.choice(["calibrate", "calibrate", "diagnose"]),
                               "poses": "simulate",
                               "config": rng.choice(["calibrate", "diagnose", "simulate"])}[target]
                pending.append(pool.submit(one, n, target, data, command, rng.random() < 0.5,
                                           rng.random() < 0.5))
                n += 1
                # Keep the workers busy: wait for any run (a slow one does not hold the others).
                while len(pending) >= 2 * a.jobs:
                    done, rest = wait(pending, return_when=FIRST_COMPLETED)
                    outcomes += [p.result() for p in done]
                    pending = list(rest)
            outcomes += [p.result() for p in pending]
        elapsed = a.seconds - max(0.0, deadline - time.monotonic())
        for _, command, code, _, _, _, _ in outcomes:
            counts[(command, code)] = counts.get((command, code), 0) + 1
        failures = [o for o in outcomes if o[3] is not None]
        for num, command, code, problem, err, d, args in failures[:20]:
            print("fuzz_cli: run %d: cdpr-fit %s: %s\n  stderr: %s" %
                  (num, " ".join(args), problem, err.decode(errors="replace")[-600:]))
            if a.keep:
                shutil.copytree(d, os.path.join(a.keep, "run%d" % num), dirs_exist_ok=True)
        print("fuzz_cli: %d runs in %.0f s; exit statuses %s" %
              (n, elapsed, ", ".join("%s %s: %d" % (c, s_, k) for (c, s_), k in sorted(
                  counts.items(), key=lambda x: (x[0][0], str(x[0][1]))))))
        if failures:
            print("fuzz_cli: FAILED: %d runs ended badly" % len(failures))
            return 1
        if n < a.min_runs:
            print("fuzz_cli: FAILED: only %d runs (at least %d wanted): the machine is too slow "
                  "for --seconds" % (n, a.min_runs))
            return 1
        return 0
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
