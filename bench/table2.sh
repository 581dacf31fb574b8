#!/usr/bin/env bash
# esvo Table 2 in our setting: scene memory (MiB) per octree depth and bytes
# per voxel (all levels), cubes vs contours, raw vs compressed attributes, and
# a variable-depth build.
# Usage: bench/table2.sh [MESH] [LEVELS...]
set -euo pipefail
cd "$(dirname "$0")/.."
MESH=${1:-scenes/bunny.obj}
shift || true
LEVELS=("$@")
[ ${#LEVELS[@]} -gt 0 ] || LEVELS=(8 9 10 11)
BIN=${VOXCAST:-build/voxcast}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
header="| variant |"; rule="|---|"
for l in "${LEVELS[@]}"; do header+=" $l levels MiB |"; rule+="---|"; done
echo "$header bytes/voxel at ${LEVELS[-1]} | build s at ${LEVELS[-1]} |"
echo "$rule---|---|"
# The last variant is the variable-depth build of esvo §7.1/§7.3 (leaves stop
# where shape and decoded attributes are within tolerance).
for variant in "cubes raw:" "cubes compressed:--attributes compressed" "contours raw:--contours" \
  "contours compressed:--contours --attributes compressed" \
  "variable depth:--contours --geometry-error 1 --color-error 8 --normal-error 10 --attributes compressed"; do
  name=${variant%%:*}; opts=${variant#*:}
  row="| $name |"
  for l in "${LEVELS[@]}"; do
    start=$(date +%s.%N)
    # shellcheck disable=SC2086
    "$BIN" build "$MESH" -o "$tmp/s.vxc" --resolution $((1 << l)) $opts >/dev/null
    secs=$(echo "$(date +%s.%N) - $start" | bc)
    read -r total voxels < <("$BIN" info "$tmp/s.vxc" --json | python3 -c 'import json,sys; j=json.load(sys.stdin); print(j["memory"]["total"], j["voxels_total"])')
    row+=" $(awk -v t="$total" 'BEGIN { printf "%.1f", t / 1048576 }') |"
    bpv=$(echo "scale=2; $total / $voxels" | bc)
  done
  echo "$row $bpv | $(printf %.1f "$secs") |"
done
