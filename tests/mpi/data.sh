#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# data.sh RANKS — mbvh-mpi --distribute data on RANKS ranks of this host, against one process
# (ctest, label mpi; the environment of cmake/mpi_tests.cmake):
#   - `check` on conference (primary, shadow, diffuse and path rays, closest and any hit): zero
#     genuine mismatches and at least 99.99 % of the answers bit-identical (its exit status);
#   - `trace --rays` of Sponza's path rays: at least 99.99 % of the hits equal to `mbvh trace`'s;
#   - a scene refused by one process under a per-rank budget (MBVH_MEMORY_LIMIT) is rendered on
#     RANKS ranks under the same budget, its image equal to one process's (run without the budget)
#     on at least 99.9 % of the pixels;
#   - a 1-triangle scene (ranks without a triangle): trace and render cmp-equal to one process;
#   - dynamic tiles, which the collective trace cannot take, are refused (exit status 2).
set -euo pipefail
ranks="$1"
# shellcheck source=tests/mpi/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
py="$( [ -x /usr/bin/python3 ] && echo /usr/bin/python3 || echo python3)"

mpi "$MBVH_MPI" check "$conference" --distribute data --kinds primary,shadow,diffuse,path --count 20000 --threads 1 \
  > check.log 2>&1 || { cat check.log; fail "check --distribute data on $ranks ranks"; }
grep -q " 0 genuine mismatches; at least 99.99 % of the answers bit-identical on every kind" check.log ||
  { cat check.log; fail "check did not report zero genuine mismatches and at least 99.99 % bit-identical"; }
echo "PASS: check --distribute data on $ranks ranks: 0 genuine mismatches, >= 99.99 % bit-identical"

# records_equal A B RECORD SHARE: the share of equal RECORD-byte records, at least SHARE (and sizes equal)
records_equal() {
  "$py" - "$@" <<'PY'
import sys
a, b = open(sys.argv[1], "rb").read(), open(sys.argv[2], "rb").read()
k, need = int(sys.argv[3]), float(sys.argv[4])
if len(a) != len(b) or len(a) % k:
    sys.exit(f"sizes differ: {len(a)} and {len(b)} bytes")
n = len(a) // k
same = sum(a[i * k:(i + 1) * k] == b[i * k:(i + 1) * k] for i in range(n))
diff = [i for i in range(n) if a[i * k:(i + 1) * k] != b[i * k:(i + 1) * k]]
print(f"{same} of {n} equal ({100.0 * same / max(n, 1):.3f} %); differing: {diff[:20]}")
sys.exit(0 if same >= need * n else 1)
PY
}

"$MBVH" rays "$sponza" --kind path --count 20000 -o path.rays -q
"$MBVH" trace "$sponza" --rays path.rays -o ref.hits -q --threads 1
mpi "$MBVH_MPI" trace "$sponza" --distribute data --rays path.rays -o np.hits -q --threads 1
records_equal ref.hits np.hits 16 0.9999 || fail "trace --distribute data on $ranks ranks: too few hits equal to mbvh trace's"
echo "PASS: trace --distribute data on $ranks ranks: >= 99.99 % of the hits equal to mbvh trace's"

# 100 MiB: one process needs about 168 MiB for the 1M hairball and its build; a rank, the scene
# and its part's build
scene=gen:hairball:1000000
if MBVH_MEMORY_LIMIT=100M "$MBVH" info "$scene" -q > info.log 2>&1; then fail "one process was not refused under 100M"; fi
grep -q "MBVH_MEMORY_LIMIT" info.log || { cat info.log; fail "the refusal does not name MBVH_MEMORY_LIMIT"; }
"$MBVH" render "$scene" --spp 1 --width 64 --height 48 --pfm one.pfm -o one.png -q --threads 1
MBVH_MEMORY_LIMIT=100M mpi -x MBVH_MEMORY_LIMIT "$MBVH_MPI" render "$scene" --distribute data --spp 1 --width 64 --height 48 \
  --pfm np.pfm -o np.png -q --threads 1
# a PFM's header is three lines; then 12 bytes a pixel
for f in one.pfm np.pfm; do tail -c $((64 * 48 * 12)) "$f" > "$f.px"; done
records_equal one.pfm.px np.pfm.px 12 0.999 || fail "render --distribute data: too few pixels equal to one process's"
echo "PASS: $scene, refused by one process under MBVH_MEMORY_LIMIT=100M, rendered on $ranks ranks under it: >= 99.9 % of the pixels equal"

# more ranks than triangles: the ranks without one trace nothing, the answers are one process's
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' > one.obj
"$MBVH" rays one.obj --count 500 -o one.rays -q
"$MBVH" trace one.obj --rays one.rays -o one.hits -q
"$MBVH" render one.obj --width 16 --height 16 --pfm one-img.pfm -o one-img.png -q
mpi "$MBVH_MPI" trace one.obj --distribute data --rays one.rays -o one-np.hits -q
mpi "$MBVH_MPI" render one.obj --distribute data --width 16 --height 16 --pfm one-np.pfm -o one-np.png -q
cmp one.hits one-np.hits && cmp one-img.pfm one-np.pfm || fail "a 1-triangle scene on $ranks ranks differs from one process"
echo "PASS: a 1-triangle scene on $ranks ranks (ranks without triangles): trace and render cmp-equal to one process"

set +e
mpi "$MBVH_MPI" render "$conference" --distribute data --tiles dynamic -o dyn.png -q > dyn.log 2>&1
rc=$?
set -e
[ "$rc" = 2 ] && grep -q -- "--tiles dynamic" dyn.log || { cat dyn.log; fail "--tiles dynamic with --distribute data: exit $rc, not a refusal"; }
echo "PASS: --tiles dynamic with --distribute data is refused, naming the option"
