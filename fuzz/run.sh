#!/usr/bin/env bash
# Runs every libFuzzer target (or the ones named) for a bounded time. See docs/fuzzing.md.
#
#   fuzz/run.sh [--build] [--seconds N] [--jobs N] [TARGET...]
#
#   --build      configure (preset `fuzz`, once; through ccache when installed) and build the
#                targets first: only what they link (parsers and decoders, not the identification)
#   --seconds N  fuzzing time per target (default: $CDPR_FUZZ_SECONDS, else 20)
#   --jobs N     targets run side by side (default 2)
#
# For each target: first every input kept in fuzz/regressions/<target>/ is replayed (each one once
# crashed the target), then the target fuzzes for N seconds, starting from its committed seeds
# (fuzz/corpus/<target>/) and what earlier runs found (build/fuzz/corpus/<target>/, not committed).
# A crash, sanitizer report, leak, timeout (> 25 s on one input) or out-of-memory (> 2 GB) fails
# the run; the input is written to build/fuzz/artifacts/<target>/. The table at the end gives the
# executions per target. Exit status 0 only when every target ran clean.
set -euo pipefail
cd "$(dirname "$0")/.."
src=$PWD
build=$src/build/fuzz

seconds=${CDPR_FUZZ_SECONDS:-20}
jobs=2
do_build=0
targets=()
while [ $# -gt 0 ]; do
  case $1 in
    --build) do_build=1 ;;
    --seconds) seconds=$2; shift ;;
    --jobs) jobs=$2; shift ;;
    -h|--help) sed -n '2,17p' "$0"; exit 0 ;;
    -*) echo "run.sh: unknown option $1" >&2; exit 2 ;;
    *) targets+=("$1") ;;
  esac
  shift
done
if [ ${#targets[@]} -eq 0 ]; then
  for d in "$src"/fuzz/corpus/*/; do targets+=("$(basename "$d")"); done
fi

if [ $do_build -eq 1 ]; then
  start=$(date +%s)
  # Through ccache where it is installed: a second run recompiles nothing that did not change.
  launcher=()
  if command -v ccache >/dev/null; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
  [ -f "$build/CMakeCache.txt" ] || cmake --preset fuzz "${launcher[@]}" >"$build.configure.log" 2>&1 ||
    { cat "$build.configure.log"; exit 1; }
  cmake --build --preset fuzz -j "$jobs" --target "${targets[@]/#/fuzz_}"
  echo "fuzz: build took $(($(date +%s) - start)) s"
fi

mkdir -p "$build/logs"
run_one() {
  local t=$1 exe=$build/fuzz/fuzz_$1 log=$build/logs/$1.log
  local work=$build/corpus/$t art=$build/artifacts/$t/
  mkdir -p "$work" "$art"
  : >"$log"
  if [ ! -x "$exe" ]; then
    echo "missing $exe (run with --build)" >>"$log"
    return 1
  fi
  local regressions=()
  if [ -d "$src/fuzz/regressions/$t" ]; then
    while IFS= read -r -d '' f; do regressions+=("$f"); done \
      < <(find "$src/fuzz/regressions/$t" -type f -print0 | sort -z)
  fi
  if [ ${#regressions[@]} -gt 0 ]; then
    echo "== replaying ${#regressions[@]} regression input(s)" >>"$log"
    "$exe" -artifact_prefix="$art" "${regressions[@]}" >>"$log" 2>&1 || return 1
  fi
  echo "== fuzzing for $seconds s" >>"$log"
  "$exe" -max_total_time="$seconds" -timeout=25 -rss_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="$art" "$work" "$src/fuzz/corpus/$t" >>"$log" 2>&1
}

status_dir=$(mktemp -d)
trap 'rm -rf "$status_dir"' EXIT
running=0
for t in "${targets[@]}"; do
  (
    if run_one "$t"; then echo ok >"$status_dir/$t"; else echo FAILED >"$status_dir/$t"; fi
  ) &
  running=$((running + 1))
  if [ $running -ge "$jobs" ]; then
    wait -n || true
    running=$((running - 1))
  fi
done
wait

failed=0
printf '%-18s %-7s %12s %10s %8s\n' target result executions exec/s corpus
for t in "${targets[@]}"; do
  log=$build/logs/$t.log
  result=$(cat "$status_dir/$t" 2>/dev/null || echo FAILED)
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  corpus=$(find "$build/corpus/$t" -type f 2>/dev/null | wc -l)
  printf '%-18s %-7s %12s %10s %8s\n' "$t" "$result" "${execs:--}" "${rate:--}" "$corpus"
  if [ "$result" != ok ]; then
    failed=1
    echo "---- $t: end of $log" >&2
    tail -40 "$log" >&2
  fi
done
exit $failed
