#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""gpu-summary.py — scripts/gpu-run's report: merges the per-step JSON of `mbvh check` and
`mbvh bench` into OUT/check.json and OUT/bench.json and writes OUT/summary.md: the devices and
drivers, each step's status, the check's genuine mismatches per scene, and the Mrays/s (end to
end, and by the device's clock where the backend measures it) of every backend x layout x
traversal x query x ray kind (a requested layout a backend has no record of, in a bench step that
passed, is "not supported").

  gpu-summary.py --parts DIR --out DIR --backends LIST --layouts LIST --traversals LIST
  gpu-summary.py verify OUT --backends LIST --layouts LIST --traversals LIST
      the CI check of a finished run: every step passed, every check found zero genuine
      mismatches, every requested backend has records in every bench step, all verified, and
      every requested backend x layout is either measured or "not supported" (exit 1 otherwise)

Standard library only (it runs on the GPU machine's own python3), with bench/benchlib.py.
"""
import argparse
import glob
import json
import os
import re
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bench"))
from benchlib import load  # noqa: E402  (bench/ is on the path from here)


def steps(parts):
    """[(name, status, seconds)] in run order; status: an exit code as text, or 'skipped'."""
    out = []
    path = os.path.join(parts, "steps")
    if os.path.exists(path):
        for line in open(path):
            name, status, secs = line.rstrip("\n").split("|")
            out.append((name, status, int(secs)))
    return out


def merge(parts, out):
    """Writes check.json and bench.json: {"runs": [{"step": ..., **that step's JSON}]}, in run order."""
    merged = {}
    order = [n for n, _, _ in steps(parts)]
    for what in ("check", "bench"):
        runs = []
        found = glob.glob(os.path.join(parts, what + "-*.json"))
        key = lambda p: order.index(os.path.basename(p)[:-5]) if os.path.basename(p)[:-5] in order else len(order)
        for path in sorted(found, key=key):
            step = os.path.basename(path)[: -len(".json")]
            try:
                runs.append(dict(step=step, **load(path)))
            except (ValueError, OSError) as e:
                runs.append({"step": step, "error": "unreadable: %s" % e})
        merged[what] = runs
        with open(os.path.join(out, what + ".json"), "w") as f:
            json.dump({"runs": runs}, f, indent=1)
            f.write("\n")
    return merged


def device_lines(out):
    """The device lines of devices.txt (OpenCL and Vulkan devices, `[default]` marked)."""
    path = os.path.join(out, "devices.txt")
    if not os.path.exists(path):
        return []
    lines = [l.strip() for l in open(path) if re.match(r"\s+device ", l) or "cannot start" in l or "not built" in l]
    return list(dict.fromkeys(lines))  # opencl-wide and opencl-lane list the same devices


def setup_facts(out):
    path = os.path.join(out, "setup.txt")
    if not os.path.exists(path):
        return []
    return [l.rstrip() for l in open(path) if l.startswith(("mode:", "found:", "nvidia-smi:", "machine:", "warning"))]


def scene_file(path):
    """bun_zipper.ply.zst for .../scenes/bun_zipper.ply.zst; a generator spec as it is."""
    return os.path.basename(path)


def run_backends(step, backends):
    """The backends a step ran: the one its name ends with (check-SCENE-B, a bench retried per
    backend: bench-SCENE-QUERY-B), else all of them."""
    mine = [b for b in backends if step.endswith("-" + b)]
    return mine or backends


def bench_cells(runs, backends, layouts, traversals, step_status):
    """Rows of the speed table: one per record, one "not supported" row per backend x layout a
    passed step has no record of, one "cannot start" row per backend `mbvh devices` found unready."""
    rows = []
    for run in runs:
        if "records" not in run:
            continue
        recs = run["records"]
        status = step_status.get(run["step"], "?")
        scene = scene_file(recs[0]["scene"]) if recs else run["step"]
        for b in backends:
            if step_status.get("start-" + b, "0") != "0":
                rows.append((scene, b, "", "", "", "", "cannot start (devices.txt)", "", "", "", "", ""))
                continue
            if b not in run_backends(run["step"], backends):
                continue
            for l in layouts:
                mine = [r for r in recs if r["backend"] == b and r["layout"] == l]
                if not mine:
                    rows.append((scene, b, l, "", "", "", "not supported" if status == "0" else "not run (step failed)",
                                 "", "", "", "", ""))
                    continue
                kinds = ["primary", "diffuse", "shadow"]
                for r in sorted(mine, key=lambda r: (traversals.index(r["traversal"]) if r["traversal"] in traversals
                                                     else 99, r["query"], kinds.index(r["ray_kind"])
                                                     if r["ray_kind"] in kinds else 99)):
                    rows.append((scene, b, l, r["traversal"], r["query"], r["ray_kind"], "%.2f" % r["mrays_per_s"],
                                 "%.2f–%.2f" % (r["mrays_per_s_min"], r["mrays_per_s_max"]),
                                 "%.2f" % r["device_mrays_per_s"] if r.get("device_mrays_per_s") else "",
                                 "%.2f" % r["bitstack_vs_stack"] if r["bitstack_vs_stack"] else "",
                                 "%.2f" % r["vs_cpu"] if r["vs_cpu"] else "",
                                 "yes" if r["verified"] else "NO (%d mismatches)" % r["verify_mismatches"]))
    return rows


def summary(args):
    merged = merge(args.parts, args.out)
    st = steps(args.parts)
    status = {n: s for n, s, _ in st}
    backends, layouts, traversals = args.backends.split(","), args.layouts.split(","), args.traversals.split(",")
    md = ["# mbvh gpu-run", ""]
    md += ["## Machine and devices", ""]
    md += ["- " + l for l in setup_facts(args.out)]
    md += ["- " + l for l in device_lines(args.out)]
    devs = {}
    for run in merged["bench"]:
        for r in run.get("records", []):
            devs.setdefault(r["backend"], r["device"])
    md += ["- bench `%s`: %s" % (b, d) for b, d in sorted(devs.items())]
    md += ["", "## Steps", "", "| step | status | seconds |", "|---|---|---|"]
    md += ["| %s | %s | %d |" % (n, "passed" if s == "0" else "skipped (time budget)" if s == "skipped" else
                                 "stopped at the time budget" if s in ("124", "137") else
                                 "FAILED (exit %s)" % s if s.isdigit() else "FAILED (%s)" % s, t)
           for n, s, t in st]
    md += ["", "## Check: genuine mismatches against the first `cpu` variant and the brute force", "",
           "| scene | backend | ray kind | rays | variants | comparisons | genuine mismatches | bit-identical to the reference |",
           "|---|---|---|---|---|---|---|---|"]
    for run in merged["check"]:
        for k in run.get("kinds", []):
            variants = sorted({c["a"] for c in k["comparisons"]})
            ref = [c for c in k["comparisons"] if "brute" not in c["b"] and "occluded" not in c["b"]]
            exact = sum(1 for c in ref if c["bit_identical"] == c["rays"])
            md.append("| %s | %s | %s | %d | %d | %d | %d | %d of %d |" % (
                scene_file(run["scene"]), ",".join(run_backends(run["step"], backends)), k["kind"], k["rays"],
                len(variants), len(k["comparisons"]), k["mismatches"], exact, len(ref)))
    md += ["", "## Bench: Mrays/s (median of the timed passes), verified before timing", "",
           "Mrays/s: end to end (`trace()`: ray upload, dispatch, hit download); device Mrays/s: by the device's "
           "clock, the trace kernels alone (blank: not measured).", "",
           "| scene | backend | layout | traversal | query | ray kind | Mrays/s | min–max | device Mrays/s | bitstack / stack "
           "| / cpu | verified |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    md += ["| " + " | ".join(r) + " |" for r in bench_cells(merged["bench"], backends, layouts, traversals, status)]
    md.append("")
    with open(os.path.join(args.out, "summary.md"), "w") as f:
        f.write("\n".join(md))


def verify(args):
    """Exit status 1 with the reasons when the finished run in args.out is not complete and clean."""
    problems = []
    check, bench = load(os.path.join(args.out, "check.json"))["runs"], load(os.path.join(args.out, "bench.json"))["runs"]
    text = open(os.path.join(args.out, "summary.md")).read()
    backends, layouts = args.backends.split(","), args.layouts.split(",")
    for n, s in re.findall(r"^\| ([\w-]+) \| ([^|]+) \| \d+ \|$", text, re.M):
        if s.strip() != "passed":
            problems.append("step %s: %s" % (n, s.strip()))
    if not check:
        problems.append("no check ran")
    checked = {}  # scene -> backends checked
    for run in check:
        if "kinds" not in run:
            problems.append("%s: %s" % (run["step"], run.get("error", "no result")))
            continue
        for k in run["kinds"]:
            if k["mismatches"]:
                problems.append("%s %s: %d genuine mismatches" % (run["step"], k["kind"], k["mismatches"]))
            checked.setdefault(run["scene"], set()).update(c["a"].split("/")[0] for c in k["comparisons"])
    for scene, ran in checked.items():
        problems += ["check %s: backend %s was not checked" % (scene_file(scene), b) for b in backends if b not in ran]
    if not bench:
        problems.append("no bench ran")
    for run in bench:
        recs = run.get("records", [])
        for b in run_backends(run["step"], backends):
            if not any(r["backend"] == b for r in recs):
                problems.append("%s: no record of backend %s" % (run["step"], b))
        problems += ["%s: %s/%s/%s/%s/%s not verified" % (run["step"], r["backend"], r["layout"], r["traversal"],
                                                           r["query"], r["ray_kind"]) for r in recs if not r["verified"]]
    for b in backends:
        for l in layouts:
            if not re.search(r"^\| [^|]+ \| %s \| %s \| " % (re.escape(b), l), text, re.M):
                problems.append("summary.md: no row for %s/%s" % (b, l))
    files = os.listdir(args.out)
    if len(files) > 8 or any(os.path.isdir(os.path.join(args.out, f)) for f in files):
        problems.append("the output directory holds more than 8 files or a folder: %s" % files)
    for p in problems:
        print("gpu-run verify: " + p, file=sys.stderr)
    print("gpu-run verify: %s (%d check runs, %d bench runs, %d records)" %
          ("FAILED" if problems else "ok", len(check), len(bench), sum(len(r.get("records", [])) for r in bench)))
    return 1 if problems else 0


def main():
    argv = sys.argv[1:]
    mode = "summary"
    if argv and argv[0] == "verify":
        mode, argv = "verify", argv[1:]
    ap = argparse.ArgumentParser(prog="gpu-summary.py")
    if mode == "verify":
        ap.add_argument("out")
    else:
        ap.add_argument("--parts", required=True)
        ap.add_argument("--out", required=True)
    ap.add_argument("--backends", required=True)
    ap.add_argument("--layouts", required=True)
    ap.add_argument("--traversals", required=True)
    args = ap.parse_args(argv)
    if mode == "verify":
        return verify(args)
    summary(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
