#!/usr/bin/env python3
"""Platform mass and centre of mass over independent campaigns (issue 41, docs/identification.md).

A true robot whose platform is 12 % heavier than configured and whose centre of mass is off by
(15, -10, 20) mm: config/crane4.yaml (its anchors also 2 cm out and up) or MINI (truth
config/mini-measured.yaml, nominal config/mini.yaml). Each campaign is an elastic simulation of
the designed poses with its own noise seed, calibrated from the nominal config with mass and com
estimated. Per parameter: the campaign-to-campaign spread against the stated standard deviation,
and the share of campaigns whose estimate lies within 1 and 2 stated standard deviations of the
truth (about 68 % and 95 % when the stated uncertainty is honest). With --diagnose also what
diagnose (--bootstrap 5 --folds 3) names on each campaign, and the same table for the mass and
centre of mass of the platform weight it names.

  bench/weight_coverage.py --fit build/ci/tools/cdpr-fit --source . --robot crane [--campaigns 8]
      [--diagnose]
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

ROBOTS = {
    # nominal, truth source, replacements, true mass, true com, estimate items, channels
    "crane": ("config/crane4.yaml", "config/crane4.yaml",
              [("[1.0, -1.15, 1.8]", "[1.02, -1.17, 1.82]"),
               ("[-1.0, -1.15, 1.8]", "[-1.02, -1.17, 1.82]"),
               ("[-1.0, 1.15, 1.8]", "[-1.02, 1.17, 1.82]"),
               ("[1.0, 1.15, 1.8]", "[1.02, 1.17, 1.82]"),
               ("mass: 13.0", "mass: 14.56"),
               ("center_of_mass: [0, 0, -0.35]", "center_of_mass: [0.015, -0.01, -0.33]"),
               # where the offset centre of mass makes the true platform hang at home
               ("\n  rpy: [0, 0, 0]", "\n  rpy: [0.0197578, 0.0310434, 0]")],
              14.56, (0.015, -0.01, -0.33),
              "anchors,offsets,swivel-zeros,inclinometer-mounting,mass,com", "swivel,inclinometer"),
    "mini": ("config/mini.yaml", "config/mini-measured.yaml",
             [("mass: 2.0", "mass: 2.24"),
              ("center_of_mass: [0, 0, 0]", "center_of_mass: [0.015, -0.01, 0.02]")],
             2.24, (0.015, -0.01, 0.02), "anchors,offsets,laser-plane,mass,com", None),
}


def run(cmd):
    return subprocess.run(cmd, capture_output=True, text=True)


def table(title, est, true_value):
    print(title)
    print("%-15s %10s %12s %12s %12s %8s %8s" %
          ("parameter", "truth", "mean", "spread", "stated", "in 1 sd", "in 2 sd"))
    in1 = in2 = total = 0
    for name, v in est.items():
        n = len(v)
        if n < 2:
            continue
        mean = sum(x[0] for x in v) / n
        spread = math.sqrt(sum((x[0] - mean) ** 2 for x in v) / (n - 1))
        stated = math.sqrt(sum(x[1] ** 2 for x in v) / n)
        c1 = sum(abs(x[0] - true_value[name]) <= x[1] for x in v)
        c2 = sum(abs(x[0] - true_value[name]) <= 2 * x[1] for x in v)
        in1, in2, total = in1 + c1, in2 + c2, total + n
        print("%-15s %10.4f %12.5f %12.5f %12.5f %5d/%-2d %5d/%-2d" %
              (name, true_value[name], mean, spread, stated, c1, n, c2, n))
    if total:
        print("coverage: %.0f %% within 1 sd (68 %% expected), %.0f %% within 2 sd (95 %%)" %
              (100.0 * in1 / total, 100.0 * in2 / total))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fit", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--robot", choices=sorted(ROBOTS), default="crane")
    ap.add_argument("--campaigns", type=int, default=8)
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--diagnose", action="store_true")
    a = ap.parse_args()
    nominal_rel, truth_rel, edits, mass, com, items, channels = ROBOTS[a.robot]
    nominal = os.path.join(a.source, nominal_rel)
    text = open(os.path.join(a.source, truth_rel)).read()
    for old, new in edits:
        if old not in text:
            sys.exit("%s: no '%s'" % (truth_rel, old))
        text = text.replace(old, new)
    work = tempfile.mkdtemp(prefix="weight_coverage_")
    truth = os.path.join(work, "truth.yaml")
    open(truth, "w").write(text)
    true_value = {"platform.mass": mass, "platform.com.x": com[0], "platform.com.y": com[1],
                  "platform.com.z": com[2]}
    est = {n: [] for n in true_value}  # name -> [(value, std)]
    est_diag = {n: [] for n in true_value}
    named = []
    for k in range(a.campaigns):
        rec = os.path.join(work, "rec%d.csv" % k)
        cmd = [a.fit, "simulate", "--config", truth, "--nominal", nominal, "--physics", "elastic",
               "--design", str(a.poses), "--seed", str(100 + k), "--out", rec]
        if channels:
            cmd += ["--channels", channels]
        r = run(cmd)
        if r.returncode != 0:
            sys.exit("simulate failed: " + r.stderr)
        rep = os.path.join(work, "rep%d.json" % k)
        r = run([a.fit, "calibrate", "--config", nominal, "--recording", rec, "--estimate", items,
                 "--report", rep])
        if r.returncode not in (0, 3, 4):
            sys.exit("calibrate failed (%d): %s" % (r.returncode, r.stderr + r.stdout))
        for p in json.load(open(rep))["estimate"]:
            if p["name"] in est:
                est[p["name"]].append((p["value"], p["std_dev"]))
        if a.diagnose:
            r = run([a.fit, "--json", "diagnose", "--config", nominal, "--recording", rec,
                     "--bootstrap", "5", "--folds", "3"])
            j = json.loads(r.stdout)
            named.append(",".join(j["named_effects"]) or "(nothing)")
            for e in j["accepted"]:
                for p in e["parameters"] if e["id"] == "platform_weight" else []:
                    if p["name"] in est_diag:
                        est_diag[p["name"]].append((p["value"], p["std_dev"]))
    print("%s, %d campaigns of %d poses" % (a.robot, a.campaigns, a.poses))
    table("calibrate --estimate " + items, est, true_value)
    if a.diagnose:
        table("diagnose (the platform weight where named)", est_diag, true_value)
        print("diagnose named: " + "; ".join(named))


if __name__ == "__main__":
    main()
