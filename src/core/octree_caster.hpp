#pragma once
// The one ray caster of the octree family (ESVO octree, sparse voxel DAG, and
// later a streamed ESVO): Laine & Karras 2010, Appendix A (§6.1), written once
// as templates over a node-access policy. What lives here:
//  * cast_octree: the PUSH/ADVANCE/POP loop with LOD stop (§6.1), contour
//    intersection (§5.2, Appendix A), any-hit exit, start region (§6.2) and
//    the Table 6 profiling counters (§8.5);
//  * beam_walk: the node walk of the coarse beam pass (§6.2) over the same
//    policy (the cube test and region are in core/beam_frustum.hpp);
//  * OctreeWorld: the world <-> octree frame (OctreeFrame, core/octree_ray.hpp)
//    around the two, and with it the SurfaceQuery methods of
//    OctreeStructure (include/voxcast/octree_structure.hpp).
// svdag §4: "The main traversal loop closely resembles that of Laine and
// Karras [2010a] ... the DAG data structure requires only minor changes":
// those changes are the policy; the loop and its arithmetic are shared, so
// the structures' hits are bit-identical by construction.
//
// Node-access policy P (src/esvo/octree_nodes.hpp, src/dag/octree_nodes.hpp).
// A node is named by a uint32_t; "the node at scale s" is the parent of the
// cubes of side 2^(s - kOctreeMaxScale), and c is a child slot in the
// unmirrored node (c = x | y << 1 | z << 2, as in esvo.hpp):
//   using Source               the structure's data: P is built from it per ray
//                              or beam, and it has the GridTransform `grid`
//   using Desc                 what one fetch yields; the loop caches it while
//                              ADVANCE stays in the node (§6.1 "Caching the
//                              current child descriptor")
//   bool fetched(desc)         false for Desc{} and after forget(&desc), true for
//                              every fetched node (masks are never empty:
//                              validate() checks it)
//   using Index                per-level payload carried down and saved on the
//                              stack (the DAG's voxel rank), or NoIndex
//   kContours                  contour(...) exists and may narrow a span; a
//                              runtime `bool contours` member, if the policy has
//                              one, says whether this structure has any
//                              (may_narrow_spans)
//   kResidency                 resident(...) exists; false = all resident
//   kEnteredFace               report the cube face the ray entered
//   uint32_t root()
//   Desc fetch(node, s, cnt)
//   uint32_t mask(desc)        8-bit mask of the present children
//   bool valid(desc, c)        == (mask(desc) >> c) & 1
//   bool leaf(desc, c, s)      present child c (a cube at scale s) has no children
//   bool contour(desc, node, c, &value)            kContours: child c's slab
//   bool resident(desc, node, c, s)                kResidency: may child c be entered
//   uint32_t descend(desc, node, c, s, index, cnt) child c's node, index advanced
//   Index hit_index(index, desc, node, c, s)       the payload of hit cube c
//   uint32_t children(desc, node, s, cnt), child(desc, first, c, s, cnt)
//                              the beam walk's split of descend: children()
//                              once per node, child() per child descended into
//   static name_hit(source, cast, hit)  SurfaceHit::voxel_ref and child of a hit
// `cnt` is RayCounters in the counting instantiation and NoCounters otherwise;
// policies count through count_add(), which compiles to nothing for the latter.
#include <bit>
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "core/beam_frustum.hpp"
#include "core/octree_ray.hpp"
#include "voxcast/math.hpp"
#include "voxcast/octree_structure.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::detail {

// ---- Profiling counters (§8.5, Table 6) ------------------------------------

/// The loops are templates over kCount: the counters exist only in the
/// counting instantiation, so the plain casts carry no extra instructions.
struct NoCounters {};
template <bool kCount>
using LoopCounters = std::conditional_t<kCount, RayCounters, NoCounters>;

/// cnt.*field += n in the counting instantiation; nothing otherwise.
template <class C>
inline void count_add(C& cnt, uint64_t RayCounters::*field, uint64_t n = 1) {
  if constexpr (std::is_same_v<C, RayCounters>) {
    cnt.*field += n;
  } else {
    (void)cnt, (void)field, (void)n;
  }
}

