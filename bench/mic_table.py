#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""mic_table.py — the Markdown table of bench/mic.sh: per scene x rays (query), cpu-avx512's
MBVH4 stack and bitstack with the MIC path (cpu.mic=1, a node in 16 lanes) and without (the
8-lane kernels' 4-lane node test), MBVH8 stack and bitstack (Mrays/s, the median over the passes
of both settings' runs for MBVH8, which cpu.mic does not change), and the ratios:
  MIC MBVH4 / 4-lane MBVH4 (same traversal),  best MIC MBVH4 / best MBVH8,
  MIC bitstack time / MIC stack time  (target <= 1.05).
Only verified records count (zero mismatches against cpu-scalar). The setting of a file is in its
name (…-mic0-P.json, …-mic1-P.json).
    python3 bench/mic_table.py bench/out-mic/*-mic[01]-*.json
"""
import re
import sys

from benchlib import fmt, median, records, scene_name, verified

KINDS = ["primary", "diffuse", "shadow"]


def main(paths):
    runs, order, unverified = {}, [], []
    for r in records(paths):
        m = re.search(r"-mic([01])-\d+\.json$", r["_file"])
        if not m:
            continue
        mic = m.group(1) == "1"
        key = (scene_name(r["scene"]), r["ray_kind"], r["query"])
        if not verified(r):
            unverified.append(f"{key} {r['layout']} {r['traversal']} cpu.mic={int(mic)}")
            continue
        if key not in order:
            order.append(key)
        # MBVH8 does not depend on the setting: both runs' records are its samples
        v = (r["layout"], r["traversal"], mic and r["layout"] == "mbvh4")
        runs.setdefault(key + v, []).append(r["mrays_per_s"])
    if not runs:
        sys.exit("mic_table.py: no usable records in " + " ".join(paths))
    order.sort(key=lambda k: (k[0], KINDS.index(k[1]) if k[1] in KINDS else 9, k[2]))
    print("| scene | rays | query | MBVH4 stack | MBVH4 bitstack | MIC stack | MIC bitstack | MBVH8 stack "
          "| MBVH8 bitstack | MIC / MBVH4 stack | MIC / MBVH4 bitstack | best MIC / best MBVH8 "
          "| MIC bitstack/stack time |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for key in order:
        g = lambda l, t, mic: median(runs.get(key + (l, t, mic), []))
        s4, b4 = g("mbvh4", "stack", False), g("mbvh4", "bitstack", False)
        ms, mb = g("mbvh4", "stack", True), g("mbvh4", "bitstack", True)
        s8, b8 = g("mbvh8", "stack", False), g("mbvh8", "bitstack", False)
        ratio = lambda a, b: a / b if a and b else None
        best8 = max(s8, b8) or None
        print(f"| {key[0]} | {key[1]} | {key[2]} | {fmt(s4)} | {fmt(b4)} | {fmt(ms)} | {fmt(mb)} | {fmt(s8)} | {fmt(b8)} "
              f"| {fmt(ratio(ms, s4))} | {fmt(ratio(mb, b4))} | {fmt(ratio(max(ms, mb), best8))} "
              f"| {fmt(ratio(ms, mb))} |")
    for u in unverified:
        print(f"\nnot verified (left out): {u}")


if __name__ == "__main__":
    main(sys.argv[1:])
