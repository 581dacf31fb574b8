// ESVO ray caster: a CPU port of Laine & Karras 2010, Appendix A (§6.1), and
// the EsvoStructure adapter that maps world rays into octree space.
//
// Differences from the CUDA listing (all dictated by esvo.hpp):
//  * word 0 of our descriptor carries a LEAF mask in bits 7..0; the listing
//    wants a NON-LEAF mask there, so it is converted once per fetch
//    (non_leaf = valid & ~leaf) and the loop body stays as in the paper;
//  * pointers are slot indices into octree.words (two words per slot), far
//    pointers hold a signed slot offset relative to the referencing descriptor;
//  * t is clipped to [0, tmax] (the listing uses [0, 1]);
//  * PUSH stores the active t_max (Figure 15, line 19), not tc_max as the
//    transcribed listing does;
//  * the loop is scalar and branchy like the listing: on a CPU the ADVANCE
//    and PUSH branches are mostly predicted, which breaks the t -> compare ->
//    position dependency chain. (A branch-free SSE variant computing PUSH,
//    ADVANCE and POP every iteration and selecting was 1.7x slower, an SSE
//    variant with the listing's branches 15% slower, on the bunny at 2048^3.)
//  * no contours yet: word 1 is never read. The place where the contour
//    intersection narrows [t_min, tv_max] is marked below (§6.1 "INTERSECT").
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"

