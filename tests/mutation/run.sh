#!/usr/bin/env bash
# Mutation check (issue 8, item 7): applies each deliberate bug listed in
# tests/mutation/mutations.txt to a scratch copy of this tree, rebuilds the
# test executables it names, runs its ctest subset and reports CAUGHT (some
# test failed) or MISSED. Exits 1 if any mutation is missed, 2 if a pattern no
# longer matches its file exactly once, the unmutated baseline fails, or a
# mutation does not compile.
#
#   tests/mutation/run.sh              every mutation
#   tests/mutation/run.sh NAME...      only these (names from mutations.txt)
#   tests/mutation/run.sh --check      only verify that every pattern matches
#   tests/mutation/run.sh --test REGEX --build 'TARGET...' NAME...
#                                      the named mutations against another subset
#
# The scratch copy (default ${TMPDIR:-/tmp}/voxcast-mutation-<checksum of this
# tree's path>, one per checkout; override with VOXCAST_MUTATION_DIR) keeps its
# build directory between runs, so only the first run builds everything; the
# working tree itself is never modified. A lock in the copy serializes runs.
# JOBS (default 2) is passed to the build and to ctest. ccache is used when
# installed (CMAKE_CXX_COMPILER_LAUNCHER=ccache unless set otherwise).
# Not part of ./run test: it rebuilds once per mutation.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
if [ -z "${CMAKE_CXX_COMPILER_LAUNCHER:-}" ] && command -v ccache >/dev/null; then
  export CMAKE_CXX_COMPILER_LAUNCHER=ccache
fi
scratch=${VOXCAST_MUTATION_DIR:-${TMPDIR:-/tmp}/voxcast-mutation-$(printf %s "$root" | cksum | cut -d' ' -f1)}
exec python3 "$here/mutate.py" --root "$root" --list "$here/mutations.txt" \
  --scratch "$scratch" --jobs "${JOBS:-2}" "$@"
