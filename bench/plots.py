#!/usr/bin/env python3
"""plots.py — plots and Markdown tables from `mbvh bench --json` / `mbvh info --json` files.

    python3 bench/plots.py scaling DIR    DIR/info-N.json and DIR/bench-N.json of bench/scaling.sh:
                                          DIR/scaling.png (log-log: ns per ray and build time
                                          against triangles) and a Markdown table on stdout
"""
import glob
import json
import os
import sys


def load(path):
    with open(path) as f:
        return json.load(f)


def backend_label(r):
    return f'{r["backend"]} {r["layout"]} {r["traversal"]}'


def loglog(ax, xlabel, ylabel, title):
    """Log-log axes with a grid and a legend."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


def scaling(directory):
    sizes = sorted(int(os.path.basename(p)[len("bench-"):-len(".json")]) for p in glob.glob(f"{directory}/bench-*.json"))
    if not sizes:
        sys.exit(f"plots.py: no bench-N.json in {directory}")
    series, build = {}, {}
    for n in sizes:
        info = load(f"{directory}/info-{n}.json")
        build[n] = {l["layout"]: l["build_ms"] for l in info["layouts"]}
        for r in load(f"{directory}/bench-{n}.json")["records"]:
            if r["verify_mismatches"] != 0 or r["mrays_per_s"] <= 0:
                continue
            series.setdefault(backend_label(r), {})[n] = 1e3 / r["mrays_per_s"]  # ns per ray
    # one line per backend: its bitstack on MBVH4, else on MBVH2 (the GPU path), else its stack
    # (Embree)
    chosen = {}
    for label in series:
        backend, layout, traversal = label.split()
        rank = {("mbvh4", "bitstack"): 0, ("mbvh2", "bitstack"): 1}.get((layout, traversal), 2)
        if backend not in chosen or rank < chosen[backend][0]:
            chosen[backend] = (rank, label)
    series = {label: series[label] for _, label in chosen.values()}
    # table
    labels = sorted(series)
    print("| triangles | binary build ms | MBVH4 collapse ms | " + " | ".join(f"{l} ns/ray" for l in labels) + " |")
    print("|---" * (3 + len(labels)) + "|")
    for n in sizes:
        cells = [f"{series[l][n]:.0f}" if n in series[l] else "–" for l in labels]
        print(f"| {n:,} | {build[n].get('binary', 0):.0f} | {build[n].get('mbvh4', 0):.1f} | " + " | ".join(cells) + " |")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.exit("plots.py: python3-matplotlib is missing (apt-get install python3-matplotlib)")
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    for l in labels:
        xs = sorted(series[l])
        a.plot(xs, [series[l][x] for x in xs], marker="o", label=l)
    loglog(a, "triangles (gen:hairball)", "ns per ray (diffuse, closest hit)", "time per ray")
    for layout in ("binary", "mbvh2", "mbvh4", "mbvh8"):
        ys = [build[n].get(layout) for n in sizes]
        if all(y is not None for y in ys):
            b.plot(sizes, ys, marker="o", label="SAH build" if layout == "binary" else f"{layout} collapse")
    loglog(b, "triangles (gen:hairball)", "ms", "build time")
    fig.tight_layout()
    out = f"{directory}/scaling.png"
    fig.savefig(out, dpi=100)
    print(f"\nwrote {out}", file=sys.stderr)


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("scaling",):
        sys.exit(__doc__)
    scaling(sys.argv[2])
