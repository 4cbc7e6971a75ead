#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# cache_misses.sh — cache behaviour per ray, from valgrind's cache model (cachegrind), so the
# machine's noise does not move it: instructions, L1 data misses and last-level misses per ray of
# the cpu backend's stacks (robust precision, cpu-avx2: valgrind runs no AVX-512; MBVH8 and MBVH4
# ordered, MBVH8 octant-ordered) and of the embree peer (robust; under valgrind it runs its AVX2
# kernels), 1 thread, on the interior views of bench/cpu_vs_embree.sh: primary and diffuse rays
# closest hit, shadow rays any hit, RAYS rays per kind (the same ray files for both).
#
# Per ray, without the fixed cost: each case runs twice, on the ray file and on the same rays
# twice over (one file); the difference of the two runs is one pass over the rays with warm
# caches (scene load, build, prepare, the first pass's cold misses and the output file cancel).
# Only the trace call's functions are counted (by name, below): its driver (the loop that reads
# the 32-byte rays and writes the answers) and the traversal. The cpu backend's walks are inlined
# into its batch driver, so names cannot part the two: instructions and misses are the whole
# call's on both backends. The ray stream (the doubled file's second half is memory the first pass
# never touched: about one LL miss a ray for the rays and the answers) is the same on both, so
# "LL − embree", the difference per ray, is the traversals' difference.
#
# The modelled caches: D1 32 KiB, 8-way (Zen 4's L1D) and "LL" 1 MiB, 8-way — Zen 4's L2, the
# level the shared scenes' trees (1 to 6 MB) leave; cachegrind models two levels only (and on a
# KVM guest its own L3 detection reads a direct-mapped 320 MB cache). Override with D1=, LL=
# (cachegrind's size,assoc,line).
#   bench/cache_misses.sh [--quick] [OUT] [RAYS]   (default bench/out-cache-misses, 20000 rays;
#     --quick: the bunny, 2000 rays, MBVH8 ordered and octant and embree — a smoke test, 2–3 minutes)
# Environment: JOBS (parallel valgrind runs, default 2), SCENES_LIST (default
# "bunny conference sibenik sponza"), LAYOUTS (the cpu variants, LAYOUT or LAYOUT:TRAVERSAL, default
# "mbvh8 mbvh8:stack-octant mbvh4"; a bare layout runs --traversal stack-ordered). "LL / embree" is
# the backend's default variant for the query over embree's: MBVH8 ordered for closest hit, MBVH8
# octant for any hit (where LAYOUTS has them; else the first variant).
# TABLE_ONLY=1 makes the table from an earlier run's OUT/cg without running anything.
# Writes OUT/cache-misses.md (and prints it); 96 valgrind runs, about 20 minutes with JOBS=1.
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out-cache-misses" "$@"
RAYS="${ARGS[0]:-20000}"
JOBS="${JOBS:-2}"
D1="${D1:-32768,8,64}"
LL="${LL:-1048576,8,64}"
read -r -a LAYOUTS <<< "${LAYOUTS:-mbvh8 mbvh8:stack-octant mbvh4}"
read -r -a NAMES <<< "${SCENES_LIST:-bunny conference sibenik sponza}"
if [ "$QUICK" = 1 ]; then
  RAYS=2000
  LAYOUTS=(mbvh8 mbvh8:stack-octant)
  NAMES=(bunny)
fi
command -v valgrind > /dev/null || { echo "cache_misses.sh: valgrind is not installed" >&2; exit 2; }
mkdir -p "$OUT/rays" "$OUT/cg" "$OUT/bvh"
LIST="$(scene_rows "$SCENES" "${NAMES[@]}")"

if [ "${TABLE_ONLY:-0}" != 1 ]; then
# the ray files (native runs), each also doubled
JOBLIST="$OUT/jobs.txt"
: > "$JOBLIST"
while IFS='|' read -r name scene camera; do
  for kind in primary diffuse shadow; do
    f="$OUT/rays/$name-$kind"
    # shellcheck disable=SC2086  # the camera is words
    "$MBVH" -q rays "$scene" $camera --kind "$kind" --count "$RAYS" --cache "$OUT/bvh" -o "$f.rays"
    cat "$f.rays" "$f.rays" > "$f.x2.rays"
    query=closest
    [ "$kind" = shadow ] && query=any
    for backend in "${LAYOUTS[@]}" embree; do
      for reps in x1 x2; do
        echo "$name|$scene|$kind|$query|$backend|$reps" >> "$JOBLIST"
      done
    done
  done
done <<< "$LIST"
log "$(wc -l < "$JOBLIST") cachegrind runs, $JOBS at a time"

