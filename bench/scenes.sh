# SPDX-License-Identifier: MIT
# scenes.sh — the benchmarks' scenes in one table, sourced by the bench suites and scripts/gpu-run.
# A row is NAME|SCENE|CAMERA: SCENE a file of the shared scene folder or a generator spec (gen:…),
# CAMERA the `mbvh` camera words (interior views of the three buildings; empty: the scene framed).
# shellcheck shell=bash
SCENE_TABLE="bunny|bun_zipper.ply.zst|
conference|conference.obj.zst|--camera 0,300,0,1000,200,0
sibenik|sibenik.obj.zst|--camera -14,-9,0,10,-6,0
sponza|sponza_dabrovic.obj.zst|--camera -10,4,0,10,5,0
cornell|cornell_box.obj.zst|
hairball20k|gen:hairball:20000|
hairball100k|gen:hairball:100000|
hairball1m|gen:hairball:1000000|
hairball5m|gen:hairball:5000000|
hairball10m|gen:hairball:10000000|"

# scene_names: the table's names, comma-separated
scene_names() { cut -d'|' -f1 <<< "$SCENE_TABLE" | paste -sd, -; }

# scene_rows DIR NAME...: the rows of those names, in that order, each file made a path under DIR
# (a generator spec stays as it is); status 1, with a message, at an unknown name
scene_rows() {
  local dir="$1" want name scene camera found
  shift
  for want in "$@"; do
    found=0
    while IFS='|' read -r name scene camera; do
      [ "$name" = "$want" ] || continue
      [[ "$scene" == gen:* ]] || scene="$dir/$scene"
      echo "$name|$scene|$camera"
      found=1
    done <<< "$SCENE_TABLE"
    ((found)) || { echo "unknown scene '$want' (one of $(scene_names))" >&2; return 1; }
  done
}
