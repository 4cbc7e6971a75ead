#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# replicated.sh RANKS — mbvh-mpi's replicated mode against one process, on RANKS ranks of this host
# (ctest, label mpi: cmake/mpi_tests.cmake gives MBVH, MBVH_MPI, MPIEXEC, MBVH_SCENES_DIR and Open
# MPI's settings):
#   - `trace` of Sponza's path rays, static and dynamic batches (small batches: every rank gets
#     several, and the dynamic ranks steal), through shared memory and as messages: the hits
#     `cmp`-equal to `mbvh trace`'s, closest and any;
#   - `render` of conference, static and dynamic tiles: the PFM `cmp`-equal to `mbvh render`'s;
#   - an error on the last rank (MBVH_MPI_TEST_FAIL): exit status 2, the rank named, no output.
set -euo pipefail
ranks="$1"
# shellcheck source=tests/mpi/lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"

"$MBVH" rays "$sponza" --kind path --count 60000 -o path.rays -q
for query in closest any; do
  "$MBVH" trace "$sponza" --rays path.rays --query "$query" -o ref.$query -q --threads 1
  for schedule in static dynamic; do
    for memory in "" --no-shared-memory; do
      mpi "$MBVH_MPI" trace "$sponza" --rays path.rays --query "$query" -o np.$query.$schedule$memory --threads 1 \
        --schedule "$schedule" --batch 4096 -q $memory
      cmp ref.$query np.$query.$schedule$memory ||
        fail "trace --query $query --schedule $schedule $memory on $ranks ranks differs from mbvh trace"
      echo "PASS: trace --query $query --schedule $schedule $memory on $ranks ranks: cmp-equal to mbvh trace"
    done
  done
done

"$MBVH" render "$conference" --spp 2 --width 96 --height 80 --pfm ref.pfm -o ref.png -q --threads 1
for tiles in static dynamic; do
  mpi "$MBVH_MPI" render "$conference" --spp 2 --width 96 --height 80 --pfm np.$tiles.pfm -o np.$tiles.png --tiles "$tiles" \
    --threads 1 -q
  cmp ref.pfm np.$tiles.pfm || fail "render --tiles $tiles on $ranks ranks differs from mbvh render"
  echo "PASS: render --tiles $tiles on $ranks ranks: the PFM cmp-equal to mbvh render's"
done

last=$((ranks - 1))
set +e
MBVH_MPI_TEST_FAIL=$last "$MPIEXEC" -np "$ranks" -x MBVH_MPI_TEST_FAIL "$MBVH_MPI" render "$conference" --spp 1 \
  --width 16 --height 16 -o err.png --pfm err.pfm --threads 1 > err.log 2>&1
rc=$?
set -e
[ "$rc" = 2 ] || { cat err.log; fail "an error on rank $last: exit status $rc, not 2"; }
grep -q "mbvh-mpi: error (rank $last/$ranks): MBVH_MPI_TEST_FAIL" err.log || { cat err.log; fail "the error does not name rank $last/$ranks"; }
[ ! -e err.png ] && [ ! -e err.pfm ] || fail "an output was written although rank $last failed"
echo "PASS: an error on rank $last of $ranks: exit status 2, the rank named, no output written"
