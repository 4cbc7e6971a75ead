#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# all.sh — every table and plot of docs/benchmarks.md's first part, on every backend this machine
# runs (`mbvh bench --backend all`, so a backend added later is in every table without a change):
#   1. speed and traversal state: bunny, conference, Sibenik, Sponza × primary, diffuse and the
#      path tracer's bounces (closest hit) and shadow rays (any hit) × every layout and traversal;
#   2. run time against error: robust, exact and fast on every backend that has them — genuine
#      mismatches and wrong answers against the double-precision brute force on primary, diffuse,
#      shadow and grazing/edge-aimed (special) rays of the bunny, and leaks of rays shot from
#      inside a closed sphere at its vertices and edges;
#   3. image error against time: RMSE of each backend's Sponza render against a high-sample
#      reference as samples accumulate;
#   4. scaling: the generated hairball from 10K to 10M triangles (bench/scaling.sh).
# Then bench/plots.py draws OUT/pareto.png, OUT/rmse.png, OUT/scaling/scaling.png and writes the
# Markdown tables to OUT/tables.md, and bench/plots.py check verifies the JSON (every backend ×
# traversal record present, every timed result verified).
#   bench/all.sh [--quick] [OUT]    (OUT default bench/out; about 15 minutes on 2 cores, --quick:
#                                    tiny counts, one scene, for CI, about a minute)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out" "$@"
use_matplotlib
mkdir -p "$OUT/speed" "$OUT/error" "$OUT/render" "$OUT/scaling"

if [ "$QUICK" = 1 ]; then
  RAYS=4000; ERROR_RAYS=200; WARMUP=0; SPP=4; W=48; H=32; REF_SPP=16; INSIDE=gen:sphere:24
  SPEED_SCENES=(bunny); RENDER_SCENE=bunny
else
  RAYS=100000; ERROR_RAYS=2000; WARMUP=0.25; SPP=32; W=160; H=120; REF_SPP=256; INSIDE=gen:sphere:256
  SPEED_SCENES=(bunny conference sibenik sponza); RENDER_SCENE=sponza
fi
COMMON=(--backend all --count "$RAYS" --warmup "$WARMUP")

# -- 1. speed and traversal state
LIST="$(scene_rows "$SCENES" "${SPEED_SCENES[@]}")"
while IFS='|' read -r name scene camera; do
  OUT="$OUT/speed" CLOSEST_KINDS=primary,diffuse,path run_queries "$name" "$scene" "$camera" "${COMMON[@]}" \
    --layout mbvh2,mbvh4,mbvh8 --traversal stack,bitstack,stack-ordered,bitstack-retest,stack-octant,bitstack-octant
done <<< "$LIST"
# the backends `--backend all` ran here, each once: the render step and the check cover these
BACKENDS="$("$PY" "$ROOT/bench/plots.py" backends "$OUT")"

# -- 2. run time against error: each backend's MBVH4 where it has one, else MBVH2, stack traversal
#       (every traversal of a backend gives the same bytes; the stack is the one every backend has)
IFS='|' read -r _ BUNNY _ <<< "$(scene_rows "$SCENES" bunny)"
log "error: bunny"
"$MBVH" bench "$BUNNY" "${COMMON[@]}" --layout mbvh4,mbvh2 --first-layout --traversal stack \
  --query closest --precision robust,exact,fast --kinds primary,diffuse,shadow,special --error-rays "$ERROR_RAYS" \
  --json "$OUT/error/bunny.json" > "$OUT/error/bunny.txt"
log "error: leaks out of $INSIDE"
"$MBVH" bench "$INSIDE" "${COMMON[@]}" --layout mbvh4,mbvh2 --first-layout --traversal stack \
  --query closest --precision robust,exact,fast --kinds inside --error-rays "$ERROR_RAYS" \
  --json "$OUT/error/inside.json" > "$OUT/error/inside.txt"

# -- 3. image error against time
IFS='|' read -r _ RSCENE RCAMERA <<< "$(scene_rows "$SCENES" "$RENDER_SCENE")"
read -r -a RCAM <<< "$RCAMERA"
log "render: reference, $REF_SPP spp on cpu"
"$MBVH" render "$RSCENE" "${RCAM[@]}" --backend cpu --spp "$REF_SPP" --width "$W" --height "$H" --seed 99 \
  -o "$OUT/render/reference.png" --pfm "$OUT/render/reference.pfm" > /dev/null 2>&1
for b in ${BACKENDS//,/ }; do
  for p in robust fast; do
    [ "$p" = fast ] && [ "$b" = embree ] && continue
    log "render: $b $p"
    "$MBVH" render "$RSCENE" "${RCAM[@]}" --backend "$b" --precision "$p" --spp "$SPP" --width "$W" --height "$H" \
      -o "$OUT/render/$b-$p.png" --reference "$OUT/render/reference.pfm" --curve "$OUT/render/$b-$p.json" > "$OUT/render/$b-$p.txt" 2>&1 || { cat "$OUT/render/$b-$p.txt" >&2; exit 1; }
  done
done

# -- 4. scaling
log "scaling"
if [ "$QUICK" = 1 ]; then MAXTRI=30000; SRAYS=4000; else MAXTRI=10000000; SRAYS=100000; fi
PYTHON="$PY" MBVH="$MBVH" bash "$ROOT/bench/scaling.sh" "$OUT/scaling" "$MAXTRI" "$SRAYS" "$WARMUP" > "$OUT/scaling/table.md" 2> "$OUT/scaling/log.txt" ||
  { tail -20 "$OUT/scaling/log.txt" >&2; exit 1; }

# -- plots, tables, checks
log "plots and tables"
"$PY" "$ROOT/bench/plots.py" all "$OUT" > "$OUT/tables.md"
"$PY" "$ROOT/bench/plots.py" check "$OUT" "$BACKENDS"
log "done: $OUT/tables.md, $OUT/pareto.png, $OUT/rmse.png, $OUT/scaling/scaling.png"
