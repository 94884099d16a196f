#!/usr/bin/env bash
# Checks tests/vcan/vcan-run itself: exit status, stdout/stderr, environment and directory pass
# through; the interfaces asked for exist; the path taken is reported; the time limit works.
#   vcan_run_selftest.sh [path/to/vcan-run]
set -uo pipefail
runner="${1:-$(dirname "$0")/vcan-run}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
fails=0
check() {  # check DESCRIPTION CONDITION...
  local what="$1"
  shift
  if "$@"; then echo "ok: $what"; else echo "FAILED: $what"; fails=$((fails + 1)); fi
}

cd "$work" || exit 1
export SELFTEST_VALUE=$'spaces "quotes" $dollar \\ and\nnewline'
t0=$(date +%s%N)
# shellcheck disable=SC2016  # expanded by the inner shell
"$runner" -- bash -c '
  printf "value=[%s]\n" "$SELFTEST_VALUE"
  echo "cwd=$PWD"
  echo "path=$CDPR_VCAN_PATH"
  ip -br link show type vcan
  echo "to stderr" >&2
  exit 7' >"$work/out" 2>"$work/err"
rc=$?
t1=$(date +%s%N)
echo "--- stdout"; cat "$work/out"; echo "--- stderr"; cat "$work/err"; echo "---"
echo "first run took $(((t1 - t0) / 1000000)) ms"
check "exit status 7 passes through" [ "$rc" -eq 7 ]
check "environment passes through" grep -qF "value=[spaces \"quotes\" \$dollar \\ and" "$work/out"
check "multi-line value intact" grep -qx "newline]" "$work/out"
check "runs in the caller's directory" grep -qx "cwd=$work" "$work/out"
check "vcan0 exists and is up" grep -qE '^vcan0 +UNKNOWN' "$work/out"
check "vcan1 exists and is up" grep -qE '^vcan1 +UNKNOWN' "$work/out"
check "stderr passes through" grep -qx "to stderr" "$work/err"
check "path line on stderr" grep -qE '^vcan-run: (native vcan|user-mode-linux [0-9.]+)' "$work/err"
check "CDPR_VCAN_PATH set" grep -qE '^path=(native vcan|user-mode-linux [0-9.]+)$' "$work/out"
grep -E '^vcan-run: ' "$work/err" | head -n1

"$runner" --ifaces vcan5 -- bash -c 'ip -br link show type vcan' >"$work/out2" 2>/dev/null
rc=$?
check "--ifaces vcan5: status 0" [ "$rc" -eq 0 ]
check "--ifaces vcan5: vcan5 exists" grep -qE '^vcan5 ' "$work/out2"
if grep -q "native vcan (existing" "$work/err"; then
  echo "skip: interfaces are shared on this host, vcan0 absence not checked"
else
  check "--ifaces vcan5: no vcan0" bash -c "! grep -qE '^vcan0 ' '$work/out2'"
fi

t0=$(date +%s)
"$runner" --timeout 2 -- sleep 120 >/dev/null 2>"$work/err3"
rc=$?
t1=$(date +%s)
check "time limit gives 124" [ "$rc" -eq 124 ]
check "time limit is enforced (took $((t1 - t0)) s)" [ $((t1 - t0)) -lt 30 ]

"$runner" --bogus -- true >/dev/null 2>&1
check "usage error gives 2" [ "$?" -eq 2 ]

echo "vcan_run_selftest: $fails failed"
[ "$fails" -eq 0 ]
