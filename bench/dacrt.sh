#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# dacrt.sh — the DACRT backend (divide-and-conquer ray tracing without an acceleration
# structure; THESIS-5-6-MPI.md part A) against the cpu backend, in one run on one machine, every
# timed result verified by `mbvh bench` first; ratios taken within the run, medians:
#   speed      the conference room (interior view): path (the 8-bounce path tracer's bounce rays),
#              primary and diffuse rays closest hit, shadow rays any hit, RAYS a kind; cpu (MBVH4
#              and MBVH8 stack, bitstack, ordered stack), dacrt and, where it starts, embree; 2 threads with
#              --scaling (each variant also on 1 thread, its passes interleaved)
#   hairball   gen:hairball:2900000 (the paper's Hairball size), path rays, 2 threads
#   dynamic    `mbvh bench --dynamic FRAMES` on the conference room and Sponza: primary and shadow
#              rays of a 1024x768 image, cpu rebuild+trace and refit+trace (its best traversal, the MBVH8
#              ordered stack) against dacrt update+trace
#   memory     max RSS (/usr/bin/time -v) of `mbvh trace --rays FILE` (path rays written first by
#              `mbvh rays`) on dacrt and cpu, with 1 ray and with RAYS, and of `mbvh --version`
#   ablations  dacrt's settings one at a time on the path rays of the conference room and the
#              hairball (ordered also on primary rays), dacrt-scalar, the leaf thresholds and the
#              ratio swept; one `mbvh bench` per variant, the variants interleaved in ABL_ROUNDS
#              rounds, the median of the rounds' medians
# Writes the raw outputs (JSON, the tables as text, the time -v reports) to OUT and OUT/README.md:
# the machine, the commands and the tables of bench/dacrt_table.py.
#   bench/dacrt.sh [--quick] [OUT] [RAYS] [FRAMES]
#     OUT default bench/out/dacrt; RAYS 1000000; FRAMES 10. Environment: ABL_RAYS (default RAYS),
#     ABL_ROUNDS (3), ABL_HAIRBALL (gen:hairball:2900000), QUICK=1 (as --quick: 2000 rays, the
#     bunny and a 20K hairball, 2 frames of a 64x48 image, one ablation round of one value per
#     setting: a smoke test of the script and its tables, under a minute),
#     MBVH_DACRT_STANDIN=NAME (time backend NAME in dacrt's place, without dacrt's settings and
#     traversal: a test of the pipeline on a binary without dacrt; the README says so)
set -euo pipefail
QUICK_ENV="${QUICK:-0}"
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out/dacrt" "$@"
[ "$QUICK_ENV" = 1 ] && QUICK=1
RAYS="${ARGS[0]:-1000000}"
FRAMES="${ARGS[1]:-10}"
ABL_ROUNDS="${ABL_ROUNDS:-3}"
ABL_HAIRBALL="${ABL_HAIRBALL:-gen:hairball:2900000}"
HAIRBALL=gen:hairball:2900000
DYN_IMAGE=(--width 1024 --height 768)
EXTRA=()
SPEED_NAME=conference
DYN_NAMES=(conference sponza)
if [ "$QUICK" = 1 ]; then
  RAYS=2000
  FRAMES=2
  ABL_ROUNDS=1
  HAIRBALL=gen:hairball:20000
  ABL_HAIRBALL=gen:hairball:20000
  DYN_IMAGE=(--width 64 --height 48)
  EXTRA=(--warmup 0 --passes 5)
  SPEED_NAME=bunny
  DYN_NAMES=(bunny)
fi
ABL_RAYS="${ABL_RAYS:-$RAYS}"
[ "$QUICK" = 1 ] && ABL_RAYS=2000

# -- the backends: dacrt must start here (or a stand-in is named); embree where it starts
STANDIN="${MBVH_DACRT_STANDIN:-}"
if [ -n "$STANDIN" ]; then
  DACRT="$STANDIN" DACRT_SCALAR="$STANDIN" DACRT_TRAV=bitstack TRAV_EXTRA=""
  echo "dacrt.sh: $STANDIN stands in for dacrt (a pipeline test: no dacrt settings, no dacrt traversal)" >&2
