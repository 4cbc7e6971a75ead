#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""plot_frames.py — frame time and resident memory over a camera path, from the JSON of
`mbvh render MODEL.mlod --frames N --stats-json F`.

    python3 bench/plot_frames.py STATS.json [OUT.png] [--title TEXT]

OUT.png (default: STATS-frames.png beside the JSON) has two panels sharing the frame axis: the frame
time (ms; the median and 2x the median dashed, the stutter bound of issue 35) and the bytes held
(the cache's resident and peak bytes, the budget, and the process' VmHWM, in MiB). A line of
summary (first frame, median, max/median, fps) goes to standard output.
"""
import json
import os
import sys


def main(argv):
    args = [a for a in argv if not a.startswith("--")]
    title = None
    if "--title" in argv:
        i = argv.index("--title")
        if i + 1 >= len(argv):
            sys.exit("plot_frames.py: --title needs a text")
        title = argv[i + 1]
        args = [a for a in args if a != title]
    if not args:
        sys.exit(__doc__)
    src = args[0]
    out = args[1] if len(args) > 1 else os.path.splitext(src)[0] + "-frames.png"
    with open(src) as f:
        j = json.load(f)
    frames = j.get("frames")
    if not frames:
        sys.exit(f"plot_frames.py: {src} has no frames (not `mbvh render --stats-json` output?)")
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    k = [f["frame"] for f in frames]
    ms = [1e3 * f["seconds"] for f in frames]
    mib = lambda b: b / 2**20
    s = sorted(ms)
    med = s[len(s) // 2] if len(s) % 2 else 0.5 * (s[len(s) // 2 - 1] + s[len(s) // 2])
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(8, 6))
    a1.plot(k, ms, marker=".", label="frame time")
    a1.axhline(med, color="grey", linestyle="--", linewidth=1, label=f"median {med:.1f} ms")
    a1.axhline(2 * med, color="red", linestyle=":", linewidth=1, label="2 x median")
    a1.set_ylabel("ms")
    a1.set_ylim(bottom=0)
    a1.grid(True, alpha=0.3)
    a1.legend(loc="upper right", fontsize="small")
    a2.plot(k, [mib(f["resident_bytes"]) for f in frames], label="resident blocks")
    a2.plot(k, [mib(f["peak_bytes"]) for f in frames], linestyle="--", label="peak blocks")
    vm = [mib(f["vmhwm"]) if f.get("vmhwm", -1) >= 0 else float("nan") for f in frames]
    a2.plot(k, vm, linestyle=":", label="VmHWM (process)")
    if j.get("budget"):
        a2.axhline(mib(j["budget"]), color="red", linewidth=1, label=f'budget {mib(j["budget"]):.0f} MiB')
    a2.set_ylabel("MiB")
    a2.set_xlabel("frame")
    a2.set_ylim(bottom=0)
    a2.grid(True, alpha=0.3)
    a2.legend(loc="lower right", fontsize="small")
    name = title or (f'{os.path.basename(j.get("model", src))}: {j.get("triangles", 0) / 1e6:.1f}M triangles, '
                     f'{j.get("width")}x{j.get("height")}, {"LOD q=%g" % j["quality"] if j.get("lod") else "full detail"}')
    fig.suptitle(name)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"{src}: {len(ms)} frames, first {ms[0]:.1f} ms, median {med:.1f} ms ({1e3 / med if med else 0:.2f} fps), "
          f"max {max(ms):.1f} ms ({max(ms) / med if med else 0:.2f} x the median); wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1:])
