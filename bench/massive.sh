#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# massive.sh — issue 35's benchmarks of out-of-core models (docs/massive.md "Rendering a model";
# the design's B2 and B5): not run in CI. Three parts, each resumable (a step whose output exists
# is skipped, so the suite can be run in pieces; delete a step's output to run it again):
#
#   big      gen:mandelbulb:1600 (344M triangles, 12.4 GB .mtri) generated, built out of core under
#            `/usr/bin/time -v mbvh lod build --memory 8G`, `mbvh lod info`, then rendered along a
#            60-camera fly-through (fly.txt) at 512x512, path mode with 0 bounces (primary + shadow
#            rays towards a light above the bulb, --light 0.3,3,0.3), 1 spp, LOD quality 1, an 8 GiB budget and a 200 MB/s emulated disk: cold (the
#            page cache dropped where this user may, and O_DIRECT reads in any case), then warm (the
#            path twice in one run: the second lap's frames find their blocks resident).
#   scaling  the thesis' Fig. 7 analogue: 1024x768 primary rays only (`--mode normals` traces one
#            closest-hit batch and nothing else; path mode would add shadow rays) from one fixed
#            camera, on gen:mandelbulb at RES 170, 323, 660, 1302, 1600, chosen with docs/massive.md's
#            refit T(RES) = 116.8M (RES/1024)^2.44 for the issue's 1.4M, 7M, 40M, 210M and 300M+
#            triangles; LOD on (quality 1) at every size, LOD off (full detail) where it ends within
#            OFF_TIMEOUT; frames with synchronous loading until warm, the last frame timed;
#            time(T) / time(7M) for both.
#   incore   on the same rays, in core: `mbvh render gen:mandelbulb:RES` on the cpu backend (its
#            Mrays/s in traversal) against the model at full detail and with LOD, at RES 170 and 660
#            (1.4M and 40M: 1,418,836 and 39,958,560 triangles), and `mbvh bench --kinds primary` from the same camera for reference.
#   summary  OUT/summary.md (tables) and the plots (frames-*.png, scaling.png) from what exists.
#   clean    deletes the big temporary files (DIR/*.mtri, DIR/*.mlod).
#
#   bench/massive.sh [STEP...]     (default: big scaling incore summary clean)
#
# Environment: OUT (default bench/results/massive-DATE), DIR (the big temporary files, default
# bench/out/massive-data; at least 60 GB free counting what it holds already, checked with df),
# MBVH (default build/mbvh), MBVH_MASSIVE_SMALL=1 (tiny sizes that finish in a minute or two: the
# script's own test), KEEP=1 (clean keeps the files), OFF_TIMEOUT (seconds, default 1800),
# OFF_MAX_RES (the largest RES rendered at full detail, default 1304). Run it alone on the machine
# (flock /work/timing.lock bench/massive.sh ...): every time it records is wall-clock.
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
SMALL="${MBVH_MASSIVE_SMALL:-0}"
OUT="${OUT:-$ROOT/bench/results/massive-$(date -u +%F)$([ "$SMALL" = 1 ] && echo -small)}"
DIR="${DIR:-$ROOT/bench/out/massive-data$([ "$SMALL" = 1 ] && echo -small)}"
OFF_TIMEOUT="${OFF_TIMEOUT:-1800}"
# the camera frame_scene picks for gen:mandelbulb (at RES 64; the field's box hardly moves with RES):
# the same relative view at every size
CAMERA="1.4221017,1.0685791,3.178976,0,-0.037500024,0.018750012,60"
if [ "$SMALL" = 1 ]; then
  BIG_RES=128 BIG_MEMORY=16M BUILD_MEMORY=256M FRAMES=12 BIG_SIZE=128 BANDWIDTH=200000000
  SCALING_RES="48 64 96 128" SEVEN_M=64 W=256 H=192 INCORE_RES="64 128" OFF_MAX_RES="${OFF_MAX_RES:-128}"
  MEMORY=64M OFF_MEMORY=256M NEED_GB=1
else
  BIG_RES=1600 BIG_MEMORY=8G BUILD_MEMORY=8G FRAMES=60 BIG_SIZE=512 BANDWIDTH=200000000
  SCALING_RES="170 323 660 1302 1600" SEVEN_M=323 W=1024 H=768 INCORE_RES="170 660" OFF_MAX_RES="${OFF_MAX_RES:-1302}"
  MEMORY=8G OFF_MEMORY=12G NEED_GB=60
