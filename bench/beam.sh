#!/usr/bin/env bash
# Beam optimization (esvo §6.2) on the ESVO octree and on the DAG of the same
# voxels: the tables of docs/BENCHMARKS.md "Beam optimization".
#  1. per-ray counters from `voxcast render --stats` with --beam 0, 8 and 4
#     (automatic camera, LOD 1; the counters are deterministic);
#  2. frame times on one thread from `voxcast bench --threads 1 --effects`
#     (best of REPEAT frames; the plain and the beam caster, ESVO and DAG, of
#     one LOD and block size are measured in the same process).
# Usage: bench/beam.sh [MESH] [RESOLUTION] [WxH]
#   (default tests/data/meshes/stanford-bunny.obj 2048 1024x768)
# Environment: VOXCAST (binary, default build/voxcast), REPEAT (default 5).
set -euo pipefail
cd "$(dirname "$0")/.."
MESH=${1:-tests/data/meshes/stanford-bunny.obj}
RES=${2:-2048}
SIZE=${3:-1024x768}
BIN=${VOXCAST:-build/voxcast}
REPEAT=${REPEAT:-5}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# counters FORMAT: one Markdown table of the --stats profile per beam setting.
counters() {
  local format=$1 scene=$tmp/$1.vxc
  "$BIN" build "$MESH" -o "$scene" --resolution "$RES" --format "$format" >/dev/null
  for beam in 0 8 4; do
    "$BIN" render "$scene" -o "$tmp/$format$beam.png" --size "$SIZE" --camera auto --stats \
      --beam "$beam" >"$tmp/$format$beam.txt" 2>&1
  done
  echo "| $format, per ray | off | \`--beam 8\` | \`--beam 4\` |"
  echo "|---|---|---|---|"
  for counter in iterations intersect push store advance pop bytes; do
    local row="| $counter |" base=""
    for beam in 0 8 4; do
      local v
      v=$(awk -v c="$counter" '$1 == c { print $2; exit }' "$tmp/$format$beam.txt")
      if [[ $beam == 0 ]]; then
        base=$v
        row+=" $v |"
      elif [[ $counter == iterations ]]; then
        row+=" $v ($(awk -v a="$v" -v b="$base" 'BEGIN { printf "%+.0f %%", 100 * (a / b - 1) }')) |"
      else
        row+=" $v |"
      fi
    done
    echo "$row"
  done
  # The beam must not change the image: the same PNG with and without it.
  for beam in 8 4; do
    cmp -s "$tmp/${format}0.png" "$tmp/$format$beam.png" ||
      echo "WARNING: $format image with --beam $beam differs from --beam 0"
  done
  echo
}

counters esvo
counters dag

pixels=$(awk -F x '{ print $1 * $2 }' <<<"$SIZE")
ms() { awk -v p="$pixels" -v m="$1" 'BEGIN { printf "%.1f", p / (m * 1e3) }'; }
echo "| frame ms, 1 thread, best of $REPEAT | LOD | off | \`--beam 8\` | \`--beam 4\` |"
echo "|---|---|---|---|---|"
for lod in 0 1; do
  declare -A plain=() beamed=()
  for beam in 8 4; do
    out=$("$BIN" bench "$MESH" --resolution "$RES" --size "$SIZE" --threads 1 --repeat "$REPEAT" \
      --lod "$lod" --beam "$beam" --effects --ao-rays 1 2>/dev/null)
    plain[esvo$beam]=$(sed -n 's/^voxcast  *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
    beamed[esvo$beam]=$(sed -n 's/^voxcast+beam  *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
    plain[dag$beam]=$(sed -n 's/^primary dag  *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
    beamed[dag$beam]=$(sed -n 's/^primary dag .*with beam [0-9x]* \([0-9.]*\) Mrays.*/\1/p' <<<"$out")
  done
  for s in esvo dag; do
    # The plain caster ran in both processes: its best frame of the two.
    best=$(awk -v a="${plain[${s}8]}" -v b="${plain[${s}4]}" 'BEGIN { print (a > b ? a : b) }')
    echo "| $s | $lod | $(ms "$best") | $(ms "${beamed[${s}8]}") | $(ms "${beamed[${s}4]}") |"
  done
done
