#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# python.sh — the Python module mbvh (issue 33) on one machine in one run: the binding against the
# program on the same rays, its per-call overhead, and the Python ray casters a mesh user reaches
# for otherwise, each on the same rays and triangles, ratios and answers taken within the run:
#   rays      `mbvh rays SCENE --kind random --count RAYS` (1M random rays on the conference room),
#             traced once by `mbvh trace` (closest: the .hits; any: the occlusion bytes), the answers
#             the module's must equal byte for byte
#   mbvh      bench/python_bench.py mbvh, in Debian's python3 (numpy from python3-numpy) with
#             PYTHONPATH to the module: rounds of `mbvh trace` (its printed Mrays/s), accel.trace()
#             (wall time) and accel.bench() (the library's timing), closest and any hit, 2 threads
#             and 1; the answers against the program's and the double brute force; the per-call
#             overhead of 1, 16 and 256 rays
#   peers     bench/python_bench.py peers, in the peers' venv (PEER_VENV, default OUT/../pyvenv,
#             made from /usr/bin/python3 so that the module imports there too): Open3D
#             (RaycastingScene), trimesh (RayMeshIntersector over embreex), embreex, Warp (device
#             cpu) on the same rays: Mrays/s, threads used, 1-ray call, answers against mbvh's
#             classified in double precision; and the side-by-side task (load the .obj, trace,
#             count hits) as each library's user writes it. Skipped, and said so, where the venv
#             or a peer is missing; PEER_INSTALL=1 makes the venv with the pinned versions below.
# Writes OUT/python.json (every number, the versions, the machine), OUT/python.md (the tables),
# OUT/python.log (this run's log) and OUT/load.txt (compilers or tests seen running meanwhile).
#   bench/python.sh [--quick] [OUT]
#     OUT default bench/out/python. --quick: 20K rays on the Cornell box, few rounds and calls (a
#     smoke test of the whole pipeline, well under a minute with the peers installed).
#     Environment: MBVH (the program, default build/mbvh), MBVH_PYTHONPATH (the module's folder,
#     default build/python), PYTHON (default /usr/bin/python3), PEER_VENV, PEER_INSTALL=1, RAYS.
set -euo pipefail
# shellcheck source=bench/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
bench_args "$ROOT/bench/out/python" "$@"
OUT="$(cd "$OUT" && pwd)"
exec 2> >(tee "$OUT/python.log" >&2)

PY="${PYTHON:-/usr/bin/python3}"
MODULE_PATH="${MBVH_PYTHONPATH:-$ROOT/build/python}"
PEER_VENV="${PEER_VENV:-$(dirname "$OUT")/pyvenv}"
# the peers, pinned: the newest that install on Debian 12's Python 3.11 beside numpy 1.x (the module is
# built with Debian's pybind11 2.10, which cannot import numpy 2). open3d-cpu is Open3D's CPU-only
# wheel (the same RaycastingScene as `open3d`, without the CUDA parts); its library needs Debian's
# libusb-1.0-0. embreex 4.4 wraps Embree 4.4.
PEER_PINS=("numpy==1.26.4" "open3d-cpu==0.20.0" "trimesh==5.2.0" "embreex==4.4.0.post1" "warp-lang==1.19.0")
THREADS=2
SCENE_NAME=conference RAYS="${RAYS:-1000000}" ROUNDS=7 CALLS=20000 REPS=5 BRUTE=1000 PEER_REPEAT=5 PEER_CALLS=2000 CAP=1000
TRUTH=300 LEAK_SCENE=gen:sphere:256 LEAK_RAYS=100000
if [ "$QUICK" = 1 ]; then
  SCENE_NAME=cornell RAYS=20000 ROUNDS=3 CALLS=2000 REPS=3 BRUTE=200 PEER_REPEAT=3 PEER_CALLS=300 CAP=200
  TRUTH=50 LEAK_SCENE=gen:sphere:64 LEAK_RAYS=10000
fi
IFS='|' read -r _ SCENE _ <<< "$(scene_rows "$SCENES" "$SCENE_NAME")"

