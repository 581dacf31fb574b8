#pragma once
// The attribute reduction of one octree node (§7.1: every level is a
// box-filtered LOD of the one below), shared by the in-core bottom-up
// builder (builder.cpp) and the top-down slice builder (slice_build.cpp),
// which must produce the same floats. Private to src/esvo.
#include <cmath>
#include <cstdint>

#include "voxcast/esvo.hpp"
#include "voxcast/math.hpp"

namespace voxcast::esvo::detail {

// Without input attributes every voxel gets this (documented in esvo.hpp):
// linear mid gray, normal +z, weight 1.
inline constexpr Color kDefaultColor{0.5f, 0.5f, 0.5f, 1.f};
inline constexpr Vec3 kDefaultNormal{0.f, 0.f, 1.f};

/// A node's raw value as the builders' trees hold it: the sRGB color code in
/// the low word, the cube-mapped normal code in the high word.
inline uint64_t encode_value(const Color& c, Vec3 n) {
  return uint64_t(encode_color_abgr(c)) | uint64_t(encode_normal_cube(n)) << 32;
}

/// Area-weighted average of a node's k children (in slot order). Colors
/// average linearly; normals are the normalized weighted sum; weights add up.
inline void reduce_node(const Color* cc, const Vec3* cn, const float* cw, int k, Color* color,
                        Vec3* normal, float* weight) {
  double w = 0, r4[4] = {0, 0, 0, 0}, u4[4] = {0, 0, 0, 0};
  double nx = 0, ny = 0, nz = 0;
  for (int j = 0; j < k; ++j) {
    const Color& c = cc[j];
    const double wj = cw[j];
    w += wj;
    r4[0] += wj * c.r, r4[1] += wj * c.g, r4[2] += wj * c.b, r4[3] += wj * c.a;
    u4[0] += c.r, u4[1] += c.g, u4[2] += c.b, u4[3] += c.a;
    nx += wj * cn[j].x, ny += wj * cn[j].y, nz += wj * cn[j].z;
  }
  // Zero total weight (degenerate input) falls back to the plain mean.
  const double* s = w > 0 ? r4 : u4;
  const double inv = w > 0 ? 1.0 / w : 1.0 / k;
  *color = {float(s[0] * inv), float(s[1] * inv), float(s[2] * inv), float(s[3] * inv)};
  const double len = std::sqrt(nx * nx + ny * ny + nz * nz);
  // Opposite normals can cancel exactly; keep the first child's normal then.
  *normal = len > 1e-12 ? Vec3{float(nx / len), float(ny / len), float(nz / len)} : cn[0];
  *weight = float(w);
}

}  // namespace voxcast::esvo::detail
