#!/usr/bin/env bash
# DAG memory and build cost vs resolution (svdag Table 1 / Table 2 / Figure 5
# shape): builds MESH as a geometry-only sparse voxel DAG at each resolution
# with the out-of-core builder (svdag §3 "Implementation details") and prints
# a Markdown table (the rows of docs/BENCHMARKS.md "DAG at scale"; sizes in
# MiB = 2^20 bytes). Peak RSS and wall time come from /usr/bin/time -v.
#
#   bench/dag_scaling.sh MESH [RESOLUTIONS...]   (default 1024 2048 4096 8192)
# Environment: VOXCAST (binary, default build/voxcast), BUDGET (--memory-budget,
# default 8G), VOXELIZATION (default conservative), OUT (scratch dir).
set -euo pipefail
if [[ $# -lt 1 ]]; then
  echo "usage: $0 MESH [RESOLUTION...]" >&2
  exit 2
fi
mesh=$1
shift
resolutions=("$@")
[[ ${#resolutions[@]} -gt 0 ]] || resolutions=(1024 2048 4096 8192)
here=$(cd "$(dirname "$0")/.." && pwd)
voxcast=${VOXCAST:-$here/build/voxcast}
budget=${BUDGET:-8G}
mode=${VOXELIZATION:-conservative}
out=${OUT:-$(mktemp -d)}
[[ -x $voxcast ]] || { echo "$0: no voxcast binary at $voxcast (set VOXCAST)" >&2; exit 2; }
[[ -x /usr/bin/time ]] || { echo "$0: /usr/bin/time (GNU time) is required" >&2; exit 2; }
command -v jq > /dev/null || { echo "$0: jq is required" >&2; exit 2; }

mb() { awk -v b="$1" 'BEGIN { printf "%.2f", b / 1048576 }'; }
name=$(basename "${mesh%.*}")
echo "| mesh | resolution | voxels | DAG nodes | DAG MiB | bits/voxel | SVO MiB (1 B/node) | ESVO MiB (8 B/node) | cell | build s | peak RSS MB |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
for r in "${resolutions[@]}"; do
  scene=$out/dag_$r.vxc
  log=$out/dag_$r.log
  if ! /usr/bin/time -v "$voxcast" build "$mesh" -o "$scene" --format dag --resolution "$r" \
      --voxelization "$mode" --no-attributes --out-of-core --memory-budget "$budget" > "$log" 2>&1; then
    echo "| $name | $r | build failed: $(grep -m1 'error' "$log" || tail -1 "$log") |||||||||"
    continue
  fi
  wall=$(awk -F': ' '/Elapsed \(wall clock\)/ { n = split($2, p, ":"); s = 0; for (i = 1; i <= n; ++i) s = s * 60 + p[i]; print s }' "$log")
  rss_kb=$(awk -F': ' '/Maximum resident set size/ { print $2 }' "$log")
  cell=$(sed -n 's/^out-of-core: [0-9]* cells of \([0-9]*\)^3.*/\1/p' "$log")
  info=$("$voxcast" info "$scene" --json)
  echo "| $name | ${r}^3 | $(jq .leaf_voxels <<< "$info") | $(jq .nodes.dag <<< "$info") |" \
       "$(mb "$(jq .memory.dag <<< "$info")") | $(jq '.bits_per_voxel * 1000 | round / 1000' <<< "$info") |" \
       "$(mb "$(jq .memory.svo_1byte <<< "$info")") | $(mb "$(jq .memory.esvo_8byte <<< "$info")") |" \
       "${cell}^3 | $wall | $(awk -v k="$rss_kb" 'BEGIN { printf "%.0f", k / 1024 }') |"
  rm -f "$scene"
done
