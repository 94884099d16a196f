#!/usr/bin/env bash
# Installs, from Debian's packages, exactly what cdpr needs to build, test and run its main job.
# Idempotent: packages already present are not touched. Runs as root without prompts.
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build pkg-config clang-format clang-tidy
  # compiler cache: scripts/test.sh and fuzz/run.sh compile through it, so a rerun rebuilds only
  # what changed
  ccache
  # libFuzzer targets (fuzz/, preset fuzz): clang and its sanitizer/fuzzer runtimes
  clang libclang-rt-14-dev
  # libraries
  libeigen3-dev libceres-dev libspdlog-dev libfmt-dev libmodbus-dev libyaml-cpp-dev
  nlohmann-json3-dev libcli11-dev libgtest-dev libgmock-dev libbenchmark-dev libsystemd-dev
  # virtual CAN bus through user-mode-linux, and independent protocol peers for interop tests
  user-mode-linux kmod iproute2 can-utils socat python3 python3-can python3-pymodbus python3-yaml
  tshark mbpoll
  # the report's browser test (tests/report) and the docs screenshot: headless Chromium
  chromium
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed'; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} Debian packages already installed"
  exit 0
fi

echo "install-deps: installing ${#missing[@]} Debian package(s): ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; }
  SUDO="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
# tshark asks whether non-root users may capture; answer no without a prompt.
echo "wireshark-common wireshark-common/install-setuid boolean false" | $SUDO debconf-set-selections
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "install-deps: done"
