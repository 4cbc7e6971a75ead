#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# cache.sh — issue 16's BVH-cache benchmark: per scene, `mbvh info SCENE --cache DIR` REPEATS
# times into an empty DIR (the build; "BVH built in") and REPEATS times from the written file
# (the load, checksum and structure checks included; "read from the cache in"), alternating, each
# in a fresh process, 2 threads; the medians and their ratio. Scenes: conference and
# gen:hairball:5000000 (the issue's two), and the bunny.
#   bench/cache.sh [OUT] [REPEATS]      -> OUT/cache.md
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$ROOT/bench/out-cache}"
REPEATS="${2:-5}"
MBVH="${MBVH:-$ROOT/build/mbvh}"
SCENES="$ROOT/../shared/scenes"
mkdir -p "$OUT"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
median() { sort -g | awk '{a[NR] = $1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
{
  echo "| scene | triangles | build ms (median of $REPEATS) | load ms (median of $REPEATS) | build / load | file MB |"
  echo "|---|---|---|---|---|---|"
  for scene in "$SCENES/bun_zipper.ply.zst" "$SCENES/conference.obj.zst" gen:hairball:5000000; do
    : > "$TMP/build" ; : > "$TMP/load"
    for ((i = 0; i < REPEATS; i++)); do
      rm -rf "$TMP/c"
      "$MBVH" info "$scene" --threads 2 --cache "$TMP/c" 2>&1 | sed -n 's/.*BVH built in \([0-9.]*\) ms.*/\1/p' >> "$TMP/build"
      "$MBVH" info "$scene" --threads 2 --cache "$TMP/c" 2>&1 | sed -n 's/.*read from the cache in \([0-9.]*\) ms.*/\1/p' >> "$TMP/load"
    done
    [ "$(wc -l < "$TMP/build")" = "$REPEATS" ] && [ "$(wc -l < "$TMP/load")" = "$REPEATS" ] ||
      { echo "error: $scene: the build or load times are missing from mbvh info's output" >&2; exit 1; }
    tris="$("$MBVH" info "$scene" 2>&1 | sed -n 's/^triangles *\([0-9]*\).*/\1/p')"
    b="$(median < "$TMP/build")" l="$(median < "$TMP/load")"
    mb="$(du -m "$TMP"/c/*.mbvh | cut -f1)"
    echo "| $(basename "$scene") | $tris | $b | $l | $(awk -v b="$b" -v l="$l" 'BEGIN {printf "%.1f", b / l}') | $mb |"
  done
} | tee "$OUT/cache.md"