fi
STEPS=("$@")
[ ${#STEPS[@]} -gt 0 ] || STEPS=(big scaling incore summary clean)
for s in "${STEPS[@]}"; do
  case "$s" in big | scaling | incore | summary | clean) ;; *) echo "massive.sh: unknown step '$s' (big, scaling, incore, summary, clean)" >&2; exit 2 ;; esac
done
mkdir -p "$OUT" "$DIR"
[ -x "$MBVH" ] || { echo "massive.sh: $MBVH is not built (cmake --build build --target mbvh-cli)" >&2; exit 2; }

# -- the disk: refuse to start what may fill it (the files DIR holds already count as free)
check_disk() {
  local avail held
  avail=$(df -P -k "$DIR" | awk 'NR == 2 {print $4}')
  held=$(du -s -k "$DIR" | awk '{print $1}')
  if [ $(((avail + held) / 1000000)) -lt "$NEED_GB" ]; then
    echo "massive.sh: $DIR has $((avail / 1000000)) GB free (+ $((held / 1000000)) GB of its files), under the $NEED_GB GB the runs need" >&2
    exit 2
  fi
}

{
  echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "commit: $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet -- host bench || echo ' (tree modified)')"
  echo "steps: ${STEPS[*]}; small: $SMALL; load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo "disk: $(df -P -h "$DIR" | awk 'NR == 2 {print $4 " free on " $6}')"
} >>"$OUT/run.txt"
[ -f "$OUT/lscpu.txt" ] || { lscpu >"$OUT/lscpu.txt"; free -g >>"$OUT/lscpu.txt"; }

# run OUTPUT LOG CMD...: skip when OUTPUT exists; else CMD (its standard error and output to LOG)
run() {
  local output="$1" logf="$2"
  shift 2
  if [ -e "$output" ]; then log "skip (exists): $output"; return 0; fi
  log "$*"
  echo "\$ $*" >"$logf"
  "$@" >>"$logf" 2>&1 || { echo "massive.sh: failed (see $logf): $*" >&2; tail -5 "$logf" >&2; return 1; }
}

# model RES: DIR/mbRES.mtri and DIR/mbRES.mlod (generated and built unless they exist)
model() {
  local res="$1"
  check_disk
  run "$DIR/mb$res.mtri" "$OUT/gen-$res.log" /usr/bin/time -v "$MBVH" gen "gen:mandelbulb:$res" -o "$DIR/mb$res.mtri"
  run "$DIR/mb$res.mlod" "$OUT/build-$res.log" /usr/bin/time -v "$MBVH" lod build "$DIR/mb$res.mtri" -o "$DIR/mb$res.mlod" --memory "$BUILD_MEMORY"
  run "$OUT/info-$res.txt" "$OUT/info-$res.log" sh -c "\"$MBVH\" lod info \"$DIR/mb$res.mlod\" > \"$OUT/info-$res.txt.tmp\" && mv \"$OUT/info-$res.txt.tmp\" \"$OUT/info-$res.txt\""
}

# drop_cache: the page cache dropped where this user may (reads are O_DIRECT in any case)
drop_cache() {
  if [ "$SMALL" != 1 ] && [ -w /proc/sys/vm/drop_caches ]; then
    sync && echo 3 >/proc/sys/vm/drop_caches && echo "page cache dropped" && return
  fi
  echo "page cache not dropped ($([ "$SMALL" = 1 ] && echo "small run" || echo "not allowed")): the model's reads bypass it (O_DIRECT)"
}

