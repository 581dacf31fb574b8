#!/usr/bin/env bash
# Runs `voxcast bench` on every shared mesh and prints a Markdown table row per
# mesh (the table in docs/BENCHMARKS.md). Usage:
#   bench/shared_meshes.sh [RESOLUTION] [WxH] [extra voxcast bench options...]
set -euo pipefail
cd "$(dirname "$0")/.."
RES=${1:-2048}
SIZE=${2:-1024x768}
shift $(( $# > 2 ? 2 : $# )) || true
MESHES=${MESHES:-tests/data/meshes}
BIN=${VOXCAST:-build/voxcast}
echo "| mesh | triangles | leaf voxels | coverage | voxcast Mrays/s | voxcast+beam8 | Embree x1 | Embree x8 | ratio | voxel build s | Embree build s | voxcast MiB | Embree MiB | hit agreement | depth ≤ 2 diag |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
for m in stanford-bunny.obj armadillo.off refined_elephant.off camel.off fandisk_large.off spot.obj teapot.obj CesiumMilkTruck/CesiumMilkTruck.gltf; do
  # --min-coverage 0.3: the zoomed-in camera the BENCHMARKS tables were measured with.
  out=$("$BIN" bench "$MESHES/$m" --resolution "$RES" --size "$SIZE" --min-coverage 0.3 "$@" 2>/dev/null)
  tri=$(sed -n 's/^mesh .*: \([0-9]*\) triangles/\1/p' <<<"$out")
  cov=$(sed -n 's/^image .*, \([0-9.]*\)% of pixels.*/\1/p' <<<"$out")
  leaves=$(sed -n 's/^voxels .*, \([0-9]*\) leaf voxels.*/\1/p' <<<"$out")
  agree=$(sed -n 's/^agreement *hit\/miss \([0-9.]*\)%, depth within 2 leaf voxel diagonals \([0-9.]*\)%/\1/p' <<<"$out")
  depth=$(sed -n 's/^agreement *hit\/miss \([0-9.]*\)%, depth within 2 leaf voxel diagonals \([0-9.]*\)%/\2/p' <<<"$out")
  vb=$(sed -n 's/^build *voxcast \([0-9.]*\) s.*/\1/p' <<<"$out")
  eb=$(sed -n 's/^build .*embree \([0-9.]*\) s/\1/p' <<<"$out")
  vm=$(sed -n 's/^memory *voxcast \([0-9.]*\) \([KMG]i\?B\).*/\1 \2/p' <<<"$out")
  em=$(sed -n 's/^memory .*embree \([0-9.]*\) \([KMG]i\?B\)/\1 \2/p' <<<"$out")
  v=$(sed -n 's/^voxcast *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
  vb8=$(sed -n 's/^voxcast+beam *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
  e1=$(sed -n 's/^embree x1 *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
  e8=$(sed -n 's/^embree x8 *\([0-9.]*\) Mrays.*/\1/p' <<<"$out")
  r=$(sed -n 's/^ratio voxcast\/embree: \([0-9.]*\)/\1/p' <<<"$out")
  echo "| $(basename "$m") | $tri | $leaves | $cov % | $v | $vb8 | $e1 | $e8 | $r | $vb | $eb | $vm | $em | $agree % | $depth % |"
done
