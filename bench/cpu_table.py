#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""cpu_table.py — Markdown tables from the `mbvh bench --scaling --json` files of
bench/cpu_vs_embree.sh: per scene x rays (query) x threads, the cpu backend's variants beside
Embree's robust mode (Mrays/s, medians), and the ratios its targets are set on:
  best stack-based cpu (robust) / Embree robust  >= 1.0 on every row,
  best stackless cpu (robust)   / Embree robust,
  best cpu fast                 / Embree default mode (`embree --precision fast`) >= 1.0,
  best cpu fast                 / best tinybvh layout (BVH4_CPU, BVH8_CPU)        >= 1.0,
  best cpu robust (any variant) / best tinybvh layout                             >= 0.9,
  bitstack time / its stack twin's time (MBVH4, MBVH8; MBVH8 octant bitstack / octant stack) <= 1.05;
with a summary line per target counting the rows that meet it; then the thread scaling from 1
to 2 threads. The tinybvh columns are the `tinybvh` peer's records (`--layout mbvh4` is its
BVH4_CPU, `mbvh8` its BVH8_CPU; it runs in fast precision only: not watertight), "–" where the
run has none (a build without the peer). Our robust records count only when verified (zero
mismatches against cpu-scalar); fast records and Embree's robust ones always (the fast modes and
the peers' modes differ from our robust answer by design, Embree's robust mode on a grazing ray
now and then: their mismatch counts are printed below the table).
    python3 bench/cpu_table.py bench/out/*.json
"""
import sys

from benchlib import fmt, records, scene_name, verified

ROBUST = [("cpu", "mbvh4", "stack"), ("cpu", "mbvh4", "bitstack"), ("cpu", "mbvh4", "stack-ordered"),
          ("cpu", "mbvh8", "stack"), ("cpu", "mbvh8", "bitstack"), ("cpu", "mbvh8", "stack-ordered"),
          ("cpu", "mbvh8", "stack-octant"), ("cpu", "mbvh8", "bitstack-octant")]
STACK_BASED = [0, 2, 3, 5, 6]
STACKLESS = [1, 4, 7]
EMBREE = ("embree", "mbvh4", "stack")
TINYBVH = [("tinybvh", "mbvh4", "stack"), ("tinybvh", "mbvh8", "stack")]  # BVH4_CPU, BVH8_CPU (fast)
# the targets the summary counts: (name, ratio column, bound, at least (True) or at most)
TARGETS = [("best stack-based × embree robust >= 1.0", 0, 1.0, True),
           ("best fast × embree default >= 1.0", 2, 1.0, True),
           ("best fast × best tinybvh >= 1.0", 3, 1.0, True),
           ("best robust × best tinybvh >= 0.9", 4, 0.9, True),
           ("MBVH4 bitstack/stack time <= 1.05", 5, 1.05, False),
           ("MBVH8 bitstack/stack time <= 1.05", 6, 1.05, False),
           ("MBVH8 octant bitstack/octant stack time <= 1.05", 7, 1.05, False)]
KINDS = ["primary", "diffuse", "shadow"]


def main(paths):
    speed, scaling, order, fast_mismatch, peer_mismatch = {}, {}, [], {}, {}
    for r in records(paths):
        prec = r.get("precision", "robust")
        if prec == "exact":
            continue
        ours = r["backend"] not in ("embree", "tinybvh")
        if prec == "robust" and ours and not verified(r):
            continue
        scene = scene_name(r["scene"])
        v = (r["backend"], r["layout"], r["traversal"], prec)
        rows = ((1, r.get("mrays_per_s_1_thread", 0)), (r["threads"], r["mrays_per_s"]))
        for threads, mr in rows:
            key = (scene, r["ray_kind"], r["query"], threads)
            if mr and key not in order:
                order.append(key)
            if mr:
                speed[key + v] = mr
        scaling[(scene, r["ray_kind"], r["query"]) + v] = r.get("thread_scaling", 0)
        if prec == "robust" and not ours:
            peer_mismatch[(scene, r["ray_kind"], r["backend"], r["layout"], r["traversal"])] = r.get(
                "verify_mismatches", 0)
        if prec == "fast":
            fast_mismatch[(scene, r["ray_kind"], r["backend"], r["layout"], r["traversal"])] = r.get(
                "verify_mismatches", 0)
    if not speed:
        sys.exit("cpu_table.py: no usable records in " + " ".join(paths))
    order.sort(key=lambda k: (k[0], KINDS.index(k[1]) if k[1] in KINDS else 9, k[2], k[3]))

    print("| scene | rays | query | threads | MBVH4 stack | MBVH4 bitstack | MBVH4 ordered | MBVH8 stack "
          "| MBVH8 bitstack | MBVH8 ordered | MBVH8 octant | MBVH8 octant bitstack | embree robust | best cpu fast | embree default "
          "| tinybvh BVH4_CPU | tinybvh BVH8_CPU "
          "| best stack-based × embree robust | best stackless × embree robust | best fast × embree default "
          "| best fast × best tinybvh | best robust × best tinybvh "
          "| MBVH4 bitstack/stack time | MBVH8 bitstack/stack time | MBVH8 octant bitstack/stack time |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    met = [[0, 0] for _ in TARGETS]  # per target: rows meeting it, rows with the ratio
    for key in order:
        s = [speed.get(key + v + ("robust",)) for v in ROBUST]
        emb = speed.get(key + EMBREE + ("robust",))
        emb_fast = speed.get(key + EMBREE + ("fast",))
        fast = max((speed.get(key + v + ("fast",)) or 0 for v in ROBUST), default=0) or None
        best_stack = max((s[i] for i in STACK_BASED if s[i]), default=None)
        best_less = max((s[i] for i in STACKLESS if s[i]), default=None)
        ratio = lambda x, e: None if not x or not e else x / e
        slow4 = None if not s[0] or not s[1] else s[0] / s[1]
        slow8 = None if not s[3] or not s[4] else s[3] / s[4]
        slow8o = None if not s[6] or not s[7] else s[6] / s[7]
        tiny = [speed.get(key + v + ("fast",)) for v in TINYBVH]
        best_tiny = max((x for x in tiny if x), default=None)
        best_robust = max((x for x in s if x), default=None)
        ratios = [ratio(best_stack, emb), ratio(best_less, emb), ratio(fast, emb_fast), ratio(fast, best_tiny),
                  ratio(best_robust, best_tiny), slow4, slow8, slow8o]
        for m, (_, col, bound, at_least) in zip(met, TARGETS):
            x = ratios[col]
            if x:
                m[1] += 1
                m[0] += 1 if (x >= bound if at_least else x <= bound) else 0
        print(f"| {key[0]} | {key[1]} | {key[2]} | {key[3]} | " + " | ".join(fmt(x) for x in s) +
              f" | {fmt(emb)} | {fmt(fast)} | {fmt(emb_fast)} | {fmt(tiny[0])} | {fmt(tiny[1])} "
              f"| {fmt(ratios[0])} | {fmt(ratios[1])} | {fmt(ratios[2])} | {fmt(ratios[3])} | {fmt(ratios[4])} "
              f"| {fmt(slow4, 3)} | {fmt(slow8, 3)} | {fmt(slow8o, 3)} |")
    print()
    for (name, *_), (ok, n) in zip(TARGETS, met):
        print(f"- {name}: {ok} of {n} rows" + ("" if n else " (no row has both figures)"))

    print()
    print("| scene | rays | MBVH4 stack 2/1 threads | MBVH4 bitstack | MBVH8 bitstack | MBVH8 ordered | embree robust "
          "| tinybvh BVH8_CPU |")
    print("|---|---|---|---|---|---|---|---|")
    seen = []
    for scene, kind, query, _ in order:
        if (scene, kind, query) not in seen:
            seen.append((scene, kind, query))
            cells = [scaling.get((scene, kind, query) + ROBUST[i] + ("robust",)) for i in (0, 1, 4, 5)]
            cells.append(scaling.get((scene, kind, query) + EMBREE + ("robust",)))
            cells.append(scaling.get((scene, kind, query) + TINYBVH[1] + ("fast",)))
            print(f"| {scene} | {kind} | " + " | ".join(fmt(c) for c in cells) + " |")

    bad = {k: m for k, m in fast_mismatch.items() if m}
    if bad:
        print()
        print("fast-mode answers that differ from the robust reference (by design; not timed out): " +
              ", ".join(f"{k[0]}/{k[1]} {k[2]} {k[3]}/{k[4]}: {m}" for k, m in sorted(bad.items())))
    bad = {k: m for k, m in peer_mismatch.items() if m}
    if bad:
        print()
        print("a peer's robust-mode answers that differ from cpu-scalar's (a witness, not ours; timed all the same): " +
              ", ".join(f"{k[0]}/{k[1]} {k[2]}: {m}" for k, m in sorted(bad.items())))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
