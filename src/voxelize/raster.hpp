#pragma once
// Per-triangle surface rasterization into an integer voxel grid (Hitchhiker's
// guide to voxels, "Voxelization"; Schwarz & Seidel 2010, sec. 3), shared by
// the whole-grid voxelizer (voxelize.cpp) and the cell-restricted one of the
// out-of-core DAG build (cell.cpp). Private to src/voxelize.
//
// raster_triangle_box() limits the triangle's voxel range to a box first;
// every loop bound after that is derived from that range and every voxel is
// decided by the same multiply-only predicates on the same doubles, so the
// output for a box is exactly the whole-grid output restricted to it. (The
// per-row column interval is settled from both ends; each edge predicate is
// monotone in the column index under round-to-nearest, so the passing set is
// an interval and settling a narrower range yields its intersection.)
#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "voxcast/morton.hpp"

namespace voxcast::detail::raster {

// 2-D edge function of one projected edge, evaluated at the minimum corner
// (p, q) of an integer cell: a*p + b*q + c >= 0 <=> the cell passes the edge.
// The critical-point offset is folded into c (guide: "Critical Points",
// d_max = n_e.p + max(n_ex dp,0) + max(n_ey dp,0) - n_e.v0, constant per edge).
struct EdgeEq {
  double a = 0, b = 0, c = 0;
};

// Edge equations of the projection along `axis`, 2-D coordinates
// p = (axis+1)%3, q = (axis+2)%3. `sign` orients the inward edge normals
// (sign of the triangle normal's `axis` component). Conservative: the
// critical point is the box corner furthest inside the edge; 6-separating
// (S&S sec. 3.2): the furthest point of the box's inscribed diamond, i.e. the
// center plus 1/2 max(|n_ex|, |n_ey|).
inline void edge_equations(const double v[3][3], int axis, double sign, bool six, EdgeEq out[3]) {
  const int p = (axis + 1) % 3, q = (axis + 2) % 3;
  for (int e = 0; e < 3; ++e) {
    const double* s = v[e];
    const double* t = v[e == 2 ? 0 : e + 1];
    double np = -(t[q] - s[q]) * sign;
    double nq = (t[p] - s[p]) * sign;
    double c = -(np * s[p] + nq * s[q]);
    if (six)
      c += 0.5 * (np + nq) + 0.5 * std::max(std::fabs(np), std::fabs(nq));
    else
      c += std::max(np, 0.0) + std::max(nq, 0.0);
    out[e] = {np, nq, c};
  }
}

// ceil/floor of a double clamped to a safe int range first (a huge quotient
// from a nearly degenerate edge must not overflow the conversion).
inline int ceil_clamped(double x, int lo, int hi) {
  return int(std::ceil(std::clamp(x, double(lo), double(hi))));
}
inline int floor_clamped(double x, int lo, int hi) {
  return int(std::floor(std::clamp(x, double(lo), double(hi))));
}

// A zero-area triangle (segment or point): the separating-axis test reduces to
// the voxel boxes overlapping the bounding box and, for each axis a_j, the box
// straddling the line along L_j = d x a_j (d = segment direction).
template <class Emit>
void raster_segment(const double v[3][3], const int lo[3], const int hi[3], Emit& emit) {
  // Endpoints: the farthest pair of the collinear vertices.
  int ia = 0, ib = 1;
  double best = -1;
  for (int s = 0; s < 3; ++s)
    for (int t = s + 1; t < 3; ++t) {
      double d2 = 0;
      for (int k = 0; k < 3; ++k) d2 += (v[t][k] - v[s][k]) * (v[t][k] - v[s][k]);
      if (d2 > best) best = d2, ia = s, ib = t;
    }
  if (!(best > 0)) {
    // A point: exactly the voxels of its bounding box (up to 8 on a corner).
    for (int z = lo[2]; z <= hi[2]; ++z)
      for (int y = lo[1]; y <= hi[1]; ++y)
        for (int x = lo[0]; x <= hi[0]; ++x) emit(morton_encode(x, y, z));
    return;
  }
  const double* P = v[ia];
  double d[3] = {v[ib][0] - P[0], v[ib][1] - P[1], v[ib][2] - P[2]};
  int w = 0;
  for (int a = 1; a < 3; ++a)
    if (std::fabs(d[a]) > std::fabs(d[w])) w = a;
  // L_j = d x a_j for j = x, y, z; the segment projects to the single value L_j.P.
  double L[3][3] = {{0, d[2], -d[1]}, {-d[2], 0, d[0]}, {d[1], -d[0], 0}};
  double lp[3], lmin[3], lmax[3];
  for (int j = 0; j < 3; ++j) {
    lp[j] = L[j][0] * P[0] + L[j][1] * P[1] + L[j][2] * P[2];
    lmin[j] = std::min(L[j][0], 0.0) + std::min(L[j][1], 0.0) + std::min(L[j][2], 0.0);
    lmax[j] = std::max(L[j][0], 0.0) + std::max(L[j][1], 0.0) + std::max(L[j][2], 0.0);
  }
  auto ok = [&](const int c[3]) {
    for (int j = 0; j < 3; ++j) {
      double base = (L[j][0] * c[0] + L[j][1] * c[1]) + L[j][2] * c[2];
      if (base + lmin[j] > lp[j] || base + lmax[j] < lp[j]) return false;
    }
    return true;
  };
  // Walk the slabs of the dominant axis of d: inside slab [k, k+1] the other
  // coordinates move by at most one voxel, so a few candidates per slab.
  const int u = (w + 1) % 3, vv = (w + 2) % 3;
  for (int k = lo[w]; k <= hi[w]; ++k) {
    double t0 = std::clamp((double(k) - P[w]) / d[w], 0.0, 1.0);
    double t1 = std::clamp((double(k) + 1.0 - P[w]) / d[w], 0.0, 1.0);
    double u0 = P[u] + d[u] * t0, u1 = P[u] + d[u] * t1;
    double v0 = P[vv] + d[vv] * t0, v1 = P[vv] + d[vv] * t1;
    int ilo = std::max(lo[u], floor_clamped(std::min(u0, u1), -4, 1 << 22) - 2);
    int ihi = std::min(hi[u], floor_clamped(std::max(u0, u1), -4, 1 << 22) + 1);
    int jlo = std::max(lo[vv], floor_clamped(std::min(v0, v1), -4, 1 << 22) - 2);
    int jhi = std::min(hi[vv], floor_clamped(std::max(v0, v1), -4, 1 << 22) + 1);
    for (int i = ilo; i <= ihi; ++i)
      for (int j = jlo; j <= jhi; ++j) {
        int c[3];
        c[w] = k, c[u] = i, c[vv] = j;
        if (ok(c)) emit(morton_encode(c[0], c[1], c[2]));
      }
  }
}

// Emits the Morton code of every voxel [i,i+1]^3 of the n^3 grid that the
// closed triangle `v` (grid units) overlaps (conservative), or its
// 6-separating subset. Conservative is exactly the 13-axis separating-axis
// test: bounding box (3 box axes), plane (triangle normal), and the 2-D edge
// tests of the three projections (the 9 edge x axis cross products; S&S
// sec. 3.1). Every candidate is decided by the multiply-only predicates; the
// divisions only bound the loops (with one cell of slack for rounding).
template <class Emit>
void raster_triangle_box(const double v[3][3], int n, bool six, const int box_lo[3],
                         const int box_hi[3], Emit&& emit) {
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    double mn = std::min({v[0][a], v[1][a], v[2][a]});
    double mx = std::max({v[0][a], v[1][a], v[2][a]});
    // Closed boxes: [i, i+1] meets [mn, mx] iff i <= mx and i + 1 >= mn;
    // narrowed to the cell (box_lo/box_hi lie inside [0, n-1]).
    lo[a] = std::max(box_lo[a], ceil_clamped(mn, -4, n + 4) - 1);
    hi[a] = std::min(box_hi[a], floor_clamped(mx, -4, n + 4));
    if (lo[a] > hi[a]) return;
  }

