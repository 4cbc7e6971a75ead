#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""plots.py — plots and Markdown tables from `mbvh bench --json` / `mbvh info --json` files.

    python3 bench/plots.py scaling DIR    DIR/info-N.json and DIR/bench-N.json of bench/scaling.sh:
                                          DIR/scaling.png (log-log: ns per ray and build time
                                          against triangles) and a Markdown table on stdout
    python3 bench/plots.py all DIR        the output of bench/all.sh: DIR/pareto.png, DIR/rmse.png
                                          and every Markdown table on stdout
    python3 bench/plots.py check DIR B1,B2,...
                                          fails unless DIR holds a record of every backend Bi for every
                                          ray kind, query and traversal pair (stack and bitstack for
                                          mbvh's own backends) and every timed result was verified
    python3 bench/plots.py backends DIR   the backends of DIR's speed records, in the order they ran,
                                          comma-separated (what `mbvh bench --backend all` ran)
"""
import glob
import os
import sys

from benchlib import load, median, pyplot, records, scene_name, verified


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
            if not verified(r) or r["mrays_per_s"] <= 0:
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
    plt = need_pyplot()
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


def need_pyplot():
    return pyplot("plots.py") or sys.exit(1)


KINDS = ["primary", "diffuse", "path", "shadow"]
# the thesis' bitstack-vs-stack slowdowns (Áfra & Szirmay-Kalos 2014) and the backend that plays
# each platform here
THESIS = {"cpu": ("CPU (MBVH4)", "9–17 %"), "opencl": ("MIC (16-wide MBVH4)", "13–16 %"),
          "vulkan": ("GPU (MBVH2)", "20–31 %")}


def speed_tables(directory):
    recs = [r for r in records(f"{directory}/speed/*.json")]
    if not recs:
        return
    doc = recs[0]["_doc"]
    print(f"Machine: {doc['cpu']}, {doc['machine']}; {doc['compiler']}.\n")
    scenes = list(dict.fromkeys(scene_name(r["scene"]) for r in recs))
    for scene in scenes:
        rows = {}
        for r in recs:
            if scene_name(r["scene"]) != scene:
                continue
            key = (r["backend"], r["layout"], r["traversal"])
            rows.setdefault(key, {})[r["ray_kind"]] = r
        print(f"#### {scene}: Mrays/s (median of {recs[0]['passes']}, {recs[0]['rays']:,} rays per kind, "
              f"{recs[0]['threads']} threads; shadow rays any hit, the rest closest hit)\n")
        print("| backend | layout | traversal | state B/ray | " + " | ".join(KINDS) + " | path vs cpu |")
        print("|---" * (5 + len(KINDS)) + "|")
        for (b, l, t), kinds in rows.items():
            cells = [f"{kinds[k]['mrays_per_s']:.2f}" if k in kinds else "–" for k in KINDS]
            vs = kinds.get("path", {}).get("vs_cpu", 0)
            st = next(iter(kinds.values()))["state_bytes_per_ray"]
            print(f"| {b} | {l} | {t} | {st if st else 'internal'} | " + " | ".join(cells) +
                  f" | {f'{vs:.2f}x' if vs else ''} |")
        print()
    # traversal state: capacity and the measured high-water mark, against the bitstack's fixed state,
    # with the work per ray (Sponza's path rays, or the last scene's)
    pick = "sponza" if "sponza" in scenes else scenes[-1]
    print(f"#### Traversal state and work per ray ({pick}, the path tracer's bounce rays; each backend counts "
          "its own work, and backends that share a traversal count the same)\n")
    print("| layout | traversal | state B/ray (capacity) | × bitstack | high-water B/ray (mean) | "
          "nodes | box tests | leaves | triangles | climbs | backends |")
    print("|---" * 11 + "|")
    groups = {}
    for r in recs:
        if scene_name(r["scene"]) != pick or r["ray_kind"] != "path" or not r["state_bytes_per_ray"]:
            continue
        key = (r["layout"], r["traversal"], r["state_bytes_per_ray"], round(r["peak_state_bytes_per_ray"], 1),
               round(r["nodes_per_ray"], 1), round(r["box_tests_per_ray"], 1), round(r["leaves_per_ray"], 2),
               round(r["triangles_per_ray"], 1), round(r["climbs_per_ray"], 2))
        groups.setdefault(key, []).append(r["backend"])
    for (l, t, st, peak, n, bt, lf, tr, cl), names in groups.items():
        print(f"| {l} | {t} | {st} | {st / 12.0:.0f}× | {peak:.1f} | {n:.1f} | {bt:.1f} | {lf:.2f} | {tr:.1f} | {cl:.2f} | "
              f"{', '.join(names)} |")
    print()
    # bitstack vs stack: time of the bitstack / time of its stack twin - 1, over scenes and kinds
    print("#### Bitstack vs stack: extra time of the bitstack over its stack twin (same backend, layout, "
          "rays; all scenes and ray kinds above)\n")
    print("| backend | layout | min | median | max | thesis (platform) |")
    print("|---" * 6 + "|")
    slow = {}
    for r in recs:
        if r["traversal"] == "bitstack" and r["bitstack_vs_stack"] > 0:
            slow.setdefault((r["backend"], r["layout"]), []).append(100.0 * (1.0 / r["bitstack_vs_stack"] - 1.0))
    for (b, l), xs in slow.items():
        platform, fig = THESIS.get(b, ("", ""))
        print(f"| {b} | {l} | {min(xs):+.0f} % | {median(xs):+.0f} % | {max(xs):+.0f} % | "
              f"{fig + ' (' + platform + ')' if fig else ''} |")
    print()


def error_points(directory):
    """(backend, precision) -> ns per ray (median over kinds), checked rays, genuine, wrong, leaks, inside rays."""
    pts = {}
    for r in records(f"{directory}/error/*.json"):
        key = (r["backend"], r["precision"], r["layout"], r["traversal"])
        p = pts.setdefault(key, {"ns": [], "checked": 0, "genuine": 0, "wrong": 0, "leaks": 0, "inside": 0})
        if r["ray_kind"] == "inside":  # every inside ray is checked (a miss is a leak): not sampled again
            p["leaks"] += r["leaks"]
            p["inside"] += r["rays"]
            continue
        p["ns"].append(1e3 / r["mrays_per_s"])
        p["checked"] += r["error_rays"]
        p["genuine"] += r["error_mismatches"]
        p["wrong"] += r["wrong_answers"]
    # one layout and traversal per backend: MBVH4 before MBVH2, the bitstack before the stack
    best = {}
    for (b, pr, l, t) in pts:
        rank = {("mbvh4", "bitstack"): 0, ("mbvh2", "bitstack"): 1, ("mbvh4", "stack"): 2}.get((l, t), 3)
        if (b, pr) not in best or rank < best[(b, pr)][0]:
            best[(b, pr)] = (rank, l, t)
    return {(b, pr, l, t): pts[(b, pr, l, t)] for (b, pr), (_, l, t) in best.items()}


def pareto(directory):
    pts = error_points(directory)
    if not pts:
        return
    print("#### Run time against error (bunny: primary, diffuse, shadow and grazing/edge-aimed rays; leaks: "
          "rays from inside a closed sphere at its vertices and edges)\n")
    print("| backend | layout/traversal | precision | ns/ray (median of kinds) | genuine mismatches | "
          "wrong answers | leaks | errors per million rays |")
    print("|---" * 8 + "|")
    plt = need_pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    marker = {"robust": "o", "exact": "s", "fast": "^"}
    for (b, pr, l, t), p in sorted(pts.items()):
        ns = median(p["ns"])
        rate = 1e6 * (p["wrong"] + p["leaks"]) / max(1, p["checked"] + p["inside"])
        print(f"| {b} | {l}/{t} | {pr} | {ns:.0f} | {p['genuine']} / {p['checked']:,} | {p['wrong']} / {p['checked']:,} | "
              f"{p['leaks']} / {p['inside']:,} | {rate:,.0f} |")
        ax.scatter([max(rate, 1.0)], [ns], marker=marker.get(pr, "x"), s=60, label=f"{b} {pr}")
        ax.annotate(f"{b} {pr}", (max(rate, 1.0), ns), fontsize=7, xytext=(4, 2), textcoords="offset points")
    print()
    ax.set_xscale("log")
    ax.set_xlabel("wrong answers + leaks per million rays (1 = none)")
    ax.set_ylabel("ns per ray (median over ray kinds)")
    ax.set_title("run time against error, per backend and accuracy mode")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(f"{directory}/pareto.png", dpi=100)
    print(f"wrote {directory}/pareto.png", file=sys.stderr)


def rmse_plot(directory):
    curves = [load(p) for p in sorted(glob.glob(f"{directory}/render/*.json"))]
    if not curves:
        return
    c0 = curves[0]
    print(f"#### Image error against time ({scene_name(c0['scene'])}, {c0['width']}×{c0['height']}, "
          "8-bounce path tracing; RMSE of the running mean against a high-sample cpu reference)\n")
    print("| backend | precision | Mrays/s | spp | seconds (all) | RMSE at 1 spp | RMSE at the end |")
    print("|---" * 7 + "|")
    plt = need_pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    for c in curves:
        pts = c["points"]
        print(f"| {c['backend']} | {c['precision']} | {c['mrays_per_s']:.2f} | {pts[-1]['spp']} | "
              f"{pts[-1]['total_seconds']:.2f} | {pts[0]['rmse']:.4f} | {pts[-1]['rmse']:.4f} |")
        ax.plot([p["total_seconds"] for p in pts], [p["rmse"] for p in pts], marker=".",
                linestyle="--" if c["precision"] == "fast" else "-", label=f"{c['backend']} {c['precision']}")
    print()
    loglog(ax, "seconds (render so far, shading included)", "RMSE against the reference", "image error against time")
    fig.tight_layout()
    fig.savefig(f"{directory}/rmse.png", dpi=100)
    print(f"wrote {directory}/rmse.png", file=sys.stderr)


def check(directory, backends):
    """Every backend has a record for every ray kind and query of every speed file, stack and bitstack
    both for mbvh's own backends with a hierarchy (state bytes > 0; a peer keeps its stack internal;
    dacrt has its own traversal only), the accuracy
    modes it offers in the error files, a render curve; every timed result verified."""
    problems = []
    speed = records(f"{directory}/speed/*.json")
    error = records(f"{directory}/error/*.json")
    if not speed or not error:
        problems.append(f"no speed or error records under {directory}")
    for r in speed + error:
        if not r.get("verified"):
            problems.append(f"{r['_file']}: {r['backend']}/{r['layout']}/{r['traversal']}/{r['ray_kind']}/"
                            f"{r['precision']} was not verified")
    for f in sorted({r["_file"] for r in speed}):
        rs = [r for r in speed if r["_file"] == f]
        for kind in sorted({r["ray_kind"] for r in rs}):
            for b in backends:
                mine = [r for r in rs if r["backend"] == b and r["ray_kind"] == kind]
                trav = {r["traversal"] for r in mine}
                own = any(r["state_bytes_per_ray"] > 0 for r in mine)
                if not mine:
                    problems.append(f"{f}: no {kind} record of backend {b}")
                elif own and trav != {"dacrt"} and not {"stack", "bitstack"} <= trav:  # dacrt: its own only
                    problems.append(f"{f}: backend {b} lacks a stack or bitstack {kind} record (has {sorted(trav)})")
    for b in backends:
        if not [r for r in error if r["backend"] == b and r["precision"] == "robust"]:
            problems.append(f"error: no robust record of backend {b}")
        if not os.path.exists(f"{directory}/render/{b}-robust.json"):
            problems.append(f"render: no image-error curve of backend {b}")
    for f in sorted({r["_file"] for r in error}):
        if not [r for r in error if r["_file"] == f and r["error_rays"] > 0]:
            problems.append(f"{f}: no result was compared with the brute force")
    if problems:
        sys.exit("plots.py check: " + str(len(problems)) + " problem(s)\n  " + "\n  ".join(problems))
    print(f"plots.py check: {len(speed) + len(error)} records of {len(backends)} backends, every one verified")


def backends(directory):
    names = list(dict.fromkeys(r["backend"] for r in records(f"{directory}/speed/*.json")))
    if not names:
        sys.exit(f"plots.py backends: no speed records under {directory}")
    print(",".join(names))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "scaling":
        scaling(sys.argv[2])
    elif len(sys.argv) == 3 and sys.argv[1] == "all":
        speed_tables(sys.argv[2])
        pareto(sys.argv[2])
        rmse_plot(sys.argv[2])
    elif len(sys.argv) == 3 and sys.argv[1] == "backends":
        backends(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "check":
        check(sys.argv[2], [b for b in sys.argv[3].split(",") if b])
    else:
        sys.exit(__doc__)