else
  if ! "$MBVH" devices --resolve dacrt > /dev/null 2>&1; then
    echo "dacrt.sh: the dacrt backend does not start in $MBVH (see \`mbvh devices\`); MBVH_DACRT_STANDIN=cpu-scalar" \
         "tests the script without it" >&2
    exit 2
  fi
  DACRT=dacrt DACRT_SCALAR=dacrt-scalar DACRT_TRAV=dacrt TRAV_EXTRA=",dacrt"
fi
EMBREE=""
if "$MBVH" devices --ready 2>/dev/null | grep -qx embree; then EMBREE=",embree"; fi

# -- the machine and the run, for the README
{
  echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "machine: $(lscpu | sed -n 's/^Model name: *//p' | head -1), $(nproc) cores" \
       "($(lscpu | sed -n 's/^Hypervisor vendor: *//p' | head -1 | sed 's/^$/bare metal or unknown/') guest;" \
       "$(lscpu | sed -n 's/^Flags:.*\(avx512f\).*/AVX-512/p; s/^Flags:.*\(avx2\).*/AVX2/p' | head -1))"
  echo "kernel: $(uname -srm)"
  echo "compiler: $(c++ --version 2>/dev/null | head -1)"
  echo "code: $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)$(git -C "$ROOT" diff --quiet 2>/dev/null || echo ' (modified)')"
  echo "dacrt: $DACRT$([ -n "$STANDIN" ] && echo ' (STAND-IN: not the dacrt backend)')"
  echo "embree: $([ -n "$EMBREE" ] && echo yes || echo "does not start here")"
  echo "rays: $RAYS a kind; frames: $FRAMES; ablations: $ABL_RAYS rays, $ABL_ROUNDS rounds; quick: $QUICK"
} > "$OUT/machine.txt"
cat "$OUT/machine.txt" >&2

# -- speed: the conference room (the bunny with --quick), 2 threads and 1 (--scaling)
row="$(scene_rows "$SCENES" "$SPEED_NAME")"
IFS='|' read -r name scene camera <<< "$row"
# shellcheck disable=SC2054  # the commas are mbvh's lists
SPEED=(--backend "cpu,$DACRT$EMBREE" --layout mbvh4,mbvh8 --traversal "stack,bitstack,stack-ordered$TRAV_EXTRA"
       --count "$RAYS" --threads 2 --scaling "${EXTRA[@]}")
CLOSEST_KINDS=path,primary,diffuse run_queries "speed-$name" "$scene" "$camera" "${SPEED[@]}"

# -- the hairball, 2 threads, path rays
log "hairball $HAIRBALL: path rays"
"$MBVH" bench "$HAIRBALL" --backend "cpu,$DACRT" --layout mbvh4,mbvh8 --traversal "bitstack,stack-ordered$TRAV_EXTRA" \
  --query closest --kinds path --count "$RAYS" --threads 2 "${EXTRA[@]}" --json "$OUT/hairball-closest.json" \
  | tee "$OUT/hairball-closest.txt" >&2

# -- dynamic frames: rebuild / refit / update + trace
for dname in "${DYN_NAMES[@]}"; do
  IFS='|' read -r name scene camera <<< "$(scene_rows "$SCENES" "$dname")"
  log "dynamic: $name, $FRAMES frames"
  # shellcheck disable=SC2086  # the camera is words
  "$MBVH" bench "$scene" --backend "cpu,$DACRT" --dynamic "$FRAMES" --kinds primary,shadow "${DYN_IMAGE[@]}" \
    --layout mbvh8 --traversal stack-ordered \
    --threads 2 $camera --json "$OUT/dynamic-$name.json" | tee "$OUT/dynamic-$name.txt" >&2
done

