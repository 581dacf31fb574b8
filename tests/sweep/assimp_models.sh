#!/usr/bin/env bash
# Every model of Debian's assimp-testmodels (/usr/share/assimp/models: ~580
# files in ~50 formats, among them deliberately broken ones) through
# `voxcast build`, `info` on what it built (and `convert` to .vox for the mesh path of convert): each
# must either succeed or fail with exit status 1 and exactly one line on
# stderr — never a crash (signal), a hang (timeout), another exit status,
# or stray importer output.
#   tests/sweep/assimp_models.sh VOXCAST [MODELS_DIR] [TIMEOUT_S]
# Prints one line per failure and a summary; exit 1 if anything failed.
set -u
voxcast=${1:?usage: assimp_models.sh VOXCAST [MODELS_DIR] [TIMEOUT_S]}
models=${2:-/usr/share/assimp/models}
limit=${3:-60}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
ok=0 refused=0 bad=0 total=0
check() {  # check FILE SUBCOMMAND ARGS...
  local file=$1 rc lines
  shift
  timeout -s KILL "$limit" "$voxcast" "$@" >"$work/out" 2>"$work/err"
  rc=$?
  lines=$(wc -l <"$work/err")
  total=$((total + 1))
  if ((rc == 0)); then
    # success may warn ("voxcast: warning: ...") and give the mesh summary
    # ("mesh: N triangles ... dropped"), nothing else
    if grep -Eqv '^(voxcast: warning: |mesh: )' "$work/err"; then
      bad=$((bad + 1))
      echo "STRAY  $1 $file: $(head -c 300 "$work/err" | tr '\n' '|')"
      return 1
    fi
    ok=$((ok + 1))
    return 0
  elif ((rc == 1 && lines == 1)) && grep -q '^voxcast: error: ' "$work/err"; then
    refused=$((refused + 1))
    return 1
  else
    bad=$((bad + 1))
    echo "FAIL   rc=$rc lines=$lines $1 $file: $(head -c 300 "$work/err" | tr '\n' '|')"
    return 1
  fi
}
while IFS= read -r -d '' f; do
  rm -f "$work/s.vxc"
  check "$f" build "$f" -o "$work/s.vxc" --resolution 32 --memory-budget 2G &&
    check "$f" info "$work/s.vxc"
  check "$f" convert "$f" "$work/s.vox" --resolution 32
done < <(find "$models" -type f ! -name '*.txt' ! -name '*.md' ! -name '*.png' ! -name '*.jpg' \
  ! -name '*.bmp' ! -name '*.tga' ! -name '*.dds' ! -name '*.bin' ! -name '*.mtl' -print0 | sort -z)
echo "assimp models: $total runs: $ok succeeded, $refused refused in one line, $bad failed"
((bad == 0))