/// Adds a loop's local counts to *to (if set) on every exit of the loop.
template <bool kCount>
struct CounterFlush {
  [[maybe_unused]] LoopCounters<kCount>* from;
  RayCounters* to;
  ~CounterFlush() {
    if constexpr (kCount) {
      if (to != nullptr) *to += *from;
    }
  }
};

// ---- The Appendix A loop ----------------------------------------------------

/// Whether contours may narrow a span in this structure: P::kContours and,
/// for a policy with a runtime `contours` flag (the ESVO's: false when the
/// octree has no contour attachment, so no contour mask is set, validate()),
/// that flag. False allows the loop's early miss exit (below).
template <class P>
[[gnu::always_inline]] inline bool may_narrow_spans(const P& nodes) {
  if constexpr (!P::kContours)
    return false;
  else if constexpr (requires { nodes.contours; })
    return nodes.contours;
  else
    return true;
}

/// Where a ray starts in the root cube (the loop's set-up, shared with the
/// packet caster, core/octree_packet_caster.hpp, so that both start from the
/// same floats): the active span, the stack-write threshold h and the first
/// child (mirrored slot idx, min corner pos).
struct CastEntry {
  float t_min, t_max, h;
  int idx;
  float pos_x, pos_y, pos_z;
};

/// Fills *e for `ray` (mirrored frame) clipped to [0, tmax] and `region` (may
/// be null); false if the span is empty: the t-span only shrinks during
/// traversal, so a ray missing the root cube (or starting past tmax) stops
/// here; the listing would step through the root's children to find out.
[[gnu::always_inline]] inline bool enter_root(const MirroredRay& ray, float tmax,
                                              const Aabb* region, CastEntry* e) {
  // Active t-span: the root cube [1,2]^3 clipped to [0, tmax].
  float t_min = vmax(vmax(ray.tx(2.0f), ray.ty(2.0f)), ray.tz(2.0f));
  float t_max = vmin(vmin(ray.tx(1.0f), ray.ty(1.0f)), ray.tz(1.0f));
  e->h = t_max;  // stays the root's exit: it only gates stack writes
  // Beam optimization (§6.2): start at the entry planes of the region and
  // end at its exit planes (see "Why a start region gives bit-identical hits").
  if (region != nullptr) ray.clip_to_region(*region, &t_min, &t_max);
  t_min = vmax(t_min, 0.0f);
  t_max = vmin(t_max, tmax);
  if (!(t_min <= t_max)) return false;
  e->t_min = t_min;
  e->t_max = t_max;
  e->idx = 0;
  e->pos_x = e->pos_y = e->pos_z = 1.0f;
  if (ray.tx(1.5f) > t_min) e->idx ^= 1, e->pos_x = 1.5f;
  if (ray.ty(1.5f) > t_min) e->idx ^= 2, e->pos_y = 1.5f;
  if (ray.tz(1.5f) > t_min) e->idx ^= 4, e->pos_z = 1.5f;
  return true;
}

/// Contour (§5.2, §6.1, Appendix A): the slab |n.(x - c) - cpos| <= cthick of
/// the voxel (center c, side scale_exp2; n = integer normal) narrows
/// [*t_min, *tv_max]. With x = p + t d: t = (n.(c - p) + cpos +- cthick) /
/// n.d, and tx_mid * n.x * d.x = n.x (c.x - p.x) in the unmirrored frame
/// (tx_mid is where the ray crosses the center plane, whatever the
/// mirroring), hence the products with the UNMIRRORED d (after
/// avoid_tiny_components). The slab uses the listing's incremental center t,
/// t(corner) + half * coef: any function of the voxel alone keeps the
/// start-region argument, and this one keeps contour images bit-identical to
/// those rendered before the descent switched to t(pos + half).
/// `coef`: the MirroredRay's tx/ty/tz_coef. Always inlined: the packet
/// kernels call it from their own ISA's translation units.
[[gnu::always_inline]] inline void contour_span(uint32_t value, Vec3 coef, Vec3 d, float tx_corner,
                                                float ty_corner, float tz_corner, float scale_exp2,
                                                float* t_min, float* tv_max) {
  const float half = scale_exp2 * 0.5f;
  const float tx_mid = std::fma(half, coef.x, tx_corner);
  const float ty_mid = std::fma(half, coef.y, ty_corner);
  const float tz_mid = std::fma(half, coef.z, tz_corner);
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
  const float tavg = tx_mid * cdirx + ty_mid * cdiry + tz_mid * cdirz + cpos;
  const float tdiff = std::fabs(cthick * tcoef);
  *t_min = vmax(*t_min, tcoef * tavg - tdiff);  // override t_min with tv_min
  *tv_max = vmin(*tv_max, tcoef * tavg + tdiff);
}