namespace voxcast::esvo {
namespace {

// min/max that compile to one minss/maxss: std::fmin/fmax must honour NaN
// operands and end up as libm calls that spill the loop's registers (they
// were ~10% of the caster in a profile). Inputs are checked finite up front.
inline float vmin(float a, float b) { return a < b ? a : b; }
inline float vmax(float a, float b) { return a > b ? a : b; }

inline uint32_t float_bits(float f) { return std::bit_cast<uint32_t>(f); }
inline float bits_float(uint32_t u) { return std::bit_cast<float>(u); }

// Converts our descriptor word 0 into the listing's layout: valid mask in
// bits 15..8, NON-leaf mask in bits 7..0, pointer/far bits unchanged.
inline uint32_t to_listing_layout(uint32_t w) {
  uint32_t non_leaf = (w >> 8) & ~w & 0xFFu;
  return (w & 0xFFFFFF00u) | non_leaf;
}

}  // namespace

CastResult cast_ray(const EsvoOctree& octree, Vec3 p, Vec3 d, float tmax, float size_coef,
                    float size_bias) {
  constexpr int s_max = kMaxScale;         // float mantissa bits
  constexpr float epsilon = 0x1p-23f;      // exp2f(-s_max)
  const uint32_t* const words = octree.words.data();

  CastResult result;
  result.hit = false;
  result.t = INFINITY;
  result.pos = {0, 0, 0};
  result.parent_slot = 0;
  result.child = 0;
  result.scale = s_max;
  // NaN/Inf would make the t arithmetic below meaningless (and the loop
  // might not terminate): such a ray hits nothing.
  if (!(is_finite(p) && is_finite(d))) return result;

  // Stack of parent voxels indexed by scale (Appendix A). Entry s holds the
  // parent descriptor of the cube at scale s and the active t_max there.
  uint32_t stack_parent[s_max + 1];
  float stack_tmax[s_max + 1];

  // Get rid of small direction components to avoid division by zero. The
  // sign of a zero component is kept (copysign), which picks the side a ray
  // lying exactly in a grid plane is considered to be on.
  if (std::fabs(d.x) < epsilon) d.x = std::copysign(epsilon, d.x);
  if (std::fabs(d.y) < epsilon) d.y = std::copysign(epsilon, d.y);
  if (std::fabs(d.z) < epsilon) d.z = std::copysign(epsilon, d.z);

  // t(x) = x * coef - bias for each axis, in the mirrored frame where every
  // direction component is negative (§6.1 "Alternate coordinate system").
  const float tx_coef = 1.0f / -std::fabs(d.x);
  const float ty_coef = 1.0f / -std::fabs(d.y);
  const float tz_coef = 1.0f / -std::fabs(d.z);
  float tx_bias = tx_coef * p.x;
  float ty_bias = ty_coef * p.y;
  float tz_bias = tz_coef * p.z;

  int octant_mask = 7;
  if (d.x > 0.0f) octant_mask ^= 1, tx_bias = 3.0f * tx_coef - tx_bias;
  if (d.y > 0.0f) octant_mask ^= 2, ty_bias = 3.0f * ty_coef - ty_bias;
  if (d.z > 0.0f) octant_mask ^= 4, tz_bias = 3.0f * tz_coef - tz_bias;

  // Each corner/center t below is one FMA: t = fma(x, coef, -bias).
  auto tx = [&](float x) { return std::fma(x, tx_coef, -tx_bias); };
  auto ty = [&](float y) { return std::fma(y, ty_coef, -ty_bias); };
  auto tz = [&](float z) { return std::fma(z, tz_coef, -tz_bias); };

  // Active t-span: the root cube [1,2]^3 clipped to [0, tmax].
  float t_min = vmax(vmax(tx(2.0f), ty(2.0f)), tz(2.0f));
  float t_max = vmin(vmin(tx(1.0f), ty(1.0f)), tz(1.0f));
  float h = t_max;
  t_min = vmax(t_min, 0.0f);
  t_max = vmin(t_max, tmax);

  // The t-span only shrinks during traversal, so a ray missing the root cube
  // (or starting past tmax) can stop here; the listing would step through the
  // root's children to find out.
  if (!(t_min <= t_max)) return result;

  uint32_t parent = octree.root_slot();
  uint32_t child_descriptor = 0;  // listing layout; 0 = not fetched
  int idx = 0;
  float pos_x = 1.0f, pos_y = 1.0f, pos_z = 1.0f;
  int scale = s_max - 1;
  float scale_exp2 = 0.5f;  // exp2f(scale - s_max)

  if (tx(1.5f) > t_min) idx ^= 1, pos_x = 1.5f;
  if (ty(1.5f) > t_min) idx ^= 2, pos_y = 1.5f;
  if (tz(1.5f) > t_min) idx ^= 4, pos_z = 1.5f;

  while (scale < s_max) {
    // Fetch the child descriptor unless the cached copy is valid (§6.1
    // "Caching the current child descriptor"): ADVANCE keeps the parent.
    if (child_descriptor == 0) child_descriptor = to_listing_layout(words[size_t(parent) * 2]);

    // Maximum t of the cube: the planes through its exit corner.
    const float tx_corner = tx(pos_x);
    const float ty_corner = ty(pos_y);
    const float tz_corner = tz(pos_z);
    const float tc_max = vmin(vmin(tx_corner, ty_corner), tz_corner);

    // Slot bits are permuted by the mirroring.
    const int child_shift = idx ^ octant_mask;
    const uint32_t child_masks = child_descriptor << child_shift;
    if ((child_masks & 0x8000u) != 0 && t_min <= t_max) {
      // LOD termination: the voxel is small enough for the ray's footprint.
      if (tc_max * size_coef + size_bias >= scale_exp2) [[unlikely]] break;  // at t_min

      // INTERSECT: active span vs cube, and the center t values that PUSH
      // reuses (§6.1 "Sharing computation between INTERSECT and PUSH").
      float tv_max = vmin(t_max, tc_max);
      const float half = scale_exp2 * 0.5f;
      const float tx_center = std::fma(half, tx_coef, tx_corner);
      const float ty_center = std::fma(half, ty_coef, ty_corner);
      const float tz_center = std::fma(half, tz_coef, tz_corner);

      // (Contours, §5.2/§6.1: when the contour bit of word 1 is set, t_min and
      // tv_max are narrowed by the slab here, using the center t values. Our
      // descriptors carry no contours yet.)

      if (t_min <= tv_max) {
        // A leaf (valid, not subdivided): hit at t_min.
        if ((child_masks & 0x0080u) == 0) [[unlikely]] break;

        // PUSH: save (parent, t_max), the active span end of this cube's
        // level, as in Figure 15 line 19 (the Appendix A transcription stores
        // tc_max there, which would cut the span of the cube's siblings after
        // a POP). The `h` threshold skips writes the stack already holds.
        if (tc_max < h) {
          stack_parent[scale] = parent;
          stack_tmax[scale] = t_max;
        }
        h = tc_max;

        uint32_t ofs = child_descriptor >> 17;  // child pointer, in slots
        int32_t rel = int32_t(ofs);
        if ((child_descriptor & 0x10000u) != 0) [[unlikely]] {  // far: slot holds the offset
          std::memcpy(&rel, &words[size_t(parent + ofs) * 2], sizeof rel);
        }
        rel += std::popcount(child_masks & 0x7Fu);
        parent = uint32_t(int32_t(parent) + rel);

        // Select the child the ray enters first.
        idx = 0;
        scale--;
        scale_exp2 = half;
        if (tx_center > t_min) idx ^= 1, pos_x += scale_exp2;
        if (ty_center > t_min) idx ^= 2, pos_y += scale_exp2;
        if (tz_center > t_min) idx ^= 4, pos_z += scale_exp2;

        t_max = tv_max;
        child_descriptor = 0;
        continue;
      }
    }

    // ADVANCE: step to the next sibling along the ray.
    int step_mask = 0;
    if (tx_corner <= tc_max) step_mask ^= 1, pos_x -= scale_exp2;
    if (ty_corner <= tc_max) step_mask ^= 2, pos_y -= scale_exp2;
    if (tz_corner <= tc_max) step_mask ^= 4, pos_z -= scale_exp2;

    t_min = tc_max;
    idx ^= step_mask;

    // The bit flips disagree with the (negative) ray direction: we left the
    // parent. POP to the highest level whose cube still contains pos.
    if ((idx & step_mask) != 0) {
      // Highest differing bit between the old and new positions = new scale.
      uint32_t differing_bits = 0;
      if ((step_mask & 1) != 0) differing_bits |= float_bits(pos_x) ^ float_bits(pos_x + scale_exp2);
      if ((step_mask & 2) != 0) differing_bits |= float_bits(pos_y) ^ float_bits(pos_y + scale_exp2);
      if ((step_mask & 4) != 0) differing_bits |= float_bits(pos_z) ^ float_bits(pos_z + scale_exp2);
      scale = std::bit_width(differing_bits) - 1;
      if (scale >= s_max) [[unlikely]] break;  // left the root cube
      scale_exp2 = bits_float(uint32_t(scale - s_max + 127) << 23);

      parent = stack_parent[scale];
      t_max = stack_tmax[scale];

      // Round the position down to the cube at the new scale; its slot index
      // is the bit just below.
      const uint32_t shx = float_bits(pos_x) >> scale;
      const uint32_t shy = float_bits(pos_y) >> scale;
      const uint32_t shz = float_bits(pos_z) >> scale;
      pos_x = bits_float(shx << scale);
      pos_y = bits_float(shy << scale);
      pos_z = bits_float(shz << scale);
      idx = int((shx & 1) | ((shy & 1) << 1) | ((shz & 1) << 2));

      // Prevent the same parent from being stored again; refetch descriptor.
      h = 0.0f;
      child_descriptor = 0;
    }
  }

  if (scale >= s_max) return result;  // outside the octree: miss

  // Undo the mirroring: the cube [x, x+s] mirrored is [3-s-x, 3-x] (exact).
  if ((octant_mask & 1) == 0) pos_x = 3.0f - scale_exp2 - pos_x;
  if ((octant_mask & 2) == 0) pos_y = 3.0f - scale_exp2 - pos_y;
  if ((octant_mask & 4) == 0) pos_z = 3.0f - scale_exp2 - pos_z;

  result.hit = true;
  result.t = t_min;
  // p + t d can leave the cube by rounding (§6.1 "Hit position"): clamp.
  result.pos = {pos_x, pos_y, pos_z};
  result.parent_slot = parent;
  result.child = idx ^ octant_mask ^ 7;
  result.scale = scale;
  return result;
}

// ---------------------------------------------------------------------------

EsvoStructure::EsvoStructure(std::shared_ptr<const EsvoOctree> octree) : octree_(std::move(octree)) {
  if (!octree_) throw Error("EsvoStructure: no octree");
  if (octree_->words.size() < 4) throw Error("EsvoStructure: empty octree");
  if (!(octree_->grid.side() > 0)) throw Error("EsvoStructure: octree has a non-positive side");
}

Aabb EsvoStructure::bounds() const {
  const GridTransform& g = octree_->grid;
  const float side = float(g.side());
  return {g.origin, g.origin + Vec3{side, side, side}};
}

bool EsvoStructure::trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const {
  const GridTransform& g = octree_->grid;
  const float side = float(g.side());
  const float inv_side = float(1.0 / g.side());
  // Octree space: p' = (p - origin)/side + 1, d' = d/side, so t stays the
  // world distance along the unit world direction.
  const Vec3 p = (ray.origin - g.origin) * inv_side + Vec3{1, 1, 1};
  const Vec3 d = ray.dir * inv_side;
  const CastResult r =
      cast_ray(*octree_, p, d, ray.tmax, lod.size_per_t * inv_side, lod.size_at_origin * inv_side);
  if (!r.hit) return false;
  const float cube = bits_float(uint32_t(r.scale - kMaxScale + 127) << 23);  // 2^(scale-23), octree units
  // Hit point p + t d, clamped into the hit cube (§6.1 "Hit position").
  const float eps = 0x1p-23f;
  Vec3 q = p + d * r.t;
  q.x = vmin(vmax(q.x, r.pos.x + eps), r.pos.x + cube - eps);
  q.y = vmin(vmax(q.y, r.pos.y + eps), r.pos.y + cube - eps);
  q.z = vmin(vmax(q.z, r.pos.z + eps), r.pos.z + cube - eps);
  hit->t = r.t;
  hit->position = g.origin + (q - Vec3{1, 1, 1}) * side;
  hit->voxel_size = cube * side;
  hit->voxel_ref = r.parent_slot;
  hit->child = uint32_t(r.child);
  hit->level = kMaxScale - r.scale;  // root cube is scale kMaxScale, level 0
  return true;
}

void EsvoStructure::attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const {
  octree_->attributes(uint32_t(hit.voxel_ref), int(hit.child), color, normal);
}

}  // namespace voxcast::esvo
