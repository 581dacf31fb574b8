#pragma once
// Ray set-up of the octree-family caster (core/octree_caster.hpp; ESVO
// octree, sparse voxel DAG): the structure occupies [1,2]^3 (OctreeFrame maps
// world space there) and the coordinate system is mirrored so that every
// direction component is negative (esvo §6.1 "Alternate coordinate system",
// Appendix A).
#include <bit>
#include <cmath>
#include <cstdint>

#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::detail {

/// s_max of Appendix A (float mantissa bits): the root cube [1,2]^3 has scale
/// 23, a cube at scale s has side 2^(s - 23) (esvo::kMaxScale).
inline constexpr int kOctreeMaxScale = 23;

// min/max that compile to one minss/maxss: std::fmin/fmax must honour NaN
// operands and end up as libm calls that spill the loop's registers (they
// were ~10% of the caster in a profile). Callers check inputs are finite.
inline float vmin(float a, float b) {
  return a < b ? a : b;
}
inline float vmax(float a, float b) {
  return a > b ? a : b;
}
inline uint32_t float_bits(float f) {
  return std::bit_cast<uint32_t>(f);
}
inline float bits_float(uint32_t u) {
  return std::bit_cast<float>(u);
}

/// Replaces direction components smaller than 2^-23 by ±2^-23 (Appendix A) to
/// avoid division by zero. The sign of a zero is kept (copysign), which picks
/// the side a ray lying exactly in a grid plane is considered to be on.
/// The threshold is relative to the largest component: octree-space
/// directions have length 1/side (OctreeFrame), and an absolute 2^-23 would
/// tilt an axis-parallel ray of a large scene by up to 2^-23 * side radians
/// (a wrong voxel on a 151-unit mesh; DagOracle.WorldScaleDoesNotTiltAxisRays).
/// Relative, the tilt stays below 2^-23 rad at every scale.
inline Vec3 avoid_tiny_components(Vec3 d) {
  const float largest = std::fmax(std::fabs(d.x), std::fmax(std::fabs(d.y), std::fabs(d.z)));
  float epsilon = 0x1p-23f * largest;
  // A zero (or denormal-tiny) direction keeps the listing's absolute epsilon.
  if (!(epsilon >= 0x1p-126f)) epsilon = 0x1p-23f;
  if (std::fabs(d.x) < epsilon) d.x = std::copysign(epsilon, d.x);
  if (std::fabs(d.y) < epsilon) d.y = std::copysign(epsilon, d.y);
  if (std::fabs(d.z) < epsilon) d.z = std::copysign(epsilon, d.z);
  return d;
}

/// t(x) = x * coef - bias per axis in the mirrored frame; `octant_mask` has
/// bit a clear where axis a was mirrored (direction component > 0).
struct MirroredRay {
  float tx_coef, ty_coef, tz_coef;
  float tx_bias, ty_bias, tz_bias;
  int octant_mask;

  /// `p`, `d` in octree space; `d` already passed through avoid_tiny_components.
  MirroredRay(Vec3 p, Vec3 d)
      : tx_coef(1.0f / -std::fabs(d.x)),
        ty_coef(1.0f / -std::fabs(d.y)),
        tz_coef(1.0f / -std::fabs(d.z)),
        tx_bias(tx_coef * p.x),
        ty_bias(ty_coef * p.y),
        tz_bias(tz_coef * p.z),
        octant_mask(7) {
    if (d.x > 0.0f) octant_mask ^= 1, tx_bias = 3.0f * tx_coef - tx_bias;
    if (d.y > 0.0f) octant_mask ^= 2, ty_bias = 3.0f * ty_coef - ty_bias;
    if (d.z > 0.0f) octant_mask ^= 4, tz_bias = 3.0f * tz_coef - tz_bias;
  }
  // Each corner/center t is one FMA.
  float tx(float x) const { return std::fma(x, tx_coef, -tx_bias); }
  float ty(float y) const { return std::fma(y, ty_coef, -ty_bias); }
  float tz(float z) const { return std::fma(z, tz_coef, -tz_bias); }

  /// Beam optimization (esvo §6.2): narrows the active span [t_min, t_max] to
  /// the entry and exit planes of `region` (octree space). In the mirrored
  /// frame the entry corner of [lo, hi] is hi on an unmirrored axis and
  /// 3 - lo on a mirrored one (exact for dyadic coordinates in [1, 2]).
  /// Why this keeps the hits bit-identical: detail::cast_octree.
  void clip_to_region(const Aabb& region, float* t_min, float* t_max) const {
    const bool mx = (octant_mask & 1) == 0, my = (octant_mask & 2) == 0,
               mz = (octant_mask & 4) == 0;
    const float in_x = mx ? 3.0f - region.lo.x : region.hi.x;
    const float in_y = my ? 3.0f - region.lo.y : region.hi.y;
    const float in_z = mz ? 3.0f - region.lo.z : region.hi.z;
    const float out_x = mx ? 3.0f - region.hi.x : region.lo.x;
    const float out_y = my ? 3.0f - region.hi.y : region.lo.y;
    const float out_z = mz ? 3.0f - region.hi.z : region.lo.z;
    *t_min = vmax(*t_min, vmax(vmax(tx(in_x), ty(in_y)), tz(in_z)));
    *t_max = vmin(*t_max, vmin(vmin(tx(out_x), ty(out_y)), tz(out_z)));
  }
};

/// World <-> octree space of a structure on `grid` (esvo §6.1): the grid's
/// cube maps to [1,2]^3, p' = (p - origin)/side + 1, d' = d/side, so t stays
/// the world distance along a unit world direction. The one place this
/// mapping is written: the casters and the beam pass must agree on every float.
struct OctreeFrame {
  explicit OctreeFrame(const GridTransform& grid)
      : origin(grid.origin), side(float(grid.side())), inv_side(float(1.0 / grid.side())) {}

  Vec3 point(Vec3 p) const { return (p - origin) * inv_side + Vec3{1, 1, 1}; }
  Vec3 direction(Vec3 d) const { return d * inv_side; }
  /// A world length (LOD footprint terms) in octree units.
  float length(float l) const { return l * inv_side; }
  /// World bounds of the root cube.
  Aabb bounds() const { return {origin, origin + Vec3{side, side, side}}; }

  /// Fills the geometric part of *hit (t, position, voxel_size, level) from a
  /// cast of the octree-space ray p + t d that hit the cube at `pos` (min
  /// corner) of side 2^(scale - 23).
  void hit_to_world(Vec3 p, Vec3 d, float t, Vec3 pos, int scale, SurfaceHit* hit) const {
    const float cube = bits_float(uint32_t(scale - kOctreeMaxScale + 127) << 23);
    // p + t d can leave the cube by rounding (§6.1 "Hit position"): clamp.
    const float eps = 0x1p-23f;
    Vec3 q = p + d * t;
    q.x = vmin(vmax(q.x, pos.x + eps), pos.x + cube - eps);
    q.y = vmin(vmax(q.y, pos.y + eps), pos.y + cube - eps);
    q.z = vmin(vmax(q.z, pos.z + eps), pos.z + cube - eps);
    hit->t = t;
    hit->position = origin + (q - Vec3{1, 1, 1}) * side;
    hit->voxel_size = cube * side;
    hit->level = kOctreeMaxScale - scale;  // root cube is scale 23, level 0
  }

  Vec3 origin;
  float side, inv_side;
};

}  // namespace voxcast::detail
