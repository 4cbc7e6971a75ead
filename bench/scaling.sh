#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# scaling.sh — build time and time per ray against triangle count on the generated hairball
# (gen:hairball:N, thin random tubes), N from 10K to 10M, on one backend of each kind this machine
# runs (each with its default layout and the bitstack; Embree with its stack), 100K diffuse rays
# (seed 1), every result verified first. Writes OUT/info-N.json and OUT/bench-N.json and draws
# OUT/scaling.png (bench/plots.py).
#   bench/scaling.sh [OUT] [MAX_TRIANGLES] [RAYS] [WARMUP]    (about 3 minutes on 2 cores up to 10M, 100K rays;
#                                                              WARMUP: mbvh bench --warmup, default 0.25 s)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
OUT="${1:-$ROOT/bench/out/scaling}"
MAX="${2:-10000000}"
RAYS="${3:-100000}"
WARMUP="${4:-0.25}"
mkdir -p "$OUT"
use_matplotlib
# every backend that starts here but the ISA and OpenCL-mapping variants: `cpu` stands for the
# best ISA, `opencl` for the device's mapping
ready="$("$MBVH" devices --ready 2>/dev/null || true)"
BACKENDS="$(grep -vx -e 'cpu-avx[0-9]*' -e 'opencl-wide' -e 'opencl-lane' <<<"$ready" | paste -sd, -)"
for alias in cpu opencl; do  # each alias once, where what it stands for starts here
  "$MBVH" devices --resolve "$alias" > /dev/null 2>&1 && BACKENDS="$BACKENDS,$alias"
done
echo "backends: $BACKENDS" >&2
for n in 10000 30000 100000 300000 1000000 3000000 10000000; do
  [ "$n" -le "$MAX" ] || break
  "$MBVH" info "gen:hairball:$n" --json "$OUT/info-$n.json" > /dev/null
  "$MBVH" bench "gen:hairball:$n" --backend "$BACKENDS" --layout mbvh2,mbvh4 --traversal bitstack,stack \
    --query closest --kinds diffuse --count "$RAYS" --warmup "$WARMUP" --json "$OUT/bench-$n.json" >&2
done
"$PY" "$ROOT/bench/plots.py" scaling "$OUT"
