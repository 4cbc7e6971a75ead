#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# mpi.sh [--quick] [OUT] — mbvh-mpi on this host (docs/mpi.md), one run, side by side:
#   0. replicated, bit for bit: 300K path rays of Sponza traced on 1-4 ranks (static and dynamic
#      batches) and conference rendered at 256x256, 2 spp on 2-4 ranks (static and dynamic tiles),
#      each `cmp`-ed with one process's output;
#   1. replicated, speed: `mbvh bench` (1 process x 2 threads) against `mpirun -np 2 mbvh-mpi bench`
#      (2 ranks x 1 thread) and -np 1 x 2 threads, on 1M path rays of conference (the thesis'
#      workload), alternated ROUNDS times; Mrays/s medians, the ratio, the share of the ranks' time
#      in MPI calls and the bytes moved a ray; the static and dynamic schedules;
#   2. data-parallel: `mbvh-mpi check --distribute data` at 2-4 ranks on conference and the 1M
#      hairball (primary, shadow, diffuse, path rays), and `mbvh-mpi bench --distribute data` at
#      1-4 ranks (rounds, forwards a ray, bytes a ray, verified);
#   3. a scene one process refuses under a per-rank budget (the 4M hairball, MBVH_MEMORY_LIMIT=400M)
#      rendered on 4 ranks under it, the image compared with one process's (no budget).
# Results: OUT (default bench/out/mpi) *.txt and summary.md. Open MPI's settings for one host as in
# cmake/mpi_tests.cmake.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out/mpi" "$@"
MBVH_MPI="${MBVH_MPI:-$ROOT/build/mbvh-mpi}"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1 \
  OMPI_MCA_btl=self,vader OMPI_MCA_btl_vader_single_copy_mechanism=none OMPI_MCA_hwloc_base_binding_policy=none
conference="$SCENES/conference.obj.zst"
count=1000000 rounds=3 dp_count=200000
if [ "$QUICK" = 1 ]; then count=200000 rounds=1 dp_count=20000; fi
summary="$OUT/summary.md"
{
  echo "# mbvh-mpi on $(hostname), $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo
  echo "CPU: $(sed -n 's/^model name\s*: //p' /proc/cpuinfo | head -1), $(nproc) cores; $(mpirun --version | head -1)"
  echo
} > "$summary"

# -- 0. replicated, bit for bit
sponza="$SCENES/sponza_dabrovic.obj.zst"
n_path=300000
[ "$QUICK" = 1 ] && n_path=30000
"$MBVH" rays "$sponza" --kind path --count "$n_path" -o "$OUT/path.rays" -q
"$MBVH" trace "$sponza" --rays "$OUT/path.rays" -o "$OUT/one.hits" -q
"$MBVH" render "$conference" --spp 2 --width 256 --height 256 --pfm "$OUT/one.pfm" -o "$OUT/one.png" -q
{
  echo "## Replicated, bit for bit: $n_path path rays of Sponza; conference at 256x256, 2 spp"
  echo
  echo "| run | ranks | cmp with one process |"
  echo "|---|---|---|"
} >> "$summary"
for np in 1 2 3 4; do
  for sched in static dynamic; do
    log "trace on $np ranks, $sched batches"
    mpirun -np "$np" "$MBVH_MPI" trace "$sponza" --rays "$OUT/path.rays" -o "$OUT/np.hits" --threads 1 --schedule "$sched" -q
    echo "| trace, $sched batches | $np | $(cmp -s "$OUT/one.hits" "$OUT/np.hits" && echo equal || echo DIFFERENT) |" >> "$summary"
  done
done
for np in 2 3 4; do
  for tiles in static dynamic; do
    log "render on $np ranks, $tiles tiles"
    mpirun -np "$np" "$MBVH_MPI" render "$conference" --spp 2 --width 256 --height 256 --pfm "$OUT/np.pfm" -o "$OUT/np.png" \
      --threads 1 --tiles "$tiles" -q
    echo "| render (PFM), $tiles tiles | $np | $(cmp -s "$OUT/one.pfm" "$OUT/np.pfm" && echo equal || echo DIFFERENT) |" >> "$summary"
  done
