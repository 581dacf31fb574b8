// ESVO ray caster (Laine & Karras 2010, §6.1, Appendix A) and the
// EsvoStructure (Structure + SurfaceQuery): the loop, the coarse beam walk (§6.2), the world <->
// octree frame and the profiling counters (§8.5) are the octree family's
// (core/octree_caster.hpp); the ESVO contributes its node access
// (esvo/octree_nodes.hpp: child descriptors with leaf masks and far pointers,
// contours).
#include <algorithm>
#include <cstdint>

#include "core/octree_caster.hpp"
#include "core/octree_packets.hpp"
#include "core/tile_frustum.hpp"
#include "esvo/compress.hpp"
#include "esvo/octree_nodes.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"

namespace voxcast::esvo {
namespace {

using Nodes = ::voxcast::detail::EsvoNodes;

CastResult to_cast_result(const ::voxcast::detail::OctreeCast<Nodes::Index>& r) {
  auto out = ::voxcast::detail::cast_result<CastResult>(r);
  out.parent_slot = r.node;
  out.child = r.child;
  return out;
}

}  // namespace

CastResult cast_ray(const EsvoOctree& octree, Vec3 p, Vec3 d, float tmax, float size_coef,
                    float size_bias) {
  return cast_ray(octree, p, d, tmax, size_coef, size_bias, nullptr, nullptr);
}

CastResult cast_ray(const EsvoOctree& octree, Vec3 p, Vec3 d, float tmax, float size_coef,
                    float size_bias, const Aabb* region, RayCounters* counters) {
  return to_cast_result(::voxcast::detail::cast_octree_counted<Nodes, false>(
      octree, p, d, tmax, size_coef, size_bias, region, counters));
}

// ---------------------------------------------------------------------------

EsvoStructure::EsvoStructure(std::shared_ptr<const EsvoOctree> octree)
    : octree_(std::move(octree)) {
  if (!octree_) throw Error("EsvoStructure: no octree");
  if (octree_->words.size() < 4) throw Error("EsvoStructure: empty octree");
  if (!(octree_->grid.side() > 0)) throw Error("EsvoStructure: octree has a non-positive side");
}

::voxcast::detail::OctreeWorld<Nodes> EsvoStructure::world() const {
  return ::voxcast::detail::OctreeWorld<Nodes>(*octree_);
}

uint64_t EsvoStructure::attribute_bytes_per_hit() const {
  return octree_->attribute_format() == AttributeFormat::Compressed
             ? uint64_t(detail::kCompressedBlockWords) * 4
             : 4 + 8;
}

void EsvoStructure::attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                               Vec3* normal) const {
  // Bytes of the attachment read per hit. Raw (§5.4, Figure 7): one 32-bit
  // lookup entry and one 64-bit value. Compressed (§5.5): the compression
  // block holding the voxel. (Page header and info section reads are
  // per-block metadata that stays cached; they are not counted.) Counted
  // before the fetch so that the fetch is a tail call on the plain path.
  if (ctx.counting) ctx.counters.attribute_bytes += attribute_bytes_per_hit();
  octree_->attributes(uint32_t(hit.voxel_ref), int(hit.child), color, normal);
}

void EsvoStructure::attributes_batch(const SurfaceHit* const* hits, int n, TraceContext& ctx,
                                     Color* colors, Vec3* normals) const {
  if (ctx.counting)
    ctx.counters.attribute_bytes += uint64_t(std::max(n, 0)) * attribute_bytes_per_hit();
  constexpr int kChunk = 64;
  uint32_t slots[kChunk];
  uint8_t children[kChunk];
  for (int i0 = 0; i0 < n; i0 += kChunk) {
    const int m = std::min(kChunk, n - i0);
    for (int i = 0; i < m; ++i) {
      slots[i] = uint32_t(hits[i0 + i]->voxel_ref);
      children[i] = uint8_t(hits[i0 + i]->child);
    }
    octree_->attributes(slots, children, size_t(m), colors + i0, normals + i0);
  }
}

void EsvoStructure::prefetch_attribute_index(const SurfaceHit& hit) const {
  octree_->prefetch_attribute_entry(uint32_t(hit.voxel_ref));
}

void EsvoStructure::prefetch_attributes(const SurfaceHit& hit) const {
  octree_->prefetch_attribute_value(uint32_t(hit.voxel_ref), int(hit.child));
}

}  // namespace voxcast::esvo

namespace voxcast {
template class OctreeStructure<esvo::EsvoStructure>;
}  // namespace voxcast
