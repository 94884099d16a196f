#!/usr/bin/env bash
# Writes the MINI example of the calibration report into DIR: the measured MINI with a concealed
# force-sensor gain error (gain 2.1 raw units per N where the config says 2), 30 designed poses
# measured through the nominal model (config/mini.yaml) with elastic cables, then
# `cdpr-fit diagnose --html report.html`. The files are named as an engineer would give them
# (config/mini.yaml, rec.csv: relative to DIR, which gets a link to config/).
#   bash scripts/report-example.sh CDPR_FIT DIR
# Used by the browser test (tests/report) and by scripts/report-screenshot.sh.
set -euo pipefail
fit=$(realpath "$1")
dir=$2
source_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
mkdir -p "$dir"
cd "$dir"
ln -sfn "$source_dir/config" config
sed 's/force_sensor: {gain: 2, offset: 0}/force_sensor: {gain: 2.1, offset: 0}/' \
  config/mini-measured.yaml >truth.yaml
grep -q 'gain: 2.1' truth.yaml || { echo "report-example: could not set the gain error" >&2; exit 1; }
"$fit" simulate --config truth.yaml --nominal config/mini.yaml --physics elastic --design 30 \
  --seed 3 --out rec.csv >/dev/null
# diagnose exits 3 when it finds a mismatch (the point of the example); 1 and 2 are errors.
status=0
"$fit" diagnose --config config/mini.yaml --recording rec.csv --html report.html \
  --out calibrated.yaml >diagnose.txt || status=$?
if [ "$status" -ne 0 ] && [ "$status" -ne 3 ] && [ "$status" -ne 4 ]; then
  cat diagnose.txt >&2
  echo "report-example: cdpr-fit diagnose failed (exit $status)" >&2
  exit 1
fi
test -s report.html