/// Side of a cube at `scale`: exp2f(scale - s_max), exact.
inline float scale_side(int scale) {
  return bits_float(uint32_t(scale - kOctreeMaxScale + 127) << 23);
}

/// kEnteredFace: the face through which the ray (mirrored `ray`, direction
/// `d` after avoid_tiny_components) entered the cube at mirrored min corner
/// `mpos`: the axis whose entry plane (the mirrored cube's upper corner) is
/// crossed last. Entering a cube while moving +x means its -x face.
/// Here from the ray's terms, t(c) = fma(c, coef, neg_bias) per axis
/// (MirroredRay::tx with neg_bias = -tx_bias; the tile caster keeps them
/// per ray, core/octree_tile_caster.hpp TileRays).
inline int entered_face(Vec3 coef, Vec3 neg_bias, Vec3 d, Vec3 mpos, int scale) {
  const float s = scale_side(scale);
  const float ex = std::fma(mpos.x + s, coef.x, neg_bias.x);
  const float ey = std::fma(mpos.y + s, coef.y, neg_bias.y);
  const float ez = std::fma(mpos.z + s, coef.z, neg_bias.z);
  const int axis = (ex >= ey && ex >= ez) ? 0 : (ey >= ez ? 1 : 2);
  return axis * 2 + (d[axis] > 0.0f ? 1 : 0);
}
/// The same of a MirroredRay.
inline int entered_face(const MirroredRay& ray, Vec3 d, Vec3 mpos, int scale) {
  return entered_face({ray.tx_coef, ray.ty_coef, ray.tz_coef},
                      {-ray.tx_bias, -ray.ty_bias, -ray.tz_bias}, d, mpos, scale);
}

/// Undoes the mirroring of a cube's min corner: the cube [x, x+s] mirrored is
/// [3-s-x, 3-x] (exact).
inline Vec3 unmirror(int octant_mask, Vec3 mpos, int scale) {
  const float s = scale_side(scale);
  if ((octant_mask & 1) == 0) mpos.x = 3.0f - s - mpos.x;
  if ((octant_mask & 2) == 0) mpos.y = 3.0f - s - mpos.y;
  if ((octant_mask & 4) == 0) mpos.z = 3.0f - s - mpos.z;
  return mpos;
}

/// Index type of policies without a per-level payload.
struct NoIndex {
  bool operator==(const NoIndex&) const = default;
};

/// Why the loop stopped (all but kMiss are hits at the current cube).
enum class CastStop : uint8_t { kMiss, kLeaf, kLod, kNotResident };

/// Result of cast_octree, octree space (root cube [1,2]^3).
template <class Index>
struct OctreeCast {
  bool hit = false;
  CastStop stop = CastStop::kMiss;
  float t = INFINITY;           // entry t of the hit cube (the input ray's parameterization)
  Vec3 pos{0, 0, 0};            // min corner of the hit cube
  uint32_t node = 0;            // the hit cube's parent node
  int child = 0;                // the hit cube's slot in `node`
  int scale = kOctreeMaxScale;  // hit cube side = 2^(scale - kOctreeMaxScale)
  int face = 0;                 // kEnteredFace: axis * 2 + (outward normal negative ? 1 : 0)
  Index index{};                // P::hit_index of the hit cube (closest hit only)
};