run_one() {
  IFS='|' read -r name scene kind query backend reps <<< "$1"
  local rays="$OUT/rays/$name-$kind.rays" args
  [ "$reps" = x2 ] && rays="$OUT/rays/$name-$kind.x2.rays"
  local layout="${backend%%:*}" traversal=stack-ordered tag="${backend//:/-}"  # tag: no ':' in file names
  [ "$layout" = "$backend" ] || traversal="${backend#*:}"
  if [ "$backend" = embree ]; then args="--backend embree"; else args="--backend cpu-avx2 --layout $layout --traversal $traversal"; fi
  # shellcheck disable=SC2086  # args are words
  valgrind --tool=cachegrind --cache-sim=yes --I1=32768,8,64 --D1="$D1" --LL="$LL" \
    --cachegrind-out-file="$OUT/cg/$name-$kind-$tag-$reps.out" \
    "$MBVH" -q trace "$scene" --cache "$OUT/bvh" --rays "$rays" $args --query "$query" --threads 1 \
    -o "$OUT/cg/$name-$kind-$tag-$reps.bin" > "$OUT/cg/$name-$kind-$tag-$reps.log" 2>&1 \
    || { echo "failed: $1 (see $OUT/cg/$name-$kind-$tag-$reps.log)" >&2; return 1; }
}
export -f run_one
export OUT MBVH D1 LL
xargs -P "$JOBS" -I{} bash -c 'run_one "$@"' _ {} < "$JOBLIST"
fi

python3 - "$OUT" "$RAYS" "$D1" "$LL" "${LAYOUTS[*]}" "${NAMES[@]}" << 'EOF' | tee "$OUT/cache-misses.md"
import re, sys
out, rays, d1, ll, layouts, names = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], sys.argv[5].split(), sys.argv[6:]
# the tool's own work on the ray file, outside the backend's trace call
# What the figures count, by function name (the whole process's difference also holds the noise
# of phases that are not per ray, e.g. the build's load): the traversal — the cpu backend's ISA
# namespace, Embree's library (no symbols: ???) and its entry points — and the drivers: the cpu
# backend's batch loop (trace_parallel, run_batch; the ray set-up inlined) and the embree peer's
# trace_batch with what it runs per batch (its ray conversion).
TRAVERSAL = re.compile(r"mbvh::avx2::|mbvh::avx512::|^\?\?\?$|^rtc|embree::")
DRIVER = re.compile(r"trace_parallel|run_batch|run_interleaved|EmbreeBackend::trace_batch")

def totals(path):
    """Event totals of a cachegrind file over the trace call's functions (traversal and drivers)."""
    events, counted = None, False
    with open(path) as f:
        for line in f:
            if line.startswith("events:"):
                events = line.split()[1:]
                call = [0] * len(events)
            elif line.startswith("fn="):
                fn = line[3:].strip()
                counted = bool(DRIVER.search(fn) or TRAVERSAL.search(fn))
            elif line[:1].isdigit() and counted:
                for k, x in enumerate(line.split()[1:]):
                    call[k] += int(x)
    return dict(zip(events, call))

def per_ray(name, kind, backend):
    tag = backend.replace(":", "-")
    a = totals(f"{out}/cg/{name}-{kind}-{tag}-x1.out")
    b = totals(f"{out}/cg/{name}-{kind}-{tag}-x2.out")
    d = {e: (b[e] - a[e]) / rays for e in a}
    return d["Ir"], d["D1mr"] + d["D1mw"], d["DLmr"] + d["DLmw"]

print(f"Per ray, one warm pass over {rays} rays (cachegrind: D1 {d1}, LL {ll}; size,assoc,line), 1 thread; "
      f"cpu: cpu-avx2, robust, ordered stack (octant: the octant-ordered stack); embree: robust. Instructions: the "
      f"trace call, instructions and misses alike (its driver's ray stream, about one LL miss a ray, included on "
      f"both backends). LL / embree and LL − embree: the default variant's LL misses (MBVH8 ordered for closest "
      f"hit, MBVH8 octant for any hit) over and minus embree's.\n")
cols = layouts + ["embree"]
def label(v):
    layout, _, trav = v.partition(":")
    return layout.upper() + (" " + trav.replace("stack-", "") if trav else "")
names_of = {l: label(l) for l in layouts}
names_of["embree"] = "embree"
head = ["scene", "rays"] + [f"{names_of[c]} {what}" for what in ("instr", "D1 misses", "LL misses") for c in cols] + ["LL / embree", "LL − embree"]
print("| " + " | ".join(head) + " |")
print("|" + "---|" * len(head))
for name in names:
    for kind in ("primary", "diffuse", "shadow"):
        r = {c: per_ray(name, kind, c) for c in cols}
        cells = [f"{r[c][0]:.0f}" for c in cols] + [f"{r[c][1]:.3f}" for c in cols] + [f"{r[c][2]:.3f}" for c in cols]
        default = "mbvh8:stack-octant" if kind == "shadow" else "mbvh8"
        el, cl = r["embree"][2], r[default if default in r else cols[0]][2]
        cells.append(f"{cl / el:.2f}" if el > 0 else "-")
        cells.append(f"{cl - el:+.3f}")
        print(f"| {name} | {kind} | " + " | ".join(cells) + " |")
EOF
