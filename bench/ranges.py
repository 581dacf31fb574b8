#!/usr/bin/env python3
"""Prints the ranges that docs/BENCHMARKS.md states in prose, computed from the
tables beside them, so that no range is typed by hand.

Usage: bench/ranges.py [docs/BENCHMARKS.md]

Each table is found by the first cells of its header row; a quantity is a
function of one table row; the range is min-max over the rows.
"""
import re
import sys


def tables(text):
    """Every Markdown table as (header cells, list of row dicts)."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        if lines[i].startswith("|") and i + 1 < len(lines) and re.match(r"^\|[-:| ]+\|$", lines[i + 1]):
            head = [c.strip() for c in lines[i].strip("|").split("|")]
            rows, i = [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                cells = [c.strip() for c in lines[i].strip("|").split("|")]
                rows.append(dict(zip(head, cells)))
                i += 1
            out.append((head, rows))
        else:
            i += 1
    return out


def num(cell):
    """The first number in a cell ("10.46", "99.738 %", "1,501.43")."""
    m = re.search(r"-?[0-9][0-9,]*\.?[0-9]*", cell)
    if not m:
        raise ValueError(f"no number in {cell!r}")
    return float(m.group(0).replace(",", ""))


def find(all_tables, *first_cells):
    for head, rows in all_tables:
        if head[: len(first_cells)] == list(first_cells):
            return rows
    raise SystemExit(f"table with header {first_cells} not found")


def span(values, digits=2):
    return f"{min(values):.{digits}f}–{max(values):.{digits}f}"


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else "docs/BENCHMARKS.md"
    t = tables(open(path, encoding="utf-8").read())

    rows = find(t, "mesh", "triangles", "leaf voxels")
    print("Primary rays (bench/shared_meshes.sh):")
    print("  ratio (best voxcast / Embree x8):", span([num(r["ratio"]) for r in rows], 3))
    print("  best voxcast / Embree x1:",
          span([max(num(r["voxcast Mrays/s"]), num(r["voxcast+beam8"])) / num(r["Embree x1"]) for r in rows]))
    print("  voxcast+beam8 / voxcast:", span([num(r["voxcast+beam8"]) / num(r["voxcast Mrays/s"]) for r in rows]))
    print("  depth <= 2 diag (LOD 1):", span([num(r["depth ≤ 2 diag"]) for r in rows], 1), "%")

    rows = find(t, "mesh", "image", "coverage", "cubes")
    print("Table 4 shape (bench/table4.sh):")
    print("  contours / cubes:", span([num(r["contours"]) / num(r["cubes"]) for r in rows]))
    print("  contours+beam / cubes:", span([num(r["contours+beam"]) / num(r["cubes"]) for r in rows]))
    print("  contours+beam / best Embree:", span([num(r["contours+beam / Embree best"]) for r in rows], 3))
    print("  contours+beam / Embree x1:", span([num(r["contours+beam"]) / num(r["Embree x1"]) for r in rows]))

    for first in ("per ray", "DAG, per ray"):
        rows = find(t, first, "off")
        it = [r for r in rows if r[first] == "iterations"][0]
        print(f"Beam counters ({first!r}): iterations",
              ", ".join(f"{k} {100 * (num(it[k]) / num(it['off']) - 1):+.0f} %" for k in ("`--beam 8`", "`--beam 4`")))

    rows = find(t, "ESVO", "ESVO + beam 8", "DAG")
    r = rows[0]
    print("DAG vs ESVO primary rays: DAG slower by",
          span([100 * (1 - num(r["DAG"]) / num(r["ESVO"])),
                100 * (1 - num(r["DAG + beam 8"]) / num(r["ESVO + beam 8"]))], 0), "%;",
          "best DAG / best Embree", f"{max(num(r['DAG']), num(r['DAG + beam 8'])) / max(num(r['Embree x1']), num(r['Embree x8'])):.2f}")

    rows = find(t, "rays", "ESVO", "DAG")
    print("Shadow/AO best voxel / Embree:",
          span([max(num(r["ESVO"]), num(r["DAG"])) / num(r["Embree rtcOccluded1"]) for r in rows]))

    rows = [r for r in find(t, "mesh", "resolution", "voxels", "DAG nodes") if r["mesh"] == "bunny"]
    by_res = {int(num(r["resolution"])): r for r in rows}
    print("DAG at scale, bunny DAG / pointer-less SVO:",
          ", ".join(f"{n}^3 {num(by_res[n]['DAG MB']) / num(by_res[n]['SVO MB']):.2f}" for n in (16384, 32768)
                    if n in by_res))
    ress = sorted(by_res)
    steps = [num(by_res[b]["bits/voxel"]) / num(by_res[a]["bits/voxel"]) for a, b in zip(ress, ress[1:]) if b == 2 * a]
    print("  bunny bits/voxel factor per resolution doubling (4096^3 up):", span(steps))
    rows = find(t, "terrain", "triangles", "resolution")
    tr = [r for r in rows if r["terrain"].startswith("32²")]
    if len(tr) == 2:
        print("  32² terrain bits/voxel factor 16384^3 -> 32768^3:",
              f"{num(tr[1]['bits/voxel']) / num(tr[0]['bits/voxel']):.2f}")


if __name__ == "__main__":
    main()
