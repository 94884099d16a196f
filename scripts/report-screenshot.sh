#!/usr/bin/env bash
# Regenerates docs/report-mini.png, the screenshot of the MINI example of the calibration report
# (scripts/report-example.sh) as headless Chromium shows it 1280 px wide (README links it).
#   bash scripts/report-screenshot.sh [BUILD_DIR]     (default build/ci; cdpr-fit must be built)
set -euo pipefail
source_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
build=${1:-$source_dir/build/ci}
fit=$build/tools/cdpr-fit
command -v chromium >/dev/null || { echo "report-screenshot: chromium missing (bash scripts/install-deps.sh)" >&2; exit 1; }
[ -x "$fit" ] || { echo "report-screenshot: $fit missing (cmake --build --preset ci --target cdpr-fit)" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
bash "$source_dir/scripts/report-example.sh" "$fit" "$work/example"
# --no-sandbox: Chromium refuses to start its sandbox as root (CI containers).
chromium --headless --no-sandbox --disable-gpu --hide-scrollbars --window-size=1280,2000 \
  --screenshot="$work/shot.png" "file://$work/example/report.html" >/dev/null 2>&1
mv "$work/shot.png" "$source_dir/docs/report-mini.png"
echo "wrote docs/report-mini.png ($(stat -c %s "$source_dir/docs/report-mini.png") bytes)"
