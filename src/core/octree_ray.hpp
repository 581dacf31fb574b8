#pragma once
// Ray set-up shared by the casters of the octree family (ESVO octree, sparse
// voxel DAG): the structure occupies [1,2]^3 and the coordinate system is
// mirrored so that every direction component is negative (esvo §6.1
// "Alternate coordinate system", Appendix A). Sharing it keeps the DAG's hits
// bit-identical to the octree's: both evaluate the same floats the same way.
#include <bit>
#include <cmath>
#include <cstdint>

#include "voxcast/math.hpp"

namespace voxcast::detail {

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
inline Vec3 avoid_tiny_components(Vec3 d) {
  constexpr float epsilon = 0x1p-23f;
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
  /// Why this keeps the hits bit-identical: src/esvo/traverse.cpp.
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

}  // namespace voxcast::detail
