#!/usr/bin/env bash
# esvo Table 4 in our setting: primary-ray Mrays/s for cubical voxels, contours
# and contours + beam, against Embree, at three image sizes, all measured in
# one `voxcast bench` run per mesh. Usage:
#   bench/table4.sh [RESOLUTION] [MESH...]
set -euo pipefail
cd "$(dirname "$0")/.."
RES=${1:-1024}
shift || true
MESHES=("$@")
[ ${#MESHES[@]} -gt 0 ] || MESHES=(tests/data/meshes/stanford-bunny.obj tests/data/meshes/fandisk_large.off tests/data/meshes/armadillo.off)
BIN=${VOXCAST:-build/voxcast}
SIZES=512x384,1024x768,2048x1536
echo "| mesh | image | coverage | cubes | cubes+beam | contours | contours+beam | Embree x1 | Embree x8 | contours+beam / Embree best |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for m in "${MESHES[@]}"; do
  # --min-coverage 0.3: the zoomed-in camera the BENCHMARKS table was measured with.
  out=$("$BIN" bench "$m" --resolution "$RES" --size "$SIZES" --contours --repeat 3 --min-coverage 0.3 2>/dev/null)
  awk -v mesh="$(basename "$m")" '
    /^image/ {split($2, s, ","); img=s[1]; cov=$3}
    /^voxcast  / {c=$2} /^voxcast\+beam/ {cb=$2}
    /^contours  / {k=$2} /^contours\+beam/ {kb=$2}
    /^embree x1/ {e1=$3} /^embree x8/ {e8=$3;
      best = (e1 > e8 ? e1 : e8);
      printf "| %s | %s | %s | %s | %s | %s | %s | %s | %s | %.3f |\n", mesh, img, cov, c, cb, k, kb, e1, e8, kb / best }' <<<"$out"
done
