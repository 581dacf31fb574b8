// DAG packet casting (voxcast/packet_caster.hpp): the octree family's packet
// driver (core/octree_packet_caster.hpp) with the DAG's kernels.
#include <cstdint>

#include "core/frustum_packets.hpp"
#include "core/octree_packet_caster.hpp"
#include "core/packet_kernels.hpp"
#include "dag/octree_nodes.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/packet_caster.hpp"

namespace voxcast {

void trace_packets(const dag::DagStructure& s, const Ray* rays, size_t n, const LodFootprint& lod,
                   SurfaceHit* hits, uint8_t* found, Isa isa, const BeamStart* const* beams) {
  detail::structure_trace_packets<detail::DagNodes>(
      s, s.dag(), isa, &detail::dag_packet_kernel_avx2, &detail::dag_packet_kernel_avx512, rays, n,
      lod, beams, hits, found);
}

void occluded_packets(const dag::DagStructure& s, const Ray* rays, size_t n,
                      const LodFootprint& lod, uint8_t* occluded, Isa isa) {
  detail::structure_packets<detail::DagNodes>(s, s.dag(), isa, &detail::dag_packet_kernel_avx2,
                                              &detail::dag_packet_kernel_avx512, rays, n, lod,
                                              nullptr, true, nullptr, occluded);
}

}  // namespace voxcast