# -- what runs beside the benchmark (compilers, linkers, tests): sampled every 5 s into OUT/load.txt
# (the brackets keep the pattern from matching the shells that carry it)
busy() { pgrep -af '[c]c1plus|[n]inja|[c]test|[ /][l]d ' || true; }
: > "$OUT/load.txt"
( while sleep 5; do b="$(busy)"; [ -n "$b" ] && { echo "$(date -u '+%H:%M:%S') $(uptime | sed 's/.*load/load/')"; echo "$b" | cut -c1-160; }; done >> "$OUT/load.txt" ) &
SAMPLER=$!
trap 'kill "$SAMPLER" 2>/dev/null || true' EXIT

# -- the machine and the run
{
  echo "date: $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "machine: $(lscpu | sed -n 's/^Model name: *//p' | head -1), $(nproc) cores" \
       "($(lscpu | sed -n 's/^Hypervisor vendor: *//p' | head -1 | sed 's/^$/bare metal or unknown/') guest;" \
       "$(lscpu | sed -n 's/^Flags:.*\(avx512f\).*/AVX-512/p; s/^Flags:.*\(avx2\).*/AVX2/p' | head -1))"
  echo "kernel: $(uname -srm)"
  echo "compiler: $(c++ --version 2>/dev/null | head -1)"
  echo "code: $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)$(git -C "$ROOT" diff --quiet 2>/dev/null || echo ' (modified)')"
  echo "program: $MBVH ($("$MBVH" --version 2>&1 | head -1))"
  echo "python: $PY ($("$PY" --version 2>&1)), module: $MODULE_PATH"
  echo "scene: $SCENE; rays: $RAYS random; threads: $THREADS; rounds: $ROUNDS; quick: $QUICK"
  echo "load at start: $(uptime | sed 's/.*load/load/')"
  b="$(busy)"; echo "running at start: ${b:-nothing that compiles or tests}" | head -3 | cut -c1-200
} > "$OUT/machine.txt"
cat "$OUT/machine.txt" >&2

if ! PYTHONPATH="$MODULE_PATH" "$PY" -c "import mbvh, numpy" 2> "$OUT/import.err"; then
  echo "python.sh: $PY cannot import mbvh and numpy with PYTHONPATH=$MODULE_PATH (build the module:" \
       "python3-dev pybind11-dev python3-numpy, MBVH_PYTHON=ON; see docs/python.md):" >&2
  cat "$OUT/import.err" >&2
  exit 2
fi
rm -f "$OUT/import.err"

# -- the rays and the program's answers
log "rays: $RAYS random rays on $SCENE_NAME"
"$MBVH" rays "$SCENE" --kind random --count "$RAYS" --seed 1 --threads "$THREADS" -o "$OUT/random.rays" >&2
"$MBVH" trace "$SCENE" --rays "$OUT/random.rays" --backend cpu --threads "$THREADS" -o "$OUT/random.hits" >&2
"$MBVH" trace "$SCENE" --rays "$OUT/random.rays" --backend cpu --threads "$THREADS" --query any \
  -o "$OUT/random.occlusion" >&2
# the leak test: rays from inside a closed sphere, half aimed exactly at its vertices and edge midpoints
log "leaks: $LEAK_RAYS inside rays of $LEAK_SCENE"
"$MBVH" rays "$LEAK_SCENE" --kind inside --count "$LEAK_RAYS" --seed 1 -o "$OUT/inside.rays" >&2
"$MBVH" trace "$LEAK_SCENE" --rays "$OUT/inside.rays" --threads "$THREADS" -o "$OUT/inside.hits" >&2
"$MBVH" trace "$LEAK_SCENE" --rays "$OUT/inside.rays" --threads "$THREADS" --query any -o "$OUT/inside.occlusion" >&2
COMMON=(--scene "$SCENE" --rays "$OUT/random.rays" --hits "$OUT/random.hits" --occlusion "$OUT/random.occlusion"
        --threads "$THREADS" --call-reps "$REPS" --leak-scene "$LEAK_SCENE" --leak-rays "$OUT/inside.rays"
        --leak-hits "$OUT/inside.hits" --leak-occlusion "$OUT/inside.occlusion")