done
echo >> "$summary"

# -- 1. replicated against one process
mrays() { awk '$1 == "path" { print $3 }' "$1"; }
share() { awk '$1 == "path" { print $4 }' "$1"; }
bytes() { awk '$1 == "path" { print $5 }' "$1"; }
for r in $(seq 1 "$rounds"); do
  log "round $r: mbvh bench, 1 process x 2 threads"
  "$MBVH" bench "$conference" --kinds path --count "$count" --threads 2 --layout mbvh8 --traversal stack-ordered \
    --query closest --json "$OUT/one-$r.json" > "$OUT/one-$r.txt"
  for sched in static dynamic; do
    log "round $r: mbvh-mpi bench, 2 ranks x 1 thread, $sched batches"
    mpirun -np 2 "$MBVH_MPI" bench "$conference" --kinds path --count "$count" --threads 1 --schedule "$sched" \
      > "$OUT/np2-$sched-$r.txt"
    log "round $r: mbvh-mpi bench, 1 rank x 2 threads, $sched batches"
    mpirun -np 1 "$MBVH_MPI" bench "$conference" --kinds path --count "$count" --threads 2 --schedule "$sched" \
      > "$OUT/np1-$sched-$r.txt"
  done
done
median() { sort -g | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
one=$(for r in $(seq 1 "$rounds"); do python3 -c "import json,sys; print('%.3f' % json.load(open(sys.argv[1]))['records'][0]['mrays_per_s'])" "$OUT/one-$r.json"; done | median)
{
  echo "## Replicated: conference, $count path rays (closest hit), $rounds rounds, medians"
  echo
  echo "| run | Mrays/s | / mbvh bench 2 threads | MPI share | bytes moved a ray |"
  echo "|---|---|---|---|---|"
  echo "| mbvh bench, 1 process x 2 threads (mbvh8/stack-ordered) | $one | 1.00 | - | - |"
  for sched in static dynamic; do
    for np in 2 1; do
      m=$(for r in $(seq 1 "$rounds"); do mrays "$OUT/np$np-$sched-$r.txt"; done | median)
      s=$(for r in $(seq 1 "$rounds"); do share "$OUT/np$np-$sched-$r.txt" | tr -d %; done | median)
      b=$(for r in $(seq 1 "$rounds"); do bytes "$OUT/np$np-$sched-$r.txt"; done | median)
      t=$([ "$np" = 2 ] && echo "2 ranks x 1 thread" || echo "1 rank x 2 threads")
      echo "| mbvh-mpi bench, $t, $sched schedule | $m | $(awk -v a="$m" -v b="$one" 'BEGIN { printf "%.2f", a / b }') | $s % | $b |"
    done
  done
  echo
} >> "$summary"

# -- 2. data-parallel
{
  echo "## Data-parallel against one process: \`mbvh-mpi check --distribute data\`, $dp_count rays a kind"
  echo
  echo "| scene | ranks | kind | query | bit-identical | ties | genuine mismatches |"
  echo "|---|---|---|---|---|---|---|"
} >> "$summary"
: > "$OUT/balance.txt"
scene_of() { [ "$1" = hairball ] && echo gen:hairball:1000000 || echo "$conference"; }  # NAME: its path or spec
for scene in conference hairball; do
  s="$(scene_of "$scene")"
  for np in 2 3 4; do
    log "data-parallel check: $scene on $np ranks"
    mpirun -np "$np" "$MBVH_MPI" check "$s" --distribute data --kinds primary,shadow,diffuse,path --count "$dp_count" \
      --threads 1 > "$OUT/check-$scene-np$np.txt" 2> "$OUT/check-$scene-np$np.err" || true
    awk -v scene="$scene" -v np="$np" '$2 ~ /^(closest|any)$/ { printf "| %s | %s | %s | %s | %s | %s | %s |\n", scene, np, $1, $2, $4, $5, $6 }' \
      "$OUT/check-$scene-np$np.txt" >> "$summary"
    grep -o "the largest [0-9]* triangles, [0-9.]* of an equal share" "$OUT/check-$scene-np$np.err" | sed "s/^/  $scene, $np ranks: /" >> "$OUT/balance.txt" || true
  done
done
{
  echo
  echo "Partition balance (the largest part against an equal share):"
  echo
  sed 's/^/-/' "$OUT/balance.txt"
  echo
} >> "$summary"
{
  echo "## Data-parallel: $dp_count rays a kind, 2 threads in all (ranks x threads <= 2 where it can)"
  echo
  echo "| scene | ranks | kind | Mrays/s | MPI share | bytes a ray | rounds | forwards a ray | verified |"
  echo "|---|---|---|---|---|---|---|---|---|"
} >> "$summary"
for scene in conference hairball; do
  s="$(scene_of "$scene")"
  for np in 1 2 3 4; do
    threads=$(( np == 1 ? 2 : 1 ))
    log "data-parallel: $scene on $np ranks"
    mpirun -np "$np" "$MBVH_MPI" bench "$s" --distribute data --kinds primary,shadow,diffuse --count "$dp_count" \
      --threads "$threads" --reps 1 > "$OUT/data-$scene-np$np.txt"
    awk -v scene="$scene" -v np="$np" '$1 ~ /^(primary|shadow|diffuse)$/ {
      v = ""; for (i = 8; i <= NF; ++i) v = v (i > 8 ? " " : "") $i
      printf "| %s | %s | %s | %s | %s | %s | %s | %s | %s |\n", scene, np, $1, $3, $4, $5, $6, $7, v }' \
      "$OUT/data-$scene-np$np.txt" >> "$summary"
  done
