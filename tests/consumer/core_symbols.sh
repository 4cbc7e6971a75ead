#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# core_symbols.sh CORE_LIB CPU_LIB — the core links no backend: `nm -C` on the core library shows no
# backend symbol (defined or referenced). The same pattern must find the cpu backend's symbols in
# CPU_LIB, so the check is known to see what it looks for.
set -euo pipefail
core="$1" cpu="$2"
pattern='opencl|OpenCL|vulkan|Vulkan|embree|Embree|\brtc[A-Z]|\bcl[A-Z][a-zA-Z]+\(|\bvk[A-Z][a-zA-Z]+|cpu_kernels|avx2|avx512|register_builtin_backends|register_cpu|register_opencl|register_vulkan|register_embree'
syms="$(nm -C "$core")"
grep -q "mbvh::Accel::build(" <<<"$syms" || { echo "error: $core does not define mbvh::Accel::build" >&2; exit 1; }
if grep -E "$pattern" <<<"$syms"; then
  echo "error: the core library $core has the backend symbols above" >&2
  exit 1
fi
n="$(nm -C "$cpu" | grep -cE "$pattern" || true)"
[ "$n" -gt 0 ] || { echo "error: the pattern finds nothing in $cpu either: the check is blind" >&2; exit 1; }
echo "$core: $(grep -c . <<<"$syms") symbols, none of a backend ($n backend symbols found in $cpu)"