step_big() {
  model "$BIG_RES"
  # the fly-through: a half orbit spiralling in from 3.6 to 1.7 (the bulb's radius is about 1.1),
  # descending from 1.1 to 0.5 above the centre, looking at the centre
  [ -f "$OUT/fly.txt" ] || /usr/bin/python3 - "$FRAMES" >"$OUT/fly.txt" <<'EOF'
import math, sys
n = int(sys.argv[1])
print("# bench/massive.sh: a fly-through of gen:mandelbulb, one camera a line (ex,ey,ez,tx,ty,tz,fov)")
a0 = math.atan2(1.4221017, 3.178976)
for k in range(n):
    s = k / (n - 1)
    a, r, y = a0 + math.pi * s, 3.6 - 1.9 * s, 1.1 - 0.6 * s
    print(f"{r * math.sin(a):.6f},{y:.6f},{r * math.cos(a):.6f},0,0,0,60")
EOF
  # the light above the bulb: render's default light (near the top of the box, centred) lies
  # inside the Mandelbulb, where every shadow ray ends at once and the image is black
  local common=("$MBVH" render "$DIR/mb$BIG_RES.mlod" --lod --memory "$BIG_MEMORY" --camera-path "$OUT/fly.txt" --light 0.3,3,0.3
    --lod-io-bandwidth "$BANDWIDTH" --width "$BIG_SIZE" --height "$BIG_SIZE" --mode path --bounces 0 --spp 1)
  if [ ! -e "$OUT/big-cold.json" ]; then drop_cache >>"$OUT/run.txt"; fi
  run "$OUT/big-cold.json" "$OUT/big-cold.log" /usr/bin/time -v "${common[@]}" --frames "$FRAMES" \
    --stats-json "$OUT/big-cold.json" -o "$OUT/big-cold.png"
  run "$OUT/big-warm.json" "$OUT/big-warm.log" /usr/bin/time -v "${common[@]}" --frames $((2 * FRAMES)) \
    --stats-json "$OUT/big-warm.json" -o "$OUT/big-warm.png"
}

step_scaling() {
  local res
  for res in $SCALING_RES; do
    model "$res"
    # LOD on: synchronous loading, 3 frames of the one view (the first loads, the last is timed)
    run "$OUT/scaling-$res-on.json" "$OUT/scaling-$res-on.log" "$MBVH" render "$DIR/mb$res.mlod" --lod --lod-sync \
      --memory "$MEMORY" --camera "$CAMERA" --frames 3 --width "$W" --height "$H" --mode normals --spp 1 \
      --stats-json "$OUT/scaling-$res-on.json" -o "$OUT/scaling-$res-on.png"
    if [ "$res" -le "$OFF_MAX_RES" ] && [ ! -e "$OUT/scaling-$res-off.timeout" ]; then
      if ! run "$OUT/scaling-$res-off.json" "$OUT/scaling-$res-off.log" timeout "$OFF_TIMEOUT" "$MBVH" render \
        "$DIR/mb$res.mlod" --lod off --memory "$OFF_MEMORY" --camera "$CAMERA" --frames 2 --width "$W" --height "$H" \
        --mode normals --spp 1 --stats-json "$OUT/scaling-$res-off.json" -o "$OUT/scaling-$res-off.png"; then
        echo "full detail at RES $res: did not finish in $OFF_TIMEOUT s (or failed: $OUT/scaling-$res-off.log)" \
          >"$OUT/scaling-$res-off.timeout"
      fi
    fi
  done
}

step_incore() {
  local res
  for res in $INCORE_RES; do
    model "$res"
    run "$OUT/incore-$res-render.log.done" "$OUT/incore-$res-render.log" sh -c "\"$MBVH\" render gen:mandelbulb:$res \
      --camera $CAMERA --width $W --height $H --mode normals --spp 1 -o \"$OUT/incore-$res.png\" && touch \"$OUT/incore-$res-render.log.done\""
    run "$OUT/incore-$res-bench.json" "$OUT/incore-$res-bench.log" "$MBVH" bench "gen:mandelbulb:$res" --backend cpu \
      --kinds primary --camera "$CAMERA" --count $((W * H)) --query closest --json "$OUT/incore-$res-bench.json"
    # the model on the same rays as the in-core render: full detail (2 frames, the last warm) and LOD
    [ -e "$OUT/scaling-$res-off.json" ] || run "$OUT/incore-$res-off.json" "$OUT/incore-$res-off.log" "$MBVH" render \
      "$DIR/mb$res.mlod" --lod off --memory "$OFF_MEMORY" --camera "$CAMERA" --frames 2 --width "$W" --height "$H" \
      --mode normals --spp 1 --stats-json "$OUT/incore-$res-off.json" -o "$OUT/incore-$res-off.png"
    [ -e "$OUT/scaling-$res-on.json" ] || run "$OUT/incore-$res-on.json" "$OUT/incore-$res-on.log" "$MBVH" render \
      "$DIR/mb$res.mlod" --lod --lod-sync --memory "$MEMORY" --camera "$CAMERA" --frames 3 --width "$W" --height "$H" \
      --mode normals --spp 1 --stats-json "$OUT/incore-$res-on.json" -o "$OUT/incore-$res-on.png"
  done
}

