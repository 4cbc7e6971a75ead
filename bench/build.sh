#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# build.sh — issue 15's build benchmark: build time and tree quality of our builders (--quality
# low / medium / high: binned SAH, and SBVH spatial splits) beside Embree's (RTC_BUILD_QUALITY_LOW /
# MEDIUM / HIGH) on the same triangles: the bunny, conference, Sibenik and Sponza (interior cameras
# as in bench/cpu_vs_embree.sh) and gen:hairball 100K and 1M (10M with BUILD_BENCH_10M=1: about
# 6 GB and several minutes). Per scene and quality:
#   `mbvh build-bench` — build time, median of REPEATS (ours: Accel::build + MBVH4 collapse;
#                        Embree: rtcCommitScene), 2 threads, and our SAH cost;
#   `mbvh bench`       — diffuse rays on `cpu` (MBVH4 stack) and `embree`, verified, with nodes,
#                        leaves and triangles per ray for ours (Embree has no counters).
# Writes OUT/*.json, OUT/build.json (merged), OUT/build.md (Markdown table) and OUT/build.png
# (build time against diffuse Mrays/s per builder; needs python3-matplotlib, see bench/python.sh).
#   bench/build.sh [--quick] [OUT] [RAYS] [REPEATS]
#   --quick: the CI smoke, bunny and gen:hairball:20000, 20K rays, 1 repeat, no plot (seconds)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
QUICK=0
if [ "${1:-}" = "--quick" ]; then QUICK=1; shift; fi
OUT="${1:-$ROOT/bench/out-build}"
MBVH="${MBVH:-$ROOT/build/mbvh}"
SCENES="$ROOT/../shared/scenes"
if [ "$QUICK" = 1 ]; then
  RAYS="${2:-20000}"; REPEATS="${3:-1}"; PASSES=5; WARMUP=0
  LIST="bunny|$SCENES/bun_zipper.ply.zst|
hairball20k|gen:hairball:20000|"
else
  RAYS="${2:-1000000}"; REPEATS="${3:-5}"; PASSES=10; WARMUP=0.25
  LIST="bunny|$SCENES/bun_zipper.ply.zst|
conference|$SCENES/conference.obj.zst|--camera 0,300,0,1000,200,0
sibenik|$SCENES/sibenik.obj.zst|--camera -14,-9,0,10,-6,0
sponza|$SCENES/sponza_dabrovic.obj.zst|--camera -10,4,0,10,5,0
hairball100k|gen:hairball:100000|
hairball1m|gen:hairball:1000000|"
  if [ "${BUILD_BENCH_10M:-0}" = 1 ]; then LIST="$LIST
hairball10m|gen:hairball:10000000|"; fi
fi
mkdir -p "$OUT"
BACKENDS=cpu
devices="$("$MBVH" devices 2>/dev/null || true)"  # captured: `| grep -q` can SIGPIPE under pipefail
grep -q '^embree  *ready' <<<"$devices" && BACKENDS=cpu,embree || true
while IFS='|' read -r name scene camera; do
  for q in low medium high; do
    "$MBVH" build-bench "$scene" --quality "$q" --threads 2 --repeats "$REPEATS" --json "$OUT/build-$name-$q.json" >&2
    # shellcheck disable=SC2086
    "$MBVH" bench "$scene" --quality "$q" --threads 2 --backend "$BACKENDS" --layout mbvh4 --traversal stack \
      --query closest --kinds diffuse --count "$RAYS" --passes "$PASSES" --warmup "$WARMUP" $camera \
      --json "$OUT/bench-$name-$q.json" >&2
  done
done <<< "$LIST"
PLOT=--plot
if [ "$QUICK" = 1 ]; then PLOT=; else
  # shellcheck source=bench/python.sh
  . "$ROOT/bench/python.sh"
fi
"${PY:-python3}" "$ROOT/bench/build_table.py" "$OUT" $PLOT
