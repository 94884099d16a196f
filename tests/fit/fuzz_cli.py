#!/usr/bin/env python3
"""Mutation run of cdpr-fit's calibrate, diagnose, validate and simulate as a user would meet them.

Two robots: MINI (over-constrained, laser) and config/crane4.yaml (a suspended 4-cable crane with
swivel encoders, an inclinometer and an IMU heading). For each, a valid session (designed poses,
an elastic recording, a second recording held out) plus the inputs of issue 16 (a 0xFF cell,
cmd_x = 1e300, a -1e308 cell, noise 1e300, a BOM). Each run mutates the recording, the robot
config or the pose list (byte flips and insertions of any byte, 0xFF and NUL included; extreme
numbers in cells; duplicated, dropped, swapped and truncated lines) or none of them, and runs a
command with a random combination of its options (--gauge, --home-pose, --estimate words or
none, --loss, --method, --max-iterations, --fit-alpha, the --noise-* overrides, --validate),
with and without --json and the reports.

Every run must end by itself (no signal, within --per-run seconds) with a documented exit status
(0, 1, 2; calibrate and diagnose also 3, 4; calibrate 5 with --validate); with --json, stdout must
be one JSON document; a config that calibrate or diagnose wrote must load again (a fixed-model
calibrate on it names no error in it). The run stops after --runs runs or --seconds, whichever
comes first, and fails when fewer than --min-runs ran. The random generator is seeded (--seed):
the same seed gives the same runs.

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
# calibrate --validate: 5 the calibrated model predicts the held-out recording worse than nominal.
ALLOWED = {"calibrate": {0, 1, 2, 3, 4, 5}, "simulate": {0, 1, 2}, "diagnose": {0, 1, 2, 3, 4},
           "validate": {0, 1, 2}}
ESTIMATE_WORDS = ["anchors", "paper-anchors", "platform-anchors", "offsets", "scales", "stiffness",
                  "stiffness-per-cable", "force-gains", "force-offsets", "laser-origin",
                  "laser-direction", "laser-plane", "swivel-zeros", "inclinometer-mounting",
                  "imu-yaw-zero", "mass", "com"]
NOISES = ["length", "laser", "force", "swivel", "inclination", "imu-yaw", "ref-position",
          "ref-angle"]
# The robots: config, true robot (a file, or the config with text replaced), channels.
ROBOTS = {
    "mini": {"config": "config/mini.yaml", "truth": "config/mini-measured.yaml", "replace": [],
             "channels": "laser", "poses": 12},
    "crane": {"config": "config/crane4.yaml", "truth": None,
              # Anchors 2 cm further out and up (symmetric: it still hangs level at home), a
              # heavier platform.
              "replace": [("[1.0, -1.15, 1.8]", "[1.02, -1.17, 1.82]"),
                          ("[-1.0, -1.15, 1.8]", "[-1.02, -1.17, 1.82]"),
                          ("[-1.0, 1.15, 1.8]", "[-1.02, 1.17, 1.82]"),
                          ("[1.0, 1.15, 1.8]", "[1.02, 1.17, 1.82]"),
                          ("mass: 13.0", "mass: 14.0")],
              "channels": "swivel,inclinometer,imu-yaw", "poses": 10},
}


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


def set_up(fit, source, work, name, robot):
    """The valid session of one robot in work/name: config.yaml, poses.csv, rec.csv, held.csv."""
    d = os.path.join(work, name)
    os.makedirs(d)
    shutil.copy(os.path.join(source, robot["config"]), os.path.join(d, "config.yaml"))
    if robot["truth"]:
        shutil.copy(os.path.join(source, robot["truth"]), os.path.join(d, "truth.yaml"))
    else:
        text = open(os.path.join(source, robot["config"])).read()
        for old, new in robot["replace"]:
            if old not in text:
                return "%s: %r is not in %s" % (name, old, robot["config"])
            text = text.replace(old, new)
        open(os.path.join(d, "truth.yaml"), "w").write(text)
    design = ["design-poses", "--config", "config.yaml", "--count", str(robot["poses"]),
              "--out", "poses.csv"]
    for cmd in [design] + [["simulate", "--config", "truth.yaml", "--nominal", "config.yaml",
                            "--physics", "elastic", "--poses", "poses.csv", "--channels",
                            robot["channels"], "--seed", seed, "--out", out]
                           for seed, out in (("3", "rec.csv"), ("4", "held.csv"))]:
        code, _, err, _ = run(fit, cmd, 120, d)
        if code != 0:
            return "%s: %s: %s" % (name, " ".join(cmd), err.decode(errors="replace"))
    return None


def issue_inputs(seeds):
    """The inputs of issue 16 for one robot's seeds: (target, bytes)."""
    fixed = [("poses", b"# units: SI\npose,x,y,z,roll,pitch,yaw\n0,\xff,0,0,0,0,0\n"),
             ("rec", b"\xef\xbb\xbf" + seeds["rec"]),
             ("config", seeds["config"].replace(b"name: ", b"name: \xff", 1))]
    lines = seeds["rec"].split(b"\n")
    header = next(i for i, l in enumerate(lines) if l.startswith(b"pose,"))
    names = lines[header].split(b",")
    for column, value in ((b"cmd_x", b"1e300"), (b"length_2", b"-1e308"), (b"laser_1", b"512.3")):
        if column in names:
            row = lines[header + 3].split(b",")
            row[names.index(column)] = value
            fixed.append(("rec", b"\n".join(lines[:header + 3] + [b",".join(row)] +
                                           lines[header + 4:])))
    fixed.append(("rec", b"\n".join(l if not l.startswith(b"# noise_length_m")
                                    else b"# noise_length_m: 1e300" for l in lines)))
    return fixed


