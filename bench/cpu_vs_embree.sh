#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# cpu_vs_embree.sh — issue 14's deciding benchmark (issue 3's, extended): the cpu backend beside
# two Embree peers in one run — Embree's robust mode (`embree`, RTC_SCENE_FLAG_ROBUST) and its
# default mode (`embree --precision fast`, the flag off) — with the cpu backend in robust and fast
# precision: MBVH4 stack / bitstack / ordered stack and MBVH8 stack / bitstack / ordered stack;
# primary and diffuse rays as closest hit, shadow rays as any hit (occlusion); on 1 and 2 threads
# (`--scaling` times each variant on one thread too, its passes interleaved with the 2-thread
# ones); on the bunny and the interior views of the conference room, Sibenik and Sponza, and the
# generated hairball at 100K and 1M triangles (10M with MBVH_BENCH_10M=1: about 2 GB and minutes
# of build). Every timed result is verified by `mbvh bench` first (robust: against cpu-scalar;
# fast modes: mismatches are reported, not required to be 0). Writes one JSON per scene and
# query to OUT (default bench/out) and prints the Markdown tables of bench/cpu_table.py.
#   bench/cpu_vs_embree.sh [--quick] [OUT] [RAYS] [LEAF_BLOCK]
#     (about 15 minutes on 2 cores with RAYS=1000000; LEAF_BLOCK: the build's --leaf-block,
#     default 1; --quick: 2000 rays, the bunny and a 20K hairball, no warm-up — a smoke test of
#     the script and the table, under 30 s)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
QUICK=0
if [ "${1:-}" = "--quick" ]; then QUICK=1; shift; fi
OUT="${1:-$ROOT/bench/out}"
RAYS="${2:-1000000}"
LEAF_BLOCK="${3:-1}"
MBVH="${MBVH:-$ROOT/build/mbvh}"
SCENES="$ROOT/../shared/scenes"
mkdir -p "$OUT"
EXTRA=()
if [ "$QUICK" = 1 ]; then
  RAYS=2000
  EXTRA=(--warmup 0 --passes 5)
  LIST="bunny|$SCENES/bun_zipper.ply.zst|
hairball20k|gen:hairball:20000|"
else
  # name | scene | camera (interior views of the three buildings; the bunny and hairballs framed)
  LIST="bunny|$SCENES/bun_zipper.ply.zst|
conference|$SCENES/conference.obj.zst|--camera 0,300,0,1000,200,0
sibenik|$SCENES/sibenik.obj.zst|--camera -14,-9,0,10,-6,0
sponza|$SCENES/sponza_dabrovic.obj.zst|--camera -10,4,0,10,5,0
hairball100k|gen:hairball:100000|
hairball1m|gen:hairball:1000000|"
  if [ "${MBVH_BENCH_10M:-0}" = 1 ]; then LIST="$LIST
hairball10m|gen:hairball:10000000|"; fi
fi
COMMON=(--backend cpu,embree --precision robust,fast --layout mbvh4,mbvh8 --traversal stack,bitstack,stack-ordered
        --count "$RAYS" --threads 2 --scaling --leaf-block "$LEAF_BLOCK")
while IFS='|' read -r name scene camera; do
  # shellcheck disable=SC2086
  "$MBVH" bench "$scene" "${COMMON[@]}" "${EXTRA[@]}" --query closest --kinds primary,diffuse $camera \
    --json "$OUT/$name-closest.json" >&2
  # shellcheck disable=SC2086
  "$MBVH" bench "$scene" "${COMMON[@]}" "${EXTRA[@]}" --query any --kinds shadow $camera \
    --json "$OUT/$name-any.json" >&2
done <<< "$LIST"
python3 "$ROOT/bench/cpu_table.py" "$OUT"/*.json
