#!/usr/bin/env bash
M="$1"; O="$2"; mkdir -p "$O"
for sc in /work/shared/scenes/*.zst; do
  n=$(basename $sc)
  "$M" -q check "$sc" --backend all --kinds primary,shadow,diffuse --count 20000 --json "$O/$n.json" > "$O/$n.txt" 2>&1; echo "rc=$?" >> "$O/$n.txt"
done
