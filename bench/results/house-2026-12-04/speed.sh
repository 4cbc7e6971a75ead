#!/usr/bin/env bash
# speed.sh OLD NEW ROUNDS: side-by-side medians of mbvh bench (Mrays/s), alternating binaries per round
set -euo pipefail
OLD="$1"; NEW="$2"; R="${3:-3}"; S=/work/shared/scenes; T=$(mktemp -d)
for r in $(seq 1 "$R"); do
  for who in old new; do
    B=$OLD; [ $who = new ] && B=$NEW
    for sc in conference.obj.zst sponza_dabrovic.obj.zst; do
      "$B" -q bench $S/$sc --backend cpu-avx2 --layout mbvh4,mbvh8 --traversal stack,bitstack --query closest,any \
        --kinds primary,diffuse --count 200000 --passes 5 --warmup 0.1 --threads 2 --json $T/$who-$r-$sc.json >/dev/null 2>&1
      "$B" -q bench $S/$sc --backend cpu-avx2 --layout mbvh2 --traversal packet --query closest,any \
        --kinds primary,diffuse --count 200000 --passes 5 --warmup 0.1 --threads 2 --json $T/$who-pk-$r-$sc.json >/dev/null 2>&1
    done
  done
done
python3 - "$T" <<'PY'
import json,glob,sys,statistics,collections
d=collections.defaultdict(lambda: collections.defaultdict(list))
for f in glob.glob(sys.argv[1]+'/*.json'):
    who=f.split('/')[-1].split('-')[0]
    recs=json.load(open(f))
    recs=recs.get('records',recs) if isinstance(recs,dict) else recs
    for r in recs:
        k=(r.get('scene'),r.get('layout'),r.get('traversal'),r.get('query'),r.get('kind') or r.get('ray_kind'))
        d[k][who].append(r.get('mrays_per_s') or r.get('mrays'))
rat=[]
for k in sorted(d, key=str):
    o=statistics.median(d[k]['old']); n=statistics.median(d[k]['new']); rat.append(n/o)
    print(*k, f"old {o:.2f} new {n:.2f} ratio {n/o:.3f}")
print("median ratio new/old:", round(statistics.median(rat),3), "min", round(min(rat),3), "max", round(max(rat),3))
PY
