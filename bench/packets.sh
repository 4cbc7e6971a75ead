#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# packets.sh — issue 18's benchmark: the cpu backend's packet traversals (packet-ranged,
# packet-partition: 64-ray packets over MBVH2, the hybrid switch on) beside its best single-ray
# traversals (MBVH4 and MBVH8, stack and ordered stack) and Embree's single-ray and packet
# queries (robust mode; rtcIntersect8/rtcOccluded8 with its coherent flag), in one run per scene
# and query: primary and diffuse rays as closest hit, shadow rays
# toward the point light as any hit; 1 and 2 threads (`--scaling`); on the interior views of the
# conference room, Sibenik and Sponza, the bunny and the Cornell box. The generated rays come in
# 8x8 image tiles (primary) and from the hits of such tiles (shadow, diffuse), as a tiled renderer
# traces them. Every timed result is verified against cpu-scalar first (`mbvh bench`). Writes one
# JSON per scene and query to OUT (default bench/out-packets) and prints bench/packet_table.py's
# Markdown table: Mrays/s, packet / best single-ray, packet / Embree's faster query, SIMD
# utilisation, nodes per ray.
#   bench/packets.sh [--quick] [OUT] [RAYS]
#     (RAYS default 300000: about 3 minutes on 2 cores; --quick: 4096 rays on the Cornell box and
#     the bunny, no warm-up — a smoke test of the script and the table, under 30 s)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
QUICK=0
if [ "${1:-}" = "--quick" ]; then QUICK=1; shift; fi
OUT="${1:-$ROOT/bench/out-packets}"
RAYS="${2:-300000}"
MBVH="${MBVH:-$ROOT/build/mbvh}"
SCENES="$ROOT/../shared/scenes"
mkdir -p "$OUT"
EXTRA=()
LIST="cornell|$SCENES/cornell_box.obj.zst|
bunny|$SCENES/bun_zipper.ply.zst|"
if [ "$QUICK" = 1 ]; then
  RAYS=4096
  EXTRA=(--warmup 0 --passes 5)
else
  # name | scene | camera (interior views of the three buildings; the others framed)
  LIST="$LIST
conference|$SCENES/conference.obj.zst|--camera 0,300,0,1000,200,0
sibenik|$SCENES/sibenik.obj.zst|--camera -14,-9,0,10,-6,0
sponza|$SCENES/sponza_dabrovic.obj.zst|--camera -10,4,0,10,5,0"
fi
COMMON=(--backend cpu,embree --layout mbvh4,mbvh8 --traversal stack,stack-ordered,packet-ranged,packet-partition,packet
        --set embree.coherent=1 --count "$RAYS" --threads 2 --scaling)
while IFS='|' read -r name scene camera; do
  # shellcheck disable=SC2086
  "$MBVH" bench "$scene" "${COMMON[@]}" "${EXTRA[@]}" --query closest --kinds primary,diffuse $camera \
    --json "$OUT/$name-closest.json" >&2
  # shellcheck disable=SC2086
  "$MBVH" bench "$scene" "${COMMON[@]}" "${EXTRA[@]}" --query any --kinds shadow $camera \
    --json "$OUT/$name-any.json" >&2
done <<< "$LIST"
python3 "$ROOT/bench/packet_table.py" "$OUT"/*.json
