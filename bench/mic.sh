#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# mic.sh — the MIC path (`cpu-avx512 --set cpu.mic=1`: an MBVH4 node's four children tested in 16
# lanes on the Node4W view, Áfra's thesis ch. 4) beside the 8-lane kernels' MBVH4 and MBVH8 (the
# same backend, cpu.mic=0): MBVH4/MBVH8 stack and bitstack, closest hit on diffuse rays and any hit
# on shadow rays, on the bunny and the interior views of the conference room, Sibenik and Sponza,
# 2 threads. A setting is one per `mbvh bench` run, so each scene and query is run with cpu.mic=0
# and cpu.mic=1 back to back, PASSES times alternately (the medians of bench/mic_table.py then
# see the same machine state for both). Every timed result is verified against cpu-scalar first.
# Writes OUT/NAME-QUERY-micM-P.json and prints the Markdown table of bench/mic_table.py.
#   bench/mic.sh [--quick] [OUT] [RAYS] [PASSES]   (defaults: bench/out-mic, 100000, 2)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out-mic" "$@"
RAYS="${ARGS[0]:-100000}"
PASSES="${ARGS[1]:-2}"
read -r -a NAMES <<< "${MIC_SCENES:-bunny conference sibenik sponza}"  # MIC_SCENES: a subset, space-separated
EXTRA=()
if [ "$QUICK" = 1 ]; then
  RAYS=2000
  PASSES=1
  NAMES=(bunny)
  EXTRA=(--warmup 0 --passes 5)
fi
if ! "$MBVH" devices --ready 2>/dev/null | grep -qx cpu-avx512; then
  log "cpu-avx512 does not run here (no AVX-512, or MBVH_CPU_ISA caps it): the MIC path cannot be measured"
  exit 0
fi
LIST="$(scene_rows "$SCENES" "${NAMES[@]}")"
# shellcheck disable=SC2054  # the commas are mbvh's lists
COMMON=(--backend cpu-avx512 --layout mbvh4,mbvh8 --traversal stack,bitstack --count "$RAYS" --threads 2)
while IFS='|' read -r name scene camera; do
  for ((p = 0; p < PASSES; ++p)); do
    for mic in 0 1; do
      log "$name: cpu.mic=$mic, pass $p"
      # shellcheck disable=SC2086  # the camera is words
      "$MBVH" bench "$scene" "${COMMON[@]}" "${EXTRA[@]}" --set cpu.mic=$mic --query closest --kinds diffuse $camera \
        --json "$OUT/$name-closest-mic$mic-$p.json" > "$OUT/$name-closest-mic$mic-$p.txt"
      # shellcheck disable=SC2086
      "$MBVH" bench "$scene" "${COMMON[@]}" "${EXTRA[@]}" --set cpu.mic=$mic --query any --kinds shadow $camera \
        --json "$OUT/$name-any-mic$mic-$p.json" > "$OUT/$name-any-mic$mic-$p.txt"
    done
  done
done <<< "$LIST"
python3 "$ROOT/bench/mic_table.py" "$OUT"/*-mic[01]-*.json
