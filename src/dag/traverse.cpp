// Sparse voxel DAG ray caster (svdag §4: "The main traversal loop closely
// resembles that of Laine and Karras [2010a] ... the DAG data structure
// requires only minor changes"): the loop of src/esvo/traverse.cpp (esvo
// Appendix A) with the same floating-point operations in the same order, so
// that a DAG and an ESVO octree of the same voxels give bit-identical hits.
//
// Differences from the ESVO caster:
//  * the node kind follows from the scale: above the leaf-mask level a node
//    is a header (child mask) + one absolute pointer per present child; a
//    leaf-mask node is a 64-bit 4^3 mask whose byte c is the 2^3 sub-block in
//    slot c; inside a sub-block the "node" is that byte itself, and its
//    children are the leaf voxels. Leaves are only at the finest level;
//  * the stack per scale also keeps the voxel-index base (Hitchhiker's guide,
//    "Dynamic voxel indexing"): the Morton rank of the first leaf voxel of the
//    current parent. Descending adds the parent's prefix sum for the child
//    (stored next to the pointer in voxel_prefix) or a popcount inside a mask;
//  * no contours (svdag §4: "we do not need to perform any intersection tests
//    with contours"), which lets the loop stop as soon as t_min passes the
//    span's end (see ADVANCE) instead of stepping out through every ancestor;
//  * the beam optimization (esvo §6.2) is the ESVO's: the same start region
//    clipping here, the coarse pass in src/dag/beam.cpp;
//  * the any-hit variant (shadow rays) skips the index bookkeeping; the first
//    leaf found is returned immediately, as in the closest-hit variant (the
//    loop visits voxels front to back, so it is also the closest one).
#include <immintrin.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "core/octree_ray.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"

