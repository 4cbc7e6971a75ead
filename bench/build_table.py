#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""build_table.py — merges bench/build.sh's files (DIR/build-SCENE-Q.json of `mbvh build-bench`,
DIR/bench-SCENE-Q.json of `mbvh bench`) into DIR/build.json and a Markdown table (DIR/build.md,
also on stdout); with --plot, DIR/build.png: build time against diffuse Mrays/s, one marker per
builder (ours and Embree, low / medium / high) and scene.
    python3 bench/build_table.py DIR [--plot]
"""
import glob
import json
import os
import sys

from benchlib import fmt, load, pyplot, verified

QUALITIES = ["low", "medium", "high"]


def main(d, plot):
    rows = []
    for path in sorted(glob.glob(os.path.join(d, "build-*-*.json"))):
        name, q = os.path.basename(path)[len("build-"):-len(".json")].rsplit("-", 1)
        b = load(path)
        bench_path = os.path.join(d, f"bench-{name}-{q}.json")
        recs = load(bench_path)["records"] if os.path.exists(bench_path) else []
        cpu = next((r for r in recs if r["backend"].startswith("cpu") and r["ray_kind"] == "diffuse"), None)
        emb = next((r for r in recs if r["backend"] == "embree" and r["ray_kind"] == "diffuse"), None)
        ok = all(verified(r) for r in recs)
        rows.append({
            "scene": name, "quality": q, "triangles": b["triangles"], "references": b["references"],
            "build_ms": b["build_ms"], "embree_build_ms": b.get("embree_build_ms"),
            "sah_binary": b["sah_binary"], "sah_mbvh4": b["sah_mbvh4"],
            "faults_per_tri": b.get("faults_per_triangle"), "embree_faults_per_tri": b.get("embree_faults_per_triangle"),
            "rebuild_ms": b.get("rebuild_ms"), "rebuild_speedup": b.get("rebuild_speedup"),
            "rebuild_faults_per_tri": b.get("rebuild_faults_per_triangle"),
            "faults_first_per_tri": b.get("faults_first_per_triangle"),
            "embree_faults_first_per_tri": b.get("embree_faults_first_per_triangle"),
            "nodes_per_ray": cpu and cpu["nodes_per_ray"], "leaves_per_ray": cpu and cpu["leaves_per_ray"],
            "triangles_per_ray": cpu and cpu["triangles_per_ray"],
            "cpu_mrays": cpu and cpu["mrays_per_s"], "embree_mrays": emb and emb["mrays_per_s"], "verified": ok})
    if not rows:
        sys.exit("build_table.py: no build-*.json in " + d)
    order = {n: i for i, n in enumerate(["bunny", "conference", "sibenik", "sponza", "hairball100k", "hairball1m", "hairball10m"])}
    rows.sort(key=lambda r: (order.get(r["scene"], 99), r["scene"], QUALITIES.index(r["quality"])))
    with open(os.path.join(d, "build.json"), "w") as f:
        json.dump(rows, f, indent=2)
    def faults(x):  # a count per triangle: 0 is a value here, not a missing one
        return "–" if x is None else f"{x:.4f}"

    lines = ["| scene | quality | triangles | refs | ours build ms | Embree build ms | page faults per tri (ours / Embree) | "
             "first build's (ours / Embree) | "
             "rebuild ms (kept context) | cold / rebuild | SAH (binary / MBVH4) | "
             "nodes / tris per diffuse ray | cpu diffuse Mrays/s | Embree diffuse Mrays/s |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f'| {r["scene"]} | {r["quality"]} | {r["triangles"]} | {r["references"]} | {fmt(r["build_ms"], 1)} | '
                     f'{fmt(r["embree_build_ms"], 1)} | {faults(r["faults_per_tri"])} / {faults(r["embree_faults_per_tri"])} | '
                     f'{faults(r["faults_first_per_tri"])} / {faults(r["embree_faults_first_per_tri"])} | '
                     f'{fmt(r["rebuild_ms"], 1)} | {fmt(r["rebuild_speedup"], 2)}x | '
                     f'{fmt(r["sah_binary"])} / {fmt(r["sah_mbvh4"])} | '
                     f'{fmt(r["nodes_per_ray"], 1)} / {fmt(r["triangles_per_ray"], 1)} | {fmt(r["cpu_mrays"])} | '
                     f'{fmt(r["embree_mrays"])} |' + ("" if r["verified"] else " (unverified)"))
    text = "\n".join(lines) + "\n"
    with open(os.path.join(d, "build.md"), "w") as f:
        f.write(text)
    print(text)
    if not all(r["verified"] for r in rows):
        sys.exit("build_table.py: some timed results did not match the reference")
    plt = pyplot("build_table.py: no plot") if plot else None
    if plt:
        scenes = sorted({r["scene"] for r in rows}, key=lambda s: order.get(s, 99))
        fig, axes = plt.subplots(1, len(scenes), figsize=(4 * len(scenes), 4), squeeze=False)
        marks = {"low": "v", "medium": "o", "high": "^"}
        for ax, s in zip(axes[0], scenes):
            for r in (r for r in rows if r["scene"] == s):
                if r["cpu_mrays"]:
                    ax.scatter(r["build_ms"], r["cpu_mrays"], marker=marks[r["quality"]], color="C0",
                               label=f'ours {r["quality"]} (cpu)')
                if r["embree_mrays"] and r["embree_build_ms"]:
                    ax.scatter(r["embree_build_ms"], r["embree_mrays"], marker=marks[r["quality"]], color="C1",
                               label=f'Embree {r["quality"]}')
            ax.set_xscale("log")
            ax.set_xlabel("build ms (2 threads, median)")
            ax.set_ylabel("diffuse Mrays/s")
            ax.set_title(s)
            ax.grid(True, alpha=0.3)
        axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(d, "build.png"), dpi=120)
        print("wrote " + os.path.join(d, "build.png"), file=sys.stderr)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--plot"]
    if len(args) != 1:
        sys.exit(__doc__)
    main(args[0], "--plot" in sys.argv[1:])
