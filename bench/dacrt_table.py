#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""dacrt_table.py — the Markdown tables of bench/dacrt.sh from the files it wrote to OUT:
speed (speed-*.json), the hairball (hairball-*.json), dynamic frames (dynamic-*.json), memory
(mem-*.time, mem-info.txt) and the ablations (ablation-SCENE-LABEL-rN.json).
    bench/dacrt_table.py OUT [DACRT [DACRT_SCALAR]]    (DACRT: the backend timed as dacrt)
"""
import glob
import os
import re
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import benchlib  # noqa: E402

OUT = sys.argv[1]
DACRT = sys.argv[2] if len(sys.argv) > 2 else "dacrt"
DACRT_SCALAR = sys.argv[3] if len(sys.argv) > 3 else "dacrt-scalar"
fmt = benchlib.fmt


def variant(r):
    return f"{r['backend']} {r['layout']} {r['traversal']}"


def ratio(a, b):
    return a / b if a and b else 0


def speed_table(pattern, title, targets):
    """Per ray kind: cpu's default (MBVH4 bitstack) and best variant, dacrt, embree; dacrt over
    each cpu column, at 2 threads and (with --scaling) 1 thread."""
    recs = benchlib.records(pattern)
    if not recs:
        return ""
    one = any(r.get("mrays_per_s_1_thread") for r in recs)
    lines = [f"### {title}", ""]
    head = ["scene", "rays", "query", "threads", "cpu bitstack", "cpu best (variant)", DACRT, "embree",
            f"{DACRT} / cpu bitstack", f"{DACRT} / cpu best", "target", "rays a kind", "verified"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    keys = sorted({(r["scene"], r["ray_kind"], r["query"]) for r in recs})
    for scene, kind, query in keys:
        rs = [r for r in recs if (r["scene"], r["ray_kind"], r["query"]) == (scene, kind, query)]
        for threads, field in ([("2", "mrays_per_s"), ("1", "mrays_per_s_1_thread")] if one else
                               [(str(rs[0]["threads"]), "mrays_per_s")]):
            cpu = [r for r in rs if r["backend"] == "cpu" and r["traversal"] != "dacrt"]  # its BVH traversals
            bit = next((r[field] for r in cpu if r["traversal"] == "bitstack"), 0)
            best = max(cpu, key=lambda r: r[field] or 0, default=None)
            d = next((r[field] for r in rs if r["backend"] == DACRT), 0)
            e = next((r[field] for r in rs if r["backend"] == "embree"), 0)
            ok = all(benchlib.verified(r) for r in rs)
            target = targets(kind, threads)
            rb = ratio(d, best[field]) if best else 0
            met = "" if not target else (" met" if rb >= target else " **not met**")
            lines.append("| " + " | ".join([
                benchlib.scene_name(scene), kind, query, threads, fmt(bit),
                f"{fmt(best[field])} ({best['layout']} {best['traversal']})" if best else "–", fmt(d), fmt(e),
                fmt(ratio(d, bit)), fmt(rb), (f"≥ {target}{met}" if target else ""), str(rs[0]["rays"]),
                "yes" if ok else "**NO**"]) + " |")
    return "\n".join(lines) + "\n"


def conference_targets(kind, threads):  # issue 32's targets, against the best cpu variant
    if kind == "path":
        return 0.9 if threads == "1" else 0.6
    return 0.9 if kind == "primary" and threads == "1" else 0


def hairball_targets(kind, threads):  # issue 32
    return 0.3 if kind == "path" and threads == "2" else 0


def dynamic_tables():
    lines = []
    for path in sorted(glob.glob(os.path.join(OUT, "dynamic-*.json"))):
        doc = benchlib.load(path)
        recs = doc["records"]
        if not recs:
            continue
        rays = recs[0]["rays"]
        lines += [f"### Dynamic frames: {benchlib.scene_name(doc['scene'])} ({doc['triangles']} triangles), "
                  f"{recs[0]['ray_kind']} ({recs[0]['query']}), {rays} rays in the last frame, "
                  f"{recs[0]['frames']} frames, {recs[0]['threads']} threads", ""]
        head = ["backend", "mode", "ms/frame (median)", "min–max", "update ms", "trace ms", "× update", "× rebuild",
                "held MiB", "peak+ MiB", "verified"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        mib = lambda b: "–" if b is None else f"{b / 2**20:.1f}"  # noqa: E731
        for r in recs:
            lines.append("| " + " | ".join([
                f"{r['backend']} {r['layout']} {r['traversal']}", r["mode"], fmt(r["ms_per_frame"]),
                f"{fmt(r['ms_per_frame_min'])}–{fmt(r['ms_per_frame_max'])}", fmt(r["update_ms"]),
                " + ".join(fmt(t) for t in r["trace_ms"]), fmt(r["time_vs_update"]), fmt(r["time_vs_rebuild"]),
                mib(r["held_bytes"]), mib(r["peak_extra_bytes"]), "yes" if r["verified"] else "**NO**"]) + " |")
        upd = [r for r in recs if r["mode"] == "update+trace"]
        reb = [r for r in recs if r["mode"] == "rebuild+trace"]
        if upd and reb:
            per = [f"{r['backend']} {r['traversal']}: {fmt(r['time_vs_update'])}" for r in reb]
            met = all((r["time_vs_update"] or 0) >= 1.2 for r in reb)
            lines += ["", f"(rebuild+trace)/(update+trace): {', '.join(per)} — target ≥ 1.2 (issue 32): "
                      f"{'met' if met else '**not met**'}"]
        lines += ["", "ms per frame, frame by frame: " + "; ".join(
            f"{r['backend']} {r['mode']}: " + " ".join(fmt(f["total_ms"], 1) for f in r["per_frame"]) for r in recs), ""]
    return "\n".join(lines) + "\n" if lines else ""


def max_rss(path):
    """Maximum resident set size, bytes, from a `/usr/bin/time -v` report."""
    with open(path) as f:
        m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", f.read())
    return int(m.group(1)) * 1024 if m else 0


def memory_table():
    info = os.path.join(OUT, "mem-info.txt")
    if not os.path.exists(info):
        return ""
    with open(info) as f:
        text = f.read()
    m = re.search(r"triangles\s+(\d+) .*?, (\d+) vertices", text)
    tris, verts = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
    scene_bytes = 12 * verts + 12 * tris  # the loaded scene's arrays: float vertices, uint32 triangles
    base = max_rss(os.path.join(OUT, "mem-process.time"))
    lines = ["### Memory: max RSS of `mbvh trace --rays FILE` (path rays written first)", "",
             f"{tris} triangles, {verts} vertices (the scene's arrays {scene_bytes / 2**20:.1f} MiB); "
             f"`mbvh --version` alone: {base / 2**20:.1f} MiB. B/ray: (RSS with the file's rays − RSS with 1 ray) "
             "/ rays; B/tri: (RSS with 1 ray − the process alone − the scene's arrays) / triangles: the structure, "
             "the backend's copies and the loader's peak, if it is the larger.", ""]
    head = ["backend", "rays", "max RSS MiB", "1-ray RSS MiB", "B/ray", "B/tri"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for b in ["cpu", DACRT]:
        one, full = (os.path.join(OUT, f"mem-{b}-{f}.time") for f in ("mem1", "mem"))
        if not (os.path.exists(one) and os.path.exists(full)):
            continue
        with open(os.path.join(OUT, f"mem-{b}-mem.txt")) as f:
            m = re.search(r"traced (\d+) rays", f.read())
        n = int(m.group(1)) if m else 0
        r1, rn = max_rss(one), max_rss(full)
        lines.append("| " + " | ".join([b, str(n), f"{rn / 2**20:.1f}", f"{r1 / 2**20:.1f}",
                                        fmt((rn - r1) / (n - 1) if n > 1 else 0, 1),
                                        fmt((r1 - base - scene_bytes) / tris if tris else 0, 1)]) + " |")
    return "\n".join(lines) + "\n"


def ablation_tables():
    files = sorted(glob.glob(os.path.join(OUT, "ablation-*-r*.json")))
    if not files:
        return ""
    # ablation-SCENE-LABEL-rN.json: the Mrays/s median of each round, per scene, label and kind
    runs = {}
    order = []
    variants_file = os.path.join(OUT, "ablation-variants.txt")
    if os.path.exists(variants_file):
        with open(variants_file) as f:
            order = [line.split("|")[0] for line in f if line.strip()]
    for path in files:
        m = re.match(r"ablation-(.+?)-(.+)-r(\d+)\.json$", os.path.basename(path))
        if not m:
            continue
        scene, label = m.group(1), m.group(2)
        for r in benchlib.load(path)["records"]:
            runs.setdefault((scene, r["ray_kind"], label), []).append((r["mrays_per_s"], benchlib.verified(r), r["rays"]))
    lines = ["### Ablations: dacrt's settings one at a time (Mrays/s, median of the rounds' medians, 2 threads)", ""]
    head = ["scene", "rays", "variant", "Mrays/s", "min–max over rounds", "rounds", "× adaptive (default)", "verified"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    summary = []
    for scene, kind in sorted({(s, k) for s, k, _ in runs}):
        labels = [lb for lb in order if (scene, kind, lb) in runs] + \
                 sorted(lb for s, k, lb in runs if (s, k) == (scene, kind) and lb not in order)
        med = {lb: statistics.median(v for v, _, _ in runs[(scene, kind, lb)]) for lb in labels}
        base = med.get("adaptive", 0)
        for lb in labels:
            vs = runs[(scene, kind, lb)]
            lines.append("| " + " | ".join([
                scene, f"{kind} ({vs[0][2]})", lb, fmt(med[lb]), f"{fmt(min(v for v, _, _ in vs))}–{fmt(max(v for v, _, _ in vs))}",
                str(len(vs)), fmt(ratio(med[lb], base)), "yes" if all(ok for _, ok, _ in vs) else "**NO**"]) + " |")
        if kind == "path" and base and "sah" in med and "middle" in med:
            better = max(med["sah"], med["middle"])
            summary.append(f"{scene} path: adaptive / the better fixed policy = {base / better:.3f} "
                           f"(target ≥ 0.95, A-7: {'met' if base >= 0.95 * better else '**not met**'})")
        if "ordered0" in med and base:
            summary.append(f"{scene} {kind}: ordered / unordered = {ratio(base, med['ordered0']):.3f}")
        if "scalar" in med and base:
            summary.append(f"{scene} {kind}: {DACRT} / {DACRT_SCALAR} = {ratio(base, med['scalar']):.3f}")
    return "\n".join(lines + [""] + [f"- {s}" for s in summary]) + "\n"


parts = [
    speed_table(os.path.join(OUT, "speed-*.json"), "Speed: Mrays/s, 2 threads and 1 (--scaling)", conference_targets),
    speed_table(os.path.join(OUT, "hairball-*.json"), "The hairball: path rays, 2 threads", hairball_targets),
    dynamic_tables(),
    memory_table(),
    ablation_tables(),
]
print("\n".join(p for p in parts if p))
