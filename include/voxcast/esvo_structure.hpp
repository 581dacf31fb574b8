#pragma once
// ESVO as a Structure with a SurfaceQuery, and the raw ray caster (esvo §6.1,
// Appendix A).
#include <memory>

#include "voxcast/esvo.hpp"
#include "voxcast/octree_structure.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {
struct EsvoNodes;  // its node-access policy, src/esvo/octree_nodes.hpp
}  // namespace voxcast::detail

namespace voxcast::esvo {

/// Ray in octree space (root cube [1,2]^3) and the result of a cast.
struct CastResult {
  float t;               // hit t (same parameterization as the input ray); +inf on a miss
  Vec3 pos;              // min corner of the hit cube, octree space
  uint32_t parent_slot;  // descriptor slot of the hit voxel's parent
  int child;             // child slot index of the hit voxel in its parent
  int scale;             // hit cube side = 2^(scale - kMaxScale)
  bool hit;              // authoritative hit flag (t of a hit can be any value in [0, tmax])
};

/// Appendix A, ported (the octree family's loop, src/core/octree_caster.hpp,
/// over the ESVO's descriptors): `origin`/`dir` in octree space, t in [0, tmax].
/// LOD: terminate at a voxel whose side (octree units) <= size_coef * t + size_bias
/// (t = the voxel's exit t, as in the listing); 0, 0 = always the finest level.
/// Non-finite origin/direction: miss. Direction components below 2^-23 are
/// replaced by +-2^-23 (sign kept, also for -0.0), as in the listing.
CastResult cast_ray(const EsvoOctree& octree, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias);

/// cast_ray with the beam optimization and profiling counters (esvo §6.2,
/// §8.5). `region` (octree space, may be null = the root cube): a box that is
/// known to contain every voxel the ray can hit, typically the result of
/// EsvoStructure::beam_start; the ray starts at its entry and stops at its
/// exit, computed with the caster's own plane arithmetic, so the result equals
/// cast_ray's bit for bit. `counters` (may be null) accumulates Table 6 counts.
CastResult cast_ray(const EsvoOctree& octree, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias, const Aabb* region, RayCounters* counters);

class EsvoStructure final : public OctreeStructure<EsvoStructure> {
 public:
  explicit EsvoStructure(std::shared_ptr<const EsvoOctree> octree);
  // bounds, surface, trace, transmittance, beam_start: the octree family's
  // (octree_structure.hpp); SurfaceHit::voxel_ref = the parent's descriptor
  // slot, child = the slot in it.
  /// The hit voxel's attributes; while ctx.counting, adds the attachment
  /// bytes it reads (raw: a 32-bit lookup entry and a 64-bit value, esvo §5.4;
  /// compressed: the voxel's block, §5.5).
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override;
  /// Raw attributes are a lookup entry, then the value it points to:
  /// prefetch_attribute_index starts the entry's read, prefetch_attributes
  /// the value's (EsvoOctree::prefetch_attribute_entry / _value).
  void prefetch_attribute_index(const SurfaceHit& hit) const override;
  void prefetch_attributes(const SurfaceHit& hit) const override;
  /// The hits' attributes together (EsvoOctree::attributes of many slots).
  void attributes_batch(const SurfaceHit* const* hits, int n, TraceContext& ctx, Color* colors,
                        Vec3* normals) const override;
  std::string name() const override { return "esvo"; }
  const EsvoOctree& octree() const { return *octree_; }

 private:
  friend class OctreeStructure<EsvoStructure>;
  ::voxcast::detail::OctreeWorld<::voxcast::detail::EsvoNodes> world() const;
  /// What attributes() counts per hit (ctx.counting).
  uint64_t attribute_bytes_per_hit() const;

  std::shared_ptr<const EsvoOctree> octree_;
};

}  // namespace voxcast::esvo
