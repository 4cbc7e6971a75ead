#!/usr/bin/env python3
"""cpu_table.py — Markdown tables from `mbvh bench --json` files of bench/cpu_vs_embree.sh:
the cpu backend's variants beside Embree (Mrays/s, medians), the ratios issue 3 sets targets
for (stack-based cpu / Embree >= 1.0, bitstack time / stack time <= 1.10) and the thread
scaling from 1 to 2 threads (>= 1.9 on incoherent rays).
    python3 bench/cpu_table.py bench/out/*.json
"""
import json
import os
import sys
from collections import defaultdict

VARIANTS = [("cpu", "mbvh4", "stack"), ("cpu", "mbvh4", "bitstack"), ("cpu", "mbvh4", "stack-ordered"),
            ("cpu", "mbvh8", "stack-ordered"), ("embree", "mbvh4", "stack")]


def main(paths):
    speed = {}  # (scene, kind, threads, backend, layout, traversal) -> Mrays/s
    order = []
    for p in paths:
        with open(p) as f:
            doc = json.load(f)
        for r in doc["records"]:
            if r["query"] != "closest" or r.get("verify_mismatches", 0) != 0:
                continue
            scene = os.path.basename(r["scene"]).split(".")[0]
            key = (scene, r["ray_kind"], r["threads"])
            if key not in order:
                order.append(key)
            speed[key + (r["backend"], r["layout"], r["traversal"])] = r["mrays_per_s"]
    if not speed:
        sys.exit("cpu_table.py: no verified closest-hit records in " + " ".join(paths))

    def get(key, v):
        return speed.get(key + v)

    def fmt(x, digits=2):
        return "–" if x is None else f"{x:.{digits}f}"

    print("| scene | rays | threads | MBVH4 stack | MBVH4 bitstack | MBVH4 ordered | MBVH8 ordered | embree "
          "| MBVH4 stack × embree | best cpu × embree | bitstack / stack time |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for key in order:
        s = [get(key, v) for v in VARIANTS]
        emb = s[4]
        best = max((x for x in s[:4] if x is not None), default=None)
        ratio = lambda x: None if x is None or not emb else x / emb
        slow = None if not s[0] or not s[1] else s[0] / s[1]
        print(f"| {key[0]} | {key[1]} | {key[2]} | " + " | ".join(fmt(x) for x in s) +
              f" | {fmt(ratio(s[0]))} | {fmt(ratio(best))} | {fmt(slow, 3)} |")

    print()
    print("| scene | rays | MBVH4 stack 2/1 threads | MBVH8 ordered 2/1 | embree 2/1 |")
    print("|---|---|---|---|---|")
    seen = set()
    for scene, kind, _ in order:
        if (scene, kind) in seen:
            continue
        seen.add((scene, kind))
        cells = []
        for v in (VARIANTS[0], VARIANTS[3], VARIANTS[4]):
            one, two = get((scene, kind, 1), v), get((scene, kind, 2), v)
            cells.append(None if not one or not two else two / one)
        print(f"| {scene} | {kind} | " + " | ".join(fmt(c) for c in cells) + " |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
