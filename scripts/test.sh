#!/usr/bin/env bash
# The README's test command: installs what is missing, checks formatting, builds and runs every test.
#   bash scripts/test.sh            (CI preset: warnings are errors)
#   CDPR_PRESET=debug bash scripts/test.sh   (ASan/UBSan build; vcan tests excluded)
# At the end (also when a step fails) it prints the wall time of each phase and the 15 slowest
# tests, so that a slower build or test is seen when it happens. Compiles go through ccache
# when it is installed (scripts/install-deps.sh installs it).
set -euo pipefail
cd "$(dirname "$0")/.."
preset=${CDPR_PRESET:-ci}
ctest_log=build/$preset-ctest.log

phase_names=()
phase_seconds=()
current=""
started=0
begin() {
  finish
  current=$1
  started=$SECONDS
  echo "== $current =="
}
finish() {
  if [ -n "$current" ]; then
    phase_names+=("$current")
    phase_seconds+=($((SECONDS - started)))
    current=""
  fi
}
mmss() { printf '%d:%02d' $(($1 / 60)) $(($1 % 60)); }
# "<seconds> <name>" per test from CTest's output, slowest first.
test_times() {
  sed -nE 's/^ *[0-9]+\/[0-9]+ +Test +#[0-9]+: ([^ ]+) .* ([0-9]+\.[0-9]+) sec$/\2 \1/p' \
    "$ctest_log" | sort -rn
}
summary() {
  local rc=$?
  # The summary must not change the exit status: no -e, no pipefail (a reader that stops early
  # would end the pipeline with SIGPIPE, 141), and the status of the run is returned explicitly.
  set +e +o pipefail
  finish
  echo
  echo "== wall time per phase (preset $preset; exit status $rc) =="
  local i total=0
  for i in "${!phase_names[@]}"; do
    printf '  %-28s %6d s  %8s\n' "${phase_names[$i]}" "${phase_seconds[$i]}" \
      "$(mmss "${phase_seconds[$i]}")"
    total=$((total + phase_seconds[i]))
  done
  if [ -f "$ctest_log" ]; then
    # The fuzz run (its own clang build, then 20 s per target) is one CTest test, run alone.
    local fuzz
    fuzz=$(test_times | awk '$2 == "fuzz_all_targets" { printf "%d", $1 }')
    [ -n "$fuzz" ] && printf '  %-28s %6d s  %8s\n' "  of which fuzz_all_targets" "$fuzz" "$(mmss "$fuzz")"
  fi
  printf '  %-28s %6d s  %8s\n' total "$total" "$(mmss "$total")"
  if [ -f "$ctest_log" ]; then
    echo "== the 15 slowest tests (s) =="
    test_times | awk 'NR <= 15 { printf "  %8.1f  %s\n", $1, $2 }'
  fi
  exit "$rc"
}
trap summary EXIT
rm -f "$ctest_log"

begin "deps (install-deps.sh)"
bash scripts/install-deps.sh
begin "format (check-format.sh)"
bash scripts/check-format.sh

launcher=()
if command -v ccache >/dev/null; then launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache); fi
begin "configure (preset $preset)"
cmake --preset "$preset" "${launcher[@]}"
begin "build"
cmake --build --preset "$preset" -j "$(nproc)"
begin "tests (ctest)"
mkdir -p build
ctest --preset "$preset" -j "$(nproc)" 2>&1 | tee "$ctest_log"
