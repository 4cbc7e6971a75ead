#!/usr/bin/env bash
# cpu_vs_embree.sh — issue 3's benchmark: the cpu backend (MBVH4 stack / bitstack / ordered
# stack, MBVH8 ordered stack) beside Embree's robust single-ray kernels on the bunny, conference,
# Sibenik and Sponza, 1M primary, diffuse and shadow rays, on 1 and 2 threads, closest hit.
# Every timed result is verified by `mbvh bench` first; `--scaling` times each variant on one
# thread too, its passes interleaved with the 2-thread ones, so the 1-to-2-thread ratio is taken
# side by side. Writes one JSON per scene to OUT (default bench/out) and prints the Markdown
# tables of bench/cpu_table.py.
#   bench/cpu_vs_embree.sh [OUT] [RAYS] [LEAF_BLOCK]   (about 4 minutes on 2 cores with RAYS=1000000;
#   LEAF_BLOCK: the build's --leaf-block, default 1)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$ROOT/bench/out}"
RAYS="${2:-1000000}"
LEAF_BLOCK="${3:-1}"
MBVH="${MBVH:-$ROOT/build/mbvh}"
SCENES="$ROOT/../shared/scenes"
mkdir -p "$OUT"
# name | file | camera (interior views of the three buildings; the bunny framed by default)
while IFS='|' read -r name file camera; do
  # shellcheck disable=SC2086
  "$MBVH" bench "$SCENES/$file" --backend cpu,embree --layout mbvh4,mbvh8 \
    --traversal stack,bitstack,stack-ordered --query closest --kinds primary,diffuse,shadow \
    --count "$RAYS" --threads 2 --scaling --leaf-block "$LEAF_BLOCK" $camera --json "$OUT/$name.json" >&2
done <<'SCENES'
bunny|bun_zipper.ply.zst|
conference|conference.obj.zst|--camera 0,300,0,1000,200,0
sibenik|sibenik.obj.zst|--camera -14,-9,0,10,-6,0
sponza|sponza_dabrovic.obj.zst|--camera -10,4,0,10,5,0
SCENES
python3 "$ROOT/bench/cpu_table.py" "$OUT"/*.json
