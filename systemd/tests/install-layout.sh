#!/usr/bin/env bash
# install-layout.sh CMAKE BUILD_DIR SOURCE_DIR "PROGRAMS"
#
# `cmake --install` into temporary prefixes and checks the layout that cmake/CdprInstall.cmake
# promises (docs/deployment.md): programs (every shipped one, each answering --version from the
# installed tree), units, sysusers entry, configuration, docs, examples; nothing written outside
# the prefix; an existing configuration file is not replaced; with the
# prefix /usr the configuration goes to /etc/cdpr (under DESTDIR).
set -euo pipefail
cmake_bin=$1 build=$2 src=$3
read -r -a programs <<<"${4//;/ }"

tmp=$(mktemp -d /tmp/cdpr-install-XXXXXX)
trap 'rm -rf "$tmp"' EXIT
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
need_file() { [[ -f $1 ]] || fail "missing $1"; }

# Expected files, derived from the source tree.
expected_configs() {  # config files relative to config/, examples and scenarios left out
  (cd "$src/config" && find . -type f \( -name '*.yaml' -o -name '*.eds' \) \
     -not -path './examples/*' -not -path './scenarios/*' | sed 's|^\./||' | sort)
}

check_tree() {  # check_tree ROOT_OF_PREFIX ETC_DIR
  local p=$1 etc=$2
  for prog in "${programs[@]}"; do
    [[ -x $p/bin/$prog ]] || fail "program $prog not installed as $p/bin/$prog"
  done
  for unit in cdprd.service cdpr-calibrate.service cdpr-calibrate.timer; do
    need_file "$p/lib/systemd/system/$unit"
  done
  need_file "$p/lib/sysusers.d/cdpr.conf"
  local n=0
  while read -r f; do
    need_file "$etc/$f"
    n=$((n + 1))
  done < <(expected_configs)
  [[ $n -gt 0 ]] || fail "no configuration files found in $src/config"
  need_file "$p/share/doc/cdpr/README.md"
  for d in "$src"/docs/*.md; do need_file "$p/share/doc/cdpr/$(basename "$d")"; done
  need_file "$p/share/doc/cdpr/deployment.md"
  for f in "$src"/systemd/network/*; do
    need_file "$p/share/doc/cdpr/examples/network/$(basename "$f")"
  done
  for f in "$src"/config/scenarios/*; do
    need_file "$p/share/doc/cdpr/examples/scenarios/$(basename "$f")"
  done
  for f in "$src"/config/examples/*; do
    [[ $f == *.py ]] && continue
    need_file "$p/share/doc/cdpr/examples/data/$(basename "$f")"
  done
}

# Every program the project ships: the executables defined outside the tests, benchmarks and
# fuzz targets (controller/, sim/, tools/). Each must be built and installed.
shipped=$(grep -ho 'add_executable([A-Za-z0-9_-]*' "$src"/controller/*.cmake "$src"/controller/CMakeLists.txt \
            "$src"/sim/CMakeLists.txt "$src"/tools/CMakeLists.txt "$src"/tools/*.cmake 2>/dev/null |
          sed 's/add_executable(//' | sort -u)
[[ -n $shipped ]] || fail "no shipped program found in $src"
for prog in $shipped; do
  [[ " ${programs[*]} " == *" $prog "* ]] || fail "shipped program $prog is not in the install rules"
done

# 1. A plain prefix: everything under it.
prefix=$tmp/prefix
"$cmake_bin" --install "$build" --prefix "$prefix" >"$tmp/install1.log"
check_tree "$prefix" "$prefix/etc/cdpr"
# Each installed program runs from where it was installed: --version exits 0 and names it.
for prog in "${programs[@]}"; do
  [[ -x $prefix/bin/$prog ]] || continue
  if ! out=$("$prefix/bin/$prog" --version 2>&1); then
    fail "$prefix/bin/$prog --version exited with an error: $out"
  elif [[ $out != "$prog "* ]]; then
    fail "$prefix/bin/$prog --version printed '$out', expected '$prog <version>'"
  else
    echo "$out"
  fi
done
while read -r f; do
  [[ $f == "$prefix"/* ]] || fail "installed outside the prefix: $f"
done <"$build/install_manifest.txt"
echo "prefix install: $(wc -l <"$build/install_manifest.txt") files, programs: ${programs[*]:-none}"

# 2. Reinstall over an edited configuration file: the edit survives.
first=$(expected_configs | head -n1)
echo "# edited by the operator" >>"$prefix/etc/cdpr/$first"
"$cmake_bin" --install "$build" --prefix "$prefix" >"$tmp/install2.log"
grep -q "edited by the operator" "$prefix/etc/cdpr/$first" ||
  fail "reinstall replaced the edited $first"
grep -q "Kept (exists): .*$first" "$tmp/install2.log" || fail "reinstall did not say it kept $first"

# 3. The system layout: prefix /usr under DESTDIR, configuration in /etc/cdpr.
dest=$tmp/root
DESTDIR=$dest "$cmake_bin" --install "$build" --prefix /usr >"$tmp/install3.log"
check_tree "$dest/usr" "$dest/etc/cdpr"
[[ ! -e $dest/usr/etc ]] || fail "configuration installed to /usr/etc instead of /etc"

if [[ $failures -gt 0 ]]; then
  echo "$failures layout problems"
  exit 1
fi
echo "install layout OK"
