#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# cpu_vs_embree.sh — the cpu backend beside two Embree peers in one run: Embree's robust mode
# (`embree`, RTC_SCENE_FLAG_ROBUST) and its default mode (`embree --precision fast`, the flag off),
# with the cpu backend in robust and fast precision: MBVH4 stack / bitstack / ordered stack and
# MBVH8 stack / bitstack / ordered stack / octant-ordered stack (stack-octant) / octant-ordered bitstack (bitstack-octant); primary and diffuse rays as closest hit, shadow rays as
# any hit (occlusion); beside them, where this build has it, the tinybvh peer's two CPU layouts
# (`tinybvh`, fast precision only: BVH4_CPU as --layout mbvh4, BVH8_CPU as mbvh8, each its stack
# traversal) on the same rays and threads; on 1 and 2 threads (`--scaling` times each variant on one thread too, its
# passes interleaved with the 2-thread ones); on the bunny and the interior views of the
# conference room, Sibenik and Sponza, and the generated hairball at 100K and 1M triangles (10M
# with MBVH_BENCH_10M=1: about 2 GB and minutes of build). Every timed result is verified by
# `mbvh bench` first (robust: against cpu-scalar; fast modes: mismatches are reported, not
# required to be 0). Writes one JSON per scene and query to OUT (default bench/out) and prints
# the Markdown tables of bench/cpu_table.py.
#   bench/cpu_vs_embree.sh [--quick] [OUT] [RAYS] [LEAF_BLOCK]
#     (about 15 minutes on 2 cores with RAYS=1000000; LEAF_BLOCK: the build's --leaf-block,
#     default 1; --quick: 2000 rays, the bunny and a 20K hairball, no warm-up — a smoke test of
#     the script and the table, under 30 s)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out" "$@"
RAYS="${ARGS[0]:-1000000}"
LEAF_BLOCK="${ARGS[1]:-1}"
EXTRA=()
if [ "$QUICK" = 1 ]; then
  RAYS=2000
  EXTRA=(--warmup 0 --passes 5)
  NAMES=(bunny hairball20k)
else
  NAMES=(bunny conference sibenik sponza hairball100k hairball1m)
  if [ "${MBVH_BENCH_10M:-0}" = 1 ]; then NAMES+=(hairball10m); fi
fi
# MBVH_BENCH_SCENES=a,b: only these rows of bench/scenes.sh (e.g. hairball10m added to an earlier
# run's OUT: the table is made from every JSON in OUT)
if [ -n "${MBVH_BENCH_SCENES:-}" ]; then read -ra NAMES <<< "${MBVH_BENCH_SCENES//,/ }"; fi
LIST="$(scene_rows "$SCENES" "${NAMES[@]}")"
# the tinybvh peer where this build has it and this CPU runs it (AVX2 and FMA)
BACKENDS=cpu,embree
if "$MBVH" devices --ready 2>/dev/null | grep -qx tinybvh; then
  BACKENDS=cpu,embree,tinybvh
else
  log "no tinybvh peer in this build (or no AVX2 here): its columns stay empty"
fi
# shellcheck disable=SC2054  # the commas are mbvh's lists
COMMON=(--backend "$BACKENDS" --precision robust,fast --layout mbvh4,mbvh8 --traversal stack,bitstack,stack-ordered,stack-octant,bitstack-octant
        --count "$RAYS" --threads 2 --scaling --leaf-block "$LEAF_BLOCK")
while IFS='|' read -r name scene camera; do
  run_queries "$name" "$scene" "$camera" "${COMMON[@]}" "${EXTRA[@]}"
done <<< "$LIST"
python3 "$ROOT/bench/cpu_table.py" "$OUT"/*.json
