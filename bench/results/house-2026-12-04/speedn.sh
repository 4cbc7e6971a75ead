#!/usr/bin/env bash
# speedn.sh ROUNDS BIN... : packet medians, rounds interleaved
set -euo pipefail
R="$1"; shift; S=/work/shared/scenes; T=$(mktemp -d)
for r in $(seq 1 "$R"); do
  for B in "$@"; do
    n=$(basename $B)
    "$B" -q bench $S/sponza_dabrovic.obj.zst --backend cpu-avx2 --layout mbvh2 --traversal packet --query closest,any \
        --kinds primary,diffuse --count 300000 --passes 9 --warmup 0.1 --threads 2 --json $T/$n-$r.json >/dev/null 2>&1
  done
done
python3 - "$T" "$@" <<'PY'
import json,glob,sys,statistics,collections,os
T=sys.argv[1]; bins=[os.path.basename(b) for b in sys.argv[2:]]
d=collections.defaultdict(lambda: collections.defaultdict(list))
for b in bins:
  for f in glob.glob(f"{T}/{b}-*.json"):
    for r in json.load(open(f))['records']:
        d[(r['query'],r['ray_kind'])][b].append(r['mrays_per_s'])
print("query kind", *bins)
for k in sorted(d):
    print(*k, *[f"{statistics.median(d[k][b]):.2f}" for b in bins])
PY
