#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# instances.sh — instancing against the same triangles flattened: build/mbvh-instances-bench
# (bench/instances.cpp) on the bunny: INSTANCES copies traced instanced (random and primary rays,
# closest and any hit), the first FLAT of them also flattened, built and traced with the same
# kernels on the same rays (the ratio), answers compared with the flattened BVH (every ray) and the
# double brute force (a sample). Times under flock /work/timing.lock when it exists (one timer at a
# time on a shared machine); records the load, lscpu and the commit beside the table in OUT.
#   bench/instances.sh [OUT] [INSTANCES] [FLAT] [RAYS] [REPEATS] [THREADS]
#   (default bench/out, 1000, 100, 262144, 5, 0 = all; BUILD=build)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${BUILD:-$ROOT/build}"
OUT="${1:-$ROOT/bench/out}"
N="${2:-1000}" FLAT="${3:-100}" RAYS="${4:-262144}" REPEATS="${5:-5}" THREADS="${6:-0}"
MESH="$ROOT/../shared/scenes/bun_zipper.ply.zst"
mkdir -p "$OUT"
{
  echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "commit: $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet -- backends host bench || echo ' (tree modified)')"
  echo "load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
  lscpu | grep -E 'Model name|^CPU\(s\)|Flags' | cut -c1-200
} >"$OUT/instances-run.txt"
lock=()
[ -e /work/timing.lock ] && lock=(flock /work/timing.lock)
"${lock[@]}" "$BUILD/mbvh-instances-bench" "$MESH" "$N" "$FLAT" "$RAYS" "$REPEATS" "$THREADS" | tee "$OUT/instances.md"