done
echo >> "$summary"

# -- 3. refused by one process under a per-rank budget, rendered on 4 ranks under it
big=gen:hairball:4000000
[ "$QUICK" = 1 ] && big=gen:hairball:1000000
limit=400M
[ "$QUICK" = 1 ] && limit=100M
log "$big under MBVH_MEMORY_LIMIT=$limit"
refused=$(MBVH_MEMORY_LIMIT=$limit "$MBVH" info "$big" -q > /dev/null 2> "$OUT/refused.txt" && echo "NOT refused" || echo "refused (exit $?): $(cat "$OUT/refused.txt")")
"$MBVH" render "$big" --spp 1 --width 256 --height 256 --pfm "$OUT/big-one.pfm" -o "$OUT/big-one.png" -q
MBVH_MEMORY_LIMIT=$limit /usr/bin/time -v mpirun -np 4 -x MBVH_MEMORY_LIMIT "$MBVH_MPI" render "$big" --distribute data --spp 1 \
  --width 256 --height 256 --pfm "$OUT/big-np4.pfm" -o "$OUT/big-np4.png" --threads 1 > "$OUT/big-np4.txt" 2>&1
equal=$(python3 - "$OUT/big-one.pfm" "$OUT/big-np4.pfm" <<'PY'
import sys
a, b = (open(f, "rb").read()[-256 * 256 * 12:] for f in sys.argv[1:])
same = sum(a[i:i + 12] == b[i:i + 12] for i in range(0, len(a), 12))
print(f"{same} of {len(a) // 12} pixels equal ({100.0 * same / (len(a) // 12):.3f} %)")
PY
)
{
  echo "## A scene one process refuses, on 4 ranks: $big, MBVH_MEMORY_LIMIT=$limit a process"
  echo
  echo "- one process: $refused"
  echo "- 4 ranks under the same budget: $(grep -o 'rendered.*' "$OUT/big-np4.txt" | head -1)"
  echo "- the image against one process's (no budget): $equal"
  echo
} >> "$summary"
rm -f "$OUT"/*.rays "$OUT"/*.hits "$OUT"/*.pfm  # the compared files (the comparisons are in the summary)
cat "$summary"
