#pragma once
// The octree family of voxel structures (ESVO octree, sparse voxel DAG; a
// streamed ESVO later): structures in the [1,2]^3 octree space of esvo §6.1
// that share one ray caster, the Appendix A loop of src/core/octree_caster.hpp
// over a node-access policy. Deriving from OctreeStructure<Self> makes a
// structure a Structure whose surface() is itself, with the SurfaceQuery
// tracing methods (trace, transmittance, beam_start) from that caster; Self
// supplies attributes() and `world()` (its policy and grid), declared private
// with OctreeStructure<Self> as a friend, and instantiates the template in
// its own source file (src/esvo/traverse.cpp, src/dag/traverse.cpp), which
// also include the packet casters' members (src/core/octree_packets.hpp).
//
// The counting instantiation of the caster (esvo §8.5 counters) is chosen
// once per call from TraceContext::counting; the plain instantiation has no
// counter code in its loop.
#include "voxcast/structure.hpp"
#include "voxcast/surface_query.hpp"

namespace voxcast {

namespace detail {
template <class Nodes>
struct OctreeWorld;  // what Self::world() returns: src/core/octree_caster.hpp
}  // namespace detail

struct AnyHitOptions;  // voxcast/occlusion_packets.hpp
struct AnyHitStats;

// SurfaceQuery is the first base: the renderer calls trace() and
// attributes() through a SurfaceQuery pointer once per ray, and at offset 0
// those calls need no this-adjusting thunk (Structure's methods run once per
// frame, SurfacePackets' once per queue of rays).
template <class Self>
class OctreeStructure : public SurfaceQuery, public Structure, public SurfacePackets {
 public:
  /// World-space bounds of the root cube.
  Aabb bounds() const override;
  /// An in-core octree answers every surface query; it has no volume query
  /// and ignores the frame loop (it never pushes a request).
  const SurfaceQuery* surface() const override { return this; }
  /// First hit (esvo §6.1, Appendix A), LOD stop from the footprint; `beam`
  /// starts the ray at the region of the coarse pass (esvo §6.2; bit-identical
  /// hits). Counts into ctx.counters while ctx.counting.
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override;
  /// 0 or 1: the same loop stopped at the first hit, without the hit's
  /// position or attribute handle (shadow and AO rays); `beam` clips it as in
  /// trace(), with the same answer.
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam = nullptr) const override;
  /// Coarse pass of the beam optimization (esvo §6.2, core/beam_frustum.hpp).
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const override;
  /// The tile frustum pass (core/tile_frustum.hpp): the cube list and its region.
  void frustum_start(const BeamFrustum& beam, int octant, TraceContext& ctx, BeamStart* start,
                     const BeamStart* within = nullptr) const override;
  /// Every octree structure has the packet casters (voxcast/packet_caster.hpp).
  const SurfacePackets* packets() const override { return this; }
  /// voxcast::trace_packets / occluded_packets on Self (bit-identical to
  /// trace() / occluded()); ctx is not used (packets do not count).
  void trace_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                     SurfaceHit* hits, uint8_t* found, Isa isa,
                     const BeamStart* const* beams = nullptr) const override;
  void occluded_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                        uint8_t* occluded, Isa isa) const override;
  /// The tile caster (core/octree_tile_caster.hpp): one walk of the tree per
  /// 16 x 16 pixels, hits bit-identical to trace(); ctx is not used.
  bool trace_tile(const CameraRays& cam, int x0, int y0, int x1, int y1, const LodFootprint& lod,
                  TraceContext& ctx, SurfaceHit* hits, uint8_t* found, Isa isa) const override;
  /// occluded_packets for the active ISA; the scalar caster while
  /// ctx.counting (the Table 6 counters). The same values as transmittance().
  void transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                           float* out, int group = 0, const Vec3* normals = nullptr) const override;

  /// What the free functions of voxcast/packet_caster.hpp and
  /// voxcast/occlusion_packets.hpp call (src/core/octree_packets.hpp).
  void cast_packets(const Ray* rays, size_t n, const LodFootprint& lod, SurfaceHit* hits,
                    uint8_t* found, Isa isa, const BeamStart* const* beams) const;
  void cast_anyhit(const Ray* rays, size_t n, const LodFootprint& lod, uint8_t* occluded,
                   const AnyHitOptions& o, AnyHitStats* stats) const;
};

}  // namespace voxcast
