#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# header_check.sh CC CXX INCLUDE_DIR — mbvh/mbvh_c.h alone, every warning an error: as C99 and C11
# with -pedantic (so it includes no C++ header and uses no extension), and as C++11 and C++20.
set -euo pipefail
cc="$1" cxx="$2" inc="$3"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
cat > "$tmp/use.c" <<'SRC'
#include <mbvh/mbvh_c.h>
int main(void) {
  mbvh_trace_options t;
  mbvh_build_options b;
  mbvh_trace_options_init(&t);
  mbvh_build_options_init(&b);
  return (int)(t.leaf_block + b.threads) + (int)sizeof(mbvh_ray) - 32;
}
SRC
cp "$tmp/use.c" "$tmp/use.cpp"
warn=(-Wall -Wextra -pedantic -Wshadow -Wconversion -Werror)
for std in c99 c11; do
  "$cc" -std="$std" "${warn[@]}" -Wstrict-prototypes -Wmissing-prototypes -I"$inc" -c "$tmp/use.c" -o "$tmp/use-$std.o"
done
for std in c++11 c++20; do
  "$cxx" -std="$std" "${warn[@]}" -I"$inc" -c "$tmp/use.cpp" -o "$tmp/use-$std.o"
done
echo "mbvh/mbvh_c.h compiles as C99, C11, C++11 and C++20 (-pedantic -Werror)"