# -- mbvh: the binding against the program
log "mbvh: $ROUNDS rounds of mbvh trace / accel.trace / accel.bench; per-call overhead"
PYTHONPATH="$MODULE_PATH" "$PY" "$ROOT/bench/python_bench.py" mbvh "${COMMON[@]}" --exe "$MBVH" --rounds "$ROUNDS" \
  --calls "$CALLS" --brute "$BRUTE" -o "$OUT/mbvh.json"

# -- the peers
if [ "${PEER_INSTALL:-0}" = 1 ] && [ ! -x "$PEER_VENV/bin/python" ]; then
  log "peers: making $PEER_VENV (${PEER_PINS[*]})"
  /usr/bin/python3 -m venv "$PEER_VENV"
  "$PEER_VENV/bin/pip" install -q "${PEER_PINS[@]}" >&2
fi
PEERS_JSON=""
if [ -x "$PEER_VENV/bin/python" ]; then
  {
    echo "peers' python: $PEER_VENV/bin/python ($("$PEER_VENV/bin/python" --version 2>&1))"
    echo "peers' packages: $("$PEER_VENV/bin/pip" list 2>/dev/null | grep -iE '^(numpy|open3d|open3d-cpu|trimesh|embreex|warp-lang) ' | awk '{print $1 "==" $2}' | paste -sd' ' -)"
  } | tee -a "$OUT/machine.txt" >&2
  OBJ="$OUT/task/$(basename "${SCENE%.zst}")"
  mkdir -p "$OUT/task"
  case "$SCENE" in *.zst) unzstd -q -f "$SCENE" -o "$OBJ" ;; *) cp "$SCENE" "$OBJ" ;; esac
  log "peers: the same rays in each peer of $PEER_VENV; the side-by-side task on $(basename "$OBJ")"
  PYTHONPATH="$MODULE_PATH" "$PEER_VENV/bin/python" "$ROOT/bench/python_bench.py" peers "${COMMON[@]}" \
    --calls "$PEER_CALLS" --repeat "$PEER_REPEAT" --classify-cap "$CAP" --truth-cap "$TRUTH" --obj "$OBJ" -o "$OUT/peers.json"
  PEERS_JSON="$OUT/peers.json"
  rm -rf "$OUT/task"
else
  echo "python.sh: no peers' venv at $PEER_VENV: Open3D, trimesh, embreex and Warp are not measured" \
       "(PEER_INSTALL=1 makes it: /usr/bin/python3 -m venv, pip install ${PEER_PINS[*]})" | tee -a "$OUT/machine.txt" >&2
fi

# -- the tables
{
  echo "load at end: $(uptime | sed 's/.*load/load/')"
  if [ -s "$OUT/load.txt" ]; then echo "compilers or tests ran during the run: in $(grep -c '^[0-9][0-9]:[0-9][0-9]:' "$OUT/load.txt") of the $(( (SECONDS - BENCH_START) / 5 )) 5-s samples (load.txt)"
  else echo "compilers or tests ran during the run: none seen (5-s samples)"; fi
} | tee -a "$OUT/machine.txt" >&2
"$PY" "$ROOT/bench/python_bench.py" report --mbvh "$OUT/mbvh.json" ${PEERS_JSON:+--peers "$PEERS_JSON"} \
  --machine "$OUT/machine.txt" -o "$OUT/python.json" --md "$OUT/tables.md" > /dev/null
{
  echo "# The Python module against the program and the Python peers: $(sed -n 's/^date: //p' "$OUT/machine.txt")"
  echo
  echo '```'
  cat "$OUT/machine.txt"
  echo "command: bench/python.sh $*"
  echo '```'
  echo
  cat "$OUT/tables.md"
} > "$OUT/python.md"
rm -f "$OUT/tables.md" "$OUT/mbvh.json" "$OUT/peers.json" "$OUT"/random.{rays,hits,occlusion} "$OUT"/inside.{rays,hits,occlusion}
cat "$OUT/python.md"
log "wrote $OUT/python.md and $OUT/python.json"
