#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# pocl_isa.sh — the OpenCL MIC path (`opencl-wide`: the 16-wide MBVH4 node test) on PoCL's CPU device
# compiled for AVX-512 (PoCL's own choice on such a host) and for AVX2 (POCL_LLVM_CPU_NAME=haswell with
# POCL_KERNELLIB_NAME=avx2: the device becomes pthread-haswell, its kernels use no zmm register),
# beside the cpu backend's two ISAs on the same rays: the opencl / cpu ratio for both (issue 40, item 6).
# On the interior views of the conference room, Sibenik and Sponza and the bunny: primary and diffuse
# rays closest hit, shadow rays any hit, 2 threads. Needs an AVX-512 host for the first pair.
#   bench/pocl_isa.sh [OUT] [RAYS]   (default bench/out-pocl, 100000 rays; about 3 minutes)
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out-pocl" "$@"
RAYS="${ARGS[0]:-100000}"
LIST="$(scene_rows "$SCENES" bunny conference sibenik sponza)"
run() {  # NAME SCENE CAMERA TAG BACKENDS [ENV...]
  local name="$1" scene="$2" camera="$3" tag="$4" backends="$5"
  shift 5
  # shellcheck disable=SC2086  # the camera is words
  env "$@" "$MBVH" bench "$scene" $camera --backend "$backends" --query closest --kinds primary,diffuse \
    --count "$RAYS" --threads 2 --json "$OUT/$name-closest-$tag.json" > "$OUT/$name-closest-$tag.txt" 2>&1
  # shellcheck disable=SC2086
  env "$@" "$MBVH" bench "$scene" $camera --backend "$backends" --query any --kinds shadow \
    --count "$RAYS" --threads 2 --json "$OUT/$name-any-$tag.json" > "$OUT/$name-any-$tag.txt" 2>&1
}
while IFS='|' read -r name scene camera; do
  log "$name"
  run "$name" "$scene" "$camera" avx512 cpu-avx512,cpu-avx2,opencl-wide POCL_CACHE_DIR="$OUT/pocl-avx512"
  run "$name" "$scene" "$camera" avx2 opencl-wide POCL_CACHE_DIR="$OUT/pocl-avx2" POCL_LLVM_CPU_NAME=haswell \
    POCL_KERNELLIB_NAME=avx2
done <<< "$LIST"
rm -rf "$OUT/pocl-avx512" "$OUT/pocl-avx2"
python3 - "$OUT" <<'PY'
import glob, json, os, sys
out = sys.argv[1]
rows = {}
for f in sorted(glob.glob(os.path.join(out, "*.json"))):
    tag = f.rsplit("-", 1)[1][:-5]
    d = json.load(open(f))
    for r in d["records"]:
        key = (r["scene"], r["ray_kind"], r["query"])
        col = "opencl-wide " + tag if r["backend"] == "opencl-wide" else r["backend"]
        rows.setdefault(key, {})[col] = max(rows.setdefault(key, {}).get(col, 0), r["mrays_per_s"])
print("| scene | rays | query | cpu-avx512 | cpu-avx2 | opencl-wide AVX-512 | opencl-wide AVX2 | opencl / cpu (AVX-512) | opencl / cpu (AVX2) | opencl AVX-512 / AVX2 |")
print("|---|---|---|---|---|---|---|---|---|---|")
for (scene, kind, query), c in rows.items():
    a, b, o5, o2 = (c.get(k, 0) for k in ("cpu-avx512", "cpu-avx2", "opencl-wide avx512", "opencl-wide avx2"))
    r = lambda x, y: f"{x / y:.2f}" if x and y else "-"
    print(f"| {os.path.basename(scene).split('.')[0]} | {kind} | {query} | {a:.2f} | {b:.2f} | {o5:.2f} | {o2:.2f} | {r(o5, a)} | {r(o2, b)} | {r(o5, o2)} |")
PY
