#pragma once
// Voxelizer internals shared between the files of src/voxelize/ (not a public
// interface).
#include <cstdint>

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

}  // namespace voxcast::detail
