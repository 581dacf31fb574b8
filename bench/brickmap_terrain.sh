#!/usr/bin/env bash
# Brickmap worlds on terrain (issue 11 benchmark; van Wingerden 2015 §5.2):
#  1. Mrays/s per viewpoint (distant / medium / close) for ESVO, the DAG, the
#     brickmap world and Embree on the same scene in one run per view: the
#     `generate terrain` height-field mesh, voxelized once per run into all
#     three structures; Embree traces that mesh (its triangles, not voxels).
#  2. The procedural brickmap terrain (caves, overhangs) written chunk by
#     chunk: wall time and peak RSS per size (/usr/bin/time).
#  3. Memory per component (`voxcast info`) of the largest terrain.
#  4. Streaming that world with a budget far below it: per-frame figures,
#     chunk decode GB/s and peak RSS.
#  5. Edit throughput on a terrain world (`voxcast edit`).
# Usage: bench/brickmap_terrain.sh [RESOLUTION] [SIZES...]   (default 1024; 1024 2048 4096)
set -euo pipefail
cd "$(dirname "$0")/.."
RES=${1:-1024}
shift || true
SIZES=("$@")
[ ${#SIZES[@]} -gt 0 ] || SIZES=(1024 2048 4096)
BIN=${VOXCAST:-build/voxcast}
tmp=${BENCH_TMP:-$(mktemp -d)}
[ -n "${BENCH_TMP:-}" ] || trap 'rm -rf "$tmp"' EXIT
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"

echo "== 1. viewpoints (terrain mesh, ${RES}^3 voxels, one thread) =="
"$BIN" generate terrain --size $((RES + 1)) -o "$tmp/terrain.obj" -q
for view in "distant:--orbit 30,35" "medium:--look-at 0.5,0.4,1.2,0.5,0.0,0.45" \
  "close:--look-at 0.75,0.2,0.8,0.3,0.08,0.3"; do
  name=${view%%:*}; cam=${view#*:}
  echo "-- $name ($cam)"
  # shellcheck disable=SC2086
  "$BIN" bench "$tmp/terrain.obj" --resolution "$RES" --size 512x384 --threads 1 --repeat 3 \
    --effects --ao-rays 1 --beam 0 $cam -q
done

echo "== 2. procedural brickmap terrain, chunk by chunk (2 threads) =="
for s in "${SIZES[@]}"; do
  /usr/bin/time -f "  wall %e s, peak RSS %M KiB" \
    "$BIN" generate terrain --size "${s}x${s}x256" --threads 2 -q -o "$tmp/t$s.vxc" 2>&1
done
big=$tmp/t${SIZES[-1]}.vxc

echo "== 3. memory of the largest terrain (voxcast info) =="
"$BIN" info "$big" | sed -n '/^voxels/,$p'

echo "== 4. streaming it within 64M =="
/usr/bin/time -f "  wall %e s, peak RSS %M KiB" \
  "$BIN" render "$big" --stream --frames 8 --budget 64M --uploads 8192 --size 480x320 \
  --orbit 30,35 --threads 1 -q -o "$tmp/stream.png" 2>&1

echo "== 5. edits on the ${SIZES[0]} terrain =="
# The surface of the default 1024^2 terrain at (0.1, 0.1) lies at y = 0.035
# (a ray straight down); the remove and paint spheres are centered on it
# (the generated world keeps only exposed voxels, so a sphere inside the
# hollow interior would change nothing).
"$BIN" edit "$tmp/t${SIZES[0]}.vxc" --sphere 0.1,0.035,0.1,0.05 --remove -q
"$BIN" edit "$tmp/t${SIZES[0]}.vxc" --sphere 0.1,0.15,0.1,0.04 --add --color 0.9,0.9,1 -q
"$BIN" edit "$tmp/t${SIZES[0]}.vxc" --sphere 0.1,0.035,0.1,0.06 --paint 0.2,0.6,0.2 -q
