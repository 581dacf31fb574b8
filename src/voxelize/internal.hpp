#pragma once
// Voxelizer internals shared between the files of src/voxelize/ (not a public
// interface).
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "voxcast/mesh.hpp"

namespace voxcast::detail {

/// Part of one triangle inside one voxel (box filter of the surface, used for
/// the voxel's attributes).
struct VoxelClip {
  double area = 0;   // clipped polygon area, voxel units^2 (0: touches only)
  float bary_u = 0;  // barycentrics of the clipped polygon's centroid
  float bary_v = 0;  // (weights of vertex 1 and vertex 2)
};

// Touch-only pairs (the triangle meets the voxel in a point or segment) get
// this area so that every voxel has defined attributes; it is far below any
// real contribution, so weights still sum to the surface area (1e-9 voxel^2
// per touching pair).
inline constexpr double kTouchWeight = 1e-9;

/// Clips triangle `tri` (grid units) to the voxel box [x,x+1]x[y,y+1]x[z,z+1]
/// with Sutherland-Hodgman against its six planes, in double.
VoxelClip clip_triangle_to_voxel(const double tri[3][3], uint32_t x, uint32_t y, uint32_t z);

/// Box filter of one voxel's attributes (area-weighted means over the
/// triangles touching it): each triangle is clipped to the voxel, its clipped
/// area weights the surface color and shading normal at the clipped centroid.
/// Triangles are visited in the order given (ascending index) so that the sums
/// are the same whatever produced the list. If the normals cancel (opposite
/// sheets of a thin wall in one voxel) the face normal of the largest
/// contribution is used. `tri_verts(t, v)` gives triangle t in grid units;
/// `tri_at(k)` the k-th triangle of the voxel, k in [0, count).
template <class TriVerts, class TriAt>
void box_filter_voxel(const Mesh& mesh, const TriVerts& tri_verts, uint32_t x, uint32_t y,
                      uint32_t z, size_t count, const TriAt& tri_at, Color* color, Vec3* normal,
                      float* weight) {
  double wsum = 0, col[4] = {0, 0, 0, 0}, nsum[3] = {0, 0, 0};
  double best_w = -1;
  uint32_t best_tri = 0;
  for (size_t k = 0; k < count; ++k) {
    const uint32_t t = tri_at(k);
    double tri[3][3];
    tri_verts(t, tri);
    const VoxelClip clip = clip_triangle_to_voxel(tri, x, y, z);
    const double wgt = std::max(clip.area, kTouchWeight);
    const Color c = mesh.surface_color(t, clip.bary_u, clip.bary_v);
    const Vec3 nm = mesh.surface_normal(t, clip.bary_u, clip.bary_v);
    wsum += wgt;
    col[0] += wgt * c.r, col[1] += wgt * c.g, col[2] += wgt * c.b, col[3] += wgt * c.a;
    nsum[0] += wgt * nm.x, nsum[1] += wgt * nm.y, nsum[2] += wgt * nm.z;
    if (wgt > best_w) best_w = wgt, best_tri = t;
  }
  *color = {float(col[0] / wsum), float(col[1] / wsum), float(col[2] / wsum),
            float(col[3] / wsum)};
  const double len = std::sqrt(nsum[0] * nsum[0] + nsum[1] * nsum[1] + nsum[2] * nsum[2]);
  if (len > 1e-6 * wsum) {
    *normal = {float(nsum[0] / len), float(nsum[1] / len), float(nsum[2] / len)};
  } else {
    double tri[3][3];
    tri_verts(best_tri, tri);
    double a[3], b[3];
    for (int k = 0; k < 3; ++k) a[k] = tri[1][k] - tri[0][k], b[k] = tri[2][k] - tri[0][k];
    const double fn[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                          a[0] * b[1] - a[1] * b[0]};
    const double fl = std::sqrt(fn[0] * fn[0] + fn[1] * fn[1] + fn[2] * fn[2]);
    *normal = fl > 0 ? Vec3{float(fn[0] / fl), float(fn[1] / fl), float(fn[2] / fl)}
                     : Vec3{0, 0, 1};
  }
  *weight = float(wsum);
}

}  // namespace voxcast::detail
