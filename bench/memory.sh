#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# memory.sh — resident memory of mbvh's build beside Embree's on the same scene: build/mbvh-memory-
# bench (bench/memory.cpp) for each peer in a process of its own, REPEATS times with the peers
# alternating, and the medians: peak RSS after build (VmHWM above the RSS with the scene and rays
# loaded), RSS held after build and after tracing, and mbvh / Embree. Peers: mbvh (Accel::build
# and the cpu backend's batch traces with TraceOptions{}), mbvh-query (the same build, the
# single-ray RayQuery defaults) and embree (robust, build quality medium, on the scene's own
# arrays). Scenes: the 100K-triangle hairball and conference. Records lscpu and the commit in OUT.
#   bench/memory.sh [OUT] [REPEATS] [RAYS]   (default bench/out-memory, 5, 100000; BUILD=build)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
BUILD="${BUILD:-$ROOT/build}"
OUT="${1:-$ROOT/bench/out-memory}"
REPEATS="${2:-5}"
RAYS="${3:-100000}"
PEERS=(mbvh mbvh-query embree)
mkdir -p "$OUT"
{
  echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "commit: $(git -C "$ROOT" rev-parse --short HEAD)$(git -C "$ROOT" diff --quiet -- host bench || echo ' (tree modified)')"
  echo "load at start: $(cut -d' ' -f1-3 /proc/loadavg)"
  echo "repeats: $REPEATS, rays: $RAYS"
} >"$OUT/run.txt"
lscpu >"$OUT/lscpu.txt"
: >"$OUT/samples.jsonl"
LIST="$(scene_rows "$SCENES" hairball100k conference)"
while IFS='|' read -r name scene _; do
  for ((i = 0; i < REPEATS; i++)); do
    for peer in "${PEERS[@]}"; do
      log "$name: $peer ($((i + 1))/$REPEATS)"
      "$BUILD/mbvh-memory-bench" "$peer" "$scene" "$RAYS" | sed "s/^{/{\"name\": \"$name\", /" >>"$OUT/samples.jsonl"
    done
  done
done <<<"$LIST"
/usr/bin/python3 - "$OUT/samples.jsonl" <<'EOF' | tee "$OUT/memory.md"
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
mb = lambda b: b / 1e6
med = lambda name, peer, key: statistics.median(r[key] for r in rows if r["name"] == name and r["peer"] == peer)
print("| scene | triangles | peer | peak after build MB | B/tri | held after build MB | held after trace MB | peak / Embree's | held / Embree's | Accel::memory MB |")
print("|---|---|---|---|---|---|---|---|---|---|")
for name in dict.fromkeys(r["name"] for r in rows):
    tris = next(r["triangles"] for r in rows if r["name"] == name)
    for peer in dict.fromkeys(r["peer"] for r in rows):
        peak, held, trace = (med(name, peer, k) for k in ("build_peak", "build_held", "trace_held"))
        acc = [r["accel"]["total"] for r in rows if r["name"] == name and r["peer"] == peer and "accel" in r]
        print(f"| {name} | {tris} | {peer} | {mb(peak):.2f} | {peak / tris:.1f} | {mb(held):.2f} | {mb(trace):.2f} | "
              f"{peak / med(name, 'embree', 'build_peak'):.2f} | {held / med(name, 'embree', 'build_held'):.2f} | "
              f"{mb(statistics.median(acc)) if acc else float('nan'):.2f} |")
EOF
echo "load at end: $(cut -d' ' -f1-3 /proc/loadavg)" >>"$OUT/run.txt"
