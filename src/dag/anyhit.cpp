// DAG any-hit packets (voxcast/occlusion_packets.hpp): the octree family's
// any-hit driver (core/octree_anyhit_caster.hpp) with the DAG's kernels.
#include <cstdint>

#include "core/anyhit_kernels.hpp"
#include "core/octree_anyhit_caster.hpp"
#include "dag/octree_nodes.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/packet_caster.hpp"

namespace voxcast {

void occluded_anyhit(const dag::DagStructure& s, const Ray* rays, size_t n, const LodFootprint& lod,
                     uint8_t* occluded, const AnyHitOptions& o, AnyHitStats* stats) {
  detail::structure_anyhit<detail::DagNodes>(
      s, s.dag(), o.isa, &detail::dag_anyhit_kernel_avx2, &detail::dag_anyhit_kernel_avx512, rays,
      n, lod, o.group, o.normals, o.deep_start, o.cull_budget, occluded, stats);
}

void dag::DagStructure::transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod,
                                            TraceContext& ctx, float* out, int group,
                                            const Vec3* normals) const {
  (void)group, (void)normals;
  auto occluded = [&](const Ray* r, size_t m, uint8_t* hit) {
    ::voxcast::occluded_packets(*this, r, m, lod, hit);
  };
  ::voxcast::detail::structure_transmittance_batch(*this, occluded, rays, n, lod, ctx, out);
}

}  // namespace voxcast
