# SPDX-License-Identifier: MIT
# lib.sh — sourced by the bench suites: where things are (ROOT, MBVH, SCENES), the scene table
# (bench/scenes.sh), the suites' arguments (bench_args), a progress line (log), the python that
# draws the plots (use_matplotlib) and the one step of the speed suites (run_queries).
# shellcheck shell=bash disable=SC2034  # (the variables it sets are for the scripts that source it)
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MBVH="${MBVH:-$ROOT/build/mbvh}"
SCENES="$ROOT/../shared/scenes"
# shellcheck source=bench/scenes.sh
source "$ROOT/bench/scenes.sh"

# bench_args DEFAULT_OUT [--quick] [OUT] [MORE...]: QUICK (1 after --quick, else 0), OUT (made, default
# DEFAULT_OUT) and ARGS (the MORE arguments, each suite's own)
bench_args() {
  local default_out="$1"
  shift
  QUICK=0
  if [ "${1:-}" = "--quick" ]; then QUICK=1; shift; fi
  OUT="${1:-$default_out}"
  ARGS=("${@:2}")
  mkdir -p "$OUT"
}

BENCH_START=$SECONDS
log() { echo "== [$((SECONDS - BENCH_START)) s] $*" >&2; }

# use_matplotlib: PY becomes Debian's python3 ($PYTHON overrides), the one scripts/setup.sh gives
# python3-matplotlib; status 1, with what to install, where it cannot import matplotlib
use_matplotlib() {
  PY="${PYTHON:-$( [ -x /usr/bin/python3 ] && echo /usr/bin/python3 || echo python3)}"
  "$PY" -c "import matplotlib" 2>/dev/null && return 0
  echo "bench: $PY cannot import matplotlib, which the plots need: run scripts/setup.sh" \
       "(or apt-get install python3-matplotlib), or set PYTHON to a python3 that has it" >&2
  return 1
}

# run_queries NAME SCENE CAMERA ARGS...: `mbvh bench SCENE` with ARGS twice, closest hit on
# CLOSEST_KINDS (default primary,diffuse) and any hit on shadow rays: OUT/NAME-closest.json and
# OUT/NAME-any.json, with the text tables beside them (.txt) and on standard error
run_queries() {
  local name="$1" scene="$2" camera="$3" kinds="${CLOSEST_KINDS:-primary,diffuse}"
  shift 3
  log "$name: closest hit on $kinds rays, any hit on shadow rays"
  # shellcheck disable=SC2086  # the camera is words
  "$MBVH" bench "$scene" "$@" --query closest --kinds "$kinds" $camera --json "$OUT/$name-closest.json" \
    | tee "$OUT/$name-closest.txt" >&2
  # shellcheck disable=SC2086
  "$MBVH" bench "$scene" "$@" --query any --kinds shadow $camera --json "$OUT/$name-any.json" \
    | tee "$OUT/$name-any.txt" >&2
}
