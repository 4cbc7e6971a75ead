#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""packet_table.py — the Markdown table of bench/packets.sh from its `mbvh bench --scaling --json`
files: per scene x rays x threads, the cpu backend's best single-ray traversal (the fastest of
MBVH4/MBVH8 stack and ordered stack), its packet traversals (MBVH2 packets; the layout is the
hybrid's single rays: the faster of the two is shown), Embree's single-ray and packet queries
(robust mode), Mrays/s medians, and the ratios its targets are set on:
  best packet / best single-ray cpu  (primary >= 2, shadow >= 1.3, diffuse >= 0.95),
  best packet / Embree's faster query (primary >= 1.0);
with the packets' SIMD utilisation and nodes per ray (MBVH2 nodes the ray was active in). Only
verified records count (zero mismatches against cpu-scalar). Where the run has cpu-avx2 beside
`cpu` (an AVX-512 machine: packets.sh adds it), a second table: `cpu` (its AVX-512 kernels,
kIsaTable's choice) against cpu-avx2, best packet and best single-ray traversal each, with the
targets of issue 40 (packets >= 1.25x AVX2 and >= 2.5x Embree's faster query on primary rays).
    python3 bench/packet_table.py bench/out-packets/*.json
"""
import sys

from benchlib import records, scene_name, verified

KINDS = ["primary", "shadow", "diffuse"]
SINGLE = [("mbvh4", "stack"), ("mbvh4", "stack-ordered"), ("mbvh8", "stack"), ("mbvh8", "stack-ordered")]
PACKET = ["packet-ranged", "packet-partition"]
TARGET = {"primary": 2.0, "shadow": 1.3, "diffuse": 0.95}


def main(paths):
    speed, info, order = {}, {}, []
    for r in records(paths):
        if r.get("precision", "robust") != "robust" or not verified(r):
            continue
        scene = scene_name(r["scene"])
        v = (r["backend"], r["layout"], r["traversal"])
        for threads, mr in ((1, r.get("mrays_per_s_1_thread", 0)), (r["threads"], r["mrays_per_s"])):
            if not mr:
                continue
            key = (scene, r["ray_kind"], threads)
            if key not in order:
                order.append(key)
            speed[key + v] = mr
        info[(scene, r["ray_kind"]) + v] = (r.get("simd_utilisation"), r.get("nodes_per_ray"))
    if not speed:
        sys.exit("packet_table.py: no usable records in " + " ".join(paths))
    order.sort(key=lambda k: (k[0], KINDS.index(k[1]) if k[1] in KINDS else 9, k[2]))
    print("| scene | rays | threads | best single-ray cpu | packet-ranged | packet-partition | embree 1 | embree 16 "
          "| packet / single | target | packet / embree's faster | SIMD utilisation | nodes/ray packet (single) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    met = total = met_e = total_e = 0
    for key in order:
        scene, kind, threads = key
        singles = [(speed.get(key + ("cpu",) + s, 0), s) for s in SINGLE]
        best_single, single_v = max(singles)
        packets = {t: max(speed.get(key + ("cpu", l, t), 0) for l in ("mbvh4", "mbvh8")) for t in PACKET}
        best_packet_t = max(PACKET, key=lambda t: packets[t])
        best_packet = packets[best_packet_t]
        embree1 = speed.get(key + ("embree", "mbvh4", "stack"), 0)
        embree8 = speed.get(key + ("embree", "mbvh4", "packet"), 0)
        embree = max(embree1, embree8)
        ratio = best_packet / best_single if best_single and best_packet else 0
        ratio_e = best_packet / embree if embree and best_packet else 0
        target = TARGET.get(kind, 0)
        ok = ratio >= target
        total += 1
        met += ok
        if kind == "primary":
            total_e += 1
            met_e += ratio_e >= 1.0
        # utilisation and nodes: the best packet traversal on MBVH8 single rays (the counts do not
        # depend on the hybrid's layout), the best single-ray variant's nodes
        util, nodes = info.get((scene, kind, "cpu", "mbvh8", best_packet_t), (None, None))
        snodes = info.get((scene, kind, "cpu") + single_v, (None, None))[1]
        util_s = "–" if util is None else f"{100 * util:.0f} %"
        nodes_s = "–" if nodes is None else f"{nodes:.1f} ({snodes:.1f} {single_v[0].upper()})"
        print(f"| {scene} | {kind} | {threads} | {best_single:.2f} ({single_v[0].upper()} {single_v[1]}) "
              f"| {packets['packet-ranged']:.2f} | {packets['packet-partition']:.2f} | {embree1:.2f} | {embree8:.2f} "
              f"| **{ratio:.2f}×** | ≥ {target} {'met' if ok else 'missed'} | {ratio_e:.2f}× "
              f"| {util_s} | {nodes_s} |")
    print(f"\npacket / best single-ray at its target on {met} of {total} rows; "
          f"packet >= Embree's faster query on primary rays on {met_e} of {total_e} rows")
    isa_table(speed, order)


def best(speed, key, backend):
    """The best packet and the best single-ray Mrays/s of `backend` at key (0 where none ran)."""
    packet = max(speed.get(key + (backend, l, t), 0) for l in ("mbvh4", "mbvh8") for t in PACKET)
    single = max(speed.get(key + (backend,) + s, 0) for s in SINGLE)
    return packet, single


def isa_table(speed, order):
    """`cpu` (AVX-512 here) against cpu-avx2, where the run has both."""
    rows = [k for k in order if any(speed.get(k + ("cpu-avx2",) + s, 0) for s in SINGLE)]
    if not rows:
        return
    print("\n| scene | rays | threads | packet avx2 | packet cpu | **packet cpu / avx2** | single avx2 | single cpu "
          "| single cpu / avx2 | packet cpu / embree's faster |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for key in rows:
        scene, kind, threads = key
        p2, s2 = best(speed, key, "cpu-avx2")
        p5, s5 = best(speed, key, "cpu")
        embree = max(speed.get(key + ("embree", "mbvh4", "stack"), 0), speed.get(key + ("embree", "mbvh4", "packet"), 0))
        r = lambda a, b: f"{a / b:.2f}×" if a and b else "–"
        print(f"| {scene} | {kind} | {threads} | {p2:.2f} | {p5:.2f} | **{r(p5, p2)}** | {s2:.2f} | {s5:.2f} "
              f"| {r(s5, s2)} | {r(p5, embree)} |")


if __name__ == "__main__":
    main(sys.argv[1:])