namespace voxcast::dag {
namespace {

using esvo::kMaxScale;

using ::voxcast::detail::bits_float;
using ::voxcast::detail::float_bits;
using ::voxcast::detail::vmax;
using ::voxcast::detail::vmin;

// Bit c set iff byte c of m is non-zero: the child mask of a 4^3 leaf-mask
// node over its eight 2^3 sub-blocks.
inline uint32_t byte_mask(uint64_t m) {
  m |= m >> 4;
  m |= m >> 2;
  m |= m >> 1;
  return uint32_t(_pext_u64(m, 0x0101010101010101ull));
}

// Table 6 counters (esvo §8.5) for the counting instantiation only.
struct NoCounters {};
template <bool kCount>
using LoopCounters = std::conditional_t<kCount, RayCounters, NoCounters>;

// `region` (beam optimization, esvo §6.2): clip the active span to the box
// exactly as esvo's cast_ray_impl does, so hits stay bit-identical (proof at
// the top of src/esvo/traverse.cpp). Counters: descriptor_fetches = node
// headers and 64-bit leaf masks, far_reads = child pointer words.
template <bool kAnyHit, bool kCount = false>
CastResult cast(const SparseVoxelDag& dag, Vec3 p, Vec3 d, float tmax, float size_coef,
                float size_bias, const Aabb* region = nullptr, RayCounters* counters = nullptr) {
  constexpr int s_max = kMaxScale;
  [[maybe_unused]] LoopCounters<kCount> cnt{};
  struct Flush {  // adds the loop's counts to *counters on every exit
    [[maybe_unused]] LoopCounters<kCount>* from;
    RayCounters* to;
    ~Flush() {
      if constexpr (kCount) {
        if (to) *to += *from;
      }
    }
  } flush{&cnt, counters};
  const uint32_t* const words = dag.words.data();
  const uint32_t* const prefix = dag.voxel_prefix.data();
  // Words [0, wide_words) (the top levels, nodes of >= 2^32 voxels) take
  // 64-bit prefix entries (dag.hpp "64-bit voxel indices").
  const uint64_t* const prefix_wide = dag.voxel_prefix_wide.data();
  const uint32_t wide_words = dag.wide_words;
  const int leaf_scale = s_max - dag.levels();  // scale of the leaf voxels
  const int mask_scale = leaf_scale + 1;        // children of a leaf-mask node

  CastResult result;
  result.hit = false;
  result.t = INFINITY;
  result.pos = {0, 0, 0};
  result.voxel_index = 0;
  result.scale = s_max;
  result.face = 0;
  if (!(is_finite(p) && is_finite(d))) return result;

  // Entry s: the parent of the cubes at scale s (a word index, or for
  // s == leaf_scale the 8-bit sub-block mask), the active t_max there, and
  // the Morton rank of the parent's first leaf voxel.
  uint32_t stack_parent[s_max + 1];
  float stack_tmax[s_max + 1];
  uint64_t stack_base[s_max + 1];

  d = ::voxcast::detail::avoid_tiny_components(d);
  const ::voxcast::detail::MirroredRay ray(p, d);
  const float tx_coef = ray.tx_coef, ty_coef = ray.ty_coef, tz_coef = ray.tz_coef;
  const int octant_mask = ray.octant_mask;
  auto tx = [&](float x) { return ray.tx(x); };
  auto ty = [&](float y) { return ray.ty(y); };
  auto tz = [&](float z) { return ray.tz(z); };

  float t_min = vmax(vmax(tx(2.0f), ty(2.0f)), tz(2.0f));
  float t_max = vmin(vmin(tx(1.0f), ty(1.0f)), tz(1.0f));
  float h = t_max;
  // Beam optimization (esvo §6.2), exactly as the ESVO caster.
  if (region != nullptr) ray.clip_to_region(*region, &t_min, &t_max);
  t_min = vmax(t_min, 0.0f);
  t_max = vmin(t_max, tmax);
  if (!(t_min <= t_max)) return result;

  uint32_t parent = 0;      // root node, word 0
  uint32_t child_mask = 0;  // of `parent`; 0 = not fetched (masks are never empty)
  uint64_t leaf64 = 0;      // the 4^3 mask when parent is a leaf-mask node
  uint64_t base = 0;        // Morton rank of parent's first leaf voxel
  int idx = 0;
  float pos_x = 1.0f, pos_y = 1.0f, pos_z = 1.0f;
  int scale = s_max - 1;
  float scale_exp2 = 0.5f;

  if (tx(1.5f) > t_min) idx ^= 1, pos_x = 1.5f;
  if (ty(1.5f) > t_min) idx ^= 2, pos_y = 1.5f;
  if (tz(1.5f) > t_min) idx ^= 4, pos_z = 1.5f;

  while (scale < s_max) {
    if constexpr (kCount) ++cnt.iterations;
    if (child_mask == 0) {
      if constexpr (kCount) cnt.descriptor_fetches += scale >= mask_scale;
      if (scale > mask_scale) {
        child_mask = words[parent] & 0xFFu;
      } else if (scale == mask_scale) {
        leaf64 = uint64_t(words[parent]) | uint64_t(words[parent + 1]) << 32;
        child_mask = byte_mask(leaf64);
      } else {
        child_mask = parent;  // the sub-block's byte
      }
    }

    const float tx_corner = tx(pos_x);
    const float ty_corner = ty(pos_y);
    const float tz_corner = tz(pos_z);
    const float tc_max = vmin(vmin(tx_corner, ty_corner), tz_corner);

    // Child slot in the un-mirrored node (esvo: child_shift = idx ^ octant_mask).
    const int c = idx ^ octant_mask ^ 7;
    if ((child_mask >> c) & 1u && t_min <= t_max) {
      if (tc_max * size_coef + size_bias >= scale_exp2) [[unlikely]]
        break;  // LOD, at t_min
      if constexpr (kCount) ++cnt.intersects;

      float tv_max = vmin(t_max, tc_max);
      const float half = scale_exp2 * 0.5f;
      const float tx_center = std::fma(half, tx_coef, tx_corner);
      const float ty_center = std::fma(half, ty_coef, ty_corner);
      const float tz_center = std::fma(half, tz_coef, tz_corner);

      if (t_min <= tv_max) {
        if (scale == leaf_scale) break;  // a leaf voxel: hit at t_min

        // PUSH (esvo Figure 15 line 19: the active t_max).
        if constexpr (kCount) ++cnt.pushes;
        if (tc_max < h) {
          if constexpr (kCount) ++cnt.stores;
          stack_parent[scale] = parent;
          stack_tmax[scale] = t_max;
          stack_base[scale] = base;
        }
        h = tc_max;

        if (scale > mask_scale) {
          const uint32_t w = parent + 1 + uint32_t(std::popcount(child_mask & ((1u << c) - 1)));
          if constexpr (!kAnyHit) base += w < wide_words ? prefix_wide[w] : prefix[w];
          parent = words[w];
          if constexpr (kCount) ++cnt.far_reads;
        } else {  // into sub-block c of the 4^3 mask
          if constexpr (!kAnyHit) base += uint32_t(std::popcount(leaf64 & ((1ull << (8 * c)) - 1)));
          parent = uint32_t(leaf64 >> (8 * c)) & 0xFFu;
        }

        idx = 0;
        scale--;
        scale_exp2 = half;
        if (tx_center > t_min) idx ^= 1, pos_x += scale_exp2;
        if (ty_center > t_min) idx ^= 2, pos_y += scale_exp2;
        if (tz_center > t_min) idx ^= 4, pos_z += scale_exp2;

        t_max = tv_max;
        child_mask = 0;
        continue;
      }
    }

    // ADVANCE
    if constexpr (kCount) ++cnt.advances;
    int step_mask = 0;
    if (tx_corner <= tc_max) step_mask ^= 1, pos_x -= scale_exp2;
    if (ty_corner <= tc_max) step_mask ^= 2, pos_y -= scale_exp2;
    if (tz_corner <= tc_max) step_mask ^= 4, pos_z -= scale_exp2;

    t_min = tc_max;
    idx ^= step_mask;

    // Past the end of the span: a miss. Without contours (svdag §4) every
    // active t_max is min(E, exit t of the current parent cube) with E the
    // end of [0, tmax] clipped to the root and the region, and a child's exit
    // t is <= its parent's (fma is monotone), so t_min > t_max means t_min > E.
    // From then on no t_max exceeds E, so nothing is pushed or hit, and
    // without pushes each ADVANCE moves to a cube whose exit t is >= the
    // current one (monotone again), so t_min stays > E: the loop could only
    // step out through every ancestor. The ESVO loop cannot stop here (a
    // contour also narrows t_max). Ends short AO/shadow and beam-clipped rays.
    if (t_min > t_max) return result;

    // POP: highest differing position bit = the scale to resume at.
    if ((idx & step_mask) != 0) {
      if constexpr (kCount) ++cnt.pops;
      uint32_t differing_bits = 0;
      if ((step_mask & 1) != 0)
        differing_bits |= float_bits(pos_x) ^ float_bits(pos_x + scale_exp2);
      if ((step_mask & 2) != 0)
        differing_bits |= float_bits(pos_y) ^ float_bits(pos_y + scale_exp2);
      if ((step_mask & 4) != 0)
        differing_bits |= float_bits(pos_z) ^ float_bits(pos_z + scale_exp2);
      scale = std::bit_width(differing_bits) - 1;
      if (scale >= s_max) [[unlikely]]
        break;
      scale_exp2 = bits_float(uint32_t(scale - s_max + 127) << 23);

      parent = stack_parent[scale];
      t_max = stack_tmax[scale];
      base = stack_base[scale];

      const uint32_t shx = float_bits(pos_x) >> scale;
      const uint32_t shy = float_bits(pos_y) >> scale;
      const uint32_t shz = float_bits(pos_z) >> scale;
      pos_x = bits_float(shx << scale);
      pos_y = bits_float(shy << scale);
      pos_z = bits_float(shz << scale);
      idx = int((shx & 1) | ((shy & 1) << 1) | ((shz & 1) << 2));

      h = 0.0f;
      child_mask = 0;
    }
  }

  if (scale >= s_max) return result;

  result.hit = true;
  result.t = t_min;
  result.scale = scale;
  if constexpr (!kAnyHit) {
    // Rank of the hit cube's first leaf voxel.
    const int c = idx ^ octant_mask ^ 7;
    if (scale == leaf_scale)
      base += uint32_t(std::popcount(child_mask & ((1u << c) - 1)));
    else if (scale == mask_scale)
      base += uint32_t(std::popcount(leaf64 & ((1ull << (8 * c)) - 1)));
    else
      base += dag.prefix_entry(parent + 1 + uint32_t(std::popcount(child_mask & ((1u << c) - 1))));
    result.voxel_index = base;
    // Entered face: the axis whose entry plane (the mirrored cube's upper
    // corner) is crossed last. Entering a cube while moving +x means its -x face.
    const float ex = tx(pos_x + scale_exp2), ey = ty(pos_y + scale_exp2),
                ez = tz(pos_z + scale_exp2);
    const int axis = (ex >= ey && ex >= ez) ? 0 : (ey >= ez ? 1 : 2);
    result.face = axis * 2 + (d[axis] > 0.0f ? 1 : 0);
  }
  if ((octant_mask & 1) == 0) pos_x = 3.0f - scale_exp2 - pos_x;
  if ((octant_mask & 2) == 0) pos_y = 3.0f - scale_exp2 - pos_y;
  if ((octant_mask & 4) == 0) pos_z = 3.0f - scale_exp2 - pos_z;
  result.pos = {pos_x, pos_y, pos_z};
  return result;
}

}  // namespace

CastResult cast_ray(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias) {
  return cast<false>(dag, origin, dir, tmax, size_coef, size_bias);
}

bool cast_occluded(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                   float size_bias) {
  return cast<true>(dag, origin, dir, tmax, size_coef, size_bias).hit;
}

// ---------------------------------------------------------------------------

DagStructure::DagStructure(std::shared_ptr<const SparseVoxelDag> dag) : dag_(std::move(dag)) {
  if (!dag_) throw Error("DagStructure: no DAG");
  if (dag_->words.empty() || dag_->voxel_prefix.size() != dag_->words.size())
    throw Error("DagStructure: the DAG is empty or not finalized");
  if (!(dag_->grid.side() > 0)) throw Error("DagStructure: DAG has a non-positive side");
}

Aabb DagStructure::bounds() const {
  const GridTransform& g = dag_->grid;
  const float side = float(g.side());
  return {g.origin, g.origin + Vec3{side, side, side}};
}

bool DagStructure::trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const {
  return DagStructure::trace_hinted(ray, lod, TraceHints{}, hit);
}

bool DagStructure::trace_hinted(const Ray& ray, const LodFootprint& lod, const TraceHints& hints,
                                SurfaceHit* hit) const {
  const Aabb* region = nullptr;
  if (hints.beam != nullptr && hints.beam->valid) {
    // esvo §6.2: the coarse pass (beam_start) proved that no ray of the beam hits anything.
    if (hints.beam->empty) return false;
    region = &hints.beam->region;
  }
  // World <-> octree space exactly as EsvoStructure::trace (esvo §6.1).
  const GridTransform& g = dag_->grid;
  const float side = float(g.side());
  const float inv_side = float(1.0 / g.side());
  const Vec3 p = (ray.origin - g.origin) * inv_side + Vec3{1, 1, 1};
  const Vec3 d = ray.dir * inv_side;
  const float size_coef = lod.size_per_t * inv_side, size_bias = lod.size_at_origin * inv_side;
  const CastResult r =
      hints.counters != nullptr
          ? cast<false, true>(*dag_, p, d, ray.tmax, size_coef, size_bias, region, hints.counters)
          : cast<false>(*dag_, p, d, ray.tmax, size_coef, size_bias, region);
  if (!r.hit) return false;
  const float cube = bits_float(uint32_t(r.scale - kMaxScale + 127) << 23);
  const float eps = 0x1p-23f;
  Vec3 q = p + d * r.t;
  q.x = vmin(vmax(q.x, r.pos.x + eps), r.pos.x + cube - eps);
  q.y = vmin(vmax(q.y, r.pos.y + eps), r.pos.y + cube - eps);
  q.z = vmin(vmax(q.z, r.pos.z + eps), r.pos.z + cube - eps);
  hit->t = r.t;
  hit->position = g.origin + (q - Vec3{1, 1, 1}) * side;
  hit->voxel_size = cube * side;
  hit->voxel_ref = r.voxel_index;
  hit->child = uint32_t(r.face);
  hit->level = kMaxScale - r.scale;
  return true;
}

bool DagStructure::occluded(const Ray& ray, const LodFootprint& lod) const {
  const GridTransform& g = dag_->grid;
  const float inv_side = float(1.0 / g.side());
  const Vec3 p = (ray.origin - g.origin) * inv_side + Vec3{1, 1, 1};
  const Vec3 d = ray.dir * inv_side;
  return cast_occluded(*dag_, p, d, ray.tmax, lod.size_per_t * inv_side,
                       lod.size_at_origin * inv_side);
}

void DagStructure::attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const {
  if (dag_->has_attributes()) {
    // A coarse (LOD) hit shows the mean of all its leaf voxels (dag.hpp),
    // as an ESVO parent shows its children's average (esvo §5.4).
    if (hit.level < dag_->levels() && hit.voxel_ref < dag_->leaf_voxels)
      dag_->mean_attributes(dag_->cube_range(hit.voxel_ref, hit.level), color, normal);
    else
      dag_->voxel_attributes(hit.voxel_ref, color, normal);
    return;
  }
  // Geometry-only DAG: gray, normal of the entered cube face.
  *color = {0.5f, 0.5f, 0.5f, 1.f};
  Vec3 n{0, 0, 0};
  const int axis = int(hit.child >> 1) % 3;
  n[axis] = (hit.child & 1) ? -1.f : 1.f;
  *normal = n;
}

}  // namespace voxcast::dag
