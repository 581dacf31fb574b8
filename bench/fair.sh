#!/usr/bin/env bash
# The fair benchmark of issue 10 on the shared meshes: runs
#   voxcast bench MESH --resolution RES --size WxH --threads T --effects --json ...
# per mesh (its full readable tables go to stderr), then prints the Markdown
# tables of docs/BENCHMARKS.md "Fair benchmark (issue 10)" from the JSON.
# Usage: bench/fair.sh [RESOLUTION] [WxH] [extra voxcast bench options...]
#   THREADS (default 1), MESHES (directory), MESH_LIST (names), VOXCAST (binary),
#   JSON_DIR (keep the JSON files).
set -euo pipefail
cd "$(dirname "$0")/.."
RES=${1:-2048}
SIZE=${2:-1024x768}
shift $(( $# > 2 ? 2 : $# )) || true
THREADS=${THREADS:-1}
MESHES=${MESHES:-tests/data/meshes}
BIN=${VOXCAST:-build/voxcast}
MESH_LIST=${MESH_LIST:-"stanford-bunny.obj armadillo.off refined_elephant.off camel.off fandisk_large.off spot.obj teapot.obj CesiumMilkTruck/CesiumMilkTruck.gltf"}
# JSON_DIR: keep the per-mesh JSON files there (default: a temporary directory).
if [[ -n ${JSON_DIR:-} ]]; then
  mkdir -p "$JSON_DIR"
  tmp=$JSON_DIR
else
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
fi
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"
files=()
for m in $MESH_LIST; do
  f="$tmp/$(basename "$m").json"
  "$BIN" bench "$MESHES/$m" --resolution "$RES" --size "$SIZE" --threads "$THREADS" --effects --min-coverage 0.3 \
    --ao-rays 16 --beam 8 --json "$f" "$@" >&2
  files+=("$f")
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
python3 - "${files[@]}" <<'PY'
import json, os, sys
runs = [json.load(open(f)) for f in sys.argv[1:]]
m0 = runs[0]["machine"]
print(f"machine: {m0['cpu']}, Embree ISA {m0['embree_isa']}, {m0['threads']} thread(s)")
print(f"command per mesh: {runs[0]['command']}\n")

def row(r, caster, shaded, lod=None):
    for p in r["primary"]:
        if p["caster"] == caster and p["shaded"] == shaded and (p["lod"] is None or p["lod"] == lod):
            return p
    return None

modes = ["x1", "x4", "x8", "x16", "1M"]
for shaded in (False, True):
    print("Trace + the same shading" if shaded else "Trace only (depth written)", "(Mrays/s; Mhits/s in brackets)\n")
    print("| mesh | coverage | " + " | ".join("Embree " + m for m in modes) +
          " | ESVO LOD 0 | ESVO LOD 1 | DAG LOD 0 | DAG LOD 1 | ratio LOD 0 | ratio LOD 1 |")
    print("|---" * (2 + len(modes) + 6) + "|")
    for j in runs:
        r = j["runs"][0]
        best = max(row(r, "embree " + m, shaded)["mrays_per_s"] for m in modes)
        cells = [os.path.basename(j["mesh"]), f"{100 * r['coverage']:.1f} %"]
        for m in modes:
            p = row(r, "embree " + m, shaded)
            cells.append(f"{p['mrays_per_s']:.2f} ({p['mhits_per_s']:.2f})")
        for c in ("voxcast esvo", "voxcast dag"):
            for lod in (0.0, 1.0):
                p = row(r, c, shaded, lod)
                cells.append(f"{p['mrays_per_s']:.2f} ({p['mhits_per_s']:.2f})")
        for lod in (0.0, 1.0):
            cells.append(f"{row(r, 'voxcast esvo', shaded, lod)['mrays_per_s'] / best:.3f}")
        print("| " + " | ".join(cells) + " |")
    print()

print("Occlusion rays, the same pre-generated arrays for every caster (Mrays/s; ratio = ESVO / fastest Embree)\n")
occ_modes = ["x1", "x8", "x16", "1M"]
print("| mesh | rays | occluded | " + " | ".join("Embree " + m for m in occ_modes) +
      " | ESVO any-hit | DAG any-hit | ratio ESVO | ratio DAG | ESVO = Embree |")
print("|---" * (3 + len(occ_modes) + 5) + "|")
for j in runs:
    r = j["runs"][0]
    for kind in ("shadow", "ao"):
        o = r["occlusion"][kind]
        c = {x["caster"]: x for x in o["casters"]}
        best = max(c["embree " + m]["mrays_per_s"] for m in occ_modes)
        n = max(o["rays"], 1)
        cells = [f"{os.path.basename(j['mesh'])} {kind}", str(o["rays"]),
                 f"{100 * c['embree x1']['occluded'] / n:.1f} %"]
        cells += [f"{c['embree ' + m]['mrays_per_s']:.2f}" for m in occ_modes]
        cells += [f"{c['voxcast esvo']['mrays_per_s']:.2f}", f"{c['voxcast dag']['mrays_per_s']:.2f}",
                  f"{c['voxcast esvo']['mrays_per_s'] / best:.3f}", f"{c['voxcast dag']['mrays_per_s'] / best:.3f}",
                  f"{100 * c['voxcast esvo']['same_as_embree_x1'] / n:.2f} %"]
        print("| " + " | ".join(cells) + " |")
print()

# Same rays -> same answers: every Embree mode against rtcIntersect1 / rtcOccluded1, exactly.
bad = []
for j in runs:
    r = j["runs"][0]
    for shaded in (False, True):
        hits = {row(r, "embree " + m, shaded)["hits"] for m in modes}
        if len(hits) != 1:
            bad.append(f"{os.path.basename(j['mesh'])} primary{' shaded' if shaded else ''}: {sorted(hits)}")
    for kind in ("shadow", "ao"):
        o = r["occlusion"][kind]
        for c in o["casters"]:
            if c["caster"].startswith("embree") and c["same_as_embree_x1"] != o["rays"]:
                bad.append(f"{os.path.basename(j['mesh'])} {kind} {c['caster']}: "
                           f"{o['rays'] - c['same_as_embree_x1']} answers differ")
print("Embree modes agree exactly (primary hits, occlusion answers):",
      "yes" if not bad else "NO: " + "; ".join(bad))
print()

print("Cycles per primary ray (TSC ticks, single-threaded instrumented pass)\n")
print("| mesh | caster | LOD | ray generation | traversal | attributes | shading | total |")
print("|---|---|---|---|---|---|---|---|")
for j in runs:
    for p in j["runs"][0]["cycles_per_ray"]:
        lod = "-" if p["lod"] is None else f"{p['lod']:g}"
        print(f"| {os.path.basename(j['mesh'])} | {p['caster']} | {lod} | {p['ray_generation']:.0f} | "
              f"{p['traversal']:.0f} | {p['attributes']:.0f} | {p['shading']:.0f} | {p['total']:.0f} |")
PY