def options(command, rng):
    """A random combination of the command's options (none, some or many)."""
    o = []
    if command in ("calibrate", "diagnose"):
        if rng.random() < 0.4:
            o += ["--gauge", rng.choice(["home", "start", "laser-plane", "both", "none"])]
        if rng.random() < 0.15:
            o += ["--home-pose", rng.choice(["0", "1", "3", "-1", "999"])]
        if rng.random() < 0.4:
            words = ["none"] if rng.random() < 0.15 else rng.sample(ESTIMATE_WORDS,
                                                                    rng.randint(1, 4))
            o += ["--estimate", ",".join(words)]
        if rng.random() < 0.2:
            o += ["--validate", "held.csv"]
    if command == "calibrate":
        if rng.random() < 0.15:
            o += ["--loss", rng.choice(["huber", "cauchy", "none"])]
        if rng.random() < 0.1:
            o += ["--method", "paper"]
        if rng.random() < 0.15:
            o += ["--max-iterations", rng.choice(["1", "3"])]
        if rng.random() < 0.1:
            o += ["--fit-alpha", rng.choice(["0", "1", "0.5"])]
    if command in ("calibrate", "diagnose", "validate") and rng.random() < 0.3:
        for noise in rng.sample(NOISES, rng.randint(1, 3)):
            o += ["--noise-" + noise, rng.choice(["1e-9", "1e-3", "0.5", "1e300"])]
    return o


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
    a.fit = os.path.abspath(a.fit)
    work = tempfile.mkdtemp(prefix="cdpr_fit_fuzz_")
    try:
        seeds, fixed = {}, []
        for name, robot in ROBOTS.items():
            problem = set_up(a.fit, a.source, work, name, robot)
            if problem:
                print("fuzz_cli: setting up failed:", problem)
                return 1
            seeds[name] = {key: open(os.path.join(work, name, f), "rb").read() for key, f in
                           (("rec", "rec.csv"), ("poses", "poses.csv"),
                            ("config", "config.yaml"), ("held", "held.csv"))}
            fixed += [(name, t, data) for t, data in issue_inputs(seeds[name])]

        rng = random.Random(a.seed)
        deadline = time.monotonic() + a.seconds

        def one(n, robot, target, data, command, json_flag, report, opts):
            d = os.path.join(work, "run%d" % n)
            os.makedirs(d)
            files = {"rec": "rec.csv", "poses": "poses.csv", "config": "config.yaml",
                     "held": "held.csv"}
            for key, name in files.items():
                with open(os.path.join(d, name), "wb") as f:
                    f.write(data if key == target else seeds[robot][key])
            args = (["--json"] if json_flag else [])
            if command == "calibrate":
                args += ["calibrate", "--config", "config.yaml", "--recording", "rec.csv",
                         "--out", "out.yaml"] + (["--report", "report.json"] if report else [])
            elif command == "diagnose":
                args += ["diagnose", "--config", "config.yaml", "--recording", "rec.csv",
                         "--bootstrap", "2", "--folds", "2", "--out", "out.yaml"] + \
                    (["--json", "report.json", "--html", "report.html"] if report else [])
            elif command == "validate":
                args += ["validate", "--config", "config.yaml", "--recording", "held.csv",
                         "--model", "config.yaml"] + (["--model", "held.csv"] if report else [])
            else:
                args += ["simulate", "--config", "config.yaml", "--poses", "poses.csv",
                         "--out", "out.csv"] + (["--nominal", "config.yaml", "--physics",
                                                 "elastic"] if report else [])
            args += opts
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
            if problem is None and command != "simulate" and \
                    os.path.exists(os.path.join(d, "out.yaml")):
                # What calibrate or diagnose wrote must load again: a fixed-model calibrate on it
                # may fail its fit test but must name no error in out.yaml.
                reload = ["calibrate", "--config", "out.yaml", "--recording", "rec.csv",
                          "--estimate", "none"]
                limit = min(a.per_run, max(1.0, deadline + 5.0 - time.monotonic()))
                rcode, _, rerr, _ = run(a.fit, reload, limit, d)
                if rcode is not None and (rcode < 0 or b"error: out.yaml" in rerr):
                    problem = "the config it wrote does not reload (exit %d): %s" % (
                        rcode, rerr.decode(errors="replace")[-300:])
            if problem is None:
                shutil.rmtree(d, ignore_errors=True)
            return n, command, code, problem, err, d, args

        n = 0
        outcomes = []
        with ThreadPoolExecutor(max_workers=a.jobs) as pool:
            pending = []
            while n < a.runs and time.monotonic() < deadline:
                opts = []
                if n < len(fixed) * 3:
                    robot, target, data = fixed[n // 3]
                    command = ["calibrate", "diagnose", "simulate"][n % 3]
                else:
                    robot = rng.choice(list(ROBOTS))
                    target = rng.choice(["rec", "rec", "config", "poses", "held", None])
                    data = mutate(seeds[robot][target], rng) if target else None
                    command = {"rec": rng.choice(["calibrate", "calibrate", "diagnose"]),
                               "poses": "simulate",
                               "held": rng.choice(["validate", "calibrate"]),
                               "config": rng.choice(["calibrate", "diagnose", "simulate",
                                                     "validate"]),
                               None: rng.choice(["calibrate", "calibrate", "diagnose",
                                                 "validate"])}[target]
                    opts = options(command, rng)
                    if target == "held" and command == "calibrate" and "held.csv" not in opts:
                        opts += ["--validate", "held.csv"]
                pending.append(pool.submit(one, n, robot, target, data, command,
                                           rng.random() < 0.5, rng.random() < 0.5, opts))
                n += 1
                # Keep the workers busy: wait for any run (a slow one does not hold the others).
                while len(pending) >= 2 * a.jobs:
                    done, rest = wait(pending, return_when=FIRST_COMPLETED)
                    outcomes += [p.result() for p in done]
                    pending = list(rest)
            outcomes += [p.result() for p in pending]
        elapsed = a.seconds - max(0.0, deadline - time.monotonic())
        counts = {}
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
