#!/usr/bin/env bash
# The README's main job: a full auto-calibration of MINI by cdprd against the virtual robot on a
# virtual CAN bus, ending in the calibration report.
#
#   bash scripts/main-job.sh            (output in build/main-job/; a second run reuses the build)
#
# Installs what is missing (Debian packages), builds cdprd, cdprctl and cdpr-sim (release preset),
# then, where a kernel CAN bus exists (natively, or inside user-mode-linux through
# tests/vcan/vcan-run), starts the virtual robot (truth: config/mini-measured.yaml with the hidden
# effects of config/scenarios/mini-calibration.yaml; laser over Modbus TCP on loopback) and cdprd
# (nominal: config/mini.yaml), runs `cdprctl calibrate --wait`, accepts, and prints the result
# against the sim's truth. Exit status: 0 when the calibration was accepted and applied.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
preset=${CDPR_MAIN_JOB_PRESET:-release}
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset" -j "$(nproc)" --target cdprd cdprctl cdpr-sim
out=${CDPR_MAIN_JOB_DIR:-build/main-job}
rm -rf "$out"
mkdir -p "$out"
VCAN_RUN_TIMEOUT=${VCAN_RUN_TIMEOUT:-1200} tests/vcan/vcan-run -- \
  bash scripts/main-job-inner.sh "build/$preset" "$out"