  const double e1[3] = {v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]};
  const double e2[3] = {v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]};
  double nrm[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
  if (nrm[0] == 0 && nrm[1] == 0 && nrm[2] == 0) {
    // Zero area: conservative segment/point voxelization in both modes (a
    // zero-area triangle separates nothing, so 6-separation needs no thinning).
    raster_segment(v, lo, hi, emit);
    return;
  }

  // Dominant axis w: the projection onto the other two axes (u, vv), taken in
  // cyclic order so that nrm[w] keeps its orientation, has the largest area.
  int w = 0;
  for (int a = 1; a < 3; ++a)
    if (std::fabs(nrm[a]) > std::fabs(nrm[w])) w = a;
  const int u = (w + 1) % 3, vv = (w + 2) % 3;

  EdgeEq dom[3], side_u[3], side_v[3];
  edge_equations(v, w, nrm[w] > 0 ? 1.0 : -1.0, six, dom);
  // A side projection with a zero normal component is a segment: its edge
  // tests degenerate to the plane test (the projected normal is the plane
  // normal), so they are left as always-true equations.
  if (nrm[u] != 0) edge_equations(v, u, nrm[u] > 0 ? 1.0 : -1.0, six, side_u);
  if (nrm[vv] != 0) edge_equations(v, vv, nrm[vv] > 0 ? 1.0 : -1.0, six, side_v);

  // Plane, oriented so that its w coefficient is positive.
  const double s = nrm[w] > 0 ? 1.0 : -1.0;
  const double nu = nrm[u] * s, nv = nrm[vv] * s, nw = nrm[w] * s;
  const double d0 = nu * v[0][u] + nv * v[0][vv] + nw * v[0][w];
  // Plane offsets over the column square [0,1]^2 in (u, vv): conservative
  // (guide, "Depth direction - conservative") uses the plane's min and max
  // over the whole box; 6-separating only the voxel's center line along w.
  double off_lo, off_hi;
  if (six) {
    off_lo = 0.5 * (nu + nv);
    off_hi = off_lo + nw;
  } else {
    off_lo = std::min(nu, 0.0) + std::min(nv, 0.0);
    off_hi = std::max(nu, 0.0) + std::max(nv, 0.0) + nw;
  }
  const double inv_nw = 1.0 / nw;

  // Morton codes are the OR of the per-axis deposits; precomputing the mask
  // of each of u, vv, w keeps the inner loop at one pdep per voxel.
  const uint64_t masks[3] = {kMortonMaskX, kMortonMaskY, kMortonMaskZ};
  const uint64_t mu = masks[u], mv = masks[vv], mw = masks[w];

  for (int i = lo[u]; i <= hi[u]; ++i) {
    // Column interval of this row from the dominant edge functions
    // (guide, "The edge function": half-intervals, combined).
    int jl = lo[vv], jh = hi[vv];
    double r[3];
    bool row_ok = true;
    for (int e = 0; e < 3; ++e) {
      r[e] = dom[e].a * i + dom[e].c;
      if (dom[e].b > 0)
        jl = std::max(jl, ceil_clamped(-r[e] / dom[e].b, -4, n + 4) - 1);
      else if (dom[e].b < 0)
        jh = std::min(jh, floor_clamped(-r[e] / dom[e].b, -4, n + 4) + 1);
      else if (r[e] < 0)
        row_ok = false;
    }
    if (!row_ok) continue;
    auto dom_ok = [&](int j) {
      return r[0] + dom[0].b * j >= 0 && r[1] + dom[1].b * j >= 0 && r[2] + dom[2].b * j >= 0;
    };
    // The slack cells are settled exactly, so the interval is exact.
    while (jl <= jh && !dom_ok(jl)) ++jl;
    while (jh >= jl && !dom_ok(jh)) --jh;

    // Side projection along vv (coordinates (w, u)): a*k + b*i + c.
    double sv_c[3], sv_k[3];
    for (int e = 0; e < 3; ++e) {
      sv_c[e] = side_v[e].b * i + side_v[e].c;
      sv_k[e] = side_v[e].a;
    }
    const uint64_t code_u = _pdep_u64(uint64_t(i), mu);
    const double hu = nu * i - d0;

    for (int j = jl; j <= jh; ++j) {
      // Side projection along u (coordinates (vv, w)): a*j + b*k + c.
      double su_c[3], su_k[3];
      for (int e = 0; e < 3; ++e) {
        su_c[e] = side_u[e].a * j + side_u[e].c;
        su_k[e] = side_u[e].b;
      }
      // Plane value at the column corner, without the w term.
      const double h = hu + nv * j;
      // nw*k + h + off_lo <= 0 <= nw*k + h + off_hi.
      int kl = std::max(lo[w], ceil_clamped(-(h + off_hi) * inv_nw, -4, n + 4) - 1);
      int kh = std::min(hi[w], floor_clamped(-(h + off_lo) * inv_nw, -4, n + 4) + 1);
      const uint64_t code_uv = code_u | _pdep_u64(uint64_t(j), mv);
      for (int k = kl; k <= kh; ++k) {
        const double pk = h + nw * k;
        bool ok = pk + off_lo <= 0 && pk + off_hi >= 0;
        for (int e = 0; e < 3; ++e) {
          ok &= su_c[e] + su_k[e] * k >= 0;
          ok &= sv_c[e] + sv_k[e] * k >= 0;
        }
        if (ok) emit(code_uv | _pdep_u64(uint64_t(k), mw));
      }
    }
  }
}

/// The whole grid: every voxel of the n^3 grid the triangle covers.
template <class Emit>
void raster_triangle(const double v[3][3], int n, bool six, Emit&& emit) {
  const int box_lo[3] = {0, 0, 0}, box_hi[3] = {n - 1, n - 1, n - 1};
  raster_triangle_box(v, n, six, box_lo, box_hi, emit);
}

}  // namespace voxcast::detail::raster