/// Appendix A over policy P. `p`, `d` in octree space, t in [0, tmax]; LOD:
/// stop at a cube whose side <= size_coef * (its exit t) + size_bias (octree
/// units). `region` (may be null): a box known to contain every voxel the ray
/// can hit (§6.2); the span starts at its entry and ends at its exit, and the
/// hit stays bit-identical (see "Why a start region gives bit-identical hits"
/// below). kAnyHit: the answer is only `hit` (shadow and AO rays); the
/// payload, the face and the hit position are not computed. `counters` (may
/// be null; only read when kCount) accumulates Table 6 counts.
///
/// Differences from the CUDA listing:
///  * the policy supplies masks and pointers (ESVO: valid/leaf masks and
///    near/far pointers, §5.1; DAG: header masks, absolute pointers and 4^3
///    leaf masks, svdag §3);
///  * t is clipped to [0, tmax] (the listing uses [0, 1]);
///  * PUSH stores the active t_max (Figure 15, line 19), not tc_max as the
///    transcribed listing does;
///  * each child's center t is computed from its position, t(pos + half), not
///    incrementally as t(corner) + half * coef: every t the loop compares is
///    then the rounded crossing of one grid plane, whichever cube produced it
///    (the proof below needs exactly that);
///  * the loop is scalar and branchy like the listing: on a CPU the ADVANCE
///    and PUSH branches are mostly predicted, which breaks the t -> compare ->
///    position dependency chain. (A branch-free SSE variant computing PUSH,
///    ADVANCE and POP every iteration and selecting was 1.7x slower, an SSE
///    variant with the listing's branches 15% slower, on the bunny at 2048^3.)
///  * contours (§5.2, §6.1 INTERSECT), when the policy has them: when the
///    voxel's contour bit is set, [t_min, tv_max] is narrowed by the slab as
///    in the listing, from the center t values. Fields are masked exactly and
///    scaled as documented at esvo::ContourValue (the listing converts the
///    unmasked shifted int). Since PUSH carries the narrowed span down and
///    POP restores it, a voxel's shape is its cube ∩ all ancestor slabs (§5.3).
///  * without contours the loop ends as soon as t_min passes the span's end
///    (see ADVANCE) instead of stepping out through every ancestor;
///  * residency (streaming structures): a child the policy does not hold is
///    not entered; the ray stops at the coarser cube, which shows its
///    children's average like a LOD stop (§5.4), and the caller learns it
///    from CastStop::kNotResident.
///
/// Why a start region gives bit-identical hits. Every t the loop compares or
/// returns is a rounded plane crossing t(c) = fma(c, coef, -bias) for a grid
/// plane coordinate c (dyadic, exact, and independent of the level that
/// produced it: a plane is the same float whether it is a corner or a center
/// of a big cube or a corner of a small one), or the start/end of the span,
/// or a contour slab bound, which depends only on the voxel (its planes and
/// its contour value), never on where the span started. fma rounds the exact value, so t(c) is
/// monotone in c. Descent ("center t > t_min": the plane is not crossed yet) and ADVANCE
/// ("corner t <= tc_max": crossed) use the same tie rule on the same floats,
/// so at any t the loop places the ray in the cell whose crossed planes are
/// exactly those with t(c) <= t. Hence a voxel V is hit-able iff its span
/// [max(start, t of V's entry planes, slab lows of V and its ancestors),
///  min(end, t of V's exit planes, slab highs)] is non-empty, the loop
/// returns the first hit-able voxel along the ray (a parent's span contains
/// its children's) and reports the left end of its span. Moving the start
/// from the root entry to the entry planes of a box R that contains the first
/// hit voxel V: R's entry planes are at or before V's, so by monotonicity
/// start' <= t of V's entry planes and V keeps its exact span and its t;
/// every other voxel's span only shrinks, so none becomes hit-able before V,
/// and a ray that missed still misses. The same holds for ending the span at
/// R's exit (V lies inside R). Mirrored coordinates 3 - c are exact for c in
/// [1, 2], so R's planes are grid planes like any other. (Until the center t
/// was computed incrementally, it could differ from t(center) by about an ulp
/// of t(corner), so that near-ties with t_min were outside this argument.)
template <class P, bool kCount, bool kAnyHit>
auto cast_octree(const typename P::Source& source, Vec3 p, Vec3 d, float tmax, float size_coef,
                 float size_bias, const Aabb* region, RayCounters* counters) {
  const P nodes(source);                  // local: its fields can live in registers
  constexpr int s_max = kOctreeMaxScale;  // float mantissa bits
  using Index = std::conditional_t<kAnyHit, NoIndex, typename P::Index>;
  constexpr bool kIndexed = !std::is_same_v<Index, NoIndex>;
  using Desc = typename P::Desc;
  [[maybe_unused]] LoopCounters<kCount> cnt{};
  const CounterFlush<kCount> flush{&cnt, counters};

  OctreeCast<Index> result;
  // NaN/Inf would make the t arithmetic below meaningless (and the loop
  // might not terminate): such a ray hits nothing.
  if (!(is_finite(p) && is_finite(d))) return result;

  // Stack of parent nodes indexed by scale (Appendix A). Entry s holds the
  // parent of the cubes at scale s, the active t_max there and the payload.
  uint32_t stack_node[s_max + 1];
  float stack_tmax[s_max + 1];
  [[maybe_unused]] Index stack_index[s_max + 1];

  // Mirrored frame with every direction component negative (§6.1 "Alternate
  // coordinate system"); tiny components are replaced as in Appendix A.
  d = avoid_tiny_components(d);
  const MirroredRay ray(p, d);
  const int octant_mask = ray.octant_mask;
  const int slot_flip = octant_mask ^ 7;  // mirrored idx -> unmirrored slot

  CastEntry entry;
  if (!enter_root(ray, tmax, region, &entry)) return result;
  float t_min = entry.t_min, t_max = entry.t_max, h = entry.h;

  const bool contours = may_narrow_spans(nodes);
  uint32_t parent = nodes.root();
  Desc desc{};  // P::fetched(desc) == false: fetch at the next iteration
  [[maybe_unused]] Index index{};
  int idx = entry.idx;
  float pos_x = entry.pos_x, pos_y = entry.pos_y, pos_z = entry.pos_z;
  int scale = s_max - 1;
  float scale_exp2 = 0.5f;  // exp2f(scale - s_max)
  CastStop stop = CastStop::kMiss;

  while (scale < s_max) {
    if constexpr (kCount) ++cnt.iterations;
    // Fetch the parent unless the cached copy is valid (§6.1 "Caching the
    // current child descriptor"): ADVANCE keeps the parent.
    if (!P::fetched(desc)) desc = nodes.fetch(parent, scale, cnt);

    // Maximum t of the cube: the planes through its exit corner.
    const float tx_corner = ray.tx(pos_x);
    const float ty_corner = ray.ty(pos_y);
    const float tz_corner = ray.tz(pos_z);
    const float tc_max = vmin(vmin(tx_corner, ty_corner), tz_corner);

    const int c = idx ^ slot_flip;  // slot bits are permuted by the mirroring
    if (nodes.valid(desc, c) && t_min <= t_max) {
      // LOD termination: the voxel is small enough for the ray's footprint.
      if (tc_max * size_coef + size_bias >= scale_exp2) [[unlikely]] {
        stop = CastStop::kLod;
        break;  // at t_min
      }

      // INTERSECT: active span vs cube.
      if constexpr (kCount) ++cnt.intersects;
      float tv_max = vmin(t_max, tc_max);
      const float half = scale_exp2 * 0.5f;

      if constexpr (P::kContours) {
        // Contour (§5.2, §6.1, Appendix A): contour_span, above.
        uint32_t value;
        if (contours && nodes.contour(desc, parent, c, &value)) {
          contour_span(value, {ray.tx_coef, ray.ty_coef, ray.tz_coef}, d, tx_corner, ty_corner,
                       tz_corner, scale_exp2, &t_min, &tv_max);
        }
      }

      if (t_min <= tv_max) {
        // A leaf (valid, not subdivided): hit at t_min.
        if (nodes.leaf(desc, c, scale)) [[unlikely]] {
          stop = CastStop::kLeaf;
          break;
        }
        if constexpr (P::kResidency) {
          if (!nodes.resident(desc, parent, c, scale)) [[unlikely]] {
            stop = CastStop::kNotResident;  // the coarser voxel stands in
            break;
          }
        }

        // PUSH: save (parent, t_max), the active span end of this cube's
        // level, as in Figure 15 line 19 (the Appendix A transcription stores
        // tc_max there, which would cut the span of the cube's siblings after
        // a POP). The `h` threshold skips writes the stack already holds.
        if constexpr (kCount) ++cnt.pushes;
        if (tc_max < h) {
          stack_node[scale] = parent;
          stack_tmax[scale] = t_max;
          if constexpr (kIndexed) stack_index[scale] = index;
          if constexpr (kCount) ++cnt.stores;
        }
        h = tc_max;
        parent = nodes.descend(desc, parent, c, scale, index, cnt);

        // Select the child the ray enters first: the upper half (mirrored
        // frame) on each axis whose center plane is not crossed yet at t_min.
        // The center t is the plane's own t(pos + half), the value the child
        // computes as its corner t, not the listing's t(corner) + half * coef
        // (see "Why a start region gives bit-identical hits").
        const float cx = pos_x + half, cy = pos_y + half, cz = pos_z + half;  // exact: dyadic
        idx = 0;
        if (ray.tx(cx) > t_min) idx ^= 1, pos_x = cx;
        if (ray.ty(cy) > t_min) idx ^= 2, pos_y = cy;
        if (ray.tz(cz) > t_min) idx ^= 4, pos_z = cz;
        scale--;
        scale_exp2 = half;

        t_max = tv_max;
        P::forget(&desc);
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

    if (!contours) {
      // Past the end of the span: a miss. Without contours (svdag §4; for the
      // ESVO: an octree without a contour attachment, may_narrow_spans) every
      // active t_max is min(E, exit t of the current parent cube) with E the
      // end of [0, tmax] clipped to the root and the region, and a child's
      // exit t is <= its parent's (fma is monotone), so t_min > t_max means
      // t_min > E. From then on no t_max exceeds E, so nothing is pushed or
      // hit, and without pushes each ADVANCE moves to a cube whose exit t is
      // >= the current one (monotone again), so t_min stays > E: the loop
      // could only step out through every ancestor. With contours this does
      // not hold (a contour also narrows t_max). Ends short AO/shadow and
      // beam-clipped rays.
      if (t_min > t_max) return result;
    }

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

      parent = stack_node[scale];
      t_max = stack_tmax[scale];
      if constexpr (kIndexed) index = stack_index[scale];

      // Round the position down to the cube at the new scale; its slot index
      // is the bit just below.
      const uint32_t shx = float_bits(pos_x) >> scale;
      const uint32_t shy = float_bits(pos_y) >> scale;
      const uint32_t shz = float_bits(pos_z) >> scale;
      pos_x = bits_float(shx << scale);
      pos_y = bits_float(shy << scale);
      pos_z = bits_float(shz << scale);
      idx = int((shx & 1) | ((shy & 1) << 1) | ((shz & 1) << 2));

      // Prevent the same parent from being stored again; refetch it.
      h = 0.0f;
      P::forget(&desc);
    }
  }

  if (scale >= s_max) return result;  // outside the octree: miss

  result.hit = true;
  result.stop = stop;
  result.t = t_min;
  result.scale = scale;
  if constexpr (!kAnyHit) {
    const int c = idx ^ slot_flip;
    result.node = parent;
    result.child = c;
    if constexpr (kIndexed) result.index = nodes.hit_index(index, desc, parent, c, scale);
    if constexpr (P::kEnteredFace) result.face = entered_face(ray, d, {pos_x, pos_y, pos_z}, scale);
    result.pos = unmirror(octant_mask, {pos_x, pos_y, pos_z}, scale);
  }
  return result;
}

// ---- The coarse beam pass's node walk (§6.2) --------------------------------

/// Depth-first walk of the tree (positions, not nodes: a DAG node shared by
/// many positions is visited once per occurrence, since whether a cube lies
/// in the beam depends on where it is) that classifies every present child
/// with the conservative cube test of core/beam_frustum.hpp and accumulates
/// the start region. Counters: iterations = nodes visited; the policy counts
/// its fetches and pointer reads; pushes = children descended into.
template <class P>
void beam_walk(const typename P::Source& source, const BeamFrustum& beam, BeamStart* start,
               RayCounters* counters) {
  *start = BeamStart{};
  BeamClassifier cls(beam, source.grid);
  if (!cls.valid()) return;  // no information
  RayCounters& cnt = cls.counters;
  const P nodes(source);

  struct Item {
    uint32_t node;
    int scale;  // of the node's children
    float lo[3];
    float s;  // the node's cube side, octree units
  };
  Item stack[8 * (kOctreeMaxScale + 1)];  // depth-first: <= 7 pending siblings per level
  int top = 0;
  const float root_lo[3] = {1.f, 1.f, 1.f};
  switch (cls.classify(root_lo, 1.f, false)) {
    case BeamClassifier::kKeep:
      cls.keep(root_lo, 1.f);
      break;
    case BeamClassifier::kDescend:
      stack[top++] = {nodes.root(), kOctreeMaxScale - 1, {1.f, 1.f, 1.f}, 1.f};
      break;
    default:
      break;
  }
  while (top > 0) {
    const Item item = stack[--top];
    ++cnt.iterations;
    const auto desc = nodes.fetch(item.node, item.scale, cnt);
    const uint32_t first = nodes.children(desc, item.node, item.scale, cnt);
    const float hs = item.s * 0.5f;
    for (uint32_t m = nodes.mask(desc); m != 0; m &= m - 1) {
      const int c = std::countr_zero(m);
      const float lo[3] = {item.lo[0] + ((c & 1) ? hs : 0.f), item.lo[1] + ((c & 2) ? hs : 0.f),
                           item.lo[2] + ((c & 4) ? hs : 0.f)};
      const int what = cls.classify(lo, hs, nodes.leaf(desc, c, item.scale));
      // A streaming policy's child that is not resident is kept whole: a ray
      // reaching it stops there (CastStop::kNotResident, a hit on that
      // coarser voxel), so its cube is where the rays may hit.
      bool enter = what == BeamClassifier::kDescend;
      if constexpr (P::kResidency) {
        if (enter && !nodes.resident(desc, item.node, c, item.scale)) {
          cls.keep(lo, hs);
          continue;
        }
      }
      if (what == BeamClassifier::kKeep) {
        cls.keep(lo, hs);
      } else if (enter) {
        ++cnt.pushes;
        const uint32_t child = nodes.child(desc, first, c, item.scale, cnt);
        stack[top++] = {child, item.scale - 1, {lo[0], lo[1], lo[2]}, hs};
      }
    }
  }
  cls.finish(start, counters);
}

// ---- World frame -------------------------------------------------------------

/// cast_octree with the counting instantiation chosen by `counters` != null.
template <class P, bool kAnyHit>
auto cast_octree_counted(const typename P::Source& source, Vec3 p, Vec3 d, float tmax,
                         float size_coef, float size_bias, const Aabb* region,
                         RayCounters* counters) {
  if (counters != nullptr)
    return cast_octree<P, true, kAnyHit>(source, p, d, tmax, size_coef, size_bias, region,
                                         counters);
  return cast_octree<P, false, kAnyHit>(source, p, d, tmax, size_coef, size_bias, region, nullptr);
}

/// A structure's public cast result (esvo::CastResult, dag::CastResult) with
/// the fields all of them share (hit, t, pos, scale) filled from `r`.
template <class Out, class Index>
Out cast_result(const OctreeCast<Index>& r) {
  Out out{};
  out.hit = r.hit;
  out.t = r.t;
  out.pos = r.pos;
  out.scale = r.scale;
  return out;
}

/// The SurfaceQuery of an octree-family structure: world rays mapped into
/// octree space (OctreeFrame), cast, and mapped back (t stays the world
/// distance along the unit direction); P::name_hit fills the
/// structure-specific SurfaceHit::voxel_ref and child. Each query picks the
/// caster instantiation once from ctx.counting: the plain loop has no
/// counter code at all.
template <class P>
struct OctreeWorld {
  using Nodes = P;
  explicit OctreeWorld(const typename P::Source& s) : source(s), frame(s.grid) {}

  Aabb bounds() const { return frame.bounds(); }

  /// SurfaceQuery::trace.
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam) const {
    const Aabb* region = nullptr;
    if (beam != nullptr && beam->valid) {
      // §6.2: the coarse pass proved that no ray of the beam hits anything.
      if (beam->empty) return false;
      region = &beam->region;
    }
    const Vec3 p = frame.point(ray.origin), d = frame.direction(ray.dir);
    const float coef = frame.length(lod.size_per_t), bias = frame.length(lod.size_at_origin);
    const auto r =
        ctx.counting
            ? cast_octree<P, true, false>(source, p, d, ray.tmax, coef, bias, region, &ctx.counters)
            : cast_octree<P, false, false>(source, p, d, ray.tmax, coef, bias, region, nullptr);
    if (!r.hit) return false;
    // A streaming policy asks for what stopped the ray (esvo §7: the slice
    // of a non-resident child); the coarser voxel is the hit meanwhile.
    if constexpr (requires(TraceContext & c) { P::report(source, r, c); }) {
      if (r.stop == CastStop::kNotResident) P::report(source, r, ctx);
    }
    frame.hit_to_world(p, d, r.t, r.pos, r.scale, hit);
    P::name_hit(source, r, hit);
    return true;
  }

  /// SurfaceQuery::transmittance: 0 (any hit within [0, ray.tmax]) or 1.
  /// The any-hit instantiation only where it skips work in the loop (a
  /// payload to carry, the entered face); otherwise it would differ from the
  /// closest-hit one by the final unmirroring alone, and primary and
  /// secondary rays share one copy of the loop (docs/BENCHMARKS.md "One
  /// octree caster": the ESVO's AO rays measured slower with their own).
  /// A beam region keeps the answer (see "Why a start region gives
  /// bit-identical hits": the hit/miss decision is the loop's, whatever the
  /// instantiation).
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam) const {
    constexpr bool kAnyHit = !std::is_same_v<typename P::Index, NoIndex> || P::kEnteredFace;
    const Aabb* region = nullptr;
    if (beam != nullptr && beam->valid) {
      if (beam->empty) return 1.f;
      region = &beam->region;
    }
    const Vec3 p = frame.point(ray.origin), d = frame.direction(ray.dir);
    const float coef = frame.length(lod.size_per_t), bias = frame.length(lod.size_at_origin);
    const bool hit = ctx.counting ? cast_octree<P, true, kAnyHit>(source, p, d, ray.tmax, coef,
                                                                  bias, region, &ctx.counters)
                                        .hit
                                  : cast_octree<P, false, kAnyHit>(source, p, d, ray.tmax, coef,
                                                                   bias, region, nullptr)
                                        .hit;
    return hit ? 0.f : 1.f;
  }

  /// SurfaceQuery::beam_start: the coarse pass (§6.2).
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const {
    beam_walk<P>(source, beam, start, ctx.counting ? &ctx.counters : nullptr);
  }

  const typename P::Source& source;
  OctreeFrame frame;
};

}  // namespace voxcast::detail

namespace voxcast {

// OctreeStructure's methods (include/voxcast/octree_structure.hpp), for the
// explicit instantiation in each structure's source file: Self::world() is
// its policy and grid.
template <class Self>
Aabb OctreeStructure<Self>::bounds() const {
  return static_cast<const Self&>(*this).world().bounds();
}
template <class Self>
bool OctreeStructure<Self>::trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                                  SurfaceHit* hit, const BeamStart* beam) const {
  return static_cast<const Self&>(*this).world().trace(ray, lod, ctx, hit, beam);
}
template <class Self>
float OctreeStructure<Self>::transmittance(const Ray& ray, const LodFootprint& lod,
                                           TraceContext& ctx, const BeamStart* beam) const {
  return static_cast<const Self&>(*this).world().transmittance(ray, lod, ctx, beam);
}
template <class Self>
void OctreeStructure<Self>::beam_start(const BeamFrustum& beam, TraceContext& ctx,
                                       BeamStart* start) const {
  static_cast<const Self&>(*this).world().beam_start(beam, ctx, start);
}

}  // namespace voxcast
