# SPDX-License-Identifier: MIT
# lib.sh — sourced by the MPI test scripts (replicated.sh, data.sh): checks the environment ctest
# gives them (cmake/mpi_tests.cmake: MBVH, MBVH_MPI, MPIEXEC, MBVH_SCENES_DIR), enters a fresh
# directory removed at exit, and defines fail MESSAGE and mpi PROGRAM ARGS... (on $ranks ranks).
# shellcheck shell=bash disable=SC2034  # (what it sets is for the scripts that source it)
: "${MBVH:?}" "${MBVH_MPI:?}" "${MPIEXEC:?}" "${MBVH_SCENES_DIR:?}" "${ranks:?}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
fail() { echo "FAIL: $*" >&2; exit 1; }
mpi() { "$MPIEXEC" -np "$ranks" "$@"; }
sponza="$MBVH_SCENES_DIR/sponza_dabrovic.obj.zst"
conference="$MBVH_SCENES_DIR/conference.obj.zst"
