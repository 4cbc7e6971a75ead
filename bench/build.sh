#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# build.sh — build time and tree quality of our builders (--quality low / medium / high: LBVH,
# binned SAH, and SBVH spatial splits) beside Embree's (RTC_BUILD_QUALITY_LOW / MEDIUM / HIGH) on
# the same triangles: the bunny, conference, Sibenik and Sponza (interior cameras) and
# gen:hairball 100K and 1M (10M with BUILD_BENCH_10M=1: about 6 GB and several minutes). Per
# scene and quality:
#   `mbvh build-bench` — build time, median of REPEATS (ours: Accel::build + MBVH4 collapse;
#                        Embree: rtcCommitScene), 2 threads, our SAH cost, minor page faults per
#                        triangle of each build (ours, Embree), and --rebuild: our rebuild in a
#                        kept BuildContext and the cold build / rebuild ratio;
#   `mbvh bench`       — diffuse rays on `cpu` (MBVH4 stack) and `embree`, verified, with nodes,
#                        leaves and triangles per ray for ours (Embree has no counters).
# Writes OUT/*.json, OUT/build.json (merged), OUT/build.md (Markdown table) and OUT/build.png
# (build time against diffuse Mrays/s per builder; needs python3-matplotlib, else no plot).
#   bench/build.sh [--quick] [OUT] [RAYS] [REPEATS]
#   --quick: the CI smoke, bunny and gen:hairball:20000, 20K rays, 1 repeat, no plot (seconds)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out-build" "$@"
if [ "$QUICK" = 1 ]; then
  RAYS="${ARGS[0]:-20000}"; REPEATS="${ARGS[1]:-1}"; PASSES=5; WARMUP=0
  NAMES=(bunny hairball20k)
else
  RAYS="${ARGS[0]:-1000000}"; REPEATS="${ARGS[1]:-5}"; PASSES=10; WARMUP=0.25
  NAMES=(bunny conference sibenik sponza hairball100k hairball1m)
  if [ "${BUILD_BENCH_10M:-0}" = 1 ]; then NAMES+=(hairball10m); fi
fi
LIST="$(scene_rows "$SCENES" "${NAMES[@]}")"
BACKENDS=cpu
ready="$("$MBVH" devices --ready 2>/dev/null || true)"  # captured: `| grep -q` can SIGPIPE under pipefail
if grep -qx embree <<< "$ready"; then BACKENDS=cpu,embree; fi
while IFS='|' read -r name scene camera; do
  for q in low medium high; do
    "$MBVH" build-bench "$scene" --quality "$q" --threads 2 --repeats "$REPEATS" --rebuild \
      --json "$OUT/build-$name-$q.json" >&2
    # shellcheck disable=SC2086
    "$MBVH" bench "$scene" --quality "$q" --threads 2 --backend "$BACKENDS" --layout mbvh4 --traversal stack \
      --query closest --kinds diffuse --count "$RAYS" --passes "$PASSES" --warmup "$WARMUP" $camera \
      --json "$OUT/bench-$name-$q.json" >&2
  done
done <<< "$LIST"
PLOT=()
if [ "$QUICK" = 0 ] && use_matplotlib; then PLOT=(--plot); fi
"${PY:-python3}" "$ROOT/bench/build_table.py" "$OUT" "${PLOT[@]}"
