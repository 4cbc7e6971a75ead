#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# single_ray.sh — one ray per call from the caller's threads: build/mbvh-single-ray-bench (bench/
# single_ray.cpp: mbvh's RayQuery beside Embree's rtcIntersect1 / rtcOccluded1, 1 and 2 caller
# threads) on the 100K-triangle hairball and the conference room's interior view, and the
# single-ray traversals side by side on one thread (`mbvh bench --threads 1`, MBVH4 and MBVH8,
# stack, bitstack, ordered stack: the choice of RayQuery's defaults). Waits first, up to 10
# minutes, for no compiler or ctest to run on the machine (checked every 20 s), and records the
# load, lscpu and the commit beside the tables in OUT.
#   bench/single_ray.sh [OUT] [RAYS] [REPEATS]   (default bench/out, 200000, 7; BUILD=build)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${BUILD:-$ROOT/build}"
OUT="${1:-$ROOT/bench/out}"
RAYS="${2:-200000}"
REPEATS="${3:-7}"
SCENES="$ROOT/../shared/scenes"
mkdir -p "$OUT"
for i in $(seq 30); do
  pgrep -f "cc1plus|ctest" >/dev/null || break
  echo "== waiting for compilers and ctest to finish ($i/30)" >&2
  sleep 20
done
{
  echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "commit: $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet -- backends host bench || echo ' (tree modified)')"
  echo "compilers or ctest running at start: $(pgrep -fc 'cc1plus|ctest' || true)"
  echo "load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo "rays per kind: $RAYS, repeats: $REPEATS"
} >"$OUT/run.txt"
lscpu >"$OUT/lscpu.txt"
"$BUILD/mbvh-single-ray-bench" gen:hairball:100000 "$RAYS" "$REPEATS" | tee "$OUT/hairball100k.md"
"$BUILD/mbvh-single-ray-bench" "$SCENES/conference.obj.zst" "$RAYS" "$REPEATS" 0,300,0,1000,200,0 | tee "$OUT/conference.md"
for scene in gen:hairball:100000 "$SCENES/conference.obj.zst"; do
  name=$(basename "$scene" .obj.zst | tr ':' '-')
  cam=()
  [ "$name" = conference ] && cam=(--camera 0,300,0,1000,200,0)
  "$BUILD/mbvh" bench "$scene" "${cam[@]}" --threads 1 --layout mbvh4,mbvh8 --traversal stack,bitstack,stack-ordered \
    --kinds primary,diffuse,shadow --count "$((RAYS / 2))" >"$OUT/traversals-$name.txt" 2>&1 || true
done
echo "load at end: $(cut -d' ' -f1-3 /proc/loadavg)" >>"$OUT/run.txt"
cat "$OUT/run.txt"
