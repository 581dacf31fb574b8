// Box filtering of the surface (the attribute filter of the voxelizer): the
// part of a triangle inside one voxel, its area and centroid. Per-voxel
// averaging lives in voxelize.cpp.
#include <algorithm>
#include <cmath>

#include "voxelize/internal.hpp"

namespace voxcast::detail {

namespace {

struct P2 {
  double u, v;
};

// A triangle clipped by six planes has at most 9 vertices in exact arithmetic;
// the headroom (and the guard in clip) covers sign flips from rounding.
constexpr int kMaxPoly = 24;

// One Sutherland-Hodgman step in the dominant plane: keeps the part of the
// convex polygon `in` where a*u + b*v + c >= 0. The closed half-plane keeps
// contacts of zero measure (a triangle touching the voxel).
int clip(const P2* in, int n, P2* out, double a, double b, double c) {
  int m = 0;
  double dp = a * in[0].u + b * in[0].v + c;
  for (int i = 0; i < n; ++i) {
    const P2& p = in[i];
    const P2& q = in[i + 1 == n ? 0 : i + 1];
    const double dq = a * q.u + b * q.v + c;
    if (dp >= 0 && m < kMaxPoly) out[m++] = p;
    if ((dp >= 0) != (dq >= 0) && m < kMaxPoly) {
      const double t = dp / (dp - dq);
      out[m++] = {p.u + (q.u - p.u) * t, p.v + (q.v - p.v) * t};
    }
    dp = dq;
  }
  return m;
}

}  // namespace

// All six clips happen in the projection onto the dominant plane (u, v): the
// four side planes are axis lines there, and the two planes w = z, w = z+1
// are the lines where the triangle's plane reaches those depths. Two
// coordinates instead of three per vertex, and the projected area converts
// back exactly: area = area_uv * |n| / |n_w|.
VoxelClip clip_triangle_to_voxel(const double tri[3][3], uint32_t x, uint32_t y, uint32_t z) {
  const double e1[3] = {tri[1][0] - tri[0][0], tri[1][1] - tri[0][1], tri[1][2] - tri[0][2]};
  const double e2[3] = {tri[2][0] - tri[0][0], tri[2][1] - tri[0][1], tri[2][2] - tri[0][2]};
  const double nrm[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                         e1[0] * e2[1] - e1[1] * e2[0]};
  VoxelClip r;
  if (nrm[0] == 0 && nrm[1] == 0 && nrm[2] == 0) {
    // Degenerate triangle: no area, no barycentric frame; its centroid.
    r.bary_u = r.bary_v = 1.0f / 3.0f;
    return r;
  }
  int w = 0;
  for (int a = 1; a < 3; ++a)
    if (std::fabs(nrm[a]) > std::fabs(nrm[w])) w = a;
  const int u = (w + 1) % 3, v = (w + 2) % 3;  // cyclic: signed uv area ~ n_w
  const double lo[3] = {double(x), double(y), double(z)};

  P2 buf[2][kMaxPoly];
  int n = 3, cur = 0;
  for (int k = 0; k < 3; ++k) buf[0][k] = {tri[k][u], tri[k][v]};
  auto apply = [&](double a, double b, double c) {
    n = clip(buf[cur], n, buf[cur ^ 1], a, b, c);
    cur ^= 1;
  };
  // Only the planes the triangle crosses cost anything.
  auto range = [&](int a, double& mn, double& mx) {
    mn = std::min({tri[0][a], tri[1][a], tri[2][a]});
    mx = std::max({tri[0][a], tri[1][a], tri[2][a]});
  };
  double mn, mx;
  range(u, mn, mx);
  if (mn < lo[u]) apply(1, 0, -lo[u]);
  if (mx > lo[u] + 1 && n > 0) apply(-1, 0, lo[u] + 1);
  range(v, mn, mx);
  if (mn < lo[v] && n > 0) apply(0, 1, -lo[v]);
  if (mx > lo[v] + 1 && n > 0) apply(0, -1, lo[v] + 1);
  range(w, mn, mx);
  if ((mn < lo[w] || mx > lo[w] + 1) && n > 0) {
    // Depth of the plane over (u, v): w = ka*u + kb*v + kc.
    const double ka = -nrm[u] / nrm[w], kb = -nrm[v] / nrm[w];
    const double kc = tri[0][w] - ka * tri[0][u] - kb * tri[0][v];
    if (mn < lo[w]) apply(ka, kb, kc - lo[w]);
    if (mx > lo[w] + 1 && n > 0) apply(-ka, -kb, lo[w] + 1 - kc);
  }

  const P2* poly = buf[cur];
  double cu = 0, cv = 0, area2 = 0;  // area2: twice the signed uv area
  const double sgn = nrm[w] > 0 ? 1.0 : -1.0;
  for (int k = 1; k + 1 < n; ++k) {
    const double au = poly[k].u - poly[0].u, av = poly[k].v - poly[0].v;
    const double bu = poly[k + 1].u - poly[0].u, bv = poly[k + 1].v - poly[0].v;
    const double s = (au * bv - av * bu) * sgn;
    if (s <= 0) continue;
    area2 += s;
    cu += s * (poly[0].u + poly[k].u + poly[k + 1].u);
    cv += s * (poly[0].v + poly[k].v + poly[k + 1].v);
  }
  if (area2 > 0) {
    cu /= 3.0 * area2;
    cv /= 3.0 * area2;
    const double len = std::sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
    r.area = 0.5 * area2 * len / std::fabs(nrm[w]);
  } else if (n > 0) {
    // Touching only (a point or a segment in a voxel face): the contact's mean.
    for (int k = 0; k < n; ++k) cu += poly[k].u, cv += poly[k].v;
    cu /= n;
    cv /= n;
  } else {
    // Clipping lost a contact of zero measure to rounding: the closest we have
    // is the triangle's centroid.
    cu = (tri[0][u] + tri[1][u] + tri[2][u]) / 3.0;
    cv = (tri[0][v] + tri[1][v] + tri[2][v]) / 3.0;
  }
  // Barycentrics of the centroid from the projected triangle, whose signed
  // area is n_w / 2 (non-zero: w is the dominant axis).
  const double du = cu - tri[0][u], dv = cv - tri[0][v];
  double bu = (du * e2[v] - dv * e2[u]) / nrm[w];
  double bv = (e1[u] * dv - e1[v] * du) / nrm[w];
  // Rounding can put the centroid of a sliver a hair outside the triangle.
  bu = std::clamp(bu, 0.0, 1.0);
  bv = std::clamp(bv, 0.0, 1.0);
  if (bu + bv > 1.0) {
    const double s = bu + bv;
    bu /= s;
    bv /= s;
  }
  r.bary_u = float(bu);
  r.bary_v = float(bv);
  return r;
}

}  // namespace voxcast::detail
