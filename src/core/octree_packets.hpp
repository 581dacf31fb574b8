#pragma once
// OctreeStructure's packet members (include/voxcast/octree_structure.hpp),
// for the explicit instantiation in each structure's source file
// (src/esvo/traverse.cpp, src/dag/traverse.cpp): the drivers of
// core/octree_packet_caster.hpp, core/frustum_packets.hpp (first hits from
// the tile frustum pass's cube lists) and core/octree_anyhit_caster.hpp over
// Self::world()'s policy, with that policy's kernels (core/packet_kernels.hpp).
// Written once for every octree structure, so that the public functions of
// voxcast/packet_caster.hpp and voxcast/occlusion_packets.hpp are templates
// that only forward here.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "core/frustum_packets.hpp"
#include "core/octree_anyhit_caster.hpp"
#include "core/octree_caster.hpp"
#include "core/octree_packet_caster.hpp"
#include "core/octree_tile_caster.hpp"
#include "core/packet_kernels.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/octree_structure.hpp"
#include "voxcast/packet_caster.hpp"

namespace voxcast {

template <class Self>
void OctreeStructure<Self>::cast_packets(const Ray* rays, size_t n, const LodFootprint& lod,
                                         SurfaceHit* hits, uint8_t* found, Isa isa,
                                         const BeamStart* const* beams) const {
  const Self& self = static_cast<const Self&>(*this);
  using P = typename decltype(self.world())::Nodes;
  detail::structure_trace_packets<P>(self, self.world().source, isa, detail::kPacketKernels<P>,
                                     rays, n, lod, beams, hits, found);
}

template <class Self>
void OctreeStructure<Self>::cast_anyhit(const Ray* rays, size_t n, const LodFootprint& lod,
                                        uint8_t* occluded, const AnyHitOptions& o,
                                        AnyHitStats* stats) const {
  const Self& self = static_cast<const Self&>(*this);
  using P = typename decltype(self.world())::Nodes;
  auto lanes = [&](size_t b, size_t e) {
    if (e > b)
      detail::structure_anyhit<P>(self, self.world().source, o.isa, detail::kPacketKernels<P>,
                                  rays + b, e - b, lod, o.group, o.normals, o.deep_start,
                                  o.path_share, o.cull_budget, occluded + b, stats);
  };
  if (!o.parallel || o.group != 0 || detail::beyond_gathers(self.world().source)) {
    lanes(0, n);
    return;
  }
  // Runs of parallel rays to the shared walk, the rest to the lane kernel.
  detail::require_isa(o.isa, "any-hit packets");
  auto same_dir = [](const Ray& a, const Ray& b) {
    return std::memcmp(&a.dir, &b.dir, sizeof a.dir) == 0;
  };
  size_t rest = 0;  // rays [rest, i) wait for the lane kernel
  for (size_t i = 0; i < n;) {
    size_t j = i + 1;
    while (j < n && same_dir(rays[j], rays[i])) ++j;
    if (j - i >= kParallelRun) {
      lanes(rest, i);
      detail::structure_occluded_parallel<P>(self.world(), o.isa, detail::kTileKernels<P>, rays + i,
                                             j - i, lod, occluded + i);
      if (stats != nullptr) stats->parallel_rays += j - i;
      rest = j;
    }
    i = j;
  }
  lanes(rest, n);
}

template <class Self>
void OctreeStructure<Self>::trace_packets(const Ray* rays, size_t n, const LodFootprint& lod,
                                          TraceContext&, SurfaceHit* hits, uint8_t* found, Isa isa,
                                          const BeamStart* const* beams) const {
  cast_packets(rays, n, lod, hits, found, isa, beams);
}

template <class Self>
void OctreeStructure<Self>::occluded_packets(const Ray* rays, size_t n, const LodFootprint& lod,
                                             TraceContext&, uint8_t* occluded, Isa isa) const {
  AnyHitOptions o;
  o.isa = isa;
  cast_anyhit(rays, n, lod, occluded, o, nullptr);
}

template <class Self>
bool OctreeStructure<Self>::trace_tile(const CameraRays& cam, int x0, int y0, int x1, int y1,
                                       const LodFootprint& lod, TraceContext&, SurfaceHit* hits,
                                       uint8_t* found, Isa isa) const {
  detail::require_isa(isa, "trace_tile");
  const Self& self = static_cast<const Self&>(*this);
  using P = typename decltype(self.world())::Nodes;
  detail::structure_trace_tile<P>(self.world(), isa, detail::kTileKernels<P>, cam, x0, y0, x1, y1,
                                  lod, hits, found);
  return true;
}

template <class Self>
void OctreeStructure<Self>::transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod,
                                                TraceContext& ctx, float* out, int,
                                                const Vec3*) const {
  auto occluded = [&](const Ray* r, size_t m, uint8_t* hit) {
    cast_anyhit(r, m, lod, hit, AnyHitOptions{}, nullptr);
  };
  detail::structure_transmittance_batch(*this, occluded, rays, n, lod, ctx, out);
}

}  // namespace voxcast