# -- memory: max RSS of a trace of a ray file (written first), 1 ray and RAYS, and the process alone
IFS='|' read -r name scene camera <<< "$row"
log "memory: $name"
# shellcheck disable=SC2086
"$MBVH" rays "$scene" --kind path --count "$RAYS" --threads 2 $camera -o "$OUT/mem.rays" > /dev/null
# shellcheck disable=SC2086
"$MBVH" rays "$scene" --kind primary --count 1 $camera -o "$OUT/mem1.rays" > /dev/null
"$MBVH" info "$scene" > "$OUT/mem-info.txt" 2>&1
/usr/bin/time -v "$MBVH" --version > /dev/null 2> "$OUT/mem-process.time"
for b in cpu "$DACRT"; do
  trav=()
  [ "$b" = "$DACRT" ] && trav=(--traversal "$DACRT_TRAV")  # dacrt traces only its own
  for f in mem1 mem; do
    /usr/bin/time -v "$MBVH" trace "$scene" --backend "$b" "${trav[@]}" --rays "$OUT/$f.rays" --threads 2 \
      > "$OUT/mem-$b-$f.txt" 2> "$OUT/mem-$b-$f.time"
  done
done
rm -f "$OUT/mem.rays" "$OUT/mem1.rays"

# -- ablations: one bench per variant, the variants interleaved in rounds
# LABEL|BACKEND|SETTINGS (name=value, space-separated)|KINDS
if [ "$QUICK" = 1 ]; then SWEEP_R=(8) SWEEP_T=(8) SWEEP_Q=(1); else SWEEP_R=(4 8 16 32 64) SWEEP_T=(4 8 16 32 64) SWEEP_Q=(0.5 1 2 4 8); fi
VARIANTS=("adaptive|$DACRT||path,primary" "sah|$DACRT|partition=sah|path" "middle|$DACRT|partition=middle|path"
          "ordered0|$DACRT|ordered=0|path,primary" "scalar|$DACRT_SCALAR||path")
for v in "${SWEEP_R[@]}"; do VARIANTS+=("leaf-rays=$v|$DACRT|leaf-rays=$v|path"); done
for v in "${SWEEP_T[@]}"; do VARIANTS+=("leaf-tris=$v|$DACRT|leaf-tris=$v|path"); done
for v in "${SWEEP_Q[@]}"; do VARIANTS+=("ratio=$v|$DACRT|ratio=$v|path"); done
printf '%s\n' "${VARIANTS[@]}" > "$OUT/ablation-variants.txt"
ABL_SCENES=("$SPEED_NAME" "hairball")
for round in $(seq 1 "$ABL_ROUNDS"); do
  for sname in "${ABL_SCENES[@]}"; do
    if [ "$sname" = hairball ]; then scene="$ABL_HAIRBALL" camera=""; else
      IFS='|' read -r _ scene camera <<< "$(scene_rows "$SCENES" "$sname")"; fi
    for variant in "${VARIANTS[@]}"; do
      IFS='|' read -r label backend settings kinds <<< "$variant"
      sets=()
      for s in $settings; do [ -n "$STANDIN" ] || sets+=(--set "dacrt.$s"); done
      log "ablation round $round/$ABL_ROUNDS: $sname $label"
      # shellcheck disable=SC2086
      "$MBVH" bench "$scene" --backend "$backend" "${sets[@]}" --layout mbvh4 --traversal "$DACRT_TRAV" \
        --query closest --kinds "$kinds" --count "$ABL_RAYS" --threads 2 "${EXTRA[@]}" $camera --quiet \
        --json "$OUT/ablation-$sname-$label-r$round.json"
    done
  done
done

# -- the tables
python3 "$ROOT/bench/dacrt_table.py" "$OUT" "$DACRT" "$DACRT_SCALAR" > "$OUT/tables.md"
{
  echo "# DACRT against the cpu backend: $(sed -n 's/^date: //p' "$OUT/machine.txt")"
  echo
  echo '```'
  cat "$OUT/machine.txt"
  echo "command: bench/dacrt.sh $*"
  echo '```'
  echo
  cat "$OUT/tables.md"
} > "$OUT/README.md"
cat "$OUT/tables.md"
log "wrote $OUT/README.md"
