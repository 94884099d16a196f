#!/usr/bin/env bash
# Builds the optimised preset and runs every benchmark; figures are printed, nothing is asserted.
#   bash scripts/bench.sh              all benchmarks
#   bash scripts/bench.sh model        only the ones whose program name contains "model"
set -euo pipefail
cd "$(dirname "$0")/.."
filter=${1:-}
bash scripts/install-deps.sh
cmake --preset release >/dev/null
programs=(model_bench statics_bench bench_canopen_cycle bench_sim identification_bench mismatch_bench monitoring_bench daemon_bench)
targets=()
for p in "${programs[@]}"; do [[ -z "$filter" || "$p" == *"$filter"* ]] && targets+=("$p"); done
[ ${#targets[@]} -gt 0 ] || { echo "bench: no benchmark matches '$filter'" >&2; exit 2; }
cmake --build --preset release -j "$(nproc)" --target "${targets[@]}"
for p in "${targets[@]}"; do
  exe=$(find build/release/bench -maxdepth 1 -type f -name "$p" | head -n 1)
  echo "== $p =="
  "$exe"
done