step_summary() {
  use_matplotlib
  local f
  for f in "$OUT"/big-cold.json "$OUT"/big-warm.json; do
    [ -e "$f" ] && "$PY" "$ROOT/bench/plot_frames.py" "$f" "${f%.json}-frames.png" >&2
  done
  "$PY" - "$OUT" "$SEVEN_M" "$SCALING_RES" "$INCORE_RES" "$BIG_RES" >"$OUT/summary.md" <<'EOF'
import glob, json, os, re, statistics, sys
out, seven, scaling, incore, big = sys.argv[1], int(sys.argv[2]), sys.argv[3].split(), sys.argv[4].split(), sys.argv[5]
def load(p):
    return json.load(open(p)) if os.path.exists(p) else None
def text(p):
    return open(p).read() if os.path.exists(p) else ""
def time_v(p):
    t = text(p)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", t)
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", t)
    secs = None
    if wall:
        parts = [float(x) for x in wall.group(1).split(":")]
        secs = sum(x * 60 ** i for i, x in enumerate(reversed(parts)))
    return (int(rss.group(1)) * 1024 if rss else None), secs
gib = lambda b: f"{b / 2**30:.2f} GiB" if b is not None else "-"
def last(j):  # the last (warm) frame
    return j["frames"][-1]
def mrays(f):
    return f["rays"] / f["trace_seconds"] / 1e6 if f["trace_seconds"] > 0 else float("nan")
print("# bench/massive.sh: out-of-core Mandelbulb models (issue 35)\n")
print("```\n" + text(os.path.join(out, "run.txt")).strip() + "\n```\n")
print("## The big run\n")
bm = os.path.join(out, f"build-{big}.log")
rss, secs = time_v(bm)
print(f"- build (`mbvh lod build --memory`): {secs if secs is not None else '-'} s, peak RSS {gib(rss)}")
info = text(os.path.join(out, f"info-{big}.txt")).strip()
if info:
    print("\n```\n" + info + "\n```\n")
for name in ("cold", "warm"):
    j = load(os.path.join(out, f"big-{name}.json"))
    if not j:
        continue
    s = [f["seconds"] for f in j["frames"]]
    rss, _ = time_v(os.path.join(out, f"big-{name}.log"))
    n = len(s)
    med = statistics.median(s)
    lap2 = statistics.median(s[n // 2:]) if name == "warm" else None
    print(f"- {name}: {n} frames of {j['width']}x{j['height']}, {j['mode']} {j['bounces']} bounces, "
          f"LOD {'q=%g' % j['quality'] if j['lod'] else 'off'}, budget {gib(j['budget'])}, "
          f"{j['io_bandwidth'] / 1e6:.0f} MB/s: first frame {s[0]:.3f} s, median {med:.3f} s ({1 / med:.2f} fps), "
          f"max {max(s):.3f} s = {max(s) / med:.2f} x the median, frames > 2x the median: {sum(x > 2 * med for x in s)}"
          + (f"; second lap (warm) median {lap2:.3f} s = {1 / lap2:.2f} fps" if lap2 else "")
          + f"; peak blocks {gib(j['summary']['peak_bytes'])}, VmHWM {gib(j['summary']['vmhwm'])}, peak RSS {gib(rss)}, "
          f"{j['summary']['loads']} loads, {j['summary']['evictions']} evictions")
anyj = next((load(os.path.join(out, f"scaling-{r}-on.json")) for r in scaling if os.path.exists(os.path.join(out, f"scaling-{r}-on.json"))), None)
size = f"{anyj['width']}x{anyj['height']}" if anyj else "-"
print(f"\n## Scaling ({size} primary rays, `--mode normals`, the last of the synchronous frames)\n")
print("| RES | triangles | LOD on s | on / on(7M) | LOD on Mrays/s | LOD off s | off / off(7M) | LOD off Mrays/s |")
print("|---|---|---|---|---|---|---|---|")
rows = []
for res in scaling:
    on, off = load(os.path.join(out, f"scaling-{res}-on.json")), load(os.path.join(out, f"scaling-{res}-off.json"))
    if not on and not off:
        continue
    tris = (on or off)["triangles"]
    ton = last(on)["trace_seconds"] if on else None
    toff = last(off)["trace_seconds"] if off else None
    rows.append((int(res), tris, ton, toff, on, off))
base_on = next((r[2] for r in rows if r[0] == seven), None)
base_off = next((r[3] for r in rows if r[0] == seven), None)
f = lambda x, d=3: f"{x:.{d}f}" if x is not None else "-"
for res, tris, ton, toff, on, off in rows:
    timeout = os.path.exists(os.path.join(out, f"scaling-{res}-off.timeout"))
    print(f"| {res} | {tris:,} | {f(ton)} | {f(ton / base_on if ton and base_on else None, 2)} | "
          f"{f(mrays(last(on)) if on else None, 2)} | {f(toff) if not timeout else 'timeout'} | "
          f"{f(toff / base_off if toff and base_off else None, 2)} | {f(mrays(last(off)) if off else None, 2)} |")
try:
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for idx, label in ((2, "LOD on (q=1)"), (3, "LOD off")):
        pts = [(r[1], r[idx] / (base_on if idx == 2 else base_off)) for r in rows if r[idx] and (base_on if idx == 2 else base_off)]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=label)
    ax.set_xscale("log")
    ax.set_xlabel("triangles")
    ax.set_ylabel("trace time / time at ~7M")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title("gen:mandelbulb, 1024x768 primary rays")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "scaling.png"), dpi=110)
    print("\n![scaling](scaling.png)")
