#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# cache.sh — the BVH cache: per scene, `mbvh info SCENE --cache DIR` REPEATS times into an empty
# DIR (the build; "BVH built in") and REPEATS times from the written file (the load, checksum and
# structure checks included; "read from the cache in"), alternating, each in a fresh process,
# 2 threads; the medians and their ratio. Scenes: the bunny, conference and gen:hairball:5000000.
#   bench/cache.sh [OUT] [REPEATS]      -> OUT/cache.md
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
OUT="${1:-$ROOT/bench/out-cache}"
REPEATS="${2:-5}"
mkdir -p "$OUT"
LIST="$(scene_rows "$SCENES" bunny conference hairball5m)"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
median() { sort -g | awk '{a[NR] = $1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
{
  echo "| scene | triangles | build ms (median of $REPEATS) | load ms (median of $REPEATS) | build / load | file MB |"
  echo "|---|---|---|---|---|---|"
  while IFS='|' read -r _ scene _; do
    : > "$TMP/build" ; : > "$TMP/load"
    for ((i = 0; i < REPEATS; i++)); do
      rm -rf "$TMP/c"
      "$MBVH" info "$scene" --threads 2 --cache "$TMP/c" 2>&1 | sed -n 's/.*BVH built in \([0-9.]*\) ms.*/\1/p' >> "$TMP/build"
      "$MBVH" info "$scene" --threads 2 --cache "$TMP/c" 2>&1 | sed -n 's/.*read from the cache in \([0-9.]*\) ms.*/\1/p' >> "$TMP/load"
    done
    if [ "$(wc -l < "$TMP/build")" != "$REPEATS" ] || [ "$(wc -l < "$TMP/load")" != "$REPEATS" ]; then
      echo "error: $scene: the build or load times are missing from mbvh info's output" >&2
      exit 1
    fi
    tris="$("$MBVH" info "$scene" 2>&1 | sed -n 's/^triangles *\([0-9]*\).*/\1/p')"
    b="$(median < "$TMP/build")" l="$(median < "$TMP/load")"
    mb="$(du -m "$TMP"/c/*.mbvh | cut -f1)"
    echo "| $(basename "$scene") | $tris | $b | $l | $(awk -v b="$b" -v l="$l" 'BEGIN {printf "%.1f", b / l}') | $mb |"
  done <<< "$LIST"
} | tee "$OUT/cache.md"
