#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# setup.sh — sourced by scripts/demo, scripts/test and scripts/cross-aarch64. Installs what is
# missing (Debian 12, as root) and defines mbvh_install PACKAGE... (the same for a stage's own
# packages) and mbvh_build DIR [CMAKE_ARGS...], which configures and builds mbvh in DIR.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${MBVH_BUILD_DIR:-$ROOT/build}"
PACKAGES=(build-essential cmake ninja-build pkg-config catch2 libzstd-dev zlib1g-dev nlohmann-json3-dev libcli11-dev zstd python3-matplotlib
          ocl-icd-opencl-dev opencl-headers pocl-opencl-icd
          libvulkan-dev mesa-vulkan-drivers glslang-tools vulkan-validationlayers
          libembree-dev openmpi-bin libopenmpi-dev
          python3-dev pybind11-dev python3-numpy python3-pytest python3-venv python3-setuptools python3-wheel
          ${MBVH_EXTRA_PACKAGES:-})

mbvh_install() {  # PACKAGE...: apt-get installs those not installed (a stage's own: scripts/cross-aarch64)
  local missing=() p
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  ((${#missing[@]})) || return 0
  echo "== installing: ${missing[*]}"
  local sudo=""
  [ "$(id -u)" = 0 ] || sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}
mbvh_install "${PACKAGES[@]}"

mbvh_build() {  # DIR [CMAKE_ARGS...]; MBVH_TARGETS="a b" builds only those targets
  local dir="$1"
  shift
  echo "== configuring and building in $dir $* ${MBVH_TARGETS:+(targets: $MBVH_TARGETS)}"
  # the Python module is built for Debian's python3 (python3-numpy, python3-pytest), not whichever
  # python3 comes first on PATH; MBVH_PYTHON_EXE picks another
  local py="${MBVH_PYTHON_EXE:-}"
  [ -n "$py" ] || [ ! -x /usr/bin/python3 ] || py=/usr/bin/python3
  cmake -S "$ROOT" -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=Release ${py:+"-DPython3_EXECUTABLE=$py"} "$@" >/dev/null
  # shellcheck disable=SC2086
  cmake --build "$dir" --parallel "$(nproc)" ${MBVH_TARGETS:+--target $MBVH_TARGETS}
}
