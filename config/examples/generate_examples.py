#!/usr/bin/env python3
"""Generates the example pre-calibration experiments of config/examples/ (synthetic data).

    python3 config/examples/generate_examples.py     # rewrites the two CSV files beside it

Both files are SYNTHETIC: made from the models below plus Gaussian noise with a fixed seed, not
measured. They show the formats (docs/recording-format.md) and give `cdpr-fit fit-cable` and
`cdpr-fit fit-force-sensor` something realistic to chew on.

cable-experiment.csv -- a 1.5 mm polymer (Dyneema-like) cable on a tensile bench: loaded lengths
  L = 0.5 .. 2.5 m in 0.25 m steps, tensions F = 10 .. 290 N in 20 N steps. Elongation model
  (a Hooke term with a stiffening polymer, plus a small constructional settling):
      dL = F L / EA0 * (1 - F / (2 F_s)) + c0 (1 - exp(-F / F_c))
  with EA0 = 25 kN, F_s = 900 N, c0 = 0.4 mm, F_c = 40 N, noise sigma 15 um (a dial gauge).
force-experiment.csv -- the 8 force sensors of MINI, each loaded with hanging masses 0, 1, 2, 5,
  10, 15, 20 kg (hook included). raw = gain * m * g + offset, g = 9.81 m/s^2, gains near the
  rig's 2 (2 +/- 3 %), offsets within +/- 2 raw units, noise sigma 0.05 raw.
mini-poses.csv -- a pose list for `cdpr-fit simulate --poses` on MINI: the home pose first (the
  identification's default gauge), then 29 poses drawn uniformly from +/- 0.12 m around home and
  +/- 0.05 rad in roll, pitch and yaw (not an optimised design; `cdpr-fit design-poses` makes
  better ones). All are wrench-feasible on config/mini.yaml and config/mini-measured.yaml.
"""
import math
import os
import random

HERE = os.path.dirname(os.path.abspath(__file__))


def cable(rng):
    ea0, f_s, c0, f_c, sigma = 25000.0, 900.0, 4e-4, 40.0, 15e-6
    rows = []
    for i in range(9):
        length = 0.5 + 0.25 * i
        for j in range(15):
            force = 10.0 + 20.0 * j
            dl = force * length / ea0 * (1.0 - force / (2.0 * f_s)) + c0 * (1.0 - math.exp(-force / f_c))
            rows.append((length, force, round(dl + rng.gauss(0.0, sigma), 7)))
    with open(os.path.join(HERE, "cable-experiment.csv"), "w") as f:
        f.write("# format: cdpr-cable-experiment 1\n# units: SI\n")
        f.write("# source: synthetic (config/examples/generate_examples.py, seed 2018)\n")
        f.write("# cable: 1.5 mm polymer, MINI\n")
        f.write("length_m,tension_n,elongation_m\n")
        for length, force, dl in rows:
            f.write(f"{length!r},{force!r},{dl!r}\n")


def force(rng):
    g = 9.81
    with open(os.path.join(HERE, "force-experiment.csv"), "w") as f:
        f.write("# format: cdpr-force-experiment 1\n# units: SI\n")
        f.write("# source: synthetic (config/examples/generate_examples.py, seed 2018)\n")
        f.write("# robot: MINI\n# gravity_m_s2: 9.81\n")
        f.write("channel,mass_kg,raw\n")
        for channel in range(1, 9):
            gain = 2.0 * (1.0 + rng.uniform(-0.03, 0.03))
            offset = rng.uniform(-2.0, 2.0)
            for mass in (0.0, 1.0, 2.0, 5.0, 10.0, 15.0, 20.0):
                raw = round(gain * mass * g + offset + rng.gauss(0.0, 0.05), 3)
                f.write(f"{channel},{mass!r},{raw!r}\n")


def poses(rng):
    with open(os.path.join(HERE, "mini-poses.csv"), "w") as f:
        f.write("# format: cdpr-poses 1\n# units: SI\n")
        f.write("# source: synthetic (config/examples/generate_examples.py, seed 2018)\n")
        f.write("# robot: MINI\n")
        f.write("pose,x,y,z,roll,pitch,yaw\n")
        f.write("0,0,0,0,0,0,0\n")
        for j in range(1, 30):
            p = [round(rng.uniform(-0.12, 0.12), 4) for _ in range(3)]
            a = [round(rng.uniform(-0.05, 0.05), 4) for _ in range(3)]
            f.write(f"{j}," + ",".join(repr(v) for v in p + a) + "\n")


if __name__ == "__main__":
    rng = random.Random(2018)
    cable(rng)
    force(rng)
    poses(rng)
