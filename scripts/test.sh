#!/usr/bin/env bash
# The README's test command: installs what is missing, checks formatting, builds and runs every test.
#   bash scripts/test.sh            (CI preset: warnings are errors)
#   CDPR_PRESET=debug bash scripts/test.sh   (ASan/UBSan build; vcan tests excluded)
set -euo pipefail
cd "$(dirname "$0")/.."
preset=${CDPR_PRESET:-ci}

bash scripts/install-deps.sh
bash scripts/check-format.sh

echo "== configure + build + test (preset: $preset) =="
cmake --preset "$preset"
cmake --build --preset "$preset" -j "$(nproc)"
ctest --preset "$preset" -j "$(nproc)"
