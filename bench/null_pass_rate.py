#!/usr/bin/env python3
"""How often `cdpr-fit calibrate` passes null recordings of the shipped robots (issue 41).

A null recording has no physics outside what calibrate estimates: the true robot is the shipped
config with every frame anchor moved by a random few centimetres (the uncertainty calibration is
for), simulated with the elastic physics and the default noise on poses designed on the nominal
config. Calibrate from the nominal config must then pass (exit status 0) in at least 95 % of the
seeds; any other exit is a false alarm (3: fit test failed, 4: not trustworthy, e.g. a huge
standard deviation) or a defect (anything else).

  bench/null_pass_rate.py --fit build/ci/tools/cdpr-fit --source . [--seeds 40]
      [--robots ipanema3,crane4,mini] [--poses 25] [--anchor-sd 0.02]

Prints one line per robot: passed / seeds, the exit statuses seen, the median chi2/dof and p, and
the first message of each failing seed.
"""
import argparse
import json
import os
import random
import re
import statistics
import subprocess
import sys
import tempfile

ANCHOR = re.compile(r"(frame_anchor:\s*\[)([^\]]*)(\])")


def truth_yaml(text, rng, sd):
    """The config with every frame_anchor moved by N(0, sd) per coordinate; a suspended robot
    (fewer than 7 cables: its home must stay in static equilibrium) has its frame widened and
    raised by one N(0, sd) draw instead."""
    suspended = len(ANCHOR.findall(text)) < 7
    common = rng.gauss(0.0, sd)

    def move(m):
        xyz = [float(v) for v in m.group(2).split(",")]
        if suspended:
            xyz = [xyz[0] + (common if xyz[0] > 0 else -common),
                   xyz[1] + (common if xyz[1] > 0 else -common), xyz[2] + common]
        else:
            xyz = [v + rng.gauss(0.0, sd) for v in xyz]
        return m.group(1) + ", ".join("%.6f" % v for v in xyz) + m.group(3)

    return ANCHOR.sub(move, text)


def run(cmd):
    return subprocess.run(cmd, capture_output=True, text=True)


def one_seed(fit, nominal, work, seed, poses, sd):
    rng = random.Random(seed)
    truth = os.path.join(work, "truth-%d.yaml" % seed)
    with open(nominal) as f, open(truth, "w") as g:
        g.write(truth_yaml(f.read(), rng, sd))
    rec = os.path.join(work, "rec-%d.csv" % seed)
    report = os.path.join(work, "report-%d.json" % seed)
    # The channels besides lengths and tensions: the laser where the robot has one, else the
    # suspended robot's swivel encoders and inclinometer.
    with open(nominal) as f:
        text = f.read()
    has_laser = re.search(r"^lasers?:", text, re.M) and not re.search(r"^lasers:\s*\[\]", text, re.M)
    channels = "laser" if has_laser else "swivel,inclinometer"
    s = run([fit, "simulate", "--config", truth, "--nominal", nominal, "--design", str(poses),
             "--physics", "elastic", "--seed", str(seed), "--channels", channels, "--out", rec])
    if s.returncode != 0:
        return {"exit": "simulate %d" % s.returncode, "message": s.stderr.strip()[:200]}
    c = run([fit, "calibrate", "--config", nominal, "--recording", rec, "--report", report])
    out = {"exit": c.returncode, "message": ""}
    if c.returncode != 0:
        lines = [l for l in (c.stderr + c.stdout).splitlines()
                 if l.startswith("cdpr-fit calibrate:")]
        out["message"] = (lines[0] if lines else "")[:240]
    try:
        with open(report) as f:
            r = json.load(f)
        ft = r.get("fit_test", {})
        if ft.get("dof"):
            out["chi2_dof"] = ft["chi2"] / ft["dof"]
            out["p"] = ft.get("p_value")
    except (OSError, ValueError):
        pass
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fit", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--robots", default="ipanema3,crane4,mini")
    ap.add_argument("--poses", type=int, default=25)
    ap.add_argument("--anchor-sd", type=float, default=0.02, help="m, per coordinate")
    a = ap.parse_args()
    work = tempfile.mkdtemp(prefix="null_pass_")
    worst = 1.0
    for robot in a.robots.split(","):
        nominal = os.path.join(a.source, "config", robot + ".yaml")
        results = [one_seed(a.fit, nominal, work, s, a.poses, a.anchor_sd)
                   for s in range(a.first_seed, a.first_seed + a.seeds)]
        passed = sum(1 for r in results if r["exit"] == 0)
        exits = {}
        for r in results:
            exits[str(r["exit"])] = exits.get(str(r["exit"]), 0) + 1
        chi = [r["chi2_dof"] for r in results if "chi2_dof" in r]
        ps = [r["p"] for r in results if r.get("p") is not None]
        print("%-9s passed %d/%d (%.1f %%)  exits %s  median chi2/dof %.3f  median p %.2f" %
              (robot, passed, len(results), 100.0 * passed / len(results),
               json.dumps(exits, sort_keys=True), statistics.median(chi) if chi else float("nan"),
               statistics.median(ps) if ps else float("nan")))
        for s, r in zip(range(a.first_seed, a.first_seed + a.seeds), results):
            if r["exit"] != 0:
                print("    seed %d: exit %s: %s" % (s, r["exit"], r["message"]))
        worst = min(worst, passed / len(results))
        sys.stdout.flush()
    return 0 if worst >= 0.95 else 1


if __name__ == "__main__":
    sys.exit(main())
