#!/bin/bash
# lod check on the shared scenes, the 1.4M mandelbulb and a closed sphere (issue 35 acceptance)
set -u
M=/work/main/build/mbvh
D=/work/big/check
S=/work/shared/scenes
for s in bun_zipper.ply.zst conference.obj.zst cornell_box.obj.zst sibenik.obj.zst sponza_dabrovic.obj.zst; do
  n=${s%%.*}
  $M lod build $S/$s -o $D/$n.mlod --memory 2G > $D/build-$n.log 2>&1 || echo "build $n failed"
  $M lod check $D/$n.mlod --against $S/$s --kinds primary,shadow,diffuse,random,path --count 100000 > $D/check-$n.log 2>&1; echo "$n: exit $?"
done
$M lod check /work/big/mb170.mlod --against /work/big/mb170.mtri --kinds primary,shadow,diffuse,random,path --count 100000 > $D/check-mb170.log 2>&1; echo "mb170: exit $?"
$M lod build gen:sphere:256 -o $D/sphere.mlod > $D/build-sphere.log 2>&1
$M lod check $D/sphere.mlod --against gen:sphere:256 --kinds inside,primary --count 100000 > $D/check-sphere.log 2>&1; echo "sphere: exit $?"
