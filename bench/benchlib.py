# SPDX-License-Identifier: MIT
"""benchlib.py — what the bench table and plot scripts share (bench/*_table.py, bench/plots.py,
scripts/gpu-summary.py): reading `mbvh bench --json` records, naming scenes, formatting cells.
Standard library only (scripts/gpu-summary.py runs on a GPU machine's own python3); matplotlib
is imported only by pyplot().
"""
import glob
import json
import os
import sys


def load(path):
    with open(path) as f:
        return json.load(f)


def records(paths):
    """Every record of the `mbvh bench --json` files PATHS (a list in its order, or a glob pattern:
    its matches sorted), each with "_file" (the file's name) and "_doc" (the whole document)."""
    if isinstance(paths, str):
        paths = sorted(glob.glob(paths))
    out = []
    for path in paths:
        doc = load(path)
        for r in doc["records"]:
            r["_file"] = os.path.basename(path)
            r["_doc"] = doc
            out.append(r)
    return out


def verified(r):
    """The record's answers matched the reference's in the pass before timing."""
    return r.get("verify_mismatches", 0) == 0


def scene_name(path):
    """bun_zipper for .../scenes/bun_zipper.ply.zst; a generator spec (gen:…) as it is."""
    return os.path.basename(path).split(".")[0]


def fmt(x, digits=2):
    """A table cell: x with DIGITS decimals, "–" where there is no value (None or 0)."""
    return "–" if not x else f"{x:.{digits}f}"


def median(xs):
    """The upper median (the middle element; of the middle two, the larger); 0 when empty."""
    xs = sorted(xs)
    return xs[len(xs) // 2] if xs else 0


def pyplot(who):
    """matplotlib.pyplot on the Agg backend, or None with a message naming WHO and what to install."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"{who}: python3-matplotlib is missing (scripts/setup.sh installs it: apt-get install python3-matplotlib)",
              file=sys.stderr)
        return None
    return plt
