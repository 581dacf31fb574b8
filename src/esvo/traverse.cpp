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
//  * contours (§5.2, §6.1 INTERSECT): word 1 is fetched with word 0; when the
//    voxel's contour bit is set, [t_min, tv_max] is narrowed by the slab as
//    in the listing, from the center t values. Fields are masked exactly
//    and scaled as documented at esvo::ContourValue (the listing converts
//    the unmasked shifted int). Since PUSH carries the narrowed span down and
//    POP restores it, a voxel's shape is its cube ∩ all ancestor slabs (§5.3).
//  * the loop is a template over kCount: the profiling counters of §8.5 /
//    Table 6 are compiled in only for the counting instantiation, so the
//    plain cast_ray has no extra instructions.
//  * an optional start region (beam optimization, §6.2): the active t-span
//    starts at the ray's entry into a box known to contain every voxel the
//    ray can hit and ends at its exit, instead of the root cube's. See
//    "Why a start region gives bit-identical hits" below.
//
// Why a start region gives bit-identical hits. Every t the loop compares or
// returns is a rounded plane crossing t(c) = fma(c, coef, -bias) for a grid
// plane coordinate c (dyadic, exact, and independent of the level that
// produced it: a plane is the same float whether it is a corner of a big cube
// or of a small one), or the start/end of the span. fma rounds the exact
// value, so t(c) is monotone in c. Descent ("center t > t_min": the plane
// is not crossed yet) and ADVANCE ("corner t <= tc_max": crossed) use the same
// tie rule, so at any t the loop places the ray in the cell whose crossed
// planes are exactly those with t(c) <= t. Hence a voxel V is hit-able iff its
// span [max(start, t of V's entry planes), min(end, t of V's exit planes)] is
// non-empty, the loop returns the first hit-able voxel along the ray (a
// parent's span contains its children's) and reports the left end of its span.
// Moving the start from the root entry to the entry planes of a box R that
// contains the first hit voxel V: R's entry planes are at or before V's, so
// by monotonicity start' <= t of V's entry planes and V keeps its exact span
// and its t; every other voxel's span only shrinks, so none becomes hit-able
// before V, and a ray that missed still misses. The same holds for ending the
// span at R's exit (V lies inside R). Mirrored coordinates 3 - c are exact
// for c in [1, 2], so R's planes are grid planes like any other.
// Caveat: PUSH computes a child's center t as fma(half, coef, t(corner)), not
// as t(center) itself; the two can differ by about an ulp of t(corner), so
// when t_min lies within that ulp of a center plane the descent may pick the
// neighbouring child. That choice compares against t_min, which the region
// can change, so for such near-ties the argument above is not a proof. The
// beam tests (every shared mesh, three cameras, random cameras inside and
// outside the scene, ESVO and DAG) have not found a differing hit.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "core/beam_frustum.hpp"
#include "core/octree_ray.hpp"
#include "esvo/compress.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"

