#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# packets.sh — the cpu backend's packet traversals (packet-ranged, packet-partition: packets over
# MBVH2 of 64 rays in 8-lane SIMD rays, AVX2, or 128 in 16-lane ones, AVX-512; the hybrid switch
# on) beside its best single-ray traversals (MBVH4 and MBVH8, stack and ordered stack) and
# Embree's single-ray and packet queries (robust mode; rtcIntersect16/rtcOccluded16, its fastest, with its
# coherent flag), in one run per scene and query: primary and
# diffuse rays as closest hit, shadow rays toward the point light as any hit; 1 and 2 threads
# (`--scaling`); on the interior views of the conference room, Sibenik and Sponza, the bunny and
# the Cornell box. The generated rays come in 8x8 image tiles (primary) and from the hits of such
# tiles (shadow, diffuse), as a tiled renderer traces them. Every timed result is verified
# against cpu-scalar first (`mbvh bench`). Writes one JSON per scene and query to OUT (default
# bench/out-packets) and prints bench/packet_table.py's Markdown table (on an AVX-512 machine
# cpu-avx2 runs too, and a second table sets `cpu` against it): Mrays/s, packet / best
# single-ray, packet / Embree's faster query, SIMD utilisation, nodes per ray.
#   bench/packets.sh [--quick] [OUT] [RAYS]
#     (RAYS default 300000: about 3 minutes on 2 cores; --quick: 4096 rays on the Cornell box and
#     the bunny, no warm-up — a smoke test of the script and the table, under 30 s)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out-packets" "$@"
RAYS="${ARGS[0]:-300000}"
EXTRA=()
NAMES=(cornell bunny)
if [ "$QUICK" = 1 ]; then
  RAYS=4096
  EXTRA=(--warmup 0 --passes 5)
else
  NAMES+=(conference sibenik sponza)
fi
LIST="$(scene_rows "$SCENES" "${NAMES[@]}")"
# an AVX-512 machine: cpu-avx2 beside `cpu` (AVX-512, the per-kind choice of simd_backend.cpp's
# kIsaTable), packet_table.py's second table
BACKENDS=cpu,embree
if "$MBVH" devices 2>/dev/null | grep '^cpu-avx512 *ready' >/dev/null; then BACKENDS=cpu,cpu-avx2,embree; fi
# shellcheck disable=SC2054  # the commas are mbvh's lists
COMMON=(--backend "$BACKENDS" --layout mbvh4,mbvh8 --traversal stack,stack-ordered,packet-ranged,packet-partition,packet
        --set embree.coherent=1 --set embree.packet=16 --count "$RAYS" --threads 2 --scaling)
while IFS='|' read -r name scene camera; do
  run_queries "$name" "$scene" "$camera" "${COMMON[@]}" "${EXTRA[@]}"
done <<< "$LIST"
python3 "$ROOT/bench/packet_table.py" "$OUT"/*.json
