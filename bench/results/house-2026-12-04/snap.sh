#!/usr/bin/env bash
# snap.sh MBVH OUTDIR: node hashes + trace outputs, for byte-identical comparison
set -euo pipefail
M="$1"; O="$2"; S=/work/shared/scenes
mkdir -p "$O"
for sc in $S/conference.obj.zst $S/bun_zipper.ply.zst $S/sponza_dabrovic.obj.zst gen:hairball:100000; do
  n=$(basename "$sc" | tr ':' '_')
  for q in low medium high; do for t in 1 2; do
    "$M" info "$sc" --quality $q --threads $t --json - 2>/dev/null | grep -iE 'hash|sah' > "$O/info-$n-$q-$t.txt" || true
  done; done
  for be in cpu-scalar cpu-avx2 cpu-avx512; do
    for lt in "mbvh2 stack" "mbvh4 bitstack" "mbvh8 stack" "mbvh8 bitstack" "mbvh4 bitstack-retest" "mbvh2 packet"; do
      set -- $lt
      for qy in closest any; do
        "$M" -q trace "$sc" --backend $be --layout $1 --traversal $2 --query $qy --kind diffuse --count 20000 -o - 2>/dev/null | sha1sum > "$O/trace-$n-$be-$1-$2-$qy.txt" || echo fail > "$O/trace-$n-$be-$1-$2-$qy.txt"
      done
    done
  done
done
for sc in $S/bun_zipper.ply.zst $S/conference.obj.zst; do
  n=$(basename "$sc")
  for be in opencl-wide opencl-lane vulkan embree; do
    for lt in "mbvh2 stack" "mbvh4 bitstack" "mbvh4 stack"; do
      set -- $lt
      for qy in closest any; do
        "$M" -q trace "$sc" --backend $be --layout $1 --traversal $2 --query $qy --kind diffuse --count 20000 -o - 2>/dev/null | sha1sum > "$O/dev-$n-$be-$1-$2-$qy.txt" || echo fail > "$O/dev-$n-$be-$1-$2-$qy.txt"
      done
    done
  done
done
