#!/usr/bin/env python3
"""cpu_table.py — Markdown tables from the `mbvh bench --scaling --json` files of
bench/cpu_vs_embree.sh: the cpu backend's variants beside Embree (Mrays/s, medians, on 1 and 2
threads), the ratios issue 3 sets targets for (stack-based cpu / Embree >= 1.0, bitstack time /
stack time <= 1.10) and the thread scaling from 1 to 2 threads (>= 1.9 on incoherent rays).
    python3 bench/cpu_table.py bench/out/*.json
"""
import json
import os
import sys

VARIANTS = [("cpu", "mbvh4", "stack"), ("cpu", "mbvh4", "bitstack"), ("cpu", "mbvh4", "stack-ordered"),
            ("cpu", "mbvh8", "stack-ordered"), ("embree", "mbvh4", "stack")]
STACK_BASED = [0, 2, 3]


def fmt(x, digits=2):
    return "–" if not x else f"{x:.{digits}f}"


def main(paths):
    speed, scaling, order = {}, {}, []
    for p in paths:
        with open(p) as f:
            doc = json.load(f)
        for r in doc["records"]:
            if r["query"] != "closest" or r.get("verify_mismatches", 0) != 0:
                continue
            scene = os.path.basename(r["scene"]).split(".")[0]
            v = (r["backend"], r["layout"], r["traversal"])
            for threads, mr in ((1, r.get("mrays_per_s_1_thread", 0)), (r["threads"], r["mrays_per_s"])):
                key = (scene, r["ray_kind"], threads)
                if mr and key not in order:
                    order.append(key)
                if mr:
                    speed[key + v] = mr
            scaling[(scene, r["ray_kind"]) + v] = r.get("thread_scaling", 0)
    if not speed:
        sys.exit("cpu_table.py: no verified closest-hit records in " + " ".join(paths))
    order.sort(key=lambda k: (k[0], ["primary", "diffuse", "shadow"].index(k[1]) if k[1] in ("primary", "diffuse", "shadow") else 9, k[2]))

    print("| scene | rays | threads | MBVH4 stack | MBVH4 bitstack | MBVH4 ordered | MBVH8 ordered | embree "
          "| MBVH4 stack × embree | best stack-based cpu × embree | bitstack / stack time |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for key in order:
        s = [speed.get(key + v) for v in VARIANTS]
        emb = s[4]
        best = max((s[i] for i in STACK_BASED if s[i]), default=None)
        ratio = lambda x: None if not x or not emb else x / emb
        slow = None if not s[0] or not s[1] else s[0] / s[1]
        print(f"| {key[0]} | {key[1]} | {key[2]} | " + " | ".join(fmt(x) for x in s) +
              f" | {fmt(ratio(s[0]))} | {fmt(ratio(best))} | {fmt(slow, 3)} |")

    print()
    print("| scene | rays | MBVH4 stack 2/1 threads | MBVH4 bitstack | MBVH8 ordered | embree |")
    print("|---|---|---|---|---|---|")
    seen = []
    for scene, kind, _ in order:
        if (scene, kind) not in seen:
            seen.append((scene, kind))
            cells = [scaling.get((scene, kind) + VARIANTS[i]) for i in (0, 1, 3, 4)]
            print(f"| {scene} | {kind} | " + " | ".join(fmt(c) for c in cells) + " |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