namespace voxcast::esvo {
namespace {

// Branch-free min/max and float-bit helpers (core/octree_ray.hpp).
using ::voxcast::detail::vmax;
using ::voxcast::detail::vmin;

using ::voxcast::detail::bits_float;
using ::voxcast::detail::float_bits;

// Converts our descriptor word 0 into the listing's layout: valid mask in
// bits 15..8, NON-leaf mask in bits 7..0, pointer/far bits unchanged.
inline uint32_t to_listing_layout(uint32_t w) {
  uint32_t non_leaf = (w >> 8) & ~w & 0xFFu;
  return (w & 0xFFFFFF00u) | non_leaf;
}

// Table 6 counters for the counting instantiation; an empty struct otherwise.
struct NoCounters {};
template <bool kCount>
using LoopCounters = std::conditional_t<kCount, RayCounters, NoCounters>;

template <bool kCount>
CastResult cast_ray_impl(const EsvoOctree& octree, Vec3 p, Vec3 d, float tmax, float size_coef,
                         float size_bias, const Aabb* region, RayCounters* counters) {
  constexpr int s_max = kMaxScale;  // float mantissa bits
  const uint32_t* const words = octree.words.data();
  [[maybe_unused]] LoopCounters<kCount> cnt{};
  // Adds the loop's counts to *counters on every exit.
  struct Flush {
    [[maybe_unused]] LoopCounters<kCount>* from;
    RayCounters* to;
    ~Flush() {
      if constexpr (kCount) {
        if (to) *to += *from;
      }
    }
  } flush{&cnt, counters};

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

  // Mirrored frame with every direction component negative (§6.1 "Alternate
  // coordinate system"); tiny components are replaced as in Appendix A.
  d = ::voxcast::detail::avoid_tiny_components(d);
  const ::voxcast::detail::MirroredRay ray(p, d);
  const float tx_coef = ray.tx_coef, ty_coef = ray.ty_coef, tz_coef = ray.tz_coef;
  const int octant_mask = ray.octant_mask;
  auto tx = [&](float x) { return ray.tx(x); };
  auto ty = [&](float y) { return ray.ty(y); };
  auto tz = [&](float z) { return ray.tz(z); };

  // Active t-span: the root cube [1,2]^3 clipped to [0, tmax].
  float t_min = vmax(vmax(tx(2.0f), ty(2.0f)), tz(2.0f));
  float t_max = vmin(vmin(tx(1.0f), ty(1.0f)), tz(1.0f));
  float h = t_max;  // stays the root's exit: it only gates stack writes
  // Beam optimization (§6.2): start at the entry planes of the region and
  // end at its exit planes. See "Why a start region gives bit-identical hits".
  if (region != nullptr) ray.clip_to_region(*region, &t_min, &t_max);
  t_min = vmax(t_min, 0.0f);
  t_max = vmin(t_max, tmax);

  // The t-span only shrinks during traversal, so a ray missing the root cube
  // (or starting past tmax) can stop here; the listing would step through the
  // root's children to find out.
  if (!(t_min <= t_max)) return result;

  uint32_t parent = octree.root_slot();
  uint32_t child_descriptor = 0;  // listing layout; 0 = not fetched
  uint32_t contour_word = 0;      // word 1 (contour pointer | mask), fetched with it
  int idx = 0;
  float pos_x = 1.0f, pos_y = 1.0f, pos_z = 1.0f;
  int scale = s_max - 1;
  float scale_exp2 = 0.5f;  // exp2f(scale - s_max)

  if (tx(1.5f) > t_min) idx ^= 1, pos_x = 1.5f;
  if (ty(1.5f) > t_min) idx ^= 2, pos_y = 1.5f;
  if (tz(1.5f) > t_min) idx ^= 4, pos_z = 1.5f;

  while (scale < s_max) {
    if constexpr (kCount) ++cnt.iterations;
    // Fetch the child descriptor unless the cached copy is valid (§6.1
    // "Caching the current child descriptor"): ADVANCE keeps the parent.
    if (child_descriptor == 0) {
      child_descriptor = to_listing_layout(words[size_t(parent) * 2]);
      contour_word = words[size_t(parent) * 2 + 1];
      if constexpr (kCount) ++cnt.descriptor_fetches;
    }

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
      if (tc_max * size_coef + size_bias >= scale_exp2) [[unlikely]]
        break;  // at t_min

      // INTERSECT: active span vs cube, and the center t values that PUSH
      // reuses (§6.1 "Sharing computation between INTERSECT and PUSH").
      if constexpr (kCount) ++cnt.intersects;
      float tv_max = vmin(t_max, tc_max);
      const float half = scale_exp2 * 0.5f;
      const float tx_center = std::fma(half, tx_coef, tx_corner);
      const float ty_center = std::fma(half, ty_coef, ty_corner);
      const float tz_center = std::fma(half, tz_coef, tz_corner);

      // Contour (§5.2, §6.1, Appendix A): the slab |n.(x - c) - cpos| <= cthick
      // of the voxel (center c, side scale_exp2; n = integer normal). With
      // x = p + t d: t = (n.(c - p) + cpos +- cthick) / n.d, and
      // tx_center * n.x * d.x = n.x (c.x - p.x) in the unmirrored frame
      // (tx_center is where the ray crosses the center plane, whatever the
      // mirroring), hence the products with the UNMIRRORED d below.
      const uint32_t contour_mask = contour_word << child_shift;
      if ((contour_mask & 0x80u) != 0) {
        const uint32_t value = words[size_t(parent) * 2 + (contour_word >> 8) +
                                     uint32_t(std::popcount(contour_mask & 0x7Fu))];
        const int32_t v = int32_t(value);
        const float cthick = float(value >> 25) * scale_exp2 * 0.375f;
        const float cpos = float(int32_t(uint32_t(v) << 7) >> 25) * scale_exp2 * 0.75f;
        const float cdirx = float(int32_t(uint32_t(v) << 14) >> 26) * d.x;
        const float cdiry = float(int32_t(uint32_t(v) << 20) >> 26) * d.y;
        const float cdirz = float(int32_t(uint32_t(v) << 26) >> 26) * d.z;
        float den = cdirx + cdiry + cdirz;
        // A ray parallel to the slab: a tiny denominator keeps the span
        // finite (everything or nothing of the ray's [0, tmax]) and NaN-free.
        if (std::fabs(den) < 1e-30f) den = 1e-30f;
        const float tcoef = 1.0f / den;
        const float tavg = tx_center * cdirx + ty_center * cdiry + tz_center * cdirz + cpos;
        const float tdiff = std::fabs(cthick * tcoef);
        t_min = vmax(t_min, tcoef * tavg - tdiff);  // override t_min with tv_min
        tv_max = vmin(tv_max, tcoef * tavg + tdiff);
      }

      if (t_min <= tv_max) {
        // A leaf (valid, not subdivided): hit at t_min.
        if ((child_masks & 0x0080u) == 0) [[unlikely]]
          break;

        // PUSH: save (parent, t_max), the active span end of this cube's
        // level, as in Figure 15 line 19 (the Appendix A transcription stores
        // tc_max there, which would cut the span of the cube's siblings after
        // a POP). The `h` threshold skips writes the stack already holds.
        if constexpr (kCount) ++cnt.pushes;
        if (tc_max < h) {
          stack_parent[scale] = parent;
          stack_tmax[scale] = t_max;
          if constexpr (kCount) ++cnt.stores;
        }
        h = tc_max;

        uint32_t ofs = child_descriptor >> 17;  // child pointer, in slots
        int32_t rel = int32_t(ofs);
        if ((child_descriptor & 0x10000u) != 0) [[unlikely]] {  // far: slot holds the offset
          std::memcpy(&rel, &words[size_t(parent + ofs) * 2], sizeof rel);
          if constexpr (kCount) ++cnt.far_reads;
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
    if constexpr (kCount) ++cnt.advances;
    int step_mask = 0;
    if (tx_corner <= tc_max) step_mask ^= 1, pos_x -= scale_exp2;
    if (ty_corner <= tc_max) step_mask ^= 2, pos_y -= scale_exp2;
    if (tz_corner <= tc_max) step_mask ^= 4, pos_z -= scale_exp2;

    t_min = tc_max;
    idx ^= step_mask;

    // The bit flips disagree with the (negative) ray direction: we left the
    // parent. POP to the highest level whose cube still contains pos.
    if ((idx & step_mask) != 0) {
      if constexpr (kCount) ++cnt.pops;
      // Highest differing bit between the old and new positions = new scale.
      uint32_t differing_bits = 0;
      if ((step_mask & 1) != 0)
        differing_bits |= float_bits(pos_x) ^ float_bits(pos_x + scale_exp2);
      if ((step_mask & 2) != 0)
        differing_bits |= float_bits(pos_y) ^ float_bits(pos_y + scale_exp2);
      if ((step_mask & 4) != 0)
        differing_bits |= float_bits(pos_z) ^ float_bits(pos_z + scale_exp2);
      scale = std::bit_width(differing_bits) - 1;
      if (scale >= s_max) [[unlikely]]
        break;  // left the root cube
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

}  // namespace

CastResult cast_ray(const EsvoOctree& octree, Vec3 p, Vec3 d, float tmax, float size_coef,
                    float size_bias) {
  return cast_ray_impl<false>(octree, p, d, tmax, size_coef, size_bias, nullptr, nullptr);
}

CastResult cast_ray(const EsvoOctree& octree, Vec3 p, Vec3 d, float tmax, float size_coef,
                    float size_bias, const Aabb* region, RayCounters* counters) {
  if (counters != nullptr)
    return cast_ray_impl<true>(octree, p, d, tmax, size_coef, size_bias, region, counters);
  return cast_ray_impl<false>(octree, p, d, tmax, size_coef, size_bias, region, nullptr);
}

// ---------------------------------------------------------------------------

EsvoStructure::EsvoStructure(std::shared_ptr<const EsvoOctree> octree)
    : octree_(std::move(octree)) {
  if (!octree_) throw Error("EsvoStructure: no octree");
  if (octree_->words.size() < 4) throw Error("EsvoStructure: empty octree");
  if (!(octree_->grid.side() > 0)) throw Error("EsvoStructure: octree has a non-positive side");
}

Aabb EsvoStructure::bounds() const {
  const GridTransform& g = octree_->grid;
  const float side = float(g.side());
  return {g.origin, g.origin + Vec3{side, side, side}};
}

namespace {

// World ray -> octree space, cast, octree hit -> SurfaceHit. Octree space:
// p' = (p - origin)/side + 1, d' = d/side, so t stays the world distance
// along the unit world direction.
template <bool kCount>
bool trace_impl(const EsvoOctree& octree, const Ray& ray, const LodFootprint& lod,
                const Aabb* region, RayCounters* counters, SurfaceHit* hit) {
  const GridTransform& g = octree.grid;
  const float side = float(g.side());
  const float inv_side = float(1.0 / g.side());
  const Vec3 p = (ray.origin - g.origin) * inv_side + Vec3{1, 1, 1};
  const Vec3 d = ray.dir * inv_side;
  const CastResult r = cast_ray_impl<kCount>(octree, p, d, ray.tmax, lod.size_per_t * inv_side,
                                             lod.size_at_origin * inv_side, region, counters);
  if (!r.hit) return false;
  const float cube =
      bits_float(uint32_t(r.scale - kMaxScale + 127) << 23);  // 2^(scale-23), octree units
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

}  // namespace

bool EsvoStructure::trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const {
  return trace_impl<false>(*octree_, ray, lod, nullptr, nullptr, hit);
}

bool EsvoStructure::trace_hinted(const Ray& ray, const LodFootprint& lod, const TraceHints& hints,
                                 SurfaceHit* hit) const {
  const Aabb* region = nullptr;
  if (hints.beam != nullptr && hints.beam->valid) {
    // §6.2: the coarse pass proved that no ray of the beam hits anything.
    if (hints.beam->empty) return false;
    region = &hints.beam->region;
  }
  if (hints.counters != nullptr)
    return trace_impl<true>(*octree_, ray, lod, region, hints.counters, hit);
  return trace_impl<false>(*octree_, ray, lod, region, nullptr, hit);
}

void EsvoStructure::attributes_counted(const SurfaceHit& hit, Color* color, Vec3* normal,
                                       RayCounters* counters) const {
  attributes(hit, color, normal);
  // Bytes of the attachment read per hit. Raw (§5.4, Figure 7): one 32-bit
  // lookup entry and one 64-bit value. Compressed (§5.5): the compression
  // block holding the voxel. (Page header and info section reads are
  // per-block metadata that stays cached; they are not counted.)
  if (counters != nullptr) {
    counters->attribute_bytes += octree_->attribute_format() == AttributeFormat::Compressed
                                     ? uint64_t(detail::kCompressedBlockWords) * 4
                                     : 4 + 8;
  }
}

// ---------------------------------------------------------------------------
// Coarse pass of the beam optimization (§6.2): a conservative frustum walk of
// the octree; the cube test and the start region are shared with the DAG
// (core/beam_frustum.hpp, which explains the construction). Here only the
// node iteration: child descriptors with their leaf masks and far pointers.
void EsvoStructure::beam_start(const BeamFrustum& beam, BeamStart* start,
                               RayCounters* counters) const {
  *start = BeamStart{};
  const EsvoOctree& o = *octree_;
  ::voxcast::detail::BeamClassifier beam_cls(beam, o.grid);
  if (!beam_cls.valid()) return;  // no information
  const uint32_t* const words = o.words.data();
  RayCounters& cnt = beam_cls.counters;
  using Cls = ::voxcast::detail::BeamClassifier;

  struct Node {
    uint32_t slot;
    float lo[3];
    float s;
  };
  Node stack[8 * (kMaxScale + 1)];
  int top = 0;
  const float root_lo[3] = {1.f, 1.f, 1.f};
  switch (beam_cls.classify(root_lo, 1.f, false)) {
    case Cls::kKeep:
      beam_cls.keep(root_lo, 1.f);
      break;
    case Cls::kDescend:
      stack[top++] = {o.root_slot(), {1.f, 1.f, 1.f}, 1.f};
      break;
    default:
      break;
  }
  while (top > 0) {
    const Node node = stack[--top];
    ++cnt.iterations;
    ++cnt.descriptor_fetches;
    const uint32_t w = words[size_t(node.slot) * 2];
    const uint32_t valid = (w >> 8) & 0xFFu, leaf = w & 0xFFu, non_leaf = valid & ~leaf;
    int32_t rel = int32_t(w >> 17);
    if ((w & 0x10000u) != 0) {  // far pointer (§5.1)
      std::memcpy(&rel, &words[size_t(node.slot + uint32_t(rel)) * 2], sizeof rel);
      ++cnt.far_reads;
    }
    const float hs = node.s * 0.5f;
    for (int i = 0; i < 8; ++i) {
      if ((valid >> i & 1u) == 0) continue;
      const float lo[3] = {node.lo[0] + ((i & 1) ? hs : 0.f), node.lo[1] + ((i & 2) ? hs : 0.f),
                           node.lo[2] + ((i & 4) ? hs : 0.f)};
      const int what = beam_cls.classify(lo, hs, (leaf >> i & 1u) != 0);
      if (what == Cls::kKeep) {
        beam_cls.keep(lo, hs);
      } else if (what == Cls::kDescend) {
        ++cnt.pushes;
        const uint32_t child = uint32_t(int32_t(node.slot) + rel) +
                               uint32_t(std::popcount(non_leaf & ((1u << i) - 1)));
        stack[top++] = {child, {lo[0], lo[1], lo[2]}, hs};
      }
    }
  }
  beam_cls.finish(start, counters);
}

void EsvoStructure::attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const {
  octree_->attributes(uint32_t(hit.voxel_ref), int(hit.child), color, normal);
}

}  // namespace voxcast::esvo