except Exception as e:  # the tables are the result; the plot is a view of them
    print(f"\n(no plot: {e})")
print(f"\n## In core, the same rays ({size} primary rays from the same camera)\n")
print("| RES | triangles | cpu backend (render) Mrays/s | `mbvh bench` cpu primary Mrays/s | model LOD off Mrays/s | off / cpu | model LOD on Mrays/s | on / off |")
print("|---|---|---|---|---|---|---|---|")
for res in incore:
    r = re.search(r"([\d.]+) Mrays/s in traversal", text(os.path.join(out, f"incore-{res}-render.log")))
    cpu = float(r.group(1)) if r else None
    b = load(os.path.join(out, f"incore-{res}-bench.json"))
    bench = None
    if b:
        recs = b if isinstance(b, list) else b.get("records", b.get("results", []))
        vals = [x.get("mrays_per_s") for x in recs if isinstance(x, dict) and x.get("mrays_per_s")]
        bench = max(vals) if vals else None
    off = load(os.path.join(out, f"scaling-{res}-off.json")) or load(os.path.join(out, f"incore-{res}-off.json"))
    on = load(os.path.join(out, f"scaling-{res}-on.json")) or load(os.path.join(out, f"incore-{res}-on.json"))
    moff = mrays(last(off)) if off else None
    mon = mrays(last(on)) if on else None
    tris = (on or off or {}).get("triangles")
    print(f"| {res} | {tris:,} | {f(cpu, 2)} | {f(bench, 2)} | {f(moff, 2)} | {f(moff / cpu if moff and cpu else None, 2)} | "
          f"{f(mon, 2)} | {f(mon / moff if mon and moff else None, 2)} |" if tris else f"| {res} | - | {f(cpu, 2)} | {f(bench, 2)} | - | - | - | - |")
EOF
  cat "$OUT/summary.md" >&2
}

step_clean() {
  if [ "${KEEP:-0}" = 1 ]; then log "KEEP=1: $DIR kept"; return; fi
  log "deleting the temporary models in $DIR"
  rm -f "$DIR"/mb*.mtri "$DIR"/mb*.mlod
  rmdir "$DIR" 2>/dev/null || true
}

for s in "${STEPS[@]}"; do "step_$s"; done
echo "load at end: $(cut -d' ' -f1-3 /proc/loadavg)" >>"$OUT/run.txt"
log "done: $OUT"
